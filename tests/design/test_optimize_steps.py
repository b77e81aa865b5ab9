"""``deeplens optimize``: accepted/rejected steps with their real reasons, ``--allow-vignetting``,
quick focus first (:mod:`deeplens.design.focus`), and the design applications' help."""

import copy
import json
import re

import helpers as H
import pytest
import torch

from deeplens.analysis.spot import find_pupil, spot_diagram
from deeplens.design.focus import quick_focus, quick_focus_shift
from deeplens.design.lensopt import optimize_lens
from deeplens.design.merit import Merit, SpotMerit
from deeplens.design.variables import Variables
from deeplens.optics.io import load_lens, save_lens

COOKE = H.LENS_DIR / "cooke_triplet.json"
W = 587.5618


def perturbed_cooke():
    """The issue's case: the Cooke triplet with three curvatures off by 3-5 %, ~2 mm spots."""
    lens = load_lens(COOKE).to(torch.float64)
    with torch.no_grad():
        for i, f in [(0, 1.05), (3, 0.95), (6, 1.03)]:
            lens.surfaces[i].c.mul_(f)
    return lens


def test_rejection_reasons_are_the_real_ones():
    lens = perturbed_cooke()
    start = copy.deepcopy(lens)
    names = "surfaces.*.c"
    res = optimize_lens(lens, Variables(lens, names), Merit(SpotMerit([0, 8.3], [W],
                        sampling="hexapolar:3")), steps=3, jacobian_mode="central")
    assert res.rejected > 0 and res.accepted >= 1
    assert sum(n for _, n in res.rejections()) == res.rejected
    assert dict(res.rejection_kinds()) == {"vignetted": res.rejected}
    ref = SpotMerit([0, 8.3], [W], sampling="hexapolar:3", strict_rays=False).prepare(start)
    checked = 0
    for h in res.history:
        if h["accepted"]:
            continue
        m = re.match(r"(\d+) of (\d+) rays of field ([\d.]+) deg", h["reason"])
        lost, of, field = int(m[1]), int(m[2]), float(m[3])
        # the reason is only true for the lens the step started from: the first round's trials
        # that start from the start lens are recomputed independently
        trial = copy.deepcopy(start)
        Variables(trial, names).assign(torch.tensor(h["x_trial"], dtype=torch.float64))
        start_x = Variables(start, names).x0().tolist()
        if h["x"] != start_x:
            continue
        mask = ref.masks[(field, W)]
        now = ref._trace(trial, field, W).valid
        assert int(mask.sum()) == of
        assert int((mask & ~now).sum()) == lost
        checked += 1
    assert checked >= 1


def test_quick_focus_is_the_least_rms_plane():
    lens = perturbed_cooke()
    fields = [0.0, 8.3]
    t, e0, e1 = quick_focus_shift(lens, fields, [W], sampling="hexapolar:4")
    z_sensor = float(lens.z_sensor())
    regions = {f: find_pupil(lens, f, W, "traced", grid=65, bisections=24) for f in fields}

    def mean_sq_rms(dz):
        return sum(float(spot_diagram(lens, f, W, "hexapolar:4", image_plane=z_sensor + dz,
                                      region=regions[f]).rms_radius) ** 2
                   for f in fields) / len(fields)

    assert mean_sq_rms(0.0) == pytest.approx(e0, rel=1e-9)
    assert mean_sq_rms(t) == pytest.approx(e1, rel=1e-9)
    h = 0.3
    a, b, c = mean_sq_rms(t - h), mean_sq_rms(t), mean_sq_rms(t + h)
    vertex = t + h * (a - c) / (2 * (a - 2 * b + c))   # a parabola through the three
    assert vertex == pytest.approx(t, abs=1e-6)
    assert b < a and b < c and e1 < 0.01 * e0
    r = quick_focus(lens, fields, [W], sampling="hexapolar:4")
    assert float(lens.d_sensor) == pytest.approx(r.d_sensor_before + t, rel=1e-12)


def optimize_cli(capsys, tmp_path, lens, *extra):
    src = tmp_path / "start.json"
    save_lens(lens, src)
    code, out, err = H.run_cli(["optimize", str(src), "--vary", "surfaces.*.c", "--fields",
                                "0,8.3", "--wavelengths", str(W), "--sampling", "hexapolar:3",
                                "--steps", "3", "--jacobian", "central", "--out",
                                str(tmp_path / "out.json"), *extra], capsys)
    assert code == 0, err
    return out


