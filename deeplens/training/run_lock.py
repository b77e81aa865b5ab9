"""One live run per output folder: an advisory lock on ``<output folder>/.deeplens.lock``.

Two runs writing one folder would interleave their checkpoints (``last.ckpt`` of one, the
optimiser state of the other) and their TensorBoard event files.  :func:`hold_output_folder`
takes an exclusive ``flock`` on the lock file for the run's duration; a second run asking for
the same folder is refused at once with the holder's process id and host.  The operating system
drops the lock when its process ends, however it ends (kill -9, out of memory), so a crashed run
never leaves a stale lock behind; the file itself stays, holding the last holder's id.

``deeplens train`` takes the lock before Hydra writes anything into the folder: Hydra saves
``.hydra/config.yaml``, ``hydra.yaml`` and ``overrides.yaml`` before it calls the task, so a
lock taken by the task came after a second run had overwritten the live run's records.  The
Hydra callback :class:`OutputFolderLock` (``hydra.callbacks.output_folder_lock`` in
``configs/train.yaml``) holds the folder from ``on_run_start`` (before the job's folder is
written) to ``on_run_end``; :func:`held_by_hydra` tells :func:`~.train.train` not to lock it a
second time.
"""

from __future__ import annotations

import contextlib
import os
import socket
from pathlib import Path

__all__ = ["FolderInUseError", "LOCK_NAME", "OutputFolderLock", "RunRefused", "held_by_hydra",
           "hold_output_folder"]

LOCK_NAME = ".deeplens.lock"


class FolderInUseError(RuntimeError):
    """Another live run holds the output folder; ``path`` is the folder."""

    def __init__(self, message: str, path: Path):
        super().__init__(message)
        self.path = path


@contextlib.contextmanager
def hold_output_folder(folder):
    """Hold ``folder`` (created if needed) for one run; raises :class:`FolderInUseError` if a
    live process holds it.  Without ``fcntl`` (Windows) nothing is locked."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "unknown"
            raise FolderInUseError(
                f"output folder {folder} is in use by another live run ({holder}): two runs in "
                f"one folder would mix checkpoints and TensorBoard logs; give this run its own "
                f"folder (hydra.run.dir=...) or wait for that one to end", folder) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


try:
    from hydra.experimental.callback import Callback as _HydraCallback
except ImportError:  # pragma: no cover - hydra is a dependency of training
    _HydraCallback = object

#: the key of :class:`OutputFolderLock` under ``hydra.callbacks``
CALLBACK_KEY = "output_folder_lock"


class RunRefused(SystemExit):
    """The exit of a run refused before Hydra wrote anything (:class:`OutputFolderLock`):
    status 1, the message ``error: <why>`` on stderr; ``error`` is the
    :class:`FolderInUseError`."""

    def __init__(self, error: FolderInUseError):
        super().__init__(f"error: {error}")
        self.error = error


class OutputFolderLock(_HydraCallback):
    """Hydra callback: hold the run's output folder (``hydra.run.dir``) from before Hydra
    writes into it until the run ends (module docstring).  Single runs only; the jobs of a
    multirun each lock their own folder in :func:`~.train.train`."""

    def __init__(self):
        self._held = None

    def on_run_start(self, config, **kwargs) -> None:
        from omegaconf import OmegaConf

        # the same config object Hydra then runs: a ${now:...} in the folder's name resolves
        # (cached) to the same time
        folder = os.path.abspath(str(OmegaConf.select(config, "hydra.run.dir")))
        stack = contextlib.ExitStack()
        try:
            stack.enter_context(hold_output_folder(folder))
        except FolderInUseError as e:
            # Hydra turns a callback's exception into a warning and goes on to write the
            # folder and run the task: only an exit stops it before it writes anything
            raise RunRefused(e) from None
        self._held = stack

    def on_run_end(self, config, **kwargs) -> None:
        if self._held is not None:
            self._held.close()
            self._held = None


def held_by_hydra(folder) -> bool:
    """Whether :class:`OutputFolderLock` holds ``folder`` for this process: a Hydra single run
    with the callback configured whose output folder is ``folder``."""
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode
    except ImportError:  # pragma: no cover
        return False
    if not HydraConfig.initialized():
        return False
    hc = HydraConfig.get()
    callbacks = hc.get("callbacks") or {}
    out = hc.runtime.get("output_dir")
    return (hc.mode == RunMode.RUN and CALLBACK_KEY in callbacks and out is not None
            and Path(out).resolve() == Path(folder).resolve())
