"""OpticStudio's own published first-order numbers, as tests.

The systems are the reference prescriptions of optiland's validation call (optiland/optiland
issue #710, "Help wanted: validate Optiland against Zemax OpticStudio, CODE V, or another
trusted tool"), written here by hand as ``.zmx`` files (``tests/data/zmx_opticstudio``, see its
SOURCES.md), read by deeplens' reader with its own glass catalogues:

* **Cooke triplet** (Hikari SK16, Schott F2; EPD 10 mm, 0.48/0.55/0.65 µm, primary 0.55 µm):
  values from the Merit Function Editor of OpticStudio 2026 R1.00, pasted at 16 significant
  digits (comment of 2026-09-22 by BHelber).
* **SingletStopSurf2** (Hoya LAC9, the stop on the rear surface; EPD 25 mm, F/d/C lines):
  values from OpticStudio 2025 R2.02 with the Hoya catalogue, 7 significant digits (comment of
  2026-08-14 by DaveReed7983).

Tolerances.  A paraxial y-u trace through 6 surfaces rounds each of its ~30 operations at
``eps = 2.2e-16`` relative on lengths of <= 100 mm, so EFL, F/# and pupil positions carry a
few 1e-14 mm of rounding; the back focal point and the rear principal plane are differences of
~50 mm lengths, a few 1e-14 mm too.  The tests allow 1e-12 mm (1e-13 relative), 20 to 50 times
the measured differences (<= 4e-14 mm).  The glasses: deeplens' HIKARI SK16 (archived
catalogue) and SCHOTT F2 are those optiland uses, and optiland's values agree with
OpticStudio's to 1e-14 there.  The singlet's numbers are rounded to 7 significant digits:
half a unit of the last printed digit is the tolerance.

The exit pupil is the exception: OpticStudio's Cooke values differ from deeplens' (and
optiland's) by 3.2e-7 mm in position and 1.1e-7 mm in diameter while every other number agrees
to 1e-14.  deeplens' exit pupil is the paraxial (Gaussian) image of the stop; OpticStudio
locates it with real "parabasal" rays from near the stop's centre, whose axis crossing lies
``a ε²`` from the paraxial one (the pupil's spherical aberration): a real ray at ε ≈ 3.4e-4 rad
lands exactly on OpticStudio's number (last test; docs/guide/zemax.md, "OpticStudio's own
numbers").  It is tested to that achieved accuracy, and against optiland's independent
paraxial trace to 1e-12 mm.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import pytest

from deeplens.optics.paraxial import exit_pupil, paraxial
from helpers import read_zmx_quiet

DATA = Path(__file__).resolve().parents[2] / "data" / "zmx_opticstudio"

#: OpticStudio 2026 R1.00, Merit Function Editor operands (issue #710, 2026-09-22); lengths in
#: mm, positions of the back focal point, rear principal plane and exit pupil from the image
#: surface, the entrance pupil from surface 1
COOKE_OS = {
    "efl": 4.999978307143194E+001,
    "epd": 1.000000000000000E+001,
    "enpp": 1.151215867374679E+001,
    "expd": 1.023372956403460E+001,
    "expp": -5.096134802390034E+001,
    "fno": 4.999978307143193E+000,
    "bfp": 2.070775589588518E-001,
    "p2": -4.979270551247308E+001,
}

#: OpticStudio 2025 R2.02, Hoya catalogue (issue #710, 2026-08-14), as printed (7 digits)
SINGLET_OS = {
    "efl": "101.501826", "epd": "25.000000", "enpp": "6.318809", "expd": "23.39711",
    "expp": "-92.73835", "fno": "4.060073", "bfp": "2.255622", "p2": "-99.246204",
}


@lru_cache(maxsize=None)
def first_order(name):
    """deeplens' values of the quantities above for ``tests/data/zmx_opticstudio/<name>.zmx``."""
    lens = read_zmx_quiet(DATA / f"{name}.zmx")
    p = paraxial(lens)
    z_last = float(lens.z_vertices()[-1])
    z_img = z_last + float(lens.d_sensor)
    z_xp, r_xp = exit_pupil(lens)
    return lens, {
        "efl": float(p.efl), "epd": float(p.entrance_pupil_diameter),
        "enpp": float(p.entrance_pupil_position), "expd": 2.0 * float(r_xp),
        "expp": float(z_xp) - z_img, "fno": float(p.fno),
        "bfp": z_last + float(p.bfl) - z_img,
        "p2": z_last + float(p.bfl) - float(p.efl) - z_img,
    }


def test_the_files_are_the_published_systems():
    """The glasses resolve to the catalogues the OpticStudio runs used, at the primary
    wavelength the issue gives; the stop is where the prescription puts it."""
    lens, _ = first_order("cooke_triplet")
    assert [(m.name, getattr(m, "catalogue", "")) for m in lens.materials[1::2]] == [
        ("SK16", "HIKARI"), ("F2", "SCHOTT"), ("SK16", "HIKARI")]
    assert float(lens.spec.primary_wavelength_nm) == 550.0 and lens.stop_index == 3
    lens, _ = first_order("singlet_stop_surf2")
    assert (lens.materials[1].name, lens.materials[1].catalogue) == ("LAC9", "HOYA")
    assert float(lens.spec.primary_wavelength_nm) == pytest.approx(587.5618, abs=1e-9)
    assert lens.stop_index == 1


@pytest.mark.parametrize("key", ["efl", "epd", "enpp", "fno", "bfp", "p2"])
def test_cooke_triplet_matches_opticstudio_to_16_digits(key):
    _, ours = first_order("cooke_triplet")
    assert ours[key] == pytest.approx(COOKE_OS[key], rel=1e-13, abs=1e-12)


