"""Two aperture rules met by the ninth unseen set of real files, each on a synthetic file:

* a user-defined (fixed) semi-diameter clips rays only on a surface with refractive power and
  no surface aperture (OpticStudio's *floating aperture*; User Guide, "Semi-Diameters"), so a
  fixed ``DIAM`` beside an obscuration (``OBSC``, ``ELOB``, ``SPID``) never clips, on a curved
  surface too: OpticStudio's F/8 Ritchey-Chretien tolerancing sample draws the secondary's
  shadow as ``OBSC 0 1.42`` on a curved dummy in air with ``DIAM 1.42`` fixed (refused before:
  "the obscuration radius 1.42 must be > 0 and below the semi-diameter 1.42");
* a surface aperture may extend beyond the semi-diameter in Sequential Mode (User Guide,
  *Aperture (surface properties)*), and a circular obscuration "is the complement of the
  circular aperture": a ring obscuration ``OBSC r_i r_o`` whose outer radius lies at or beyond
  the semi-diameter blocks every ray from ``r_i`` to the rim (the Fresnel zone plate sample's
  stop, ``OBSC 0.7746 1.095`` on a 1 mm stop, refused before), and a ring wholly beyond it
  blocks none.
"""

from __future__ import annotations

import warnings

import pytest
import torch
from test_zmx import write
from test_zmx_apertures import _on_axis_rays, _with_field_stop
from zmx_blocks import surf as _surf, zmx_file

from deeplens.optics.io import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.io.zmx import ZemaxWarning
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.surfaces import Aperture, Asphere

_PLANE = "SURF 4\n  TYPE STANDARD\n  CURV 0.0\n"


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path).double()


def _curved_shadow(extra):
    """The singlet with a curved dummy in air (R = 25 mm, no power: air on both sides) 10 mm
    behind the lens in the converging beam, carrying ``extra``."""
    text = _with_field_stop(clap=None, obdc=None, extra=extra)
    assert _PLANE in text
    return text.replace(_PLANE, "SURF 4\n  TYPE STANDARD\n  CURV 0.04\n", 1)


# ------------------------------------------------------------- a fixed DIAM beside an OBSC
def test_a_fixed_diam_beside_an_obscuration_on_a_curved_dummy_does_not_clip(tmp_path):
    """``DIAM 2 1`` (fixed) and ``OBSC 0 2`` on the curved dummy: exactly the rays whose hit on
    it (a trace that clips nothing) lies at r >= 2 mm pass, rays beyond the 2 mm DIAM among
    them; the note names the rule at the DIAM line.  The dummy has no power: the EFL is the
    file's without it (1e-12 relative)."""
    p = write(tmp_path, _curved_shadow(('DIAM 2 1 0 0 1 ""', "OBSC 0 2 0")))
    with pytest.warns(ZemaxWarning, match=r"t.zmx:\d+: SURF 4: the fixed DIAM 2 beside an OBSC "
                                          r"\(a surface aperture\) does not clip rays"):
        read_zmx(p)
    lens = _read(p)
    i = next(k for k, s in enumerate(lens.surfaces) if float(getattr(s, "obscuration", 0)) > 0)
    assert type(lens.surfaces[i]) is Asphere and float(lens.surfaces[i].c) == 0.04
    assert float(lens.surfaces[i].obscuration) == 2.0
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        free, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
        clipped = lens.trace(rays)
    r2 = hits[i][..., 0] ** 2 + hits[i][..., 1] ** 2
    want = free.valid & (r2 >= 4.0)
    assert 0 < int(want.sum()) < int(free.valid.sum())          # the obscuration blocks some
    assert bool((r2[want] > 2.5 ** 2).any())                    # rays beyond the DIAM pass
    assert torch.equal(clipped.valid, want)
    bare = _read(write(tmp_path, _with_field_stop(clap=None, obdc=None), "bare.zmx"))
    f, f0 = float(paraxial(lens).efl), float(paraxial(bare).efl)
    assert f == pytest.approx(f0, rel=1e-12)


