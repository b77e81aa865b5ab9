"""``SQAP`` (a rectangular clear aperture) on a lens surface of any sag type, not only on
STANDARD/EVENASPH: a flat face between glass and air, an odd asphere, a Zernike sag, a biconic.

Collimated rays parallel to the axis meet the surface at their own ``(x, y)``, so which pass is
known exactly: inside the rectangle ``|x| <= 3, |y| <= 1`` they pass, outside it (but inside its
circumscribed circle, r = 3.16 mm) they are blocked.  The rectangle survives both file formats.
"""

from __future__ import annotations

import helpers as H
import pytest
import torch
from test_zmx import singlet, write

from deeplens.optics.io import lens_to_dict, read_zmx, write_zmx
from deeplens.optics.io.lensfile import lens_from_dict
from deeplens.optics.options import TraceOptions
from deeplens.optics.surfaces.base import clear_rect_of

CASES = {
    "flat face": dict(s1_type="STANDARD", curv1=0.0, k=0.0, s1_extra=("SQAP 3 1 0",)),
    "odd asphere": dict(s1_type="ODDASPHE", s1_extra=("PARM 3 1e-4", "SQAP 3 1 0")),
    "zernike sag": dict(s1_type="SZERNSAG", s1_extra=("XDAT 1 4", "XDAT 2 4", "XDAT 6 0.001",
                                                      "SQAP 3 1 0")),
    "biconic": dict(s1_type="BICONICX", s1_extra=("PARM 1 40", "SQAP 3 1 0")),
}

INSIDE = [(0.0, 0.0), (2.9, 0.0), (0.0, 0.95), (-2.9, -0.95)]
OUTSIDE = [(0.0, 1.1), (3.05, 0.0), (1.0, -1.2), (-2.0, 2.0)]


def passes(lens, points, options=None):
    xy = torch.tensor(points, dtype=torch.float64)
    z0 = float(lens.z_vertices()[0]) - 1.0
    rays = H.collimated(xy, (0.0, 0.0, 1.0), z0, float(lens.spec.primary_wavelength_nm))
    out = lens.trace_to_sensor(rays, options=options)
    return out.valid.tolist()


@pytest.mark.parametrize("case", sorted(CASES))
def test_sqap_clips_any_surface_type(tmp_path, case):
    lens = read_zmx(write(tmp_path, singlet(**CASES[case])))
    surf = lens.surfaces[1]
    assert clear_rect_of(surf) == (3.0, 1.0)
    assert float(surf.semi_diameter) == pytest.approx(10 ** 0.5, rel=1e-15)
    for options in (None, TraceOptions(closed_form=False)):
        assert passes(lens, INSIDE, options) == [True] * len(INSIDE)
        assert passes(lens, OUTSIDE, options) == [False] * len(OUTSIDE)
    # both file formats keep it
    back = lens_from_dict(lens_to_dict(lens))
    assert clear_rect_of(back.surfaces[1]) == (3.0, 1.0)
    assert passes(back, OUTSIDE) == [False] * len(OUTSIDE)
    write_zmx(lens, tmp_path / "out.zmx")
    again = read_zmx(tmp_path / "out.zmx")
    assert clear_rect_of(again.surfaces[1]) == (3.0, 1.0)
    assert passes(again, INSIDE + OUTSIDE) == [True] * len(INSIDE) + [False] * len(OUTSIDE)


def test_without_sqap_the_same_rays_pass(tmp_path):
    """The control: the rays blocked above pass the same lens without its SQAP."""
    kw = dict(CASES["flat face"])
    kw["s1_extra"] = ()
    lens = read_zmx(write(tmp_path, singlet(**kw)))
    assert clear_rect_of(lens.surfaces[1]) is None
    assert passes(lens, OUTSIDE) == [True] * len(OUTSIDE)