def test_cooke_exit_pupil_to_the_achieved_accuracy():
    """OpticStudio's exit pupil: position within 5e-7 mm (measured 3.2e-7), diameter within
    2e-7 mm (measured 1.1e-7); see the module docstring."""
    _, ours = first_order("cooke_triplet")
    assert abs(ours["expp"] - COOKE_OS["expp"]) < 5e-7
    assert abs(ours["expd"] - COOKE_OS["expd"]) < 2e-7
    # not closer than that either: a change that closed the gap would be worth knowing about
    assert abs(ours["expp"] - COOKE_OS["expp"]) > 1e-7


def test_cooke_exit_pupil_matches_optiland():
    """The same definition in an independent paraxial trace: optiland's ``XPL``/``XPD`` of its
    own Cooke triplet (Hikari SK16, Schott F2), to 1e-12 mm."""
    pytest.importorskip("optiland")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from optiland.samples.objectives import CookeTriplet

        par = CookeTriplet().paraxial
        xpl, xpd, efl = float(par.XPL()), float(par.XPD()), float(par.f2())
    _, ours = first_order("cooke_triplet")
    assert ours["efl"] == pytest.approx(efl, rel=1e-14)
    assert ours["expp"] == pytest.approx(xpl, abs=1e-12)
    assert ours["expd"] == pytest.approx(xpd, abs=1e-12)


@pytest.mark.parametrize("key", sorted(SINGLET_OS))
def test_singlet_matches_opticstudio_to_its_printed_digits(key):
    """Every printed digit: within half a unit of the last one (the singlet's exit pupil, 2e-6
    and 4e-6 mm from deeplens' value, is the stop itself, 92.7383463 mm before the image, and
    was printed to 5 decimals)."""
    _, ours = first_order("singlet_stop_surf2")
    text = SINGLET_OS[key]
    half_ulp = 0.5 * 10.0 ** -len(text.split(".")[1])
    assert abs(ours[key] - float(text)) <= half_ulp * (1 + 1e-9)


def _real_crossing(lens, slope):
    """Where a real ray leaving the stop's centre (its vertex) with ``slope`` (in the medium
    behind it) crosses the axis in image space, from the image plane (mm; deeplens' tracer)."""
    import torch

    from deeplens.optics.rays import Rays

    k, w = lens.stop_index, float(lens.spec.primary_wavelength_nm)
    n, z = lens.indices(torch.tensor(w, dtype=torch.float64)), lens.z_vertices()
    d = torch.tensor([[0.0, slope, 1.0]], dtype=torch.float64)
    rays = Rays(torch.tensor([[0.0, 0.0, float(z[k])]], dtype=torch.float64), d / d.norm(), w)
    for i in range(k + 1, len(lens.surfaces)):
        rays = lens.trace_surface(i, rays, n[i], n[i + 1], z)
    o, d = rays.o[0], rays.d[0]
    z_cross = float(o[2] - o[1] / d[1] * d[2])
    return z_cross - (float(z[-1]) + float(lens.d_sensor))


def test_opticstudios_exit_pupil_is_a_real_parabasal_ray_crossing():
    """Real rays from the stop's centre cross the axis behind the lens at ``z(ε) = z_xp + a ε²``
    (the pupil's spherical aberration): Richardson extrapolation of two of them recovers
    deeplens' paraxial exit pupil to 1e-9 mm, and OpticStudio's published position lies on that
    parabola at ε ≈ 3.4e-4 rad (``a`` ≈ −2.7 mm/rad²), the "real parabasal rays" OpticStudio
    uses for the exit pupil (docs/guide/zemax.md).  A paraxial exit pupil 3.2e-7 mm from
    OpticStudio's is therefore the same definition, not a different one."""
    lens, ours = first_order("cooke_triplet")
    e = 1e-3
    z1, z2 = _real_crossing(lens, e), _real_crossing(lens, 2 * e)
    assert ours["expp"] == pytest.approx((4 * z1 - z2) / 3, abs=1e-9)
    a = (z2 - z1) / (3 * e * e)
    assert -3.0 < a < -2.5
    eps_os = ((COOKE_OS["expp"] - ours["expp"]) / a) ** 0.5
    assert 3.0e-4 < eps_os < 3.8e-4
    assert _real_crossing(lens, eps_os) == pytest.approx(COOKE_OS["expp"], abs=1e-10)


def test_double_gauss_matches_optiland():
    """The issue's third system, the Schott double Gauss (F/5 image-space, stop between the
    groups): no OpticStudio numbers for it are in the thread, so its first-order data are
    checked against optiland's own ``DoubleGauss`` sample (an independent paraxial trace with
    the same glasses from refractiveindex.info), to 1e-12 mm."""
    pytest.importorskip("optiland")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from optiland.samples.objectives import DoubleGauss

        par = DoubleGauss().paraxial
        ref = {"efl": float(par.f2()), "epd": float(par.EPD()), "enpp": float(par.EPL()),
               "expp": float(par.XPL()), "expd": float(par.XPD()), "bfp": float(par.F2()),
               "p2": float(par.P2())}
    lens, ours = first_order("double_gauss_schott")
    assert [m.name for m in lens.materials[1:]] == [
        "N-SSK2", "AIR", "N-SK2", "F5", "AIR", "AIR", "F5", "N-SK16", "AIR", "N-SK16", "AIR"]
    for key, v in ref.items():
        assert ours[key] == pytest.approx(v, rel=1e-13, abs=1e-12), key
    assert ours["fno"] == pytest.approx(5.0, rel=1e-14)
