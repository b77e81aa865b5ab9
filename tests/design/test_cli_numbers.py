"""Every number ``deeplens tolerance`` prints, recomputed independently (issue 25, "tests that
a wrong implementation must not pass"): the nominal RMS spots from the nominal lens's
unvignetted rays about their centroid, the RSS estimate and the sensitivities from central finite differences of the
spot residuals (float64), and the Monte Carlo percentiles and RMS from the same seeded draws
applied to copies of the lens by parameter name."""

from __future__ import annotations

import copy
import json
import math
import re

import helpers as H
import pytest
import torch

from deeplens.optics.sampling import field_rays, pupil_pattern
from deeplens.design.merit import SpotMerit
from deeplens.optics.io import load_lens

LENS = H.LENS_DIR / "cooke_triplet.json"
FIELDS, SAMPLING, MC, SEED = [0.0, 8.0], "hexapolar:3", 7, 2
TOLS = {"misalignments.0.dy": 0.02, "misalignments.3.dx": 0.03, "distances.1": 0.05,
        "surfaces.2.c": 2e-4}


def _numbers(line: str) -> list[float]:
    return [float(v) for v in re.findall(r"[-+]?\d+\.\d+(?:e[-+]?\d+)?", line.split(":", 1)[1])]


@pytest.fixture(scope="module")
def printed(tmp_path_factory):
    from deeplens.cli import main
    import contextlib
    import io

    tol = tmp_path_factory.mktemp("tol") / "tol.json"
    tol.write_text(json.dumps(TOLS))
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["tolerance", str(LENS), "--tolerances", str(tol), "--fields",
                     ",".join(str(f) for f in FIELDS), "--sampling", SAMPLING,
                     "--monte-carlo", str(MC), "--seed", str(SEED)])
    assert code == 0
    return buf.getvalue().splitlines()


@pytest.fixture(scope="module")
def reference():
    return _reference()


def _reference(**merit_options):
    """A function giving each field's RMS spot (mm) and scaled deviations for a dict of
    parameter offsets, on the nominal lens's pupil regions (as the tools prepare them)."""
    lens = load_lens(LENS).to(torch.float64)
    wl = float(lens.spec.primary_wavelength_nm)
    sm = SpotMerit(FIELDS, [wl], sampling=SAMPLING, strict_rays=False,
                   **merit_options).prepare(lens)
    masks = {}
    for f in FIELDS:  # the rays of the nominal lens that reach the image (vignetting)
        reg = sm.regions[(f, wl)]
        masks[f] = lens.trace_to_sensor(field_rays(lens, f, wl, reg.points(
            pupil_pattern(SAMPLING)), reg.z)).valid
        assert 10 < int(masks[f].sum())

    def spots(offsets: dict):
        L = copy.deepcopy(lens)
        params = dict(L.named_parameters())
        with torch.no_grad():
            for k, v in offsets.items():
                params[k].add_(v)
        out = []
        for f in FIELDS:
            reg = sm.regions[(f, wl)]
            rays = field_rays(L, f, wl, reg.points(pupil_pattern(SAMPLING)), reg.z)
            hit = L.trace_to_sensor(rays)
            ok = masks[f]
            assert bool(hit.valid[ok].all())  # no ray of the nominal spot is lost
            pts = hit.o[ok, :2]
            dev = (pts - pts.mean(0)) / math.sqrt(int(ok.sum()))
            out.append((float(torch.sqrt((dev * dev).sum())), dev.reshape(-1)))
        return out

    return spots


def _line(printed, start):
    return next(line for line in printed if line.strip().startswith(start))


def test_nominal_rms_is_the_spot_rms(printed, reference):
    nominal = _numbers(_line(printed, "nominal RMS (um)"))
    want = [1e3 * r for r, _ in reference({})]
    assert nominal == pytest.approx(want, abs=1e-4)  # printed to 4 decimals


def _fd(reference, name, h):
    plus, minus = reference({name: h}), reference({name: -h})
    return ([(a[0] - b[0]) / (2 * h) for a, b in zip(plus, minus)],
            [(a[1] - b[1]) / (2 * h) for a, b in zip(plus, minus)])


