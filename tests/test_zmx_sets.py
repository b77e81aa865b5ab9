"""The unseen-set tools: ``benchmarks/zmx_assemble.py`` rebuilds a set byte for byte from its list,
``benchmarks/zmx_draw.py`` draws a new set by the written rule; every committed list is well formed."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks import zmx_assemble, zmx_draw  # noqa: E402

LISTS = sorted((REPO / "benchmarks").glob("zmx_*_sources.tsv"))


def _zmx(curvs, *, extra="") -> str:
    lines = ["VERS 1", "MODE SEQ", "UNIT MM X W X CM MR CPMM", "ENPD 10", extra]
    for i, c in enumerate(curvs):
        lines += [f"SURF {i}", "  TYPE STANDARD", f"  CURV {c}", "  DISZ 5"]
    return "\n".join(lines) + "\n"


def _git(*args, cwd):
    subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True)


@pytest.fixture
def repo(tmp_path):
    """A git repository ``owner/name`` under a mirror folder, its files and commit."""
    work = tmp_path / "mirror" / "owner+name"
    work.mkdir(parents=True)
    _git("init", "-q", cwd=work)
    files = {
        "a/lens.zmx": _zmx([0, 0.01, -0.01]),
        "b/same_as_lens.ZMX": _zmx([0, 0.01, -0.01]),
        "c/nsc.zmx": _zmx([0, 0.02], extra="MODE NSC"),
        "d/zoom.zmx": _zmx([0, 0.03], extra="MNUM 3 1"),
        "e/other.zmx": _zmx([0, 0.04, -0.04, 0]),
        "f/seen.zmx": _zmx([0, 0.05]),
        "g/readme.txt": "not a lens\n",
    }
    for path, text in files.items():
        (work / path).parent.mkdir(parents=True, exist_ok=True)
        data = text.encode("utf-16") if path.endswith(".ZMX") else text.encode()
        (work / path).write_bytes(data)
    _git("add", "-A", cwd=work)
    _git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "x", cwd=work)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=work, check=True,
                            capture_output=True, text=True).stdout.strip()
    return work, files, commit


@pytest.mark.parametrize("tsv", LISTS, ids=lambda p: p.name)
def test_every_committed_list_is_well_formed(tsv):
    rows = zmx_assemble.read_sources(tsv)
    assert rows, tsv
    names = [r["file"] for r in rows]
    assert len(set(names)) == len(names), f"{tsv.name}: a file name repeats"
    for r in rows:
        assert r["file"].lower().endswith(".zmx"), r
        assert r["repository"].count("/") == 1, r
        assert len(r["commit"]) == 40 and int(r["commit"], 16) >= 0, r


def test_assemble_writes_each_file_byte_for_byte_and_reports_what_is_missing(repo, tmp_path, capsys):
    work, files, commit = repo
    tsv = tmp_path / "list.tsv"
    tsv.write_text("file\trepository\tpath\tcommit\tlicence\n"
                   f"x_lens.zmx\towner/name\ta/lens.zmx\t{commit}\tnone\n"
                   f"x_utf16.zmx\towner/name\tb/same_as_lens.ZMX\t{commit}\tnone\n"
                   f"x_gone.zmx\towner/name\tno/such.zmx\t{commit}\tnone\n"
                   f"x_repo.zmx\tother/repo\ta/lens.zmx\t{commit}\tnone\n")
    out = tmp_path / "out"
    rc = zmx_assemble.main([str(tsv), str(out), "--mirror", str(tmp_path / "mirror")])
    assert rc == 1
    assert (out / "x_lens.zmx").read_bytes() == (work / "a/lens.zmx").read_bytes()
    assert (out / "x_utf16.zmx").read_bytes() == (work / "b/same_as_lens.ZMX").read_bytes()
    text = capsys.readouterr().out
    assert "2 of 4 files written" in text
    assert "x_gone.zmx" in text and "x_repo.zmx: no git copy of other/repo" in text


def test_a_list_without_its_columns_is_refused_naming_the_line(tmp_path):
    tsv = tmp_path / "bad.tsv"
    tsv.write_text("# a comment\nfile\trepository\tcommit\n")
    with pytest.raises(SystemExit, match=r"bad.tsv:2: header lacks \['path'\]"):
        zmx_assemble.read_sources(tsv)


def test_draw_applies_the_rule(repo, tmp_path, capsys):
    work, files, commit = repo
    seen = tmp_path / "seen.tsv"
    seen.write_text(f"file\trepository\tpath\tcommit\tlicence\nq.zmx\towner/name\tf/seen.zmx\t{commit}\tx\n")
    against = tmp_path / "against"
    against.mkdir()
    (against / "old.zmx").write_text(_zmx([0, 0.04, -0.04, 0]))    # equals e/other.zmx
    out = tmp_path / "set"
    rc = zmx_draw.main([str(out), "--source", "t", "owner/name", str(work / ".git"), commit,
                        "--seen", str(seen), "--against", str(against)])
    assert rc == 0
    captured = capsys.readouterr()
    drawn = [line.split("\t") for line in captured.out.splitlines()[1:]]
    # of a/lens.zmx and its UTF-16 copy b/same_as_lens.ZMX, the one first in SHA-1 order is drawn
    first = min(["a/lens.zmx", "b/same_as_lens.ZMX"], key=lambda p: hashlib.sha1(p.encode()).hexdigest())
    assert [row[2] for row in drawn] == [first]
    assert (out / drawn[0][0]).read_bytes() == (work / first).read_bytes()
    dropped = {line.split("\t")[2]: line.split("\t")[3] for line in captured.err.splitlines()}
    assert dropped["c/nsc.zmx"] == "non-sequential or mixed-mode"
    assert dropped["d/zoom.zmx"] == "MNUM 3"
    assert dropped["e/other.zmx"] == "duplicate of against/old.zmx"
    assert dropped.get("b/same_as_lens.ZMX", dropped.get("a/lens.zmx")).startswith("duplicate of set/")
    assert "f/seen.zmx" not in dropped and "g/readme.txt" not in dropped


def test_surface_list_reads_infinity_and_every_surf():
    assert zmx_draw.surface_list(_zmx([0, 0.5]).replace("DISZ 5", "DISZ INFINITY", 1)) == (
        (0.0, float("inf")), (0.5, 5.0))


def test_draw_refuses_a_folder_that_is_not_empty(repo, tmp_path):
    work, files, commit = repo
    out = tmp_path / "set"
    out.mkdir()
    (out / "old.zmx").write_text("x")
    with pytest.raises(SystemExit):
        zmx_draw.main([str(out), "--source", "t", "owner/name", str(work / ".git"), commit])
    assert sorted(p.name for p in out.iterdir()) == ["old.zmx"]
