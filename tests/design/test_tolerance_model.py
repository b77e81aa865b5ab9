"""Tolerance groups (deeplens.optics.tolerance_model, deeplens.design.tolerance_groups): drawn statistics against the configured
distributions, the drawn lens against one built explicitly, gradients through a drawn lens
against central differences (float64), the refocus compensator, config errors naming the key."""

import copy
import math

import pytest
import torch
from helpers import LENS_DIR, central_fd, rel_err

from deeplens.design.tolerance_groups import load_group
from deeplens.optics.tolerance_model import (Distribution, ToleranceModel, axis_image,
                                             call_drawn, drawn)
from deeplens.optics.io import load_lens
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays


@pytest.fixture(scope="module")
def doublet():
    return load_lens(LENS_DIR / "wide_doublet.json").to(torch.float64)


def _rays(lens, n=64, field_deg=8.0):
    """A seeded bundle from a distant point at ``field_deg`` through the stop region."""
    g = torch.Generator().manual_seed(1)
    r = 0.9 * float(lens.stop.semi_diameter) * torch.sqrt(torch.rand(n, generator=g,
                                                                     dtype=torch.float64))
    phi = 2 * math.pi * torch.rand(n, generator=g, dtype=torch.float64)
    z0 = float(lens.z_vertices()[lens.stop_index].detach())
    p = torch.stack([r * torch.cos(phi), r * torch.sin(phi), torch.full_like(r, z0)], -1)
    t = math.tan(math.radians(field_deg))
    d = torch.tensor([0.0, t, 1.0], dtype=torch.float64).expand(n, 3)
    o = p - 2.0 * d
    return Rays(o, d.clone(), 587.5618)


@pytest.mark.parametrize("spec", [
    {"shape": "normal", "std": 0.02, "truncate": 2.0},
    {"shape": "normal", "std": 0.02, "truncate": 1.0},
    {"shape": "uniform", "half_width": 0.03},
])
def test_drawn_statistics_match_the_distribution(spec):
    """Mean, std (truncated-normal closed form) and bound within sampling error (5 sigma)."""
    d = Distribution.from_config(spec, "t")
    n = 40000
    x = d.sample(n, torch.Generator().manual_seed(0))
    sd = d.std
    assert abs(float(x.mean())) < 5 * sd / math.sqrt(n)
    # std of the sample std ~ sd / sqrt(2n) (kurtosis < 3 here): 5 of those
    assert abs(float(x.std()) - sd) < 5 * sd / math.sqrt(2 * n)
    assert float(x.abs().max()) <= d.bound
    assert float(x.abs().max()) > 0.97 * d.bound  # the bound is reached, not a narrower one
    if spec["shape"] == "normal":  # a truncated normal's std is below sigma, e.g. 0.880 at 2
        k = spec["truncate"]
        assert sd < spec["std"]
        assert sd == pytest.approx(spec["std"] * {2.0: 0.87962, 1.0: 0.53956}[k], rel=1e-4)


def test_lens_draws_follow_each_kind_and_are_reproducible(doublet):
    """Per-kind offsets over 1500 drawn lenses: mean and std of the configured ones; a seed
    gives the same lens again."""
    tm = ToleranceModel({"decenter": {"shape": "normal", "std": 0.01, "truncate": 2},
                         "air_gap": {"shape": "uniform", "half_width": 0.02},
                         "radius": {"unit": "relative", "shape": "normal", "std": 1e-3,
                                    "truncate": 3}})
    draws = tm.draws(doublet, 1500, seed=5)
    dx = torch.tensor([d.offsets["misalignments.1.dx"] for d in draws])
    gap = torch.tensor([d.offsets["distances.1"] for d in draws])
    rel = torch.tensor([d.relative["surfaces.1.c"] for d in draws])
    for x, dist in ((dx, tm.dists["decenter"]), (gap, tm.dists["air_gap"]),
                    (rel, tm.dists["radius"])):
        n = len(x)
        assert abs(float(x.mean())) < 5 * dist.std / math.sqrt(n)
        assert abs(float(x.std()) - dist.std) < 5 * dist.std / math.sqrt(2 * n)
        assert float(x.abs().max()) <= dist.bound
    assert "distances.2" not in draws[0].offsets  # glass thickness: not toleranced here
    assert tm.draw(doublet, 17) == tm.draw(doublet, 17)
    assert tm.draw(doublet, 17) != tm.draw(doublet, 18)


