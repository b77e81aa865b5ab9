"""The direction of travel from the traced axis (``frames.travel_directions``,
``Lens.directions``): a roof prism written as OpticStudio's Amici files write it (two mirrors
at one vertex, each tilted by its own coordinate-break pair that returns the frame) turns the
beam round without the mirror count's parity changing, so after it light travels along ``-z``
of an unturned frame and the file's thicknesses there are negative.

Synthetic files of that structure (written here, not the user files they stand for): a glass
block, the roof inside it (ridge tilted 45 degrees to the beam: an Amici roof, 90 degrees of
deviation), an exit face and a thick lens after it.  Checked against

* optiland's global ray trace of the same file (chief and rim rays of two fields, 1e-9 mm);
* closed-form geometry: the roof's two reflections compose a 180-degree rotation about the
  ridge, which is the single 45-degree fold mirror followed by a reflection in the plane of
  the fold (x -> -x), so every ray lands where the fold file lands it with x negated;
* the thick lens's EFL and BFL (travelling -z) in closed form.

The old rule (the parity) refuses the file: the planted-bug test.

A beam-splitter cube written as OpticStudio files write it: a flat mirror at normal incidence
and the thickness after it left *positive*, so the light after the mirror travels -z while
every later surface and the image plane lie along +z: OpticStudio's virtual propagation (its
thickness-sign rule: after an odd number of mirrors a positive thickness is virtual), the rays
taken back along their lines.  The reader makes those gaps ``Lens.backward_gaps`` and the image
plane virtual; checked against optiland's global trace and the closed form (the glass and the
air after the mirror cancel the passes before it: a ray of direction tangent ``u`` lands at
``y_0 + (a - b) u``, ``a`` the air before the block, ``b`` the air from block to mirror).
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from zmx_blocks import surf as _surf, zmx_file

from deeplens.optics import frames
from deeplens.optics.frames import local_frames, to_global, travel_directions
from deeplens.optics.io import read_zmx
from deeplens.optics.io.zmx import ZemaxWarning
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.sampling import field_rays
from deeplens.optics.surfaces import Aperture, CoordinateBreak, Plane

W = 587.5618
N = 1.5               # the block's and the lens's model glass (non-dispersive)
R1, R2, T = -40.0, 60.0, 4.0   # the lens after the roof, met travelling -z
PUPIL = [(0.0, 0.0), (0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0), (0.5, 0.7)]
FIELDS = (0.0, 1.5)   # degrees (YFLN 0 1.5)

#: the system lines of every file here (zmx_blocks.zmx_file)
_SYSTEM = dict(name="roof", aperture="ENPD 8.0", fields="FTYP 0 0 2 1 0 0 0\nXFLN 0 0\nYFLN 0 1.5")
_GLASS = f"___BLANK 1 0 {N} 0 0 0 0 0 0 0"


def _file(middle, after):
    """The system with ``middle`` (the roof or the fold) between the block's entry face and
    the break that turns the axis onto the returning beam (thickness ``after`` behind it)."""
    blocks = ([_surf(disz="INFINITY"), _surf(disz=10.0, stop=True),
               _surf(disz=25.0, glas=_GLASS, diam=12.0),
               _surf("COORDBRK", parms=[0, 0, -45.0, 0, 0, 0])] + middle +
              [_surf("COORDBRK", disz=after, parms=[0, 0, -45.0, 0, 0, 0]),
               _surf(disz=-15.0, diam=12.0),
               _surf(curv=1 / R1, disz=-T, glas=_GLASS, diam=8.0),
               _surf(curv=1 / R2, disz=-45.0, diam=8.0), _surf()])
    return zmx_file(blocks, **_SYSTEM)


def roof_file(after=-20.0):
    """An Amici roof: each mirror tilted about y by its own break pair (the second break of
    each pair, order flag 1, undoes the first), both at the vertex of the 45-degree frame."""
    return _file([_surf("COORDBRK", parms=[0, 0, 0, 45.0, 0, 0]),
                  _surf(glas="MIRROR", diam=20.0),
                  _surf("COORDBRK", parms=[0, 0, 0, -45.0, 0, 1]),
                  _surf("COORDBRK", parms=[0, 0, 0, -45.0, 0, 0]),
                  _surf(glas="MIRROR", diam=20.0),
                  _surf("COORDBRK", parms=[0, 0, 0, 45.0, 0, 1])], after)


def fold_file(after=-20.0):
    """The same system with one flat 45-degree fold mirror where the roof's ridge is."""
    return _file([_surf(glas="MIRROR", diam=20.0)], after)


