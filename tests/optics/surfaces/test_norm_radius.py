"""Every surface whose terms are in ``x / R_n``, ``y / R_n`` refuses a normalisation radius that is
not a finite number > 0, naming itself (one check, ``surfaces.base.norm_radius_mm``)."""

from __future__ import annotations

import math

import pytest

from deeplens.optics.surfaces import (Binary1, Binary2, ExtendedOddAsphere, ExtendedPolynomial,
                                      QType, ZernikeSag)
from deeplens.optics.surfaces.zernike_phase import ZernikeFringePhase

BUILD = {
    "QType": lambda rn: QType(0.01, 5.0, rn, [1e-4]),
    "ZernikeSag": lambda rn: ZernikeSag(0.01, 5.0, rn, [0.0, 1e-4]),
    "ExtendedOddAsphere": lambda rn: ExtendedOddAsphere(0.01, 5.0, rn, [0.0, 1e-4, 1e-5]),
    "ExtendedPolynomial": lambda rn: ExtendedPolynomial(0.01, 5.0, rn, [0.0, 1e-4]),
    "Binary2": lambda rn: Binary2(0.0, 5.0, rn, [-10.0]),
    "Binary1": lambda rn: Binary1(0.0, 5.0, rn, [0.0, 1.0]),
    "ZernikeFringePhase": lambda rn: ZernikeFringePhase(0.0, 5.0, rn, [0.0, 0.1]),
}


@pytest.mark.parametrize("owner", sorted(BUILD))
@pytest.mark.parametrize("rn", [0.0, -2.0, math.inf, math.nan])
def test_a_bad_normalisation_radius_is_refused_naming_the_surface(owner, rn):
    with pytest.raises(ValueError, match=rf"^{owner}: the normalisation radius must be a "
                                         rf"positive number of mm, got"):
        BUILD[owner](rn)


@pytest.mark.parametrize("owner", sorted(BUILD))
def test_a_good_normalisation_radius_is_kept(owner):
    assert float(BUILD[owner](4.0).norm_radius) == 4.0