def _explicit(lens, draw):
    """The drawn lens built by hand: a copy with the drawn values written in."""
    L = copy.deepcopy(lens)
    params = dict(L.named_parameters())
    with torch.no_grad():
        for n, eps in draw.relative.items():
            params[n].copy_(params[n] / (1 + eps))
        for n, dlt in draw.offsets.items():
            params[n].add_(dlt)
    return L


def test_drawn_lens_equals_the_lens_built_explicitly(doublet):
    """Traced rays through the drawn lens equal those through a copy with the drawn values
    written in (a decenter, a tilt, a curvature, a gap, the sensor), and the lens is back to
    nominal afterwards."""
    tm = ToleranceModel({"decenter": {"shape": "normal", "std": 0.05, "truncate": 2},
                         "tilt": {"shape": "normal", "std": 1e-3, "truncate": 2},
                         "radius": {"unit": "fringes", "shape": "uniform", "half_width": 5},
                         "air_gap": {"shape": "normal", "std": 0.02, "truncate": 2},
                         "sensor": {"shape": "uniform", "half_width": 0.02}})
    d = tm.draw(doublet, 3)
    assert abs(d.offsets["misalignments.1.dx"]) > 1e-3
    rays = _rays(doublet)
    before = doublet.trace_to_sensor(rays).o
    got = call_drawn(doublet, d, lambda L: L.trace_to_sensor(rays).o)
    want = _explicit(doublet, d).trace_to_sensor(rays).o
    assert float((got - want).abs().max()) < 1e-12
    assert float((got - before).abs().max()) > 1e-4  # the draw changed something
    assert float((doublet.trace_to_sensor(rays).o - before).abs().max()) == 0.0
    # a decenter alone, its sign: the image of the axis point moves with the element
    only = ToleranceModel({"decenter": {"shape": "uniform", "half_width": 0.05}}).draw(doublet, 3)
    dx = only.offsets["misalignments.1.dx"]
    want = _explicit(doublet, only).trace_to_sensor(_rays(doublet, field_deg=0.0)).o
    with drawn(doublet, only) as L:
        assert float(L.misalignments[1].dx) == dx
        got = L.trace_to_sensor(_rays(doublet, field_deg=0.0)).o
    assert float((got - want).abs().max()) < 1e-12
    # a positive element moved by +dx bends the on-axis beam towards +x
    assert math.copysign(1.0, float(got[:, 0].mean())) == math.copysign(1.0, dx)


def test_fringes_and_glass_perturbation(doublet):
    """Fringes: Δc = N λ / h²; glass: n_d + Δn, V_d scaled by 1 + ε_V (to first order)."""
    tm = ToleranceModel({"radius": {"unit": "fringes", "shape": "uniform", "half_width": 3},
                         "index": {"shape": "uniform", "half_width": 1e-3},
                         "abbe": {"shape": "uniform", "half_width": 0.02}})
    d = tm.draw(doublet, 11)
    n_frac = d.offsets["surfaces.1.c"] * 2.6 ** 2 / 632.8e-6
    assert abs(n_frac) <= 3 and abs(n_frac) > 0
    m0 = doublet.materials[2]
    nd0, vd0 = m0.nd, m0.vd
    dn, ev = d.materials[2]
    with drawn(doublet, d) as L:
        m = L.materials[2]
        assert m.nd == pytest.approx(nd0 + dn, abs=1e-12)
        assert m.vd == pytest.approx(vd0 * (1 + ev) * (nd0 + dn - 1) / (nd0 - 1), rel=1e-9)
    assert doublet.materials[2] is m0


