"""Process memory for the benchmarks (Linux): current and peak resident set size.

Shared by the benchmark scripts, which import it from their own folder (``python
benchmarks/bench_*.py`` puts that folder first on ``sys.path``).
"""

from __future__ import annotations

import os
import resource
import sys

__all__ = ["rss_bytes", "maxrss_bytes", "reset_peak_rss"]


def rss_bytes() -> int:
    """Current resident set size (bytes), Linux; ``-1`` elsewhere."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return -1


def maxrss_bytes() -> int:
    """Peak resident set size (bytes) since start or the last :func:`reset_peak_rss`."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r if sys.platform == "darwin" else r * 1024


def reset_peak_rss() -> bool:
    """Reset the kernel's RSS high-water mark (Linux >= 4.0); False if not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return False
    return maxrss_bytes() <= rss_bytes() + 4 * 1024 * 1024
