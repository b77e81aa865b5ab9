"""Regenerate data/lenses/*.json from the paper authors' tables (copies in tests/data/lenses).

    python scripts/convert_lenses.py [TABLE_DIR]

What each conversion adds that the table format cannot carry (fields, wavelengths, stop for
lenses without an A row, units) is written here, next to the file it concerns.
"""

from __future__ import annotations

import sys
from pathlib import Path

from deeplens.optics.io import lens_from_dict, save_lens, table_to_dict

ROOT = Path(__file__).resolve().parents[1]
FDC = (587.5618, 486.1327, 656.2725)  # d first: the primary wavelength

CONVERSIONS = {
    # name: (table file, options)
    "double_gauss": ("US02532751-1.txt", dict(
        fields_deg=[0.0, 7.0, 14.0, 21.0], wavelengths_nm=[587.5618],
        name="double Gauss after US 2,532,751 (DiffOptics table; Zemax file US02532751-1.zmx)")),
    "thorlabs_acl5040u": ("ACL5040U.txt", dict(
        stop_index=0, wavelengths_nm=list(FDC), name="Thorlabs ACL5040U aspheric condenser, "
        "f = 40 mm, B270 (stop: the first surface's clear aperture)")),
    "thorlabs_la1131": ("LA1131.txt", dict(
        stop_index=0, wavelengths_nm=list(FDC), name="Thorlabs LA1131 plano-convex, f = 50 mm, "
        "N-BK7 (stop: the first surface's clear aperture; the sensor distance is a placeholder)")),
    "edof_achromat": ("end2end_edof.txt", dict(
        stop_index=0, fields_deg=[0.0, 0.5, 1.0], wavelengths_nm=list(FDC),
        name="paper EDOF set-up: N-BK7/SF5 cemented achromat (f ~ 100 mm), N-BK7 plate, "
             "XY-polynomial phase surface at zero, sensor 96 mm behind")),
    # the patent example is in normalised units (EFL ~ 1.574); scaled x10 to a plausible mm size
    "nikon_z35_f1.8_x10": ("Nikon-z35-f1.8-JPA2019090949-example2.txt", dict(
        scale=10.0, wavelengths_nm=list(FDC),
        name="Nikon patent JPA2019090949 example 2 (normalised units scaled by 10)")),
}


def main(tables: Path) -> None:
    out = ROOT / "data" / "lenses"
    out.mkdir(parents=True, exist_ok=True)
    for name, (src, opts) in CONVERSIONS.items():
        d = table_to_dict(tables / src, **opts)
        lens = lens_from_dict(d, source=str(tables / src))
        save_lens(lens, out / f"{name}.json")
        print(f"wrote data/lenses/{name}.json from {src}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "tests" / "data" / "lenses")