def test_compensator_refocuses_each_drawn_lens(doublet):
    """With ``compensator: refocus`` the sensor keeps its nominal distance from the paraxial
    image of every drawn lens (plus the drawn sensor error); without it, it does not."""
    cfg = {"thickness": {"shape": "normal", "std": 0.05, "truncate": 2},
           "radius": {"unit": "relative", "shape": "normal", "std": 2e-3, "truncate": 2}}
    nominal_gap = float(doublet.d_sensor - paraxial(doublet).image_distance)
    for comp, expect_equal in (("refocus", True), (None, False)):
        tm = ToleranceModel({**cfg, "compensator": comp})
        d = tm.draw(doublet, 2)
        with drawn(doublet, d) as L:
            gap = float(L.d_sensor - paraxial(L).image_distance)
        if expect_equal:
            assert gap == pytest.approx(nominal_gap, abs=1e-12)
        else:
            assert abs(gap - nominal_gap) > 1e-3


def _field_centroid(lens, field_deg):
    """Centroid (mm) of a distant point's bundle at ``field_deg`` on the sensor: an independent
    probe (the seeded bundle of :func:`_rays`, not the compensator's hexapolar one)."""
    out = lens.trace_to_sensor(_rays(lens, 256, field_deg))
    assert bool(out.valid.all())
    return out.o[:, :2].mean(0)


def test_center_compensator_puts_the_axis_image_back(doublet):
    """``compensator: center`` translates the whole drawn lens so that the on-axis image lands
    where the nominal lens puts it (to 1e-8 mm in float64), for decentred and tilted elements;
    without it the image moves by tens of µm; the translation is rigid (every element, the stop
    included, by the same amount), and the image at 8 deg is put back too, to within the
    drawn lens's change of distortion (an independent probe bundle)."""
    cfg = {"decenter": {"shape": "normal", "std": 0.025, "truncate": 2.0},
           "tilt": {"shape": "normal", "std": 5e-4, "truncate": 2.0}}
    with torch.no_grad():
        c0, f0 = axis_image(doublet), _field_centroid(doublet, 8.0)
        for seed in range(4):
            d_free = ToleranceModel(cfg).draw(doublet, seed)
            d_cent = ToleranceModel({**cfg, "compensator": ["refocus", "center"]}).draw(doublet,
                                                                                         seed)
            assert d_cent.center and not d_free.center
            assert d_cent.offsets == d_free.offsets       # the compensator draws nothing
            moved = float((call_drawn(doublet, d_free, axis_image) - c0).norm())
            with drawn(doublet, d_cent) as L:
                back = float((axis_image(L) - c0).norm())
                field_back = float((_field_centroid(L, 8.0) - f0).norm())
                p = dict(L.named_parameters())
                shift = [(float(p[f"misalignments.{e}.dx"]) - d_cent.offsets.get(
                    f"misalignments.{e}.dx", 0.0)) for e in range(len(L.elements))]
            assert moved > 5e-3                            # > 5 µm without the compensator
            assert back < 1e-8
            assert field_back < 0.1 * moved
            assert len(set(round(v, 15) for v in shift)) == 1 and abs(shift[0]) > 1e-3
    # after the block the nominal lens is back, unchanged
    assert float((axis_image(doublet) - c0).norm()) == 0.0


def test_center_compensator_is_exact_for_a_lens_without_errors(doublet):
    """Nothing drawn: the centred lens is the nominal lens bit for bit (the miss is exactly 0)."""
    d = ToleranceModel({"decenter": {"shape": "normal", "std": 0.0},
                        "compensator": "center"}).draw(doublet, 0)
    rays = _rays(doublet)
    with torch.no_grad():
        ref = doublet.trace_to_sensor(rays).o
        got = call_drawn(doublet, d, lambda L: L.trace_to_sensor(rays).o)
    assert torch.equal(ref, got)


