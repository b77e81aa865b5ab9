"""Atomic writes (issue 38 item 8): files follow the umask like any other new file (mkstemp's
0600 is not kept), and the temporary files a killed writer left are removed at the next write
of the same target, never any other file."""

from __future__ import annotations

import contextlib
import os
import stat
import time

import pytest
import torch

from deeplens.optics.io import load_lens, save_lens
from deeplens.optics.io.atomic import STALE_AFTER_S, current_umask
from deeplens.training.checkpoint import checksum_path, write_checkpoint, write_text_atomic


@contextlib.contextmanager
def umask(mask):
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def mode(p):
    return stat.S_IMODE(os.stat(p).st_mode)


def _state():
    return {"state_dict": {"w": torch.ones(3)}, "epoch": 0}


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_atomic_files_follow_the_umask(tmp_path, mask):
    with umask(mask):
        assert current_umask() == mask
        write_checkpoint(_state(), tmp_path / "last.ckpt")
        write_text_atomic(tmp_path / "table.md", "| a |\n")
        save_lens(load_lens("double_gauss"), tmp_path / "lens.json")
        with open(tmp_path / "plain.txt", "w") as f:   # what any other file gets
            f.write("x")
    want = 0o666 & ~mask
    assert mode(tmp_path / "plain.txt") == want
    for name in ("last.ckpt", "last.ckpt.sha256", "table.md", "lens.json"):
        assert mode(tmp_path / name) == want, name


def test_a_replaced_file_keeps_its_mode(tmp_path):
    p = tmp_path / "table.md"
    p.write_text("old\n")
    os.chmod(p, 0o640)
    with umask(0o002):
        write_text_atomic(p, "new\n")
    assert p.read_text() == "new\n" and mode(p) == 0o640


def test_stale_temporary_files_of_our_pattern_are_removed_at_the_next_write(tmp_path):
    p = tmp_path / "last.ckpt"
    old = time.time() - STALE_AFTER_S - 60
    stale = [tmp_path / "last.ckpt.ab_cd123.tmp", tmp_path / "last.ckpt.sha256.zz9yx8wv.tmp"]
    fresh = tmp_path / "last.ckpt.q1w2e3r4.tmp"            # a live writer's, perhaps
    others = [tmp_path / "last.ckpt.mine.tmp", tmp_path / "other.ckpt.abcdefgh.tmp",
              tmp_path / "last.ckpt.abcdefgh.tmp.keep", tmp_path / "notes.tmp"]
    for f in stale + [fresh] + others:
        f.write_bytes(b"partial")
        if f is not fresh:
            os.utime(f, (old, old))
    write_checkpoint(_state(), p)
    assert not any(f.exists() for f in stale)
    assert fresh.exists() and all(f.exists() for f in others)
    assert checksum_path(p).exists()
    assert sorted(f.name for f in tmp_path.iterdir() if f.name.endswith(".tmp")) == sorted(
        [fresh.name, "last.ckpt.mine.tmp", "other.ckpt.abcdefgh.tmp", "notes.tmp"])
