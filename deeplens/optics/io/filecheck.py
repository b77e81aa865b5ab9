"""Reading a lens or glass file's bytes safely: a regular file of a sane size.

A path handed to a reader may be a symbolic link to ``/dev/zero`` (read until memory runs out),
a FIFO (``open`` blocks until a writer comes, forever), a directory or a multi-gigabyte file
named by mistake.  :func:`read_file_bytes` resolves symbolic links, refuses anything but a
regular file (``os.stat`` + ``stat.S_ISREG``, before opening it) and a file larger than
:data:`MAX_FILE_BYTES`, and reads at most that many bytes (a file growing while it is read is
refused too).  Every lens and glass reader (JSON, the paper authors' tables, ``.zmx``,
``.agf``) reads through it.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ..errors import LensFileError

__all__ = ["MAX_FILE_BYTES", "read_file_bytes"]

MAX_FILE_BYTES = 64 * 2 ** 20
"""Largest lens or glass file read (64 MiB): real ones are kilobytes (a vendor's ``.agf``
catalogue a few hundred kB, the largest ``.zmx`` of the test corpus 200 kB)."""

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISSOCK, "a socket"))


def read_file_bytes(path, what: str = "lens file") -> bytes:
    """The bytes of the regular file ``path`` (symbolic links followed).

    Args:
        path: the file.
        what: what it should be, for messages (``"lens file"``, ``"glass catalogue"``).

    Raises:
        FileNotFoundError: no such file (or a dangling symbolic link).
        LensFileError: not a regular file (names what it is, and the link's target), or larger
            than :data:`MAX_FILE_BYTES` (names its size); ``source`` is ``path``.
    """
    path = Path(path)
    try:
        st = os.stat(path)   # follows symbolic links: the target is what would be read
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    if not stat.S_ISREG(st.st_mode):
        kind = next((k for test, k in _KINDS if test(st.st_mode)), "not a regular file")
        target = f" (a symbolic link to {os.path.realpath(path)})" if path.is_symlink() else ""
        raise LensFileError(f"is {kind}{target}, not a regular file: a {what} must be a "
                            f"regular file", source=path)
    too_big = (f"is larger than {MAX_FILE_BYTES} bytes ({MAX_FILE_BYTES >> 20} MiB), the limit "
               f"for a {what} (real ones are kilobytes): not a {what}?")
    if st.st_size > MAX_FILE_BYTES:
        raise LensFileError(f"{st.st_size} bytes: {too_big}", source=path)
    with open(path, "rb") as f:
        data = f.read(MAX_FILE_BYTES + 1)
    if len(data) > MAX_FILE_BYTES:
        raise LensFileError(f"grew while being read: {too_big}", source=path)
    return data
