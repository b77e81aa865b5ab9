"""Atomic file writes: a temporary file beside the target, renamed over it.

Every file deeplens writes atomically (checkpoints and their ``.sha256``, lens files, eval
tables, ``deeplens optimize --out``) goes through :func:`temp_path` and :func:`replace`:

* the temporary file is ``<name>.<8 random characters>.tmp`` beside the target
  (:func:`tempfile.mkstemp`: a name no other writer uses);
* :func:`replace` gives it the mode any other new file would get, ``0o666`` less the process's
  umask (``mkstemp`` creates ``0o600``), or the mode of the file it replaces (as writing into
  an existing file keeps its mode), then renames it over the target;
* a writer killed between the two leaves its temporary file behind: :func:`temp_path` first
  removes those of the same target (:func:`clean_stale_temps`): names of exactly that pattern,
  untouched for :data:`STALE_AFTER_S` seconds (a live writer's file is written to and renamed
  within seconds), never any other file.
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
import tempfile
import time
from pathlib import Path

__all__ = ["STALE_AFTER_S", "clean_stale_temps", "current_umask", "replace", "temp_path"]

STALE_AFTER_S = 600.0
"""A temporary file of our pattern untouched this long (s) was left by a killed writer."""

# mkstemp's random part: 8 characters of tempfile._RandomNameSequence's alphabet
_RANDOM = r"[a-z0-9_]{8}"


def current_umask() -> int:
    """The process's umask, read from ``/proc/self/status`` where the kernel reports it (Linux
    4.7+), else by setting and restoring it."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def clean_stale_temps(path, older_than_s: float = STALE_AFTER_S) -> list[Path]:
    """Remove the temporary files a killed writer of ``path`` left: ``<name>.<8 chars>.tmp``
    beside it, not modified for ``older_than_s`` seconds.  Returns the files removed; a file
    that cannot be removed is left (never an error)."""
    path = Path(path)
    pattern = re.compile(re.escape(path.name) + r"\." + _RANDOM + r"\.tmp")
    now, gone = time.time(), []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return gone
    for e in entries:
        if not pattern.fullmatch(e.name):
            continue
        with contextlib.suppress(OSError):
            st = e.stat(follow_symlinks=False)
            if stat.S_ISREG(st.st_mode) and now - st.st_mtime > older_than_s:
                os.unlink(e.path)
                gone.append(Path(e.path))
    return gone


def temp_path(path) -> Path:
    """A new, empty temporary file beside ``path`` (``<name>.<random>.tmp``, a name no other
    writer uses), after removing stale ones of the same target (:func:`clean_stale_temps`)."""
    path = Path(path)
    clean_stale_temps(path)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    os.close(fd)
    return Path(tmp)


def replace(tmp, path) -> None:
    """Rename ``tmp`` over ``path`` with the mode a plain write would leave: ``path``'s own
    if it exists, else ``0o666`` less the umask."""
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        mode = 0o666 & ~current_umask()
    os.chmod(tmp, mode)
    os.replace(tmp, path)