def _read(tmp_path, text, name):
    p = tmp_path / f"{name}.zmx"
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(p).double()


def _landings(lens):
    """``{(field, px, py): (global landing point (3,), valid)}`` of the chief ray and the rim
    rays of the paraxial entrance pupil (apertures ignored)."""
    par = paraxial(lens)
    xy = torch.tensor(PUPIL, dtype=lens.dtype) * 0.5 * float(par.entrance_pupil_diameter)
    out = {}
    with torch.no_grad():
        for f in FIELDS:
            r = lens.trace_to_sensor(field_rays(lens, f, W, xy, float(par.entrance_pupil_z)),
                                     options=TraceOptions(clip_aperture=False))
            g = to_global(local_frames(lens)[-1], r.o)
            for (px, py), p, ok in zip(PUPIL, g, r.valid.tolist()):
                out[(f, px, py)] = (p, ok)
    return out


def _parity(surfaces, mirrors, indices=None, wavelength_nm=None):
    out = [1]
    for i in range(len(surfaces)):
        out.append(-out[-1] if i in mirrors else out[-1])
    return out


# ---------------------------------------------------------------------------- the rule
def test_without_breaks_and_through_folds_the_rule_is_the_mirror_parity():
    g = torch.Generator().manual_seed(3)
    for _ in range(20):   # mirrors at normal incidence: the parity, whatever the set
        n = 6
        mirrors = {i for i in range(n) if bool(torch.rand((), generator=g) < 0.4)}
        surfaces = [Plane(5.0) for _ in range(n)]
        assert travel_directions(surfaces, mirrors) == _parity(surfaces, mirrors)
    # a fold written as break, mirror, break (any angle below 90 degrees) and a Cassegrain-like
    # pair of mirrors after it
    for deg in (10.0, 45.0, 80.0):
        t = math.radians(deg)
        surfaces = [Aperture(5.0), CoordinateBreak(tilt_x=t), Plane(5.0),
                    CoordinateBreak(tilt_x=t), Plane(5.0), Plane(5.0)]
        assert travel_directions(surfaces, {2, 4, 5}) == [1, 1, 1, -1, -1, 1, -1]


def test_a_roof_turns_the_beam_round_where_the_parity_does_not(tmp_path):
    lens = _read(tmp_path, roof_file(), "roof")
    sign = lens.directions()
    assert sorted(lens.mirrors) == [4, 7]
    # object, stop, block, break, break, mirror (its own tilted frame: -z), the returning
    # break (the beam crosses the frame, d_z = 0: the sign before it), the second mirror's
    # break (+z), the second mirror, its returning break and the axis-turning break: -z, as
    # the file's negative thicknesses say; the parity would be +1 after two mirrors
    assert sign == [1, 1, 1, 1, 1, -1, -1, 1, -1, -1, -1, -1, -1, -1]
    assert _parity(lens.surfaces, lens.mirrors)[-1] == 1
    # the roof's zero-length gap is crossed backwards by half of the beam, as in OpticStudio
    assert lens.backward_gaps == frozenset({7})


def test_the_paraxial_data_after_the_roof_are_the_thick_lens_travelling_minus_z(tmp_path):
    lens = _read(tmp_path, roof_file(), "roof")
    p = paraxial(lens)
    # the lens met along -z: radii -R1, -R2 in the direction of travel
    c1, c2 = -1.0 / R1, -1.0 / R2
    phi = (N - 1) * (c1 - c2) + (N - 1) ** 2 * T * c1 * c2 / N
    assert float(p.efl) == pytest.approx(1.0 / phi, rel=1e-12)
    bfl = (1.0 - (N - 1) * T * c1 / N) / phi
    assert float(p.bfl) == pytest.approx(-bfl, rel=1e-12)   # a position along the local z
    assert float(p.entrance_pupil_diameter) == pytest.approx(8.0, rel=1e-14)