def test_a_central_obscuration_covering_the_whole_beam_is_still_refused(tmp_path):
    """The rule does not make a surface that blocks every ray load: an ``OBSC 0 10`` on the
    curved dummy, wider than the beam there (about 4 mm), is refused at its line."""
    p = write(tmp_path, _curved_shadow(('DIAM 2 1 0 0 1 ""', "OBSC 0 10 0")))
    with pytest.raises(ZemaxFileError, match=r"t.zmx:\d+: .*SURF 4 .*the central obscuration "
                                              r"\(10 mm\) must be smaller"):
        _read(p)


# ------------------------------------------------------------- a ring past the rim
def _ring_on_stop(ring):
    """The singlet (stop: a flat plane in air, ``DIAM 5`` fixed, under ``ENPD 10``) with
    ``ring`` (an ``OBSC r_i r_o`` line) on its stop."""
    text = _with_field_stop(clap=None, obdc=None)
    stop = '  STOP\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 2\n  DIAM 5 1 0 0 1 ""\n'
    assert stop in text
    return text.replace(stop, stop + f"  {ring}\n", 1)


def test_a_ring_obscuration_past_the_stops_rim_leaves_the_disc_inside_it(tmp_path):
    """``OBSC 3 6`` on the 5 mm stop: exactly the rays within 3 mm of the axis there pass (the
    ring takes out 3..5 mm, the rest of it lies past the rim); the pupil keeps the ENPD's 10 mm.
    Written back and read again: the same verdicts."""
    lens = _read(write(tmp_path, _ring_on_stop("OBSC 3 6 0")))
    stop = lens.surfaces[lens.stop_index]
    assert isinstance(stop, Aperture) and float(stop.semi_diameter) == 5.0
    assert (float(stop.obscuration_inner), float(stop.obscuration)) == (3.0, 6.0)
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(10.0, rel=1e-12)
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        free, hits = lens.trace(rays, options=TraceOptions(clip_aperture=False), record=True)
        clipped = lens.trace(rays)
    k = lens.stop_index
    r2 = hits[k][..., 0] ** 2 + hits[k][..., 1] ** 2
    want = free.valid & (r2 <= 9.0)
    assert 0 < int(want.sum()) < int(free.valid.sum())
    assert torch.equal(clipped.valid, want)
    out = tmp_path / "out.zmx"
    write_zmx(lens, out)
    again = _read(out)
    with torch.no_grad():
        assert torch.equal(again.trace(rays).valid, want)


def test_a_ring_obscuration_beyond_the_beam_blocks_nothing(tmp_path):
    """``OBSC 6 7`` on the stop (5 mm) and on a plane in the converging beam with an automatic
    ``DIAM`` (the Fresnel zone plate's outer rings): every ray of the trace that clips nothing
    passes."""
    text = _ring_on_stop("OBSC 6 7 0")
    plane = _PLANE + "  DISZ 35.0\n"
    assert plane in text
    lens = _read(write(tmp_path, text.replace(plane, plane + "  OBSC 6 7 0\n", 1)))
    rings = [s for s in lens.surfaces if isinstance(s, Aperture)
             and float(s.obscuration_inner) == 6.0]
    assert len(rings) == 2
    rays = _on_axis_rays(lens)
    with torch.no_grad():
        free = lens.trace(rays, options=TraceOptions(clip_aperture=False))
        clipped = lens.trace(rays)
    assert int(free.valid.sum()) == rays.o.shape[0]
    assert torch.equal(clipped.valid, free.valid)


def test_aperture_rings_past_the_rim_but_not_central_obscurations():
    """The :class:`Aperture` constructor: a ring may reach past the semi-diameter; a central
    obscuration at or past it (it would block every ray) and a ring whose inner radius is not
    below its outer one are refused."""
    Aperture(5.0, obscuration=6.0, obscuration_inner=3.0)
    Aperture(5.0, obscuration=7.0, obscuration_inner=6.0)
    with pytest.raises(ValueError, match="central obscuration"):
        Aperture(5.0, obscuration=5.0)
    with pytest.raises(ValueError, match="ring obscuration"):
        Aperture(5.0, obscuration=6.0, obscuration_inner=6.5)


