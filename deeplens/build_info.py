"""Which deeplens is running: the version (``deeplens.__version__``) and, where it can be
known, the commit: the git checkout the package is imported from, or the commit ``setup.py``
recorded in the wheel (``deeplens/_resources/build.json``) when it was built from a checkout.
An evaluation's table states it (:func:`deeplens.evaluation.evaluate.provenance`), whatever the
working directory of the run.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from . import __version__

__all__ = ["source_commit", "describe_source"]

_PACKAGE = Path(__file__).resolve().parent


def _git(args, cwd: Path) -> str | None:
    try:
        r = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 and r.stdout.strip() else None


def source_commit(package_dir: Path | None = None) -> tuple[str | None, str]:
    """``(commit, where)`` of the deeplens package at ``package_dir`` (default: this one):
    ``where`` is ``"checkout"`` (its folder's parent is a git checkout's top level, the
    commit ``+`` a mark when tracked files are modified), ``"build"`` (recorded in the wheel)
    or ``"unknown"`` (then ``commit`` is ``None``)."""
    pkg = _PACKAGE if package_dir is None else Path(package_dir)
    top = _git(["rev-parse", "--show-toplevel"], pkg.parent)
    if top is not None and Path(top).resolve() == pkg.parent.resolve():
        commit = _git(["rev-parse", "--short", "HEAD"], pkg.parent)
        if commit is not None:
            dirty = _git(["status", "--porcelain", "--untracked-files=no"], pkg.parent)
            return commit + ("+modified" if dirty else ""), "checkout"
    f = pkg / "_resources" / "build.json"
    if f.is_file():
        try:
            rec = json.loads(f.read_text())
            return rec["commit"] + ("+modified" if rec.get("modified") else ""), "build"
        except (ValueError, KeyError, TypeError):
            pass
    return None, "unknown"


def describe_source(package_dir: Path | None = None) -> str:
    """``deeplens 0.1.0, commit abc1234 (checkout)``, ``... (recorded at build)`` or ``...,
    commit unknown``."""
    commit, where = source_commit(package_dir)
    if commit is None:
        return f"deeplens {__version__}, commit unknown"
    return (f"deeplens {__version__}, commit {commit} "
            f"({'checkout' if where == 'checkout' else 'recorded at build'})")