# ---------------------------------------------------------------------------- where rays land
def test_the_roof_is_the_fold_with_x_negated(tmp_path):
    """Closed form: the roof's reflections compose a 180-degree rotation about the ridge,
    which is the fold's reflection followed by x -> -x (the ridge and the fold's normal lie in
    the y-z plane); the lens after it is symmetric about the returning axis (x = 0)."""
    roof = _landings(_read(tmp_path, roof_file(), "roof"))
    fold = _landings(_read(tmp_path, fold_file(), "fold"))
    flip = torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64)
    for key, (p, ok) in roof.items():
        q, ok_f = fold[key]
        assert ok and ok_f, key
        assert torch.allclose(p, q * flip, atol=1e-12, rtol=0), key
    # the roof reverses x: a rim ray at +x lands at -x of the chief ray
    assert float(roof[(0.0, 1.0, 0.0)][0][0]) < -0.1 < 0.1 < float(roof[(0.0, -1.0, 0.0)][0][0])


def test_half_of_the_beam_needs_the_roofs_backward_gap(tmp_path):
    """Rays on the -x half meet the second mirror's plane behind them: without the gap they
    are lost, with it they land where the closed form puts them (the test above)."""
    lens = _read(tmp_path, roof_file(), "roof")
    lens.backward_gaps = ()
    land = _landings(lens)
    assert not land[(0.0, -1.0, 0.0)][1] and land[(0.0, 1.0, 0.0)][1]


def test_the_roof_rays_land_where_optilands_global_trace_lands_them(tmp_path):
    pytest.importorskip("optiland")
    from optiland.fileio import load_zemax_file
    from optiland.materials import AbbeMaterial, IdealMaterial

    for name, text in (("roof", roof_file()), ("fold", fold_file())):
        p = tmp_path / f"{name}.zmx"
        p.write_text(text)
        lens = _read(tmp_path, text, name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            optic = load_zemax_file(str(p))
        surfaces = optic.surface_group.surfaces
        glass = [s for s in surfaces if isinstance(s.material_post, AbbeMaterial)]
        assert glass   # optiland's model glass of V_d = 0 is NaN: the same index, ideal
        for s in glass:
            s.material_post = IdealMaterial(n=N)
        for (f, px, py), (pt, ok) in _landings(lens).items():
            assert ok
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                optic.trace_generic(0.0, f / FIELDS[-1], px, py, W / 1000.0)
                sg = optic.surface_group
                ol = [float(torch.as_tensor(c)[-1].reshape(-1)[0]) for c in (sg.x, sg.y, sg.z)]
            # both global frames start at SURF 1 (the stop, deeplens' first vertex)
            assert [float(v) for v in pt] == pytest.approx(ol, abs=1e-9), (name, f, px, py)


# ---------------------------------------------------------------------------- planted bug
def _assert_roof_reading(lens):
    """What the roof file must read as: a real image (no virtual gaps after the roof, only the
    roof's own), a converging lens (EFL > 0, the thick lens's value)."""
    c1, c2 = -1.0 / R1, -1.0 / R2
    phi = (N - 1) * (c1 - c2) + (N - 1) ** 2 * T * c1 * c2 / N
    assert not lens.virtual_image
    assert lens.backward_gaps == frozenset({7})
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / phi, rel=1e-12)