# ------------------------------------------------------------- an automatic DIAM past the edge
def _ball_front(diam):
    """A plano-convex lens (R = 10 mm, n = 1.5, 3 mm thick) behind a stop under ``ENPD 4``, its
    curved face with ``diam`` (a whole ``DIAM`` record) and the image 20 mm behind it."""
    front = [*_surf(curv=0.1, disz=3.0, glas="___BLANK 1 0 1.5 60.0"), f"  {diam}"]
    blocks = [_surf(disz="INFINITY"), _surf(disz=1.0, stop=True), front, _surf(disz=20.0),
              _surf()]
    return zmx_file(blocks, name="edge", aperture="ENPD 4.0")


def test_an_automatic_diam_past_the_spheres_edge_is_refused_on_its_line(tmp_path):
    """OpticStudio's automatic semi-diameter (``DIAM 10.5 0``) beyond the sphere's edge r = 10
    mm (the eighth short-course array sample's 27.2273 on R = -26.5435 mm): no ray meets the
    surface there, so the file's beam misses it: refused at the DIAM line in one line naming
    the value, the edge and why; the same value on the rim (``DIAM 10 0``, a hemisphere) and a
    footprint inside it load."""
    text = _ball_front('DIAM 10.5 0 0 0 1 ""')
    line = text.splitlines().index('  DIAM 10.5 0 0 0 1 ""') + 1
    with pytest.raises(ZemaxFileError, match=rf"t.zmx:{line}: SURF 2: the automatic "
                                             r"semi-diameter \(DIAM flag 0\) 10.5 lies beyond "
                                             r"the edge of the surface \(r = 10; R = 10, k = 0\)"
                                             r": .* miss it$"):
        _read(write(tmp_path, text))
    for ok in ('DIAM 10 0 0 0 1 ""', 'DIAM 3 0 0 0 1 ""'):
        lens = _read(write(tmp_path, _ball_front(ok), "ok.zmx"))
        assert float(lens.surfaces[1].semi_diameter) == float(ok.split()[1])


# ------------------------------------------------------------- what a refusal names
def test_a_dll_surface_and_a_user_aperture_are_refused_naming_the_missing_file(tmp_path):
    """``TYPE USERSURF US_HEXARRAY.DLL`` (a compiled sample deeplens does not model; its
    ``US_ARRAY.DLL`` lenslet arrays are read, test_zmx_lenslet_array.py) and ``UDAD 0 "NAME.UDA"
    1`` (the Talbot sample's grating) are refused at their line, in one line naming the plug-in
    or the aperture file deeplens cannot use."""
    text = _ball_front('DIAM 3 0 0 0 1 ""')
    dll = text.replace("  TYPE STANDARD\n  CURV 0.1\n", "  TYPE USERSURF US_HEXARRAY.DLL\n"
                       "  CURV 0.1\n", 1)
    line = dll.splitlines().index("  TYPE USERSURF US_HEXARRAY.DLL") + 1
    with pytest.raises(ZemaxFileError) as e:
        _read(write(tmp_path, dll))
    msg = str(e.value)
    assert msg.endswith(f"t.zmx:{line}: surface type 'USERSURF' (SURF 2) is not supported: its "
                        f"shape is computed by OpticStudio's compiled plug-in US_HEXARRAY.DLL, "
                        f"which deeplens cannot run")
    assert "\n" not in msg
    uda = text.replace("  STOP\n", '  STOP\n  UDAD 0 "TALBOTIMA_SURF_1.UDA" 1.0\n', 1)
    line = uda.splitlines().index('  UDAD 0 "TALBOTIMA_SURF_1.UDA" 1.0') + 1
    with pytest.raises(ZemaxFileError, match=rf"t.zmx:{line}: UDAD on SURF 1: a user-defined "
                                             r"aperture \(file TALBOTIMA_SURF_1.UDA\) is not "
                                             r"supported"):
        _read(write(tmp_path, uda))


