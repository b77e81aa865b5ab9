"""``load_lens``: read a lens file of any supported format, chosen by its suffix.

``.json`` is the deeplens format (:mod:`.lensfile`), ``.txt`` the paper authors' table
(:mod:`.table`), ``.zmx`` a Zemax lens file (:mod:`.zmx`), ``.seq`` a CODE V file (:mod:`.codev`).  This module imports both readers; they do not import each other upwards
(``table`` builds on ``lensfile``, ``lensfile`` knows nothing of tables).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import LensFileError
from .lensfile import read_json
from .table import read_table

__all__ = ["load_lens"]


def _shipped(path: Path) -> Path:
    """The shipped lens a bare ``path`` names, or FileNotFoundError."""
    from ...resources import lens_dir

    d = lens_dir()
    if path.parent == Path(".") and path.suffix.lower() in ("", ".json"):
        p = d / path.with_suffix(".json").name
        if p.is_file():
            return p
    shipped = ", ".join(sorted(q.stem for q in d.glob("*.json")))
    raise FileNotFoundError(f"lens file not found: {path} (nor is it a lens shipped with "
                            f"deeplens: {shipped})")


def load_lens(path, **table_options):
    """Read a lens file: our JSON format (``.json``), the paper authors' table (``.txt``), a
    Zemax file (``.zmx``) or a CODE V file (``.seq``).

    ``table_options`` are passed to :func:`~.table.read_table` for ``.txt`` files and to
    :func:`~.zmx.read_zmx` for ``.zmx`` files (``glass_catalogs``, ``glass_fallback``,
    ``config``, ``qbfs_conic``, ``stop_size``, ``glass_codes``); for ``.seq`` files ``config=N``
    is zoom position ``N`` (:func:`~.codev.read_seq` ``zoom=N``).

    A bare name that is not a file here (``"double_gauss"`` or ``"double_gauss.json"``, no
    folder) is one of the lenses shipped with deeplens (:func:`deeplens.resources.lens_dir`), so
    ``load_lens("double_gauss")`` works from any directory.

    Raises:
        FileNotFoundError: no such file (nor shipped lens; the message lists those).
        LensFileError: the file cannot be read (names the file and the field or line).
    """
    path = Path(path)
    if not path.exists():
        path = _shipped(path)
    if path.is_dir():
        raise LensFileError("is a directory, not a lens file", source=path)
    suffix = path.suffix.lower()
    if suffix == ".zmx":
        from .zmx import read_zmx

        return read_zmx(path, **table_options)
    if suffix == ".seq":
        from .codev import read_seq

        zoom = table_options.pop("config", None)   # a zoom position, as a .zmx configuration
        if table_options:
            raise TypeError(f"options {sorted(table_options)} do not apply to .seq files")
        return read_seq(path, zoom=zoom)
    if suffix == ".txt":
        return read_table(path, **table_options)
    if suffix != ".json":
        raise LensFileError(f"unsupported lens file type {path.suffix!r}: deeplens reads its "
                            f"JSON format (.json), the paper authors' tables (.txt), Zemax files (.zmx) and CODE V "
                            f"files (.seq)",
                            source=path)
    if table_options:
        raise TypeError(f"options {sorted(table_options)} apply to .txt tables only")
    return read_json(path)
