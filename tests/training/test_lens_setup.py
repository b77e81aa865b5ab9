"""Per-parameter learning-rate scaling: one optimiser step of ``lr_mm`` moves each surface by
``lr_mm`` of sag at its rim, whatever the parameter's units (lens_setup module docstring)."""

from __future__ import annotations

import math
import tempfile
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
    with pytest.raises(ValueError, match=r"lens.plate_surface: missing; expected .*"
                                         r"lens.learned_start_alpha_mm"):
        build_lens(path, plate="learned", learned_start_alpha_mm=0.0025)


# ---------------------------------------------------------------- lens.plate_order (issue 20)
EDOF = str(DATA / "edof_achromat.json")
PLATE_TERMS = [f"surfaces.4.a.{m}" for m in range(3, 10)]  # configs/lens/edof.yaml


def _plate_points(R, n=400, seed=3):
    g = torch.Generator().manual_seed(seed)
    r = R * torch.sqrt(torch.rand(n, generator=g, dtype=torch.float64))
    t = 2 * math.pi * torch.rand(n, generator=g, dtype=torch.float64)
    return r * torch.cos(t), r * torch.sin(t)


@pytest.mark.parametrize("order", [3, 4, 5, 6])
def test_plate_order_keeps_the_sag_and_the_trace(order):
    """Raising the plate's order appends zero terms: the same sag at 400 random points of the
    aperture (bit for bit), the same rays on the sensor, and every old coefficient under its
    old name; the plate has (J+1)(J+2)/2 coefficients, and the lens file written from it
    loads back with them."""
    from deeplens.optics.io import load_lens as load
    from deeplens.optics.io import save_lens
    from deeplens.optics.sampling import point_source_rays
    from deeplens.training.lens_setup import build_lens

    kw = dict(trainable=PLATE_TERMS, dtype="float64", plate="learned", plate_surface=4,
              learned_start_alpha_mm=0.005, focus_mm=5760.0)
    base = build_lens(EDOF, **kw)
    with torch.no_grad():  # a plate with every one of its own terms non-zero (not only x^3, y^3)
        for m in range(10):
            base.surfaces[4].a[m].add_(1e-4 * (m + 1) / float(base.surfaces[4].semi_diameter)
                                       ** max(1, base.surfaces[4].terms[m][0]
                                              + base.surfaces[4].terms[m][1]))
    rich = build_lens(EDOF, **kw, plate_order=order)
    with torch.no_grad():
        for m in range(10):
            rich.surfaces[4].a[m].copy_(base.surfaces[4].a[m])
    s0, s1 = base.surfaces[4], rich.surfaces[4]
    assert s1.order == order and len(s1.a) == (order + 1) * (order + 2) // 2
    assert all(float(a) == 0.0 for a in s1.a[10:])
    assert float(rich.d_sensor) == float(base.d_sensor)  # focused without the plate: the same
    x, y = _plate_points(float(s0.semi_diameter))
    with torch.no_grad():
        assert torch.equal(s0.sag(x, y), s1.sag(x, y))
        assert float(s0.sag(x, y).abs().max()) > 1e-3  # a real plate, not a flat one
        rays = point_source_rays(base, (0.0, 0.0), 4500.0, 587.5618, 0, sampling="grid:24")
        a = base.trace_to_sensor(rays)
        b = rich.trace_to_sensor(point_source_rays(rich, (0.0, 0.0), 4500.0, 587.5618, 0,
                                                   sampling="grid:24"))
    assert torch.equal(a.valid, b.valid) and int(a.valid.sum()) > 100
    assert torch.allclose(a.o[a.valid], b.o[b.valid], rtol=0, atol=1e-13)
    with tempfile.TemporaryDirectory() as d:
        save_lens(rich, Path(d) / "rich.json")
        back = load(Path(d) / "rich.json")
    assert [float(v) for v in back.surfaces[4].a] == [float(v) for v in s1.a]


def test_plate_order_trains_the_added_terms_at_their_scale():
    """The added terms train with the plate (and only when the plate trains: the none and cubic
    variants have ``lens.trainable=[]``), each with ``lr = lr_mm / R^(i+j)``: one Adam step
    of a quartic and of a quintic term moves the sag by ``lr_mm`` at the corner of the
    aperture's bounding square, as the file's own terms do."""
    from deeplens.training.lens_setup import build_lens

    lens = build_lens(EDOF, trainable=PLATE_TERMS, dtype="float64", plate="learned",
                      plate_surface=4, plate_order=5)
    want = PLATE_TERMS + [f"surfaces.4.a.{m}" for m in range(10, 21)]
    assert [n for n, p in lens.named_parameters() if p.requires_grad] == want
    frozen = build_lens(EDOF, trainable=[], dtype="float64", plate="cubic", plate_surface=4,
                        plate_alpha_mm=0.005, plate_order=5)
    assert not any(p.requires_grad for p in frozen.parameters())
    not_plate = build_lens(EDOF, trainable=["d_sensor"], dtype="float64", plate="learned",
                           plate_surface=4, plate_order=5)
    assert [n for n, p in not_plate.named_parameters() if p.requires_grad] == ["d_sensor"]
    s = lens.surfaces[4]
    R = float(s.semi_diameter)
    assert s.terms[14] == (4, 0) and s.terms[17] == (2, 3) and s.terms[20] == (5, 0)
    for m in (12, 17, 20):  # x^2y^2, x^2y^3, x^5
        name = f"surfaces.4.a.{m}"
        set_trainable(lens, [name])
        (group,) = optics_param_groups(lens, LR_MM)
        i, j = s.terms[m]
        assert group["name"] == f"lens.{name}"
        assert group["lr"] == pytest.approx(LR_MM / R ** (i + j), rel=1e-15)
        opt = torch.optim.Adam([group])

        def step():
            xq = torch.tensor([0.7 * R], dtype=torch.float64)
            s.sag(xq, torch.full_like(xq, 0.4 * R)).sum().backward()
            opt.step()

        assert _max_sag_change(lens, 4, step) == pytest.approx(LR_MM, rel=1e-6)