@pytest.mark.parametrize("comp", [None, "refocus", ["refocus", "center"]])
def test_gradient_through_a_drawn_lens_reaches_the_nominal_parameters(doublet, comp):
    """d/dθ of the traced spot through a fixed drawn lens vs central FD of the nominal θ."""
    L = copy.deepcopy(doublet)
    for n in ("surfaces.1.c", "surfaces.1.a.0", "distances.2"):
        dict(L.named_parameters())[n].requires_grad_(True)
    tm = ToleranceModel({"radius": {"unit": "relative", "shape": "normal", "std": 3e-3},
                         "decenter": {"shape": "normal", "std": 0.03},
                         "thickness": {"shape": "normal", "std": 0.03},
                         "tilt": {"shape": "normal", "std": 1e-3},
                         "compensator": comp})
    d = tm.draw(L, 4)
    rays = _rays(L)

    def loss():
        o = call_drawn(L, d, lambda M: M.trace_to_sensor(rays).o)
        return ((o[:, :2] - o[:, :2].mean(0)) ** 2).sum() + o[:, 1].sum()

    params = dict(L.named_parameters())
    g = torch.autograd.grad(loss(), [params[n] for n in ("surfaces.1.c", "surfaces.1.a.0",
                                                         "distances.2")])
    for (n, h), gi in zip((("surfaces.1.c", 1e-5), ("surfaces.1.a.0", 1e-6),
                           ("distances.2", 1e-4)), g):
        fd = central_fd(loss, params[n], h)
        assert rel_err(gi, fd) < 1e-6, (n, float(gi), fd)


def test_groups_load_and_bad_values_name_the_key(doublet):
    for name in ("none", "precision", "commercial", "commercial_aligned"):
        tm = load_group(name)
        assert bool(tm) == (name != "none")
        assert tm.parameters_of(doublet)
    with pytest.raises(ValueError, match=r"tolerance\.decenter\.std"):
        ToleranceModel({"decenter": {"shape": "normal", "std": -1}})
    with pytest.raises(ValueError, match=r"tolerance\.tilt\.shape"):
        ToleranceModel({"tilt": {"shape": "gauss", "std": 1e-3}})
    with pytest.raises(ValueError, match=r"tolerance: unknown key\(s\) \['decentre'\]"):
        ToleranceModel({"decentre": {"shape": "normal", "std": 1e-3}})
    with pytest.raises(ValueError, match=r"tolerance\.sensor: unknown key\(s\) \['std'\]"):
        ToleranceModel({"sensor": {"shape": "uniform", "std": 1e-3}})
    with pytest.raises(ValueError, match=r"tolerance\.radius\.unit"):
        ToleranceModel({"radius": {"unit": "waves", "shape": "normal", "std": 1}})
    with pytest.raises(ValueError, match=r"tolerance\.compensator"):
        ToleranceModel({"compensator": "refocus_all"})
    with pytest.raises(ValueError, match=r"tolerance\.compensator: expected .*, got \['refocus', 'centre'\]"):
        ToleranceModel({"compensator": ["refocus", "centre"]})
    with pytest.raises(ValueError, match=r"tolerance\.compensator: expected .*\(each once\), got \['center', 'center'\]"):
        ToleranceModel({"compensator": ["center", "center"]})
    with pytest.raises(ValueError, match=r"tolerance\.compensator: expected null"):
        ToleranceModel({"compensator": {"center": True}})
    assert ToleranceModel({"compensator": ["center", "refocus"]}).compensators == ("refocus",
                                                                                   "center")
    with pytest.raises(ValueError, match=r"tolerance: expected a tolerance group .*, got 'precise'"):
        load_group("precise")


