"""``deeplens design search``: the flags make the spec, the files it writes are read back."""

from __future__ import annotations

import json

import pytest
import torch
from helpers import run_cli

from deeplens.optics.paraxial import paraxial
from deeplens.optics.io import load_lens

SINGLET = ["design", "search", "--efl", "100", "--fno", "16", "--hfov", "0", "--elements", "1",
           "--wavelengths", "587.5618", "--glasses", "N-BK7", "--stop", "front", "--starts", "1",
           "--polish", "1", "--hops", "1", "--keep", "2", "--screen-steps", "2",
           "--polish-steps", "2", "--hop-steps", "2", "--converge-steps", "4", "--quiet",
           "--json"]


def test_search_writes_a_lens_every_command_reads(tmp_path, capsys):
    code, out, err = run_cli([*SINGLET, "--seed", "3", "--out", str(tmp_path)], capsys)
    assert code == 0, err
    r = json.loads(out)
    lens = load_lens(tmp_path / "best.json")
    assert float(paraxial(lens.to(torch.float64)).efl) == pytest.approx(100.0, rel=1e-9)
    res = json.loads((tmp_path / "result.json").read_text())
    assert res["best"]["rms_um"] == pytest.approx(r["rms_um"])
    assert res["spec"]["efl_mm"] == 100.0 and res["config"]["seed"] == 3
    assert {"rms_um_per_field_wavelength", "efl_mm", "fno", "total_track_mm", "constraints",
            "feasible"} <= set(res["best"])
    assert res["seconds"] > 0 and res["runs"]
    conv = [run for run in res["runs"] if run["origin"].startswith("converge")]
    assert conv and all(run["steps"] <= 4 for run in conv)   # --converge-steps reached
    code, out, err = run_cli(["report", str(tmp_path / "best.json"), "--json",
                              "--sampling", "hexapolar:3"], capsys)
    assert code == 0, err


def test_spec_file_and_flags(tmp_path, capsys):
    spec = tmp_path / "s.json"
    spec.write_text(json.dumps({"efl_mm": 100, "fno": 16, "hfov_deg": 0, "elements": 1,
                                "wavelengths_nm": [587.5618], "glasses": "N-BK7",
                                "stop": "front", "max_trak_mm": 3}))
    code, out, err = run_cli(["design", "search", "--spec", str(spec), "--out",
                              str(tmp_path / "o")], capsys)
    assert code == 2 and "s.json, field 'max_trak_mm'" in err and "'max_track_mm'" in err
    code, out, err = run_cli(["design", "search", "--fno", "4", "--hfov", "5", "--out",
                              str(tmp_path / "o")], capsys)
    assert code == 2 and "--efl" in err
    code, out, err = run_cli([*SINGLET[:2], "--efl", "50", "--fno", "4", "--hfov", "5",
                              "--glasses", "N-BK77", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "unknown glass 'N-BK77'" in err


@pytest.mark.slow   # a search and a split with refinement: ~10-20 s
def test_count_trade_writes_a_lens_per_count(tmp_path, capsys):
    flags = [*SINGLET[:SINGLET.index("--keep")], *SINGLET[SINGLET.index("--keep") + 2:]]
    code, out, err = run_cli([*flags, "--hfov", "2", "--count-trade", "1-2", "--seed", "0",
                              "--out", str(tmp_path)], capsys)
    assert code == 0, err
    rows = json.loads(out)["trade"]
    assert [r["elements"] for r in rows] == [1, 2]
    assert rows[0]["origin"] == "searched" and rows[1]["origin"].startswith("split")
    two = load_lens(tmp_path / "elements_2.json").to(torch.float64)
    assert len(two.surfaces) == 5                     # the stop and two singlets
    assert float(paraxial(two).efl) == pytest.approx(100.0, rel=1e-9)
    table = json.loads((tmp_path / "count_trade.json").read_text())
    assert table["trade"] == rows
    code, out, err = run_cli([*flags, "--count-trade", "2-3", "--out", str(tmp_path)], capsys)
    assert code == 2 and "must hold --elements" in err