def test_optimize_reports_rejections_and_allows_vignetting(capsys, tmp_path):
    lens = perturbed_cooke()
    out = optimize_cli(capsys, tmp_path, lens, "--refocus", "never")
    m = re.search(r"steps: (\d+) accepted, (\d+) rejected", out)
    assert m and int(m[2]) > 0
    assert re.search(r"rejected \d+x: \d+ of \d+ rays of field 8\.3 deg at 587\.562 nm are "
                     r"vignetted", out)
    assert "--allow-vignetting" in out
    counts = [int(n) for n in re.findall(r"rejected (\d+)x: ", out)]
    assert sum(counts) == int(m[2])
    strict_after = float(re.search(r"merit [\d.e+-]+ -> ([\d.e+-]+) mm\^2", out)[1])
    r = json.loads(optimize_cli(capsys, tmp_path, lens, "--refocus", "never",
                                "--allow-vignetting", "--json"))
    assert r["allow_vignetting"] and r["refocus"] is None
    assert r["rejected_steps"] == sum(x["count"] for x in r["rejections"])
    assert all("vignetted" not in x["reason"] for x in r["rejections"])
    assert r["merit_after"] < strict_after


def test_optimize_refocuses_first_when_far_out_of_focus(capsys, tmp_path):
    r = json.loads(optimize_cli(capsys, tmp_path, perturbed_cooke(), "--json"))
    f = r["refocus"]
    assert f["applied"] and f["rms_after_um"] < 0.1 * f["rms_before_um"]
    assert f["d_sensor_after_mm"] == pytest.approx(f["d_sensor_before_mm"] + f["shift_mm"])
    out = load_lens(r["out"])
    assert float(out.d_sensor) == pytest.approx(f["d_sensor_after_mm"], rel=1e-12)
    assert max(r["rms_after_um"]) < 0.1 * min(r["rms_before_um"])
    # the nominal triplet is in focus: auto leaves its sensor alone
    nominal = json.loads(optimize_cli(capsys, tmp_path, load_lens(COOKE), "--steps", "1",
                                      "--json"))
    assert nominal["refocus"]["applied"] is False
    assert float(load_lens(nominal["out"]).d_sensor) == float(load_lens(COOKE).d_sensor)


def test_design_help_lists_every_application_uncut(capsys):
    from deeplens.design.apps import APPS, load_app

    code, out, err = H.run_cli(["design", "--help"], capsys)
    assert code == 0, err
    flat = " ".join(out.split())
    for name in APPS:
        assert f"  {name}\n" in out
        para = " ".join((load_app(name).__doc__ or "").strip().split("\n\n")[0].split())
        tail = " ".join(para.split()[-6:])   # the paragraph's end is there: nothing cut
        assert tail in flat, (name, tail)
    code, out, err = H.run_cli(["design"], capsys)
    assert code == 2 and "spherical-aberration" in err


@pytest.mark.parametrize("argv", [[], ["report"], ["plot"], ["optimize"], ["tolerance"], ["render"],
                                  ["design", "caustic"], ["design", "nikon"]])
def test_every_help_works(capsys, argv):
    code, out, err = H.run_cli([*argv, "--help"], capsys)
    assert code == 0, err
    assert out.startswith("usage: deeplens")


def test_stop_index_reads_the_authors_tables(capsys):
    table = str(H.TABLE_DIR / "LA1131.txt")
    code, out, err = H.run_cli(["report", table, "--json"], capsys)
    assert code == 2 and "--stop-index" in err and "LA1131.txt" in err
    code, out, err = H.run_cli(["report", table, "--stop-index", "0", "--json",
                                "--sampling", "hexapolar:3"], capsys)
    assert code == 0, err
    shipped = load_lens(H.LENS_DIR / "thorlabs_la1131.json")   # converted with stop_index=0
    from deeplens.optics.paraxial import paraxial

    p = paraxial(shipped)
    r = json.loads(out)
    assert r["efl_mm"] == pytest.approx(float(p.efl), rel=1e-9)
    assert r["entrance_pupil"]["diameter_mm"] == pytest.approx(
        float(p.entrance_pupil_diameter), rel=1e-9)
    code, out, err = H.run_cli(["report", table, "--stop-index", "7"], capsys)
    assert code == 2 and "stop_index" in err and "not a surface index" in err
    code, out, err = H.run_cli(["report", str(COOKE), "--stop-index", "0"], capsys)
    assert code == 2 and ".txt tables only" in err
    nikon = str(H.TABLE_DIR / "Nikon-z35-f1.8-JPA2019090949-example2.txt")
    code, out, err = H.run_cli(["report", nikon, "--scale", "10", "--json", "--sampling",
                                "hexapolar:3"], capsys)
    assert code == 0, err
    ref = paraxial(load_lens(H.LENS_DIR / "nikon_z35_f1.8_x10.json"))
    assert json.loads(out)["efl_mm"] == pytest.approx(float(ref.efl), rel=1e-9)
