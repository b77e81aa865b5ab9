"""Two OpticStudio rules met by the fifth unseen set of real files (docs/guide/zemax.md, "A
fifth unseen set"), each on a synthetic file:

* a user-defined (fixed) semi-diameter clips rays only on a surface with refractive power and
  no surface aperture (OpticStudio's *floating aperture*; User Guide, "Semi-Diameters"): on a
  flat plane in air a fixed ``DIAM`` is drawn, never clips, so an ``OBSC`` there may be wider
  than it (OpticStudio's Houghton and Maksutov samples: ``DIAM 1 1`` beside ``OBSC 0 1``,
  ``DIAM 0.001 1`` beside ``OBSC 0 2.5``), and an opening that is not the stop is written with
  a ``CLAP``;
* the direction of travel (the sign of the thicknesses) after a mirror follows the mirror's
  own vertex normal, not the local ``z`` axis: a tilted plane (``TILTSURF``) met by a beam that
  a 90-degree break turned across the frame (OpticStudio's Twyman-Green sample writes ``+1``
  after such a mirror).
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import write
from test_zmx_apertures import _on_axis_rays, _with_field_stop
from zmx_blocks import surf as _surf, zmx_file

from deeplens.optics import frames
from deeplens.optics.io import ZemaxFileError, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.io.zmx import ZemaxWarning
from deeplens.optics.options import TraceOptions
from deeplens.optics.surfaces import Aperture, XYPolynomial


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path).double()


def _field_plane(lens):
    return next(k for k, s in enumerate(lens.surfaces) if isinstance(s, Aperture) and k > 0)


# ------------------------------------------------------------- a fixed DIAM on a flat plane
def test_an_obscuration_wider_than_the_fixed_diam_blocks_only_inside_its_radius(tmp_path):
    """A plane in the converging beam 10 mm behind the singlet with ``DIAM 1 1`` (fixed) and
    ``OBSC 0 2``: exactly the rays whose unclipped hit on that plane lies at r >= 2 mm pass
    (neither the 1 mm DIAM nor anything else clips); refused before (the obscuration must lie
    inside the semi-diameter)."""
    text = _with_field_stop(clap=None, obdc=None, extra=('DIAM 1 1 0 0 1 ""', "OBSC 0 2 0"))
    p = write(tmp_path, text)
    with pytest.warns(ZemaxWarning, match=r"t.zmx:\d+: SURF 4: the fixed DIAM 1 beside an OBSC "
                                          r"\(a surface aperture\) does not clip rays"):
        read_zmx(p)
    lens = _read(p)
    i = _field_plane(lens)
    assert float(lens.surfaces[i].obscuration) == 2.0
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        free, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
        clipped = lens.trace(rays)
    r2 = hits[i][..., 0] ** 2 + hits[i][..., 1] ** 2
    want = free.valid & (r2 >= 4.0)
    assert 0 < int(want.sum()) < int(free.valid.sum())          # the obscuration blocks some
    assert bool((r2[free.valid] > 1.0).any())                   # rays beyond the 1 mm DIAM pass
    assert torch.equal(clipped.valid, want)


def test_a_tiny_fixed_diam_on_a_flat_dummy_clips_nothing(tmp_path):
    """The Maksutov sample's first surface: a flat plane in air with ``DIAM 1e-6 1``: every ray
    of the unclipped trace passes (the plane is kept, its semi-diameter the beam's extent)."""
    text = _with_field_stop(clap=None, obdc=None, extra=('DIAM 9.99999997E-7 1 0 0 1 ""',))
    lens = _read(write(tmp_path, text))
    i = _field_plane(lens)
    assert float(lens.surfaces[i].semi_diameter) > 1.0
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        free = lens.trace(rays, options=TraceOptions(clip_aperture=False))
        clipped = lens.trace(rays)
    assert int(free.valid.sum()) == rays.o.shape[0]
    assert torch.equal(clipped.valid, free.valid)


def test_an_opening_that_is_not_the_stop_is_written_with_a_clap(tmp_path):
    """The field stop (``CLAP 0 2``) read, written and read again: the written file has the
    CLAP (a fixed DIAM alone would not clip in OpticStudio, nor on reading it back), and the
    re-read lens is the same and clips the same rays."""
    lens = _read(write(tmp_path, _with_field_stop(obdc=None)))
    out = tmp_path / "out.zmx"
    write_zmx(lens, out)
    assert "  CLAP 0 2.0 0" in out.read_text().splitlines()
    again = _read(out)
    assert lens_to_dict(again) == lens_to_dict(lens)
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        a, b = lens.trace(rays), again.trace(rays)
    assert torch.equal(a.valid, b.valid) and 0 < int(a.valid.sum()) < rays.o.shape[0]


# ------------------------------------------------------------- a tilted mirror's normal
def _tilted_fold(after):
    """A stop, a flat mirror at normal incidence 20 mm behind it (light then travels -z), a
    break tilting the frame 90 degrees about x (the beam now crosses the frame along -y), a
    TILTSURF mirror ``z = -y`` at that vertex, ``after`` mm to the image plane: the Twyman-
    Green sample's arm (SURF 12-14 there, ``DISZ 1`` after the mirror)."""
    blocks = [_surf(disz="INFINITY"), _surf(disz=20.0, stop=True),
              _surf(disz=-10.0, glas="MIRROR", diam=10.0),
              _surf("COORDBRK", parms=[0, 0, 90.0, 0, 0, 0]),
              _surf("TILTSURF", disz=after, glas="MIRROR", parms=[0, -1.0], diam=8.0),
              _surf()]
    return zmx_file(blocks, name="roof", aperture="ENPD 8.0",     # test_zmx_prisms' system
                    fields="FTYP 0 0 2 1 0 0 0\nXFLN 0 0\nYFLN 0 1.5")


def test_a_tilted_plane_mirror_reflects_the_axis_about_its_own_normal(tmp_path):
    """After the break the axis is ``R^T (0, 0, -1) = (0, -1, 0)`` (across the frame); the
    mirror ``z = -y`` (normal ``(0, 1, 1)/sqrt 2``) sends it along ``d - 2 (d.n) n = (0, 0,
    +1)``: the thickness after it is positive, as OpticStudio's sample writes it, and a
    negative one (an image plane behind the light) is refused at its line.  A mirror reflecting about the local z axis leaves
    the axis across the frame, keeps ``-z``, and refuses the positive thickness."""
    lens = _read(write(tmp_path, _tilted_fold(15.0), "fold.zmx"))
    i = next(k for k, s in enumerate(lens.surfaces) if isinstance(s, XYPolynomial))
    assert i in lens.mirrors
    n = frames.vertex_normal(lens.surfaces[i])
    assert [abs(v) for v in n] == pytest.approx([0.0, 2 ** -0.5, 2 ** -0.5], abs=1e-15)
    assert lens.directions()[-1] == 1 and float(lens.d_sensor) == 15.0
    with pytest.raises(ZemaxFileError, match=r"bad.zmx:\d+: the image plane lies 15 mm before "
                                             r"the last surface's vertex \(light travels "
                                             r"towards \+z there, after 2 mirrors\)"):
        _read(write(tmp_path, _tilted_fold(-15.0), "bad.zmx"))


def test_refraction_of_the_axis_at_a_tilted_face_is_snells_law():
    """The axis along +z meets a face of slope ``t`` (normal at ``θ = atan t`` to the axis)
    from air into n = 1.5: the refracted axis makes ``θ'`` with the normal, ``sin θ' = sin θ /
    1.5``, and stays in the plane of incidence (closed form, to 1e-15)."""
    t = 0.6
    face = XYPolynomial(8.0, [0.0, t, 0.0])   # z = t y
    nv = frames.vertex_normal(face)
    a = frames._refract_axis([0.0, 0.0, 1.0], 1.0, 1.5, nv)
    theta = math.atan(t)
    cos_out = abs(sum(a[k] * nv[k] for k in range(3)))
    assert cos_out == pytest.approx(math.sqrt(1 - (math.sin(theta) / 1.5) ** 2), abs=1e-15)
    assert a[0] == 0.0 and math.hypot(*a) == pytest.approx(1.0, abs=1e-15)
    # the old rule (normal = z): no deviation at all
    assert frames._refract_axis([0.0, 0.0, 1.0], 1.0, 1.5) == [0.0, 0.0, 1.0]
