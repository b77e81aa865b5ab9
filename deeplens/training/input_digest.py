"""Content digests of the files a run reads, so that a finished run is reused only for the same
inputs (``eval.reuse_runs``): a lens file edited in place keeps its path but not its digest.

:func:`input_digests` walks a run's configuration and, for every string value naming an existing
file or folder (``lens.path``, ``data.image_folder``, ``model.perceptual_weights``, ...), records
the SHA-256 of its content under the value's dotted key.  A folder's digest covers the relative
path and content of every file under it (sorted), so adding, removing, renaming or editing an
image changes it.  A Zemax lens (``.zmx``) also brings the ``.agf`` catalogues its ``GCAT`` line
loads from its folder, so that an edited glass is a changed input too.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from ..optics.errors import LensFileError
from ..optics.io.zmx_glass import catalogue_files
from .checkpoint import sha256_file

__all__ = ["digest_path", "input_digests", "zmx_catalogue_digests"]


def digest_path(path) -> str:
    """``sha256:<hex>`` of a file's bytes, or of a folder's files (relative names and contents,
    in sorted order)."""
    path = Path(path)
    if path.is_file():
        return "sha256:" + sha256_file(path)
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(f.relative_to(path).as_posix().encode() + b"\0")
        h.update(sha256_file(f).encode() + b"\n")
    return "sha256:" + h.hexdigest()


def _is_input(v: str, outputs: list[Path]) -> bool:
    if not ((os.sep in v or "." in v) and os.path.exists(v)):
        return False
    p = Path(v).resolve()
    return not any(p == o or o in p.parents for o in outputs)


def zmx_catalogue_digests(path, glass_catalogs=(), prefix: str = "lens.path"
                          ) -> dict[str, str]:
    """``{"<prefix>[GCAT <NAME>]": digest}`` of the ``.agf`` catalogues the Zemax file ``path``
    loads when read with ``glass_catalogs`` (its ``GCAT`` names found next to it,
    :func:`~deeplens.optics.io.zmx_glass.catalogue_files`): an edited glass changes the key of
    the runs made with the lens although the ``.zmx`` is unchanged.  A file that cannot be
    parsed gives none (reading the lens reports it)."""
    try:
        files = catalogue_files(path, [c for c in glass_catalogs if isinstance(c, str)])
    except (LensFileError, OSError):
        return {}
    return {f"{prefix}[GCAT {f.stem.upper()}]": digest_path(f) for f in files}


def _glass_catalogs(tree: dict) -> list:
    """The ``table_options.glass_catalogs`` next to a lens ``path`` (a list, maybe empty)."""
    opts = tree.get("table_options")
    cats = opts.get("glass_catalogs") if isinstance(opts, dict) else None
    return list(cats) if isinstance(cats, (list, tuple)) else []


def input_digests(tree, outputs=(), prefix: str = "", _catalogs=()) -> dict[str, str]:
    """``{dotted key: digest}`` of every string in ``tree`` (nested dicts and lists of plain
    values) that names an existing file or folder, except those inside the ``outputs`` folders
    (the run's own output folder: its checkpoints and logs are not inputs).  A Zemax ``.zmx``
    file also brings the ``.agf`` catalogues its ``GCAT`` line loads from its folder
    (:func:`zmx_catalogue_digests`, with the ``table_options.glass_catalogs`` beside its key)."""
    outputs = [Path(o).resolve() for o in outputs]
    out: dict[str, str] = {}
    if isinstance(tree, dict):
        for k, v in tree.items():
            cats = _glass_catalogs(tree) if k == "path" else ()
            out.update(input_digests(v, outputs, f"{prefix}.{k}" if prefix else str(k), cats))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            out.update(input_digests(v, outputs, f"{prefix}[{i}]"))
    elif isinstance(tree, str) and _is_input(tree, outputs):
        out[prefix] = digest_path(tree)
        if tree.lower().endswith(".zmx") and Path(tree).is_file():
            out.update(zmx_catalogue_digests(tree, _catalogs, prefix))
    return out
