"""What a training or evaluation run prints: each log line once, without Lightning's
advertising tips and without the known warnings that say nothing about the user's run.

Lightning adds its own console handler to the ``lightning`` logger when it is imported
(``INFO: ...``); Hydra then configures the root logger with its own (``[time][name][INFO] -
...``), and every Lightning line is printed by both.  :func:`quiet_console` removes
Lightning's console handlers once the root logger has one (its lines then reach the console,
and Hydra's log file, once), drops the records of :data:`NOISY_RECORDS` and ignores the
warnings of :data:`NOISY_WARNINGS`: each a message pattern, never a whole category, so any
other warning is still shown.
"""

from __future__ import annotations

import contextlib
import logging
import re
import sys
import warnings

__all__ = ["NOISY_RECORDS", "NOISY_WARNINGS", "quiet_console"]

#: log messages (regular expressions, matched at the start) that are advertising, not news
NOISY_RECORDS = (
    r"💡 Tip",                      # "For seamless cloud logging ... try installing litlogger"
)
#: warning messages (regular expressions) known to say nothing about a deeplens run
NOISY_WARNINGS = (
    # Lightning's own use of torch's pytree API (torch >= 2.9), not the user's code
    r".*isinstance\(treespec, LeafSpec\)` is deprecated",
    # the training stream splits its items over workers itself (data/datamodule.py), so its
    # length is exact for any number of workers
    r"Your `IterableDataset` has `__len__` defined",
    # torch's own forward-mode AD loads its decompositions with torch.jit.script (torch >= 2.9)
    r"`torch.jit.script` is deprecated",
)
_LIGHTNING_LOGGERS = ("lightning", "lightning.pytorch", "lightning.fabric")


class _DropNoisy(logging.Filter):
    def __init__(self):
        super().__init__("deeplens.quiet")
        self._re = re.compile("|".join(f"(?:{p})" for p in NOISY_RECORDS))

    def filter(self, record: logging.LogRecord) -> bool:
        return not self._re.match(str(record.getMessage()))


def _is_console(h: logging.Handler) -> bool:
    return (type(h) is logging.StreamHandler
            and getattr(h, "stream", None) in (sys.stderr, sys.stdout, sys.__stderr__,
                                               sys.__stdout__))


@contextlib.contextmanager
def quiet_console():
    """For the duration of a run: Lightning's lines once (through the root logger's handlers
    when it has any), none of :data:`NOISY_RECORDS`, none of :data:`NOISY_WARNINGS`.  Restores
    the loggers and warning filters afterwards."""
    root = logging.getLogger()
    saved = []
    drop = _DropNoisy()
    if root.handlers:
        for name in _LIGHTNING_LOGGERS:
            lg = logging.getLogger(name)
            saved.append((lg, list(lg.handlers), lg.propagate))
            for h in [h for h in lg.handlers if _is_console(h)]:
                lg.removeHandler(h)
            lg.propagate = True
    handlers = list(root.handlers) + [h for name in _LIGHTNING_LOGGERS
                                      for h in logging.getLogger(name).handlers]
    for h in handlers:
        h.addFilter(drop)
    try:
        with warnings.catch_warnings():
            for pattern in NOISY_WARNINGS:
                warnings.filterwarnings("ignore", message=pattern)
            yield
    finally:
        for h in handlers:
            h.removeFilter(drop)
        for lg, hs, prop in saved:
            for h in hs:
                if h not in lg.handlers:
                    lg.addHandler(h)
            lg.propagate = prop
