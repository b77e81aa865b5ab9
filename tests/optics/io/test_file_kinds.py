"""Every lens and glass reader refuses a path that is not a regular file, or a huge one
(issue 38 item 15): a symbolic link to ``/dev/zero`` was read until memory ran out, a FIFO
blocked forever."""

from __future__ import annotations

import os
import shutil
import threading
from pathlib import Path

import pytest

from deeplens.optics.io import LensFileError, load_lens, read_agf
from deeplens.optics.io.agf import AgfError
from deeplens.optics.io.filecheck import MAX_FILE_BYTES

REPO = Path(__file__).resolve().parents[3]
SAMPLES = {".json": REPO / "data" / "lenses" / "double_gauss.json",
           ".txt": REPO / "tests" / "data" / "lenses" / "US02532751-1.txt",
           ".zmx": REPO / "tests" / "data" / "lenses" / "US02532751-1.zmx"}


def read(path: Path):
    """The reader of ``path``'s suffix; ``.agf`` is a glass catalogue."""
    return read_agf(path) if path.suffix == ".agf" else load_lens(path)


def errors(suffix):
    return AgfError if suffix == ".agf" else LensFileError


def call_with_deadline(fn, path: Path, fifo: bool, seconds: float = 20.0):
    """``fn(path)`` in a thread; if it is still running after ``seconds`` (blocked on a FIFO),
    a writer opens and closes the FIFO so the thread ends, and the test fails."""
    out = {}

    def run():
        try:
            out["value"] = fn(path)
        except BaseException as e:   # noqa: BLE001 - handed to the test
            out["error"] = e

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    if t.is_alive():
        if fifo:
            with open(path, "wb"):
                pass
        t.join(5.0)
        pytest.fail(f"reading {path.name} blocked for {seconds} s")
    if "error" in out:
        raise out["error"]
    return out.get("value")


@pytest.mark.parametrize("suffix", [".json", ".txt", ".zmx", ".agf"])
def test_a_symlink_to_dev_zero_is_refused(tmp_path, suffix):
    if not os.path.exists("/dev/zero"):
        pytest.skip("no /dev/zero")
    p = tmp_path / f"zero{suffix}"
    p.symlink_to("/dev/zero")
    with pytest.raises(errors(suffix), match=r"zero\.\w+: is a character device \(a symbolic "
                                             r"link to /dev/zero\), not a regular file"):
        call_with_deadline(read, p, fifo=False)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("suffix", [".json", ".txt", ".zmx", ".agf"])
def test_a_fifo_is_refused_without_blocking(tmp_path, suffix):
    p = tmp_path / f"pipe{suffix}"
    os.mkfifo(p)
    with pytest.raises(errors(suffix), match=r"pipe\.\w+: is a FIFO \(named pipe\), not a "
                                             r"regular file"):
        call_with_deadline(read, p, fifo=True)


@pytest.mark.parametrize("suffix", [".json", ".txt", ".zmx", ".agf"])
def test_a_file_beyond_the_size_limit_is_refused_with_its_size(tmp_path, suffix):
    p = tmp_path / f"big{suffix}"
    with open(p, "wb") as f:   # sparse: no disk used
        f.truncate(MAX_FILE_BYTES + 1)
    with pytest.raises(errors(suffix), match=rf"big\.\w+: {MAX_FILE_BYTES + 1} bytes: is larger "
                                             rf"than {MAX_FILE_BYTES} bytes \(64 MiB\)"):
        read(p)


@pytest.mark.parametrize("suffix", [".json", ".txt", ".zmx"])
def test_a_symlink_to_a_regular_lens_file_is_read(tmp_path, suffix):
    copy = tmp_path / f"real{suffix}"
    shutil.copy(SAMPLES[suffix], copy)
    link = tmp_path / f"link{suffix}"
    link.symlink_to(copy)
    assert load_lens(link).spec == load_lens(copy).spec
