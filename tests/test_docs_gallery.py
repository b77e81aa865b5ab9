"""The analysis gallery is drawn at every docs build (scripts/docs_gallery.py, an MkDocs hook):
every gallery picture a page shows is one the hook draws, the hook is registered, and its
command draws a real picture."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _hook():
    spec = importlib.util.spec_from_file_location("docs_gallery", REPO / "scripts" /
                                                  "docs_gallery.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_gallery_picture_is_drawn_by_the_hook_and_none_is_committed():
    hook = _hook()
    shown = {m for p in (REPO / "docs").rglob("*.md")
             for m in re.findall(r"img/(double_gauss_\w+)\.png", p.read_text())}
    drawn = {f"{hook.LENS}_{k}" for k in hook.KINDS}
    assert shown and shown <= drawn, shown - drawn
    assert not list((REPO / "docs" / "img").glob("double_gauss_*.png"))  # no stale copies
    assert "scripts/docs_gallery.py" in (REPO / "mkdocs.yml").read_text()


def test_the_gallery_command_draws_a_picture(tmp_path):
    from deeplens.cli import main

    hook = _hook()
    png = tmp_path / "layout.png"
    assert main(hook.gallery_argv("layout", str(png))) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
