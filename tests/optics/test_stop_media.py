"""Issue 25, item 9: an aperture stop between two different media is refused (a stop does not
refract, so the medium used to change there without refraction)."""

from __future__ import annotations

import pytest

from deeplens.optics.errors import LensError
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, get_material
from deeplens.optics.surfaces import Aperture, Asphere


def _lens(mid_before, mid_after):
    return Lens([Asphere(0.02, 5.0), Aperture(4.0), Asphere(-0.02, 5.0)],
                [Air(), mid_before, mid_after, Air()], [0.0, 2.0, 2.0], 40.0, 1)


def test_a_stop_between_two_glasses_is_refused_by_surface():
    with pytest.raises(LensError, match="surface 1 is an aperture stop between two different "
                                        "media") as e:
        _lens(get_material("N-BK7"), get_material("N-SF6"))
    assert e.value.surfaces == (1,)


def test_a_stop_between_glass_and_air_is_refused():
    with pytest.raises(LensError, match="surface 1 is an aperture stop"):
        _lens(get_material("N-BK7"), Air())


def test_a_stop_inside_one_glass_is_accepted():
    lens = _lens(get_material("N-BK7"), get_material("N-BK7"))
    assert lens.stop_index == 1
