"""SIGTERM and SIGINT stop training between two steps, save the state, and exit non-zero.

A scheduler (Slurm, Kubernetes, systemd) ends a job with SIGTERM; a user presses Ctrl-C (SIGINT).
Lightning's own handling exits with status 0 on SIGTERM (its ``SIGTERMException`` is a
``SystemExit`` without a code), so a scheduler would record success, and stops Ctrl-C wherever the
step happens to be.  Here both signals only raise Lightning's stop flag: the step under way
finishes, :class:`~deeplens.training.callbacks.LensCheckpoint` saves that state to
``last.ckpt`` (a mid-epoch checkpoint that resumes exactly, see
:class:`~deeplens.data.datamodule.EpochLoader`), and :func:`stopped_by_signal` turns the
stop into :class:`StoppedBySignal` with the conventional status ``128 + signal number`` (143 for
SIGTERM, 130 for SIGINT) and a message naming the checkpoint and the command to resume.  A
second Ctrl-C interrupts at once (Python's ``KeyboardInterrupt``).
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

__all__ = ["StoppedBySignal", "stopped_by_signal"]


class StoppedBySignal(SystemExit):
    """Training was stopped by a signal; ``code`` is ``128 + signum``, ``checkpoint`` the
    resumable checkpoint (or ``None``)."""

    def __init__(self, message: str, signum: int, checkpoint: str | None):
        super().__init__(128 + signum)
        self.message, self.signum, self.checkpoint = message, signum, checkpoint

    def __str__(self) -> str:
        return self.message


@contextlib.contextmanager
def stopped_by_signal(trainer):
    """While fitting: SIGTERM and SIGINT ask ``trainer`` to stop after the current step; on
    leaving, Lightning's stop (``SIGTERMException``) becomes :class:`StoppedBySignal`.
    Outside the main thread (no signal handlers there) it only does the latter."""
    from lightning.pytorch.utilities.exceptions import SIGTERMException

    received: list[int] = []
    old = {}

    def handler(signum, frame):
        received.append(signum)
        trainer._signal_connector.received_sigterm = True
        if signum == signal.SIGINT:  # a second Ctrl-C interrupts at once
            signal.signal(signal.SIGINT, signal.default_int_handler)

    if threading.current_thread() is threading.main_thread():
        for s in (signal.SIGTERM, signal.SIGINT):
            old[s] = signal.getsignal(s)
            signal.signal(s, handler)
    try:
        yield
    except SIGTERMException:
        signum = received[0] if received else signal.SIGTERM
        cb = trainer.checkpoint_callback
        path = (cb.last_model_path or None) if cb is not None else None
        where = (f"the resumable checkpoint (step {trainer.global_step}) is {path}; resume with "
                 f"ckpt_path={path}" if path else
                 "no checkpoint was configured (callbacks.model_checkpoint): nothing to resume")
        stop = StoppedBySignal(f"deeplens: training stopped by {signal.Signals(signum).name} "
                               f"after step {trainer.global_step}; {where}", signum, path)
        if trainer.is_global_zero:
            print(stop.message, file=sys.stderr, flush=True)
        raise stop from None
    finally:
        for s, h in old.items():
            signal.signal(s, h)
