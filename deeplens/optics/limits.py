"""Sizes set by user input, checked before anything is allocated.

A count typed by a user (rays per pixel, an image size, a pupil sampling such as
``hexapolar:3000``, a surface index) decides how much memory a run allocates.  A typo there must
give an error naming the key and the memory it would need, not an allocator traceback or the
operating system's out-of-memory killer.  :func:`check_allocation` compares the bytes a request
needs (``items x bytes_per_item``, the *lower bound* of what the code then allocates) with the
memory budget:

* ``DEEPLENS_MEMORY_BUDGET`` (environment; bytes, or with a ``K``/``M``/``G``/``T`` suffix) when
  set, else the machine's physical memory (``os.sysconf``), else 64 GiB.

Only requests that cannot fit are refused: a request below the budget may still be slow.
"""

from __future__ import annotations

import os

__all__ = ["MemoryBudgetError", "check_allocation", "format_bytes", "memory_budget_bytes"]

_SUFFIX = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


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


def memory_budget_bytes() -> int:
    """The memory a single request may take: ``DEEPLENS_MEMORY_BUDGET`` or physical memory."""
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
        return int(value)
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):  # not POSIX
        return 64 << 30


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
    budget = memory_budget_bytes()
    if needed > budget:
        raise MemoryBudgetError(
            f"{key}: {items:,} {what} would need at least {format_bytes(needed)} of memory, "
            f"more than this machine's {format_bytes(budget)} (DEEPLENS_MEMORY_BUDGET or "
            f"physical memory); check the value", key, needed, budget)
    return needed
