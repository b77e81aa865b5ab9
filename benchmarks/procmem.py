"""Process memory for the benchmarks (Linux): current and peak resident set size, and glibc's
malloc thresholds.

Shared by the benchmark scripts, which import it from their own folder (``python
benchmarks/bench_*.py`` puts that folder first on ``sys.path``).
"""

from __future__ import annotations

import os
import resource
import sys

__all__ = ["rss_bytes", "maxrss_bytes", "reset_peak_rss", "set_malloc_thresholds"]


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


def set_malloc_thresholds(mmap_threshold: int, trim_threshold: int) -> None:
    """glibc's ``M_MMAP_THRESHOLD`` and ``M_TRIM_THRESHOLD`` (bytes), then ``malloc_trim(0)``: small
    ones make the RSS follow the live memory (for memory readings), large ones let glibc recycle
    tensors in its heap (for timings).  Nothing where there is no glibc."""
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, mmap_threshold)   # M_MMAP_THRESHOLD
        libc.mallopt(-1, trim_threshold)   # M_TRIM_THRESHOLD
        libc.malloc_trim(0)
    except (OSError, AttributeError):
        pass