@pytest.mark.parametrize("comp", ["refocus", ["refocus", "center"]])
def test_adjoint_render_gradient_through_a_drawn_lens(comp):
    """The adjoint renderer re-traces in the backward pass: with the backward inside the
    drawn-lens context its lens gradient equals plain autograd's through the drawn lens; a
    backward after the context (the nominal lens re-traced) gives another gradient.  With the
    centring compensator (whose translation depends on the trained coefficient) every chunk's
    gradient runs through the compensator's graph again (one per wavelength here), and the
    misalignments are functions of the trained coefficient: the adjoint pass must not count that
    path twice (it did, by 0.2-4 %, before it re-entered the lens's tensors as leaves)."""
    from deeplens.optics.materials import get_material
    from deeplens.optics.lens import Lens
    from deeplens.optics.surfaces import Aperture, Asphere
    from deeplens.render import MonteCarloRenderer, Scene, Sensor

    lens = Lens([Aperture(4.0), Asphere(1 / 50.0, 8.0, coefficients=[1e-6]),
                 Asphere(-1 / 50.0, 8.0)],
                [get_material(m) for m in ("AIR", "AIR", "N-BK7", "AIR")], [0.0, 2.0, 5.0],
                48.0, 0)
    a = lens.surfaces[1].a[0]
    a.requires_grad_(True)
    sensor = Sensor((8, 8), 0.05)
    tex = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(0),
                     dtype=torch.float64)
    scene = Scene(tex, 1000.0)
    d = ToleranceModel({"decenter": {"shape": "uniform", "half_width": 0.3},
                        "tilt": {"shape": "uniform", "half_width": 0.01},
                        "compensator": comp}).draw(lens, 0)

    def grad(adjoint, backward_inside=True):
        r = MonteCarloRenderer(lens, sensor, spp=4, adjoint=adjoint, decorrelate=False)
        with drawn(lens, d):
            loss = (r(scene, seed=3) ** 2).sum()
            if backward_inside:
                return torch.autograd.grad(loss, a)[0]
        return torch.autograd.grad(loss, a)[0]

    plain, adj = grad(False), grad(True)
    assert float(plain.abs()) > 0
    assert rel_err(adj, plain) < 1e-6
    if "center" in comp:  # the centring makes the misalignments functions of ``a``: outside
        # the context they are plain frozen parameters again, and the adjoint pass says so
        with pytest.raises(RuntimeError, match="changed between the render"):
            grad(True, backward_inside=False)
    else:
        assert rel_err(grad(True, backward_inside=False), plain) > 1e-3


def test_monte_carlo_of_a_group_draws_the_same_lenses(doublet):
    """``monte_carlo(model=group)`` trial k is the lens the group draws with seed ``seed + k``
    (the lenses training and evaluation see)."""
    from deeplens.design.merit import SpotMerit
    from deeplens.design.sensitivity import field_merits
    from deeplens.design.tolerance import monte_carlo

    tm = load_group("commercial")
    sm = SpotMerit([10.0], [587.5618], sampling="hexapolar:3", strict_rays=False).prepare(doublet)
    mc = monte_carlo(doublet, sm, [], [], n=3, seed=5, model=tm)
    with torch.no_grad():
        want = torch.stack([call_drawn(doublet, tm.draw(doublet, 5 + k),
                                       lambda L: field_merits(sm, L)) for k in range(3)]) * 1e3
    assert rel_err(torch.tensor(mc["samples_um"], dtype=torch.float64), want) < 1e-12
    assert float(want.std(0)) > 0


@pytest.mark.slow
def test_deeplens_tolerance_group_draws_the_same_lenses(doublet, capsys):
    """``deeplens tolerance --group`` Monte Carlo trial k is the lens the group draws with seed
    ``--seed + k`` (the lenses training and evaluation see); --tolerances with --group is
    refused."""
    import json

    import helpers as H

    from deeplens.design.merit import SpotMerit
    from deeplens.design.sensitivity import field_merits

    path = str(LENS_DIR / "wide_doublet.json")
    code, out, err = H.run_cli(["tolerance", path, "--group", "commercial", "--monte-carlo",
                                "2", "--seed", "5", "--fields", "10", "--sampling", "hexapolar:3", "--json"], capsys)
    assert code == 0, err
    res = json.loads(out)
    assert "group commercial" in res["distribution"]
    assert "misalignments.1.dx" in res["parameters"]
    tm = load_group("commercial")
    sm = SpotMerit([10.0], [float(doublet.spec.primary_wavelength_nm)],
                   sampling="hexapolar:3", strict_rays=False).prepare(doublet)
    with torch.no_grad():
        want = torch.stack([call_drawn(doublet, tm.draw(doublet, 5 + k),
                                       lambda L: field_merits(sm, L)) for k in range(2)]) * 1e3
    got = torch.tensor(res["monte_carlo"]["mean_um"], dtype=torch.float64)
    assert rel_err(got, want.mean(0)) < 1e-9
    code, _, err = H.run_cli(["tolerance", path, "--group", "commercial", "--tolerances",
                              "x.json"], capsys)
    assert code == 2 and "not both" in err
