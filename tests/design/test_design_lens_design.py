"""Lens-level design: the best-form singlet against its analytic bending, constraints held at
the optimum, an unmet constraint named at the start, crossing steps rejected, the merit's
Jacobian against central differences, and bad variable names."""

import math

import pytest
import torch
from helpers import LENS_DIR, singlet

from deeplens.optics.paraxial import paraxial
from deeplens.design.constraints import ConstraintError, parse_constraint
from deeplens.design.lensopt import lens_residual_fn, optimize_lens
from deeplens.design.merit import Merit, SpotMerit, TargetMerit
from deeplens.design.optimizers import Infeasible, jacobian
from deeplens.design.variables import Variables
from deeplens.optics.io import load_lens
from deeplens.optics.surfaces import Sphere

W = 587.5618


pytestmark = pytest.mark.usefixtures("quiet_warnings")


def _singlet(c1, c2, d_sensor=99.0):
    return singlet(Sphere(c1, 5.0), Sphere(c2, 5.0), thickness=1.0, glass="1.5/64.0",
                   d_sensor=d_sensor)


def test_best_form_singlet_matches_the_analytic_bending():
    """Minimum spherical aberration of a thin singlet (n = 1.5, object at infinity): Coddington
    shape factor q = (c1 + c2) / (c1 - c2) = 2 (n^2 - 1) / (n + 2) = 0.714 (third order).  DLS
    from the equi-convex lens (q = 0) with the EFL held at 100 mm reaches it (1 mm thick, F/10:
    higher orders and thickness move it by < 0.01)."""
    n, f = 1.5, 100.0
    c = 1 / (f * (n - 1)) / 2
    lens = _singlet(c, -c)
    sm = SpotMerit([0.0], [W], sampling="hexapolar:3", image_plane="paraxial", pupil="paraxial")
    v = Variables(lens, "surfaces.0.c,surfaces.1.c")
    res = optimize_lens(lens, v, Merit(sm, TargetMerit("efl", f, 100.0)), steps=40)
    c1, c2 = float(lens.surfaces[0].c), float(lens.surfaces[1].c)
    q = (c1 + c2) / (c1 - c2)
    assert q == pytest.approx(2 * (n * n - 1) / (n + 2), abs=0.01)
    assert float(paraxial(lens).efl) == pytest.approx(f, rel=1e-4)
    assert res.merit_after < 0.01 * res.merit_before


def test_constraint_holds_at_the_optimum_and_is_active():
    """Best focus lies beyond a total-track limit: the optimum sits on the limit, not past it."""
    lens = load_lens(LENS_DIR / "thorlabs_acl5040u.json").to(torch.float64)
    track0 = float(lens.z_sensor() - lens.z_vertices()[0])
    limit = track0 - 0.5
    with torch.no_grad():
        lens.d_sensor -= 1.0  # start inside the limit, focus lies further out
    cons = parse_constraint(lens, f"max_track={limit}")
    sm = SpotMerit([0.0], [W], sampling="hexapolar:3", pupil="paraxial")
    res = optimize_lens(lens, Variables(lens, "d_sensor"), Merit(sm), steps=30, constraints=cons)
    track = float(lens.z_sensor() - lens.z_vertices()[0])
    assert track <= limit + 1e-9
    assert track == pytest.approx(limit, abs=0.05)
    assert res.merit_after < res.merit_before


def test_constraint_unmet_at_start_says_which_and_by_how_much():
    lens = load_lens(LENS_DIR / "thorlabs_acl5040u.json").to(torch.float64)
    cons = parse_constraint(lens, "max_track=40")  # the lens is 47 mm long
    sm = SpotMerit([0.0], [W], sampling="hexapolar:2", pupil="paraxial")
    with pytest.raises(ConstraintError, match=r"max_track: 47 <= 40 \(unmet by 7 mm\)"):
        optimize_lens(lens, Variables(lens, "d_sensor"), Merit(sm), constraints=cons)
    # a lower limit: the ACL5040U is 21 mm thick in the centre
    (thick,) = parse_constraint(lens, "min_center_glass=30")
    assert thick.violation(lens) == pytest.approx(9.0)
    assert parse_constraint(lens, "min_center_glass=20")[0].violation(lens) == 0.0
    with pytest.raises(ValueError, match="unknown constraint 'max_trak'.*max_track"):
        parse_constraint(lens, "max_trak=40")
    with pytest.raises(ValueError, match="not a number|must be a number"):
        parse_constraint(lens, "max_track=long")