def test_rss_and_sensitivities_are_finite_differences(printed, reference):
    names = list(TOLS)
    steps = {"misalignments.0.dy": 1e-5, "misalignments.3.dx": 1e-5, "distances.1": 1e-5,
             "surfaces.2.c": 1e-7}
    nominal = reference({})
    var = [r * r for r, _ in nominal]
    sens = {}
    for n in names:
        d_eps, d_res = _fd(reference, n, steps[n])
        sigma2 = TOLS[n] ** 2 / 3
        for f in range(len(FIELDS)):
            var[f] += sigma2 * float((d_res[f] ** 2).sum())
        sens[n] = max(abs(v) for v in d_eps) * 1e3
    rss = _numbers(_line(printed, "RSS estimate (um)"))
    assert rss == pytest.approx([1e3 * math.sqrt(v) for v in var], rel=1e-5, abs=1e-4)
    start = printed.index(_line(printed, "largest sensitivities"))
    rows = [line.split() for line in printed[start + 1:start + 1 + len(names)]]
    floor = 1e-5 * max(sens.values())  # entries that vanish by symmetry: FD noise
    big = [n for n in sorted(names, key=lambda n: -sens[n]) if sens[n] > floor]
    assert len(big) >= 3 and [r[0] for r in rows[:len(big)]] == big
    for r in rows:
        assert float(r[1]) == pytest.approx(sens[r[0]], rel=1e-3, abs=floor)
        assert float(r[2].strip("()+-")) == TOLS[r[0]]


def test_monte_carlo_percentiles_and_rms_are_the_trials(printed, reference):
    names = list(TOLS)
    t = torch.tensor([TOLS[n] for n in names], dtype=torch.float64)
    g = torch.Generator().manual_seed(SEED)
    trials = []
    for _ in range(MC):
        u = 2.0 * torch.rand(len(names), generator=g, dtype=torch.float64) - 1.0
        off = dict(zip(names, (u * t).tolist()))
        trials.append([1e3 * r for r, _ in reference(off)])
    s = torch.tensor(trials, dtype=torch.float64)
    assert _line(printed, "Monte Carlo").strip().startswith(f"Monte Carlo ({MC} trials, seed {SEED})")
    for p in ("50", "90", "98"):
        got = _numbers(_line(printed, f"{p}th percentile (um)"))
        want = torch.quantile(s, int(p) / 100, dim=0).tolist()
        assert got == pytest.approx(want, abs=2e-4)
    rms = _numbers(_line(printed, "RMS over trials (um)"))
    assert rms == pytest.approx(torch.sqrt((s * s).mean(0)).tolist(), abs=2e-4)


def test_design_sensitivity_prints_its_matrix_and_errors_truthfully(tmp_path, capsys):
    """``deeplens design sensitivity``: the Jacobian against central differences of the spot
    RMS computed here, ``rms_um`` against the nominal spots, and the printed ``fd_max_rel_err``
    and ``reverse_max_abs_diff`` recomputed from the matrices it reports."""
    argv = ["design", "sensitivity", "--lens", str(LENS), "--fields", "0,8",
            "--sampling", SAMPLING, "--kinds", "decenter,spacing", "--out", str(tmp_path)]
    code, text, err = H.run_cli(argv, capsys)
    assert code == 0, err
    code, js, err = H.run_cli(argv + ["--json"], capsys)
    r = json.loads(js)
    spots = _reference(shrink=0.98)
    assert [x * 1e-3 for x in r["rms_um"]] == pytest.approx([v for v, _ in spots({})],
                                                            rel=1e-9)
    J = torch.tensor(r["jacobian"], dtype=torch.float64)
    FD = torch.tensor(r["jacobian_fd"], dtype=torch.float64)
    for j, name in enumerate(r["parameters"]):
        h = 1e-5
        fd = [(a[0] - b[0]) / (2 * h) for a, b in zip(spots({name: h}), spots({name: -h}))]
        assert J[:, j].tolist() == pytest.approx(fd, rel=1e-4, abs=1e-6)
    floor = 1e-3 * float(FD.abs().max())
    rel = float(((J - FD).abs() / FD.abs().clamp_min(floor)).max())
    printed = dict(line.split(": ", 1) for line in text.splitlines() if ": " in line)
    assert float(printed["fd_max_rel_err"]) == pytest.approx(rel, rel=1e-6)
    assert float(printed["reverse_max_abs_diff"]) == pytest.approx(r["reverse_max_abs_diff"])
    assert r["reverse_max_abs_diff"] < 1e-10