def test_the_parity_rule_misreads_the_roof(tmp_path, monkeypatch):
    """The old rule (directions by the mirror count) planted back: the file's -20 mm after two
    mirrors is then 'against the direction of travel', so every gap after the roof reads as
    virtual propagation, the image as virtual and the converging lens's EFL as negative (the
    rays still land where they did: the trace itself is geometric)."""
    import deeplens.optics.io.lensfile as lensfile
    import deeplens.optics.io.zmx_read as zmx_read
    import deeplens.optics.lens as lens_mod

    _assert_roof_reading(_read(tmp_path, roof_file(), "roof"))
    for mod in (lens_mod, zmx_read, lensfile):
        monkeypatch.setattr(mod, "travel_directions", _parity)
    with pytest.raises(AssertionError):
        _assert_roof_reading(_read(tmp_path, roof_file(), "roof"))
    assert frames.travel_directions is not _parity   # only the importers were patched


def test_the_roof_gap_is_announced_at_its_line(tmp_path):
    p = tmp_path / "roof.zmx"
    p.write_text(roof_file())
    with pytest.warns(ZemaxWarning, match="roof"):
        read_zmx(p)


def test_a_lens_built_directly_with_a_roof_takes_negative_distances_after_it():
    """The rule lives in the lens, not in the reader: the roof built from surfaces, with the
    returning beam's distances negative, is accepted, and the parity's sign is refused."""
    air = Air()
    t = math.radians(45.0)
    surfaces = [Aperture(4.0), CoordinateBreak(tilt_x=-t), CoordinateBreak(tilt_y=t),
                Plane(20.0), CoordinateBreak(tilt_y=-t, order=1),
                CoordinateBreak(tilt_y=-t), Plane(20.0), CoordinateBreak(tilt_y=t, order=1),
                CoordinateBreak(tilt_x=-t), Plane(12.0)]
    dist = [0.0, 10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -20.0]
    lens = Lens(surfaces, [air] * 11, dist, -30.0, 0, mirrors=[3, 6], backward_gaps=[6])
    assert lens.directions()[-1] == -1
    with pytest.raises(ValueError, match="ordered along -z"):
        Lens(surfaces, [air] * 11, dist[:-1] + [20.0], 30.0, 0, mirrors=[3, 6])


# ---------------------------------------------------------------------------- the cube
A_AIR, B_AIR = 4.0, 20.0   # stop to block, block to mirror (and mirror-side air after it)


def cube_file():
    """A stop, a 10 mm block with its diagonal (a break pair tilting a dummy face inside the
    glass), air to a flat mirror at normal incidence, then the same thicknesses *positive*
    after the mirror (virtual propagation) through the block again to the image plane."""
    blocks = [_surf(disz="INFINITY"), _surf(disz=A_AIR, stop=True),
              _surf(disz=5.0, glas=_GLASS, diam=10.0),
              _surf("COORDBRK", parms=[0, 0, -45.0, 0, 0, 0]),
              _surf(glas=_GLASS, diam=14.0),
              _surf("COORDBRK", disz=5.0, parms=[0, 0, 45.0, 0, 0, 0]),
              _surf(disz=B_AIR, diam=10.0),
              _surf(disz=B_AIR, glas="MIRROR", diam=10.0),
              _surf(disz=5.0, glas=_GLASS, diam=10.0),
              _surf("COORDBRK", parms=[0, 0, 45.0, 0, 0, 0]),
              _surf(glas=_GLASS, diam=14.0),
              _surf("COORDBRK", disz=5.0, parms=[0, 0, -45.0, 0, 0, 0]),
              _surf(disz=B_AIR, diam=10.0), _surf()]
    return zmx_file(blocks, **_SYSTEM)


