"""Content digests of the files a run reads, so that a finished run is reused only for the same
inputs (``eval.reuse_runs``): a lens file edited in place keeps its path but not its digest.

:func:`input_digests` walks a run's configuration and, for every string value naming an existing
file or folder (``lens.path``, ``data.image_folder``, ``model.perceptual_weights``, ...), records
the SHA-256 of its content under the value's dotted key.  A folder's digest covers the relative
path and content of every file under it (sorted), so adding, removing, renaming or editing an
image changes it.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from .checkpoint import sha256_file

__all__ = ["digest_path", "input_digests"]


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


def input_digests(tree, outputs=(), prefix: str = "") -> dict[str, str]:
    """``{dotted key: digest}`` of every string in ``tree`` (nested dicts and lists of plain
    values) that names an existing file or folder, except those inside the ``outputs`` folders
    (the run's own output folder: its checkpoints and logs are not inputs)."""
    outputs = [Path(o).resolve() for o in outputs]
    out: dict[str, str] = {}
    if isinstance(tree, dict):
        for k, v in tree.items():
            out.update(input_digests(v, outputs, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            out.update(input_digests(v, outputs, f"{prefix}[{i}]"))
    elif isinstance(tree, str) and _is_input(tree, outputs):
        out[prefix] = digest_path(tree)
    return out