def test_plate_order_gradients_match_finite_differences():
    """Gradients of a traced loss (``sum w·(x, y)`` of the rays on the sensor from 4.5 m, fixed
    random weights) with respect to every added coefficient (x^4 ... y^5) at the learned
    plate's start (the 5 µm cubic plate, added terms at zero) against a fourth-order central
    difference, float64; each gradient moves the loss by far more than its float64
    resolution (~1e-13) over one step, and no step changes which rays are valid."""
    import helpers as H
    from deeplens.optics.sampling import point_source_rays
    from deeplens.training.lens_setup import build_lens

    lens = build_lens(EDOF, trainable=PLATE_TERMS, dtype="float64", plate="learned",
                      plate_surface=4, plate_order=5, learned_start_alpha_mm=0.005,
                      focus_mm=5760.0)
    s = lens.surfaces[4]
    R = float(s.semi_diameter)
    rays = point_source_rays(lens, (0.0, 0.0), 4500.0, 587.5618, 0, sampling="grid:16")
    with torch.no_grad():
        valid0 = lens.trace_to_sensor(rays).valid.clone()
    w = torch.randn(valid0.shape + (2,), generator=torch.Generator().manual_seed(0),
                    dtype=torch.float64)

    def loss():
        out = lens.trace_to_sensor(rays)
        assert torch.equal(out.valid, valid0)
        return (w * out.o[..., :2])[out.valid].sum()

    lens.zero_grad()
    loss().backward()
    for m in range(10, 21):
        i, j = s.terms[m]
        h = 1e-4 / R ** (i + j)  # 0.1 µm of sag at the rim
        g = float(s.a[m].grad)
        fd = H.central_fd(loss, s.a[m], h)
        assert abs(g * h) > 1e-5, (m, g)  # measured: 1.9e-5 (x^4) to 1.3e-2 (y^5)
        assert g == pytest.approx(fd, rel=1e-8), (m, g, fd)  # measured: <= 3e-10


@pytest.mark.parametrize("order, match", [
    (2, r"lens.plate_order: expected an int in \[3, 12\]"),   # would drop the cubic terms
    (13, r"lens.plate_order: expected an int in \[1, 12\]"),  # checked before the file is read
    (5.0, r"lens.plate_order: expected an int"),
    (True, r"lens.plate_order: expected an int"),
    ("5", r"lens.plate_order: expected an int"),
])
def test_plate_order_bad_values_are_named(order, match):
    from deeplens.training.lens_setup import build_lens

    with pytest.raises(ValueError, match=match):
        build_lens(EDOF, trainable=PLATE_TERMS, plate="learned", plate_surface=4,
                   plate_order=order)


def test_plate_order_needs_an_xy_plate():
    from deeplens.training.lens_setup import build_lens, extend_plate

    with pytest.raises(ValueError, match=r"lens.plate_surface: missing; expected .*lens.plate_order"):
        build_lens(EDOF, plate="learned", plate_order=5)
    with pytest.raises(ValueError, match=r"lens.plate_surface: expected the index of an XY-polynomial surface .*, got 3"):
        build_lens(EDOF, plate="learned", plate_surface=3, plate_order=5)
    with pytest.raises(ValueError, match=r"lens.plate_surface: expected a surface index"):
        extend_plate(load_lens(DATA / "edof_achromat.json"), 9, 5)


def test_plate_order_checked_in_the_config():
    """``lens.plate_order`` is checked at start-up with the other lens keys
    (lens_setup.check_lens_settings, called by train.check_config)."""
    from omegaconf import OmegaConf

    from deeplens.optics.errors import ConfigError
    from deeplens.training.lens_setup import check_lens_settings

    check_lens_settings(EDOF, plate_surface=4, plate_order=5)
    for bad in (0, 13, 2.5, True):
        with pytest.raises(ConfigError, match=r"an int in \[1, 12\]") as e:
            check_lens_settings(EDOF, plate_surface=4, plate_order=bad)
        assert e.value.key == "lens.plate_order" and e.value.got is bad
    cfg = OmegaConf.load(Path(__file__).resolve().parents[2] / "configs" / "lens" / "edof.yaml")
    assert cfg.plate_order is None  # the default keeps the file's order (results reproducible)
