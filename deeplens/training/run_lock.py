"""One live run per output folder: an advisory lock on ``<output folder>/.deeplens.lock``.

Two runs writing one folder would interleave their checkpoints (``last.ckpt`` of one, the
optimiser state of the other) and their TensorBoard event files.  :func:`hold_output_folder`
takes an exclusive ``flock`` on the lock file for the run's duration; a second run asking for
the same folder is refused at once with the holder's process id and host.  The operating system
drops the lock when its process ends, however it ends (kill -9, out of memory), so a crashed run
never leaves a stale lock behind; the file itself stays, holding the last holder's id.
"""

from __future__ import annotations

import contextlib
import os
import socket
from pathlib import Path

__all__ = ["FolderInUseError", "LOCK_NAME", "hold_output_folder"]

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
