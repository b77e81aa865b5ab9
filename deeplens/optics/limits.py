"""Sizes set by user input, checked before anything is allocated.

A count typed by a user (rays per pixel, an image size, a pupil sampling such as
``hexapolar:3000``, a surface index) decides how much memory a run allocates.  A typo there must
give an error naming the key and the memory it would need, not an allocator traceback or the
operating system's out-of-memory killer.  :func:`check_allocation` compares the bytes a request
needs (``items x bytes_per_item``, the *lower bound* of what the code then allocates) with the
memory budget:

* ``DEEPLENS_MEMORY_BUDGET`` (environment; bytes, or with a ``K``/``M``/``G``/``T`` suffix) when
  set, else the smallest of the machine's physical memory (``os.sysconf``), what is left under
  the process's address-space limit (``ulimit -v``, ``RLIMIT_AS``, less what the process already
  maps) and the memory limit of its cgroup (v2 ``memory.max``, v1 ``memory.limit_in_bytes``, of
  its own cgroup and their ancestors: a Slurm job's ``--mem``, a container's ``--memory``), else
  64 GiB.  The message names which of them refused, so that the setting to change is known.

Only requests that cannot fit are refused: a request below the budget may still be slow.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["MemoryBudgetError", "check_allocation", "format_bytes", "memory_budget",
           "memory_budget_bytes"]

_SUFFIX = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
# cgroup v1 writes "no limit" as a huge number (2^63 rounded down to a page)
_NO_CGROUP_LIMIT = 1 << 60


class MemoryBudgetError(ValueError):
    """A size set by user input would need more memory than the machine has; ``key`` names the
    setting, ``needed`` and ``budget`` are bytes."""

    def __init__(self, message: str, key: str, needed: int, budget: int):
        super().__init__(message)
        self.key, self.needed, self.budget = key, needed, budget


def format_bytes(n: float) -> str:
    """``1.5 GiB``-style text of a byte count."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"  # pragma: no cover


def _physical() -> tuple[int, str] | None:
    try:
        return (int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")),
                "this machine's physical memory")
    except (AttributeError, ValueError, OSError):  # not POSIX
        return None


def _mapped_bytes() -> int:
    """The address space this process already maps (``/proc/self/statm``; 0 where unknown)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError, AttributeError):
        return 0


def _address_space() -> tuple[int, str] | None:
    """What is left under the process's address-space limit (``ulimit -v``, ``RLIMIT_AS``):
    the soft limit less what the process already maps."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, AttributeError, ValueError, OSError):  # not POSIX
        return None
    if soft == resource.RLIM_INFINITY or soft < 0:
        return None
    used = _mapped_bytes()
    return (max(soft - used, 0),
            f"this process's address-space limit (ulimit -v / RLIMIT_AS: {format_bytes(soft)}, "
            f"{format_bytes(used)} of it already mapped; raise it with ulimit -v)")


def _read_limit(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
        value = int(text)
    except (OSError, ValueError):   # absent, unreadable, or "max" (cgroup v2: no limit)
        return None
    return value if 0 < value < _NO_CGROUP_LIMIT else None


def _cgroup_files(root: Path, self_cgroup: Path) -> list[Path]:
    """The memory-limit files of this process's cgroups and of their ancestors (the tightest
    one applies): cgroup v2 ``memory.max``, v1 ``memory.limit_in_bytes``."""
    try:
        lines = self_cgroup.read_text().splitlines()
    except OSError:
        lines = []
    files = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        hid, controllers, rel = parts
        if hid == "0" and controllers == "":   # v2 (unified, or the hybrid's unified mount)
            bases = [(root, "memory.max"), (root / "unified", "memory.max")]
        elif "memory" in controllers.split(","):  # v1
            bases = [(root / "memory", "memory.limit_in_bytes")]
        else:
            continue
        for base, name in bases:
            d = base / rel.strip("/") if rel.strip("/") else base
            while True:
                files.append(d / name)
                if d == base or base not in d.parents:
                    break
                d = d.parent
    files += [root / "memory.max", root / "memory" / "memory.limit_in_bytes"]
    return list(dict.fromkeys(files))


def _cgroup(root: Path = Path("/sys/fs/cgroup"),
            self_cgroup: Path = Path("/proc/self/cgroup")) -> tuple[int, str] | None:
    """The tightest cgroup memory limit of this process (``None``: none set or unreadable)."""
    found = [(v, f) for f in _cgroup_files(root, self_cgroup)
             if (v := _read_limit(f)) is not None]
    if not found:
        return None
    value, f = min(found, key=lambda t: t[0])
    return value, (f"the cgroup memory limit in {f} (a Slurm job's --mem, a container's "
                   f"--memory; raise it there)")


def memory_budget() -> tuple[int, str]:
    """``(bytes, where the budget comes from)``: ``DEEPLENS_MEMORY_BUDGET`` when set, else the
    smallest of the machine's physical memory, what is left under the process's address-space
    limit (``ulimit -v``) and its cgroup's memory limit (Slurm ``--mem``, a container's
    ``--memory``), else 64 GiB."""
    text = os.environ.get("DEEPLENS_MEMORY_BUDGET", "").strip().upper().removesuffix("B")
    if text:
        unit = text[-1] if text[-1] in _SUFFIX else ""
        try:
            value = float(text[:-1] if unit else text) * _SUFFIX[unit]
        except ValueError:
            raise ValueError(f"DEEPLENS_MEMORY_BUDGET: expected bytes such as 8G or 2000000000, "
                             f"got {os.environ['DEEPLENS_MEMORY_BUDGET']!r}") from None
        if not value > 0:
            raise ValueError(f"DEEPLENS_MEMORY_BUDGET: expected a size > 0, got {text!r}")
        return int(value), "DEEPLENS_MEMORY_BUDGET (environment)"
    limits = [x for x in (_physical(), _address_space(), _cgroup()) if x is not None]
    if not limits:
        return 64 << 30, "the default budget of 64 GiB (set DEEPLENS_MEMORY_BUDGET)"
    return min(limits, key=lambda t: t[0])


def memory_budget_bytes() -> int:
    """The memory a single request may take (bytes; :func:`memory_budget`)."""
    return memory_budget()[0]


def check_allocation(key: str, items: int, bytes_per_item: int, what: str) -> int:
    """Raise :class:`MemoryBudgetError` when ``items x bytes_per_item`` exceeds the budget.

    Args:
        key: the setting that chose the size (named in the message), e.g. ``"render.spp"``.
        items: how many items the request allocates (exact Python int, no overflow).
        bytes_per_item: bytes per item (a lower bound of what the code allocates per item).
        what: what the items are, e.g. ``"rays of one render chunk"``.

    Returns:
        The bytes needed.
    """
    needed = int(items) * int(bytes_per_item)
    budget, source = memory_budget()
    if needed > budget:
        raise MemoryBudgetError(
            f"{key}: {items:,} {what} would need at least {format_bytes(needed)} of memory, "
            f"more than the {format_bytes(budget)} this process may use, set by {source}; "
            f"check the value", key, needed, budget)
    return needed