# ------------------------------------- a fixed DIAM on a surface with power in one medium
def test_a_fixed_diam_on_an_ideal_lens_in_air_still_clips(tmp_path):
    """An ideal lens (``PARAXIAL``, f = 100 mm) has power in air: its fixed ``DIAM 3`` is
    OpticStudio's floating aperture and clips (only shape-only surface types lose their power
    in one medium).  A stop of 5 mm before it passes the 10 mm pupil; exactly the rays that
    reach the lens within 3 mm of the axis pass, and no note is given for that DIAM."""
    blocks = [_surf(disz="INFINITY"),
              _surf(stop=True, disz=1.0, diam=5.0),
              _surf("PARAXIAL", parms=[100.0, 1.0], disz=100.0, diam=3.0),
              _surf()]
    p = write(tmp_path, zmx_file(blocks, "ideal lens, fixed DIAM"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lens = read_zmx(p).double()
    assert not [w for w in caught if "does not clip" in str(w.message)]
    rays = _on_axis_rays(lens)
    r = torch.hypot(rays.o[:, 0], rays.o[:, 1])
    out = lens.trace(rays)
    assert torch.equal(out.valid, r <= 3.0)


def test_a_fixed_diam_on_a_fresnel_surface_in_air_does_not_clip(tmp_path):
    """A Fresnel surface (``FRESNELS``: a plane carrying a curved surface's facet slopes) is a
    shape alone: in air on both sides it has no power, so its fixed ``DIAM 3`` does not clip
    (the rule for every shape-only type), with the note at its ``DIAM`` line; every ray of the
    10 mm pupil passes, those beyond 3 mm among them.  An ideal lens after it focuses the beam.
    (Before the review it clipped there: ``FRESNELS`` was missing from the shape-only types.)"""
    blocks = [_surf(disz="INFINITY"),
              _surf(stop=True, disz=1.0, diam=5.0),
              _surf("FRESNELS", curv=0.02, disz=1.0, diam=3.0),
              _surf("PARAXIAL", parms=[100.0, 1.0], disz=100.0),
              _surf()]
    p = write(tmp_path, zmx_file(blocks, "Fresnel surface in air, fixed DIAM"))
    with pytest.warns(ZemaxWarning, match=r"SURF 2: the fixed DIAM 3 of a curved surface in one "
                                          r"medium \(no refractive power\).* does not clip"):
        read_zmx(p)
    lens = _read(p)
    rays = _on_axis_rays(lens)
    r = torch.hypot(rays.o[:, 0], rays.o[:, 1])
    assert bool((r > 3.0).any())
    assert bool(lens.trace(rays).valid.all())


def test_every_type_read_is_classed_shape_only_or_with_power_in_air():
    """Each surface type the reader knows is either a shape alone (a fixed ``DIAM`` in one
    medium does not clip) or has power in air (it clips), as its format states
    (``SurfaceFormat.shape_only``, set on the format class itself, never inherited): a new type
    must be classed here."""
    from deeplens.optics.io.surface_handlers import FORMATS

    shape_only = {"STANDARD", "EVENASPH", "ODDASPHE", "XPOLYNOM", "XYPOLYNOM", "TILTSURF",
                  "JONESMAT", "BIRE__IN", "BIRE_OUT", "TOROIDAL", "QED_TYPE", "BICONICX",
                  "SZERNSAG", "FZERNSAG", "XASPHERE", "GRID_SAG", "IRREGULA", "FRESNELS",
                  "USERSURF US_ARRAY.DLL", "XOSPHERE"}
    power_in_air = {"PARAXIAL", "PARAX_XY", "BINARY_1", "BINARY_2", "FZERNPHA", "DGRATING",
                    "HOLOGRM1", "HOLOGRM2", "COORDBRK", "GRINSUR1"}
    read = set(FORMATS.zmx_types())
    assert read == shape_only | power_in_air, sorted(read ^ (shape_only | power_in_air))
    for t in read:
        fmt = type(FORMATS.for_zmx_type(t))
        assert "shape_only" in vars(fmt), f"{fmt.__name__} ({t}) does not state shape_only"
        assert fmt.shape_only == (t in shape_only), t