def test_edge_thickness_constraint_value():
    """Edge thickness of the biconvex singlet: t + sag2(R) - sag1(R) (both spheres)."""
    c = 0.02
    lens = _singlet(c, -c)
    (con,) = parse_constraint(lens, "min_edge_glass=0.1")
    R = 5.0
    sag = (1 - math.sqrt(1 - c * c * R * R)) / c
    assert float(con.value(lens)) == pytest.approx(1.0 - 2 * sag, rel=1e-12)


class _WantThin:
    """A merit that pulls the centre thickness to -1 mm (through crossing surfaces)."""

    def prepare(self, lens):
        return self

    def residuals(self, lens):
        return (lens.distances[1] + 1.0).reshape(1)


def test_step_that_makes_surfaces_cross_is_rejected():
    lens = _singlet(0.02, -0.02)
    v = Variables(lens, "distances.1")
    fn = lens_residual_fn(v, _WantThin())
    with pytest.raises(Infeasible, match="cross"):
        fn(torch.tensor([0.2], dtype=torch.float64))
    res = optimize_lens(lens, v, _WantThin(), steps=20)
    t = float(lens.distances[1])
    assert math.isfinite(t) and t > 0
    lens.check()  # the final lens is valid
    assert any("cross" in h.get("reason", "") for h in res.history if not h["accepted"])


def test_merit_jacobian_equals_central_differences():
    """Forward-mode Jacobian of the ACL5040U spot residuals w.r.t. c, k, a4 (scaled) against
    central differences in float64 (h = 1e-6 mm of sag: truncation ~1e-12, rounding ~1e-10)."""
    lens = load_lens(LENS_DIR / "thorlabs_acl5040u.json").to(torch.float64)
    v = Variables(lens, "surfaces.0.c,surfaces.0.k,surfaces.0.a.0")
    sm = SpotMerit([0.0], [W], sampling="hexapolar:4").prepare(lens)
    fn = lens_residual_fn(v, Merit(sm))
    x = v.x0()
    _, J = jacobian(fn, x, "forward")
    _, Jr = jacobian(fn, x, "reverse")
    h = 1e-6
    for j in range(3):
        e = torch.zeros_like(x)
        e[j] = h
        fd = (fn(x + e) - fn(x - e)) / (2 * h)
        assert float((fd - J[:, j]).abs().max() / J[:, j].abs().max()) < 1e-6
    assert torch.allclose(J, Jr, rtol=1e-10, atol=1e-14)
    _, Jc = jacobian(fn, x, "central")  # the DLS option (nikon's default)
    assert float((Jc - J).abs().max() / J.abs().max()) < 1e-6


def test_variables_scaling_and_unknown_names():
    lens = load_lens(LENS_DIR / "thorlabs_acl5040u.json").to(torch.float64)
    v = Variables(lens, ["surfaces.0.a.0", "surfaces.0.c"])
    assert v.names == ["surfaces.0.a.0", "surfaces.0.c"]  # the order given
    R = 25.0
    assert v.scale.tolist() == pytest.approx([R ** 4, R * R / 2])
    x = v.x0()
    assert float(x[1]) == pytest.approx(float(lens.surfaces[0].c) * R * R / 2)
    with pytest.raises(ValueError, match=r"'surfaces\.9\.c' matches no lens parameter; "
                                         r"available: d_sensor, surfaces\.0\.c"):
        Variables(lens, "surfaces.9.c")
    # values are substituted, not written, until assign()
    y = x.clone()
    y[1] = 0.0
    assert float(v.call(lambda L: L.surfaces[0].c * 1.0, y)) == 0.0
    assert float(lens.surfaces[0].c) != 0.0
    v.assign(y)
    assert float(lens.surfaces[0].c) == 0.0
