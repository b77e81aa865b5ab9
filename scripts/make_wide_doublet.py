"""Regenerate data/lenses/wide_doublet.json: Thorlabs AC254-050-A (N-BAF10/N-SF10) scaled by 0.2
to f ~ 10 mm, a stop 1.5 mm in front at F/4, fields 0/10/20 deg, the sensor at the paraxial focus
with a half-diagonal of f tan(21 deg); even aspheric a4/a6 on the outer surfaces start at zero
(they are what experiment=doublet trains).

    python scripts/make_wide_doublet.py
"""

import math

from deeplens.optics.paraxial import paraxial
from deeplens.optics.io import save_lens
from deeplens.optics.lens import Lens, LensSpec
from deeplens.optics.materials import get_material as M
from deeplens.optics.surfaces import Aperture, Asphere

SCALE = 0.2
NAME = ("Wide-field cemented doublet: Thorlabs AC254-050-A scaled x0.2 (f ~ 10 mm), stop 1.5 mm "
        "in front, F/4, +-20 deg; a4/a6 on the outer surfaces start at zero")


def main():
    surfaces = [Aperture(1.25),
                Asphere(1 / (33.3 * SCALE), 2.6, coefficients=[0.0, 0.0]),
                Asphere(-1 / (22.28 * SCALE), 2.6),
                Asphere(-1 / (291.07 * SCALE), 2.6, coefficients=[0.0, 0.0])]
    media = [M("AIR"), M("AIR"), M("N-BAF10"), M("N-SF10"), M("AIR")]
    gaps = [0.0, 1.5, 9.0 * SCALE, 2.5 * SCALE]
    spec = LensSpec(fields_deg=[0.0, 10.0, 20.0], wavelengths_nm=[486.1327, 587.5618, 656.2725],
                    primary_wavelength_nm=587.5618, aperture_type="fno", aperture_value=4.0)
    p = paraxial(Lens(surfaces, media, gaps, 10.0, 0, None, spec))
    lens = Lens(surfaces, media, gaps, float(p.bfl), 0,
                float(p.efl) * math.tan(math.radians(21)), spec, name=NAME)
    save_lens(lens, "data/lenses/wide_doublet.json")
    print("wrote data/lenses/wide_doublet.json")


if __name__ == "__main__":
    main()
