"""``load_lens``: read a lens file of any supported format, chosen by its suffix.

``.json`` is the deeplens format (:mod:`.lensfile`), ``.txt`` the paper authors' table
(:mod:`.table`).  This module imports both readers; they do not import each other upwards
(``table`` builds on ``lensfile``, ``lensfile`` knows nothing of tables).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import LensFileError
from .lensfile import read_json
from .table import read_table

__all__ = ["load_lens"]


def load_lens(path, **table_options):
    """Read a lens file: our JSON format (``.json``) or the paper authors' table (``.txt``).

    ``table_options`` are passed to :func:`~.table.read_table` for ``.txt`` files.

    Raises:
        FileNotFoundError: no such file.
        LensFileError: the file cannot be read (names the file and the field or line).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"lens file not found: {path}")
    if path.is_dir():
        raise LensFileError("is a directory, not a lens file", source=path)
    suffix = path.suffix.lower()
    if suffix == ".txt":
        return read_table(path, **table_options)
    if suffix != ".json":
        raise LensFileError(f"unsupported lens file type {path.suffix!r}: deeplens reads its "
                            f"JSON format (.json) and the paper authors' tables (.txt)",
                            source=path)
    if table_options:
        raise TypeError(f"options {sorted(table_options)} apply to .txt tables only")
    return read_json(path)