def test_the_cube_reads_its_positive_thicknesses_after_the_mirror_as_virtual(tmp_path):
    p = tmp_path / "cube.zmx"
    p.write_text(cube_file())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lens = read_zmx(p).double()
    said = [str(w.message) for w in caught if issubclass(w.category, ZemaxWarning)]
    against = [w.message for w in caught if isinstance(w.message, ZemaxWarning)
               and "gaps run against the direction of travel" in w.message.message]
    assert len(against) == 1 and len(against[0].lines) == 3   # one warning naming three gaps
    assert against[0].message.startswith("3 gaps run against the direction of travel")
    assert any("virtual image plane" in m and ":100:" in m for m in said)
    # after the mirror (deeplens surface 6) light travels -z; the gaps before surfaces 7
    # (the block's face again), 9 (the diagonal, across a break) and 11 (the exit face,
    # across a break) run along +z: crossed backwards; the image plane is virtual
    assert sorted(lens.mirrors) == [6]
    assert lens.directions()[7:] == [-1] * 6
    assert lens.backward_gaps == frozenset({7, 9, 11}) and lens.virtual_image
    land = _landings(lens)
    z_img = float(lens.z_sensor())
    for (f, px, py), (pt, ok) in land.items():
        assert ok, (f, px, py)
        u = math.tan(math.radians(f))
        half = 4.0   # ENPD 8: the stop is the first surface, the pupil is on it
        want = [px * half, py * half + (A_AIR - B_AIR) * u, z_img]
        assert [float(v) for v in pt] == pytest.approx(want, abs=1e-12), (f, px, py)
    # the planted bug: gaps against the direction of travel traced forwards only
    lens.backward_gaps = ()
    assert not any(ok for _, ok in _landings(lens).values())


def test_the_cube_rays_land_where_optilands_global_trace_lands_them(tmp_path):
    pytest.importorskip("optiland")
    from optiland.fileio import load_zemax_file
    from optiland.materials import AbbeMaterial, IdealMaterial

    p = tmp_path / "cube.zmx"
    p.write_text(cube_file())
    lens = _read(tmp_path, cube_file(), "cube")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        optic = load_zemax_file(str(p))
    for s in optic.surface_group.surfaces:
        if isinstance(s.material_post, AbbeMaterial):
            s.material_post = IdealMaterial(n=N)
    for (f, px, py), (pt, ok) in _landings(lens).items():
        assert ok
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            optic.trace_generic(0.0, f / FIELDS[-1], px, py, W / 1000.0)
            sg = optic.surface_group
            ol = [float(torch.as_tensor(c)[-1].reshape(-1)[0]) for c in (sg.x, sg.y, sg.z)]
        assert [float(v) for v in pt] == pytest.approx(ol, abs=1e-9), (f, px, py)


def test_a_positive_thickness_after_a_mirror_is_still_refused_unless_opted_in():
    """In ``Lens`` the rule is unchanged: a distance against the direction of travel is an
    error unless its gap is one of ``backward_gaps`` (the reader opts a file's in, with a
    warning), and before any mirror the reader never opts one in."""
    air = Air()
    surfaces = [Aperture(4.0), Plane(6.0), Plane(6.0)]
    with pytest.raises(ValueError, match="ordered along -z"):
        Lens(surfaces, [air] * 4, [0.0, 20.0, 20.0], 10.0, 0, mirrors=[1])
    lens = Lens(surfaces, [air] * 4, [0.0, 20.0, 20.0], 10.0, 0, mirrors=[1],
                backward_gaps=[2], virtual_image=True)
    assert lens.directions() == [1, 1, -1, -1]


@pytest.mark.parametrize("make", [roof_file, cube_file], ids=["roof", "cube"])
def test_round_trips_keep_the_reading(tmp_path, make):
    """JSON and .zmx written back and read again: the same virtual image flag, direction of
    travel in image space and landing points; the JSON file also the same directions and
    backward gaps (the .zmx reading may drop a flat dummy surface inside the glass, such as
    the cube's second diagonal, which renumbers the surfaces after it)."""
    from deeplens.optics.io import lens_from_dict, lens_to_dict
    from deeplens.optics.io.zmx import write_zmx

    lens = _read(tmp_path, make(), "first")
    back_json = lens_from_dict(lens_to_dict(lens)).double()
    write_zmx(lens, tmp_path / "again.zmx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        back_zmx = read_zmx(tmp_path / "again.zmx").double()
    want = _landings(lens)
    assert back_json.directions() == lens.directions()
    assert back_json.backward_gaps == lens.backward_gaps
    for other in (back_json, back_zmx):
        assert other.directions()[-1] == lens.directions()[-1]
        assert other.virtual_image == lens.virtual_image
        for key, (p, ok) in _landings(other).items():
            assert ok and torch.allclose(p, want[key][0], atol=1e-12, rtol=0), key
