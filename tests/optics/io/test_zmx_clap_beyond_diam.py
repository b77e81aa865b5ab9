"""An annular ``CLAP lo hi`` whose outer radius lies beyond the surface's semi-diameter
(OpticStudio's Schmidt-Cassegrain sample: ``CLAP 4 1e10`` on its primary mirror, no real outer
radius).  OpticStudio calls a surface aperture extending beyond the semi-diameter not physically
meaningful (User Guide, *Aperture (surface properties)*); the reader lets the outer radius give
way to the ``DIAM`` with a located note (``zmx_surfaces._unbounded_annular_clap``) instead of
taking 1e10 as the mirror's semi-diameter and refusing it as beyond its conic's domain.
"""

from __future__ import annotations

import warnings

import pytest
from test_zmx import write
from zmx_blocks import surf as _surf, zmx_file

from deeplens.optics.errors import ZemaxWarning
from deeplens.optics.io import lens_to_dict, read_zmx
from deeplens.optics.paraxial import paraxial

def _file(clap):
    """A stop 50 mm in front of a concave conic mirror (R = -100 mm, k = -0.5: its sag is
    defined out to r = 141 mm) of semi-diameter 12 (``DIAM 12``, fixed), the ``CLAP`` line
    ``clap`` on the mirror, the image at its focus."""
    mirror = _surf(curv=-0.01, disz=-50.0, glas="MIRROR", diam=12.0) + ["  CONI -0.5", clap]
    blocks = [_surf(disz="INFINITY"), _surf(disz=50.0, stop=True), mirror, _surf()]
    return zmx_file(blocks, name="annular CLAP", aperture="ENPD 20.0")


def _read(p):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(p).double()
    return lens, [x for x in w if issubclass(x.category, ZemaxWarning)]


def test_unbounded_outer_radius_gives_way_to_the_diam(tmp_path):
    text = _file("  CLAP 4.0 1.0E+10 0")
    line = text.splitlines().index("  CLAP 4.0 1.0E+10 0") + 1
    lens, notes = _read(write(tmp_path, text, "unbounded.zmx"))
    ref, ref_notes = _read(write(tmp_path, _file("  CLAP 4.0 12.0 0"), "at_diam.zmx"))
    mirror = lens.surfaces[1]
    assert float(mirror.semi_diameter) == 12.0
    assert lens_to_dict(lens) == lens_to_dict(ref)           # as the CLAP ending at the DIAM
    assert float(paraxial(lens).efl) == float(paraxial(ref).efl)
    said = [str(x.message) for x in notes if "beyond the surface's semi-diameter" in str(x.message)]
    assert len(said) == 1 and f":{line}:" in said[0] and "1e+10" in said[0]
    assert not any("beyond the surface's semi-diameter" in str(x.message) for x in ref_notes)


@pytest.mark.parametrize("lo, hi", [(4.0, 8.0), (4.0, 12.0), (14.0, 20.0)])
def test_outer_radius_within_the_diam_or_a_ring_beyond_it_is_kept(tmp_path, lo, hi):
    """An outer radius within the DIAM, and a ring wholly beyond it (its radii the only sizes
    the file gives the opening: two real files of the first unseen set, CLAP 85 180 beside an
    automatic DIAM 72.5), keep the CLAP's outer radius as the semi-diameter."""
    lens, notes = _read(write(tmp_path, _file(f"  CLAP {lo} {hi} 0")))
    assert float(lens.surfaces[1].semi_diameter) == hi
    assert not any("beyond the surface's semi-diameter" in str(x.message) for x in notes)
