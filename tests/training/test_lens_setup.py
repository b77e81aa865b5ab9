"""Per-parameter learning-rate scaling: one optimiser step of ``lr_mm`` moves each surface by
``lr_mm`` of sag at its rim, whatever the parameter's units (lens_setup module docstring)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from deeplens.optics.io import load_lens
from deeplens.optics.surfaces import Asphere, XYPolynomial
from deeplens.training.lens_setup import optics_param_groups, parameter_scale, set_trainable

DATA = Path(__file__).resolve().parents[2] / "data" / "lenses"
LR_MM = 1e-3


def _max_sag_change(lens, index, before_after_fn):
    """max |z_after - z_before| over the clear aperture (XY polynomial: over its bounding
    square, where max |x^i y^j| = R^(i+j) is reached at a corner)."""
    s = lens.surfaces[index]
    R = float(s.semi_diameter)
    v = torch.linspace(-R, R, 41, dtype=torch.float64)
    Y, X = torch.meshgrid(v, v, indexing="ij")
    if not isinstance(s, XYPolynomial):
        keep = X ** 2 + Y ** 2 <= R * R * (1 + 1e-12)
        X, Y = X[keep], Y[keep]
    with torch.no_grad():
        z0 = s.sag(X, Y).clone()
    before_after_fn()
    with torch.no_grad():
        return float((s.sag(X, Y) - z0).abs().max())


@pytest.mark.parametrize("path, name, rel", [
    # XY-polynomial plate terms x^i y^j: scale R^(i+j)
    ("edof_achromat.json", "surfaces.4.a.3", 1e-6),
    ("edof_achromat.json", "surfaces.4.a.5", 1e-6),
    ("edof_achromat.json", "surfaces.4.a.7", 1e-6),
    ("edof_achromat.json", "surfaces.4.a.9", 1e-6),
    # even asphere a4, a6: scale R^4, R^6
    ("wide_doublet.json", "surfaces.1.a.0", 1e-6),
    ("wide_doublet.json", "surfaces.3.a.1", 1e-6),
    # curvature: dz/dc = r^2/2 only paraxially (higher orders add 13 % on the doublet)
    ("wide_doublet.json", "surfaces.1.c", 0.2),
    ("edof_achromat.json", "surfaces.0.c", 0.2),
    # a distance is already in mm: the sensor moves by lr_mm
    ("wide_doublet.json", "d_sensor", 1e-6),
])
def test_one_adam_step_moves_the_rim_by_lr_mm(path, name, rel):
    """Adam's first step moves every parameter by ``lr`` (times the sign of its gradient), so
    with ``lr = lr_mm / parameter_scale`` the largest sag change over the aperture is
    ``lr_mm``: checked through ``optics_param_groups`` and a real ``torch.optim.Adam`` step."""
    lens = load_lens(DATA / path).double()
    set_trainable(lens, [name])
    groups = optics_param_groups(lens, LR_MM)
    assert [g["name"] for g in groups] == [f"lens.{name}"]
    p = groups[0]["params"][0]
    assert groups[0]["lr"] == pytest.approx(LR_MM / parameter_scale(lens, name), rel=1e-15)
    opt = torch.optim.Adam(groups)
    if name == "d_sensor":
        before = float(p)
        loss = p * 3.0
        loss.backward()
        opt.step()
        assert abs(float(p) - before) == pytest.approx(LR_MM, rel=rel)
        return
    index = int(name.split(".")[1])
    s = lens.surfaces[index]
    R = float(s.semi_diameter)

    def step():
        x = torch.tensor([0.7 * R], dtype=torch.float64)
        loss = s.sag(x, torch.full_like(x, 0.4 * R)).sum()  # any point with a gradient
        loss.backward()
        opt.step()

    assert _max_sag_change(lens, index, step) == pytest.approx(LR_MM, rel=rel)


def test_parameter_scale_by_kind():
    """The scale of each kind against its formula written out (R the semi-diameter)."""
    edof = load_lens(DATA / "edof_achromat.json")
    plate = edof.surfaces[4]
    assert isinstance(plate, XYPolynomial)
    R = float(plate.semi_diameter)
    for k, (i, j) in enumerate(plate.terms):
        assert parameter_scale(edof, f"surfaces.4.a.{k}") == pytest.approx(R ** (i + j))
    doublet = load_lens(DATA / "wide_doublet.json")
    s = doublet.surfaces[1]
    assert isinstance(s, Asphere)
    R = float(s.semi_diameter)
    assert parameter_scale(doublet, "surfaces.1.a.0") == pytest.approx(R ** 4)
    assert parameter_scale(doublet, "surfaces.1.a.1") == pytest.approx(R ** 6)
    assert parameter_scale(doublet, "surfaces.1.c") == pytest.approx(R * R / 2)
    # a tilt of t rad moves the rim of the largest surface by about R_max t mm
    rmax = max(float(x.semi_diameter) for x in doublet.surfaces)
    assert parameter_scale(doublet, "misalignments.0.tilt_x") == pytest.approx(rmax)
    assert parameter_scale(doublet, "misalignments.0.dx") == 1.0
    assert parameter_scale(doublet, "d_sensor") == parameter_scale(doublet, "distances.1") == 1.0
    assert math.isfinite(parameter_scale(doublet, "surfaces.1.k"))


def test_learned_plate_can_start_from_a_cubic_plate():
    """``learned_start_alpha_mm``: the learned plate starts as the Dowski-Cathey plate
    ``z = α((x/R)^3 + (y/R)^3)`` (sag α at the rim on each axis, 0 at the centre) and stays
    trainable; ``None`` keeps the file's (flat) plate."""
    from deeplens.training.lens_setup import build_lens

    path = str(DATA / "edof_achromat.json")
    terms = ["surfaces.4.a.6", "surfaces.4.a.9"]
    lens = build_lens(path, trainable=terms, dtype="float64", plate="learned", plate_surface=4,
                      learned_start_alpha_mm=0.0025)
    s = lens.surfaces[4]
    R = float(s.semi_diameter)
    x = torch.tensor([R, 0.0, -R, 0.5 * R], dtype=torch.float64)
    y = torch.tensor([0.0, R, 0.0, 0.5 * R], dtype=torch.float64)
    flat = build_lens(path, dtype="float64", plate="learned", plate_surface=4)
    with torch.no_grad():
        dz = s.sag(x, y) - flat.surfaces[4].sag(x, y)
    want = 0.0025 * ((x / R) ** 3 + (y / R) ** 3)
    assert torch.allclose(dz, want, rtol=0, atol=1e-12)
    assert [n for n, p in lens.named_parameters() if p.requires_grad] == terms
    with pytest.raises(ValueError, match="lens.learned_start_alpha_mm"):
        build_lens(path, plate="learned", plate_surface=4, learned_start_alpha_mm="big")
    with pytest.raises(ValueError, match="lens.plate_surface must be set"):
        build_lens(path, plate="learned", learned_start_alpha_mm=0.0025)
