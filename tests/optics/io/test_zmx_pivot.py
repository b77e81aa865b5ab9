"""A mirror turned about a pivot by coordinate breaks (OpticStudio's scan-mirror idiom: a break
at the pivot ``d`` ahead of the mirror, the tilt, ``-d`` back to the mirror's vertex): the
distance into the mirror is negative although the mirror lies ahead of the beam, since only the
frames between move backwards (a thickness is an offset along the local z axis from the
previous vertex; a coordinate break is a dummy surface that cannot bend rays: OpticStudio User
Guide, *Thicknesses*; Zemax knowledge base, *How to tilt and decenter a sequential optical
component*).  ``Lens.check`` places the vertex through the composed frames and accepts it when
it lies ahead of the previous surface along the traced axis.

Synthetic files of that structure (written here): a stop, a 45-degree fold break, the pivot
``d`` further on, a tilt ``θ`` about x there, ``-d`` back to a curved mirror, an image plane.
Checked against optiland's global trace of the same file (1e-9 mm) and the closed form of a
rotation by ``θ`` about a point at distance ``d``: the same mirror placed directly, with the fold's thickness ``d (1 - cos θ)`` and a break that
decenters by ``d sin θ`` and tilts by ``θ`` (the break's ``R_x(θ)`` turns the z axis to
``(0, -sin θ, cos θ)``), so its vertex is ``P - d R_x(θ) e_z`` with ``P = (0, 0, d)``.  Every
ray lands on the mirror and on the image plane where the direct file lands it (1e-9 mm).
A real surface that genuinely lies behind the beam is still refused, with its line.
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from zmx_blocks import surf as _surf, zmx_file

from deeplens.optics.frames import local_frames, to_global
from deeplens.optics.io import read_zmx
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.sampling import field_rays

W = 587.5618
D = 60.0                 # the pivot's distance from the mirror, mm
C_MIRROR = -1 / 400.0    # a concave mirror (1/mm), so that a misplaced vertex moves every ray
PUPIL = [(0.0, 0.0), (0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (-1.0, 0.0), (0.5, 0.7)]
FIELDS = (0.0, 1.5)      # degrees (YFLN 0 1.5)
_SYSTEM = dict(name="pivot", aperture="ENPD 8.0",
               fields="FTYP 0 0 2 1 0 0 0\nXFLN 0 0\nYFLN 0 1.5")
_FOLD = [0, 0, -45.0, 0, 0, 0]


def _system(middle):
    return zmx_file([_surf(disz="INFINITY"), _surf(disz=50.0, stop=True, diam=4.0)] + middle +
                    [_surf(curv=C_MIRROR, disz=-80.0, glas="MIRROR", diam=20.0), _surf()],
                    **_SYSTEM)


def pivot_file(theta_deg, back=-D):
    """Fold break (``D`` to the pivot), the scan break (tilt ``θ`` about x, ``back`` to the
    mirror: ``-D`` returns to the fold point), the mirror, the image 80 mm after it."""
    return _system([_surf("COORDBRK", disz=D, parms=_FOLD),
                    _surf("COORDBRK", disz=back, parms=[0, 0, theta_deg, 0, 0, 0])])


def direct_file(theta_deg):
    """The same mirror placed directly: the pivot geometry in closed form."""
    t = math.radians(theta_deg)
    return _system([_surf("COORDBRK", disz=D * (1 - math.cos(t)), parms=_FOLD),
                    _surf("COORDBRK", parms=[0, D * math.sin(t), theta_deg, 0, 0, 0])])


def _read(tmp_path, text, name):
    p = tmp_path / f"{name}.zmx"
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(p).double()


def _landings(lens):
    """Global points ``(F * P, 2, 3)`` where the chief and rim rays of two fields meet the
    mirror and the image plane, and their validity ``(F * P,)``."""
    par = paraxial(lens)
    xy = torch.tensor(PUPIL, dtype=lens.dtype) * 0.5 * float(par.entrance_pupil_diameter)
    mirror = max(lens.mirrors)
    frames = local_frames(lens)
    pts, ok = [], []
    with torch.no_grad():
        for f in FIELDS:
            rays = field_rays(lens, f, W, xy, float(par.entrance_pupil_z))
            out, hits = lens.trace(rays, record=True, options=TraceOptions(clip_aperture=False))
            img = lens.trace_to_sensor(rays, options=TraceOptions(clip_aperture=False))
            pts.append(torch.stack([to_global(frames[mirror], hits[mirror]),
                                    to_global(frames[-1], img.o)], dim=1))
            ok.append(out.valid & img.valid)
    return torch.cat(pts), torch.cat(ok)


def _assert_lands_as_optiland(tmp_path, text, lens):
    """Every ray of :data:`PUPIL` at the two :data:`FIELDS` lands on ``lens``' image plane
    (global frame) where optiland's global trace of the same file ``text`` lands it (1e-9 mm)."""
    pytest.importorskip("optiland")
    from optiland.fileio import load_zemax_file

    p = tmp_path / "oracle.zmx"
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        optic = load_zemax_file(str(p))
    par = paraxial(lens)
    xy = torch.tensor(PUPIL, dtype=lens.dtype) * 0.5 * float(par.entrance_pupil_diameter)
    with torch.no_grad():
        for f in FIELDS:
            r = lens.trace_to_sensor(field_rays(lens, f, W, xy, float(par.entrance_pupil_z)),
                                     options=TraceOptions(clip_aperture=False))
            assert bool(r.valid.all())
            for (px, py), pt in zip(PUPIL, to_global(local_frames(lens)[-1], r.o)):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    optic.trace_generic(0.0, f / FIELDS[-1], px, py, W / 1000.0)
                    sg = optic.surface_group
                    ol = [float(torch.as_tensor(c)[-1].reshape(-1)[0])
                          for c in (sg.x, sg.y, sg.z)]
                assert [float(v) for v in pt] == pytest.approx(ol, abs=1e-9), (f, px, py)


def test_the_break_turns_the_z_axis_as_the_closed_form_says(tmp_path):
    """The closed form's ``R_x(θ) e_z = (0, -sin θ, cos θ)``, read from the file's break."""
    lens = _read(tmp_path, pivot_file(10.0), "pivot")
    brk = lens.surfaces[2]
    ez = brk.rotation(torch.zeros((), dtype=torch.float64)) @ torch.tensor([0.0, 0.0, 1.0],
                                                                           dtype=torch.float64)
    t = math.radians(10.0)
    assert torch.allclose(ez, torch.tensor([0.0, -math.sin(t), math.cos(t)],
                                           dtype=torch.float64), atol=1e-15)


@pytest.mark.parametrize("theta", [-10.0, 7.5, 0.0])
def test_a_mirror_turned_about_a_pivot_lands_every_ray_where_the_direct_placement_does(
        tmp_path, theta):
    pivot = _read(tmp_path, pivot_file(theta), "pivot")
    direct = _read(tmp_path, direct_file(theta), "direct")
    if theta:   # (at 0 the reader drops the identity break and sums the distances: 0)
        assert float(pivot.distances[3]) == -D   # the negative distance kept, not rewritten
    a, ok_a = _landings(pivot)
    b, ok_b = _landings(direct)
    assert bool(ok_a.all()) and bool(ok_b.all())
    # float64 positions of order 100 mm through two frames: ~1e-13 mm of rounding
    assert float((a - b).abs().max()) < 1e-9
    # the mirror's vertex, placed by the composed frames: the closed form, in global space
    t = math.radians(theta)
    fold_z = torch.tensor([0.0, -math.sin(math.radians(-45.0)), math.cos(math.radians(-45.0))],
                          dtype=torch.float64)
    fold_y = torch.tensor([0.0, math.cos(math.radians(-45.0)), math.sin(math.radians(-45.0))],
                          dtype=torch.float64)
    z = pivot.z_vertices().detach()
    want = (torch.stack([torch.zeros(()), torch.zeros(()), z[0] + 50.0]).to(torch.float64)
            + D * (1 - math.cos(t)) * fold_z + D * math.sin(t) * fold_y)
    m = max(pivot.mirrors)
    A, bb = local_frames(pivot)[m]
    got = bb + A @ torch.stack([torch.zeros(()), torch.zeros(()), z[m]]).to(torch.float64)
    assert float((got - want).abs().max()) < 1e-9


@pytest.mark.parametrize("theta", [-10.0, 7.5])
def test_the_pivot_rays_land_where_optilands_global_trace_lands_them(tmp_path, theta):
    """An independent reading of the same file: optiland's reader and global trace (its frames
    start at SURF 1, the stop, deeplens' first vertex)."""
    _assert_lands_as_optiland(tmp_path, pivot_file(theta),
                              _read(tmp_path, pivot_file(theta), "pivot"))


def test_a_surface_genuinely_behind_the_beam_is_still_refused(tmp_path):
    """``-2 D`` back from the pivot puts the mirror's vertex behind the stop along the beam
    (a slip of sign, not a pivot): refused at its line, saying how far behind."""
    p = tmp_path / "behind.zmx"
    p.write_text(pivot_file(10.0, back=-2.5 * D))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(ValueError) as e:
            read_zmx(p)
    msg = str(e.value)
    assert "line 41" in msg and "negative (-150 mm)" in msg
    # the scan frame's z axis is turned by -45 + 10 = -35 degrees about x: the vertex lies
    # 50 + D cos 45° - 2.5 D cos 35° = -30.45 mm along the beam from the stop
    behind = -(50 + D * math.cos(math.radians(45)) - 2.5 * D * math.cos(math.radians(35)))
    assert behind > 30
    assert f"lies {behind:g} mm behind surface 0 along the beam" in msg


# ---- after an odd number of mirrors (light travelling towards -z): a flat fold mirror, then
# the pivot idiom with the thickness signs of that space (``-(L + D)`` to the pivot, the tilt,
# ``+D`` back to the scan mirror, which lies ``L`` after the fold mirror along the beam)
L_AFTER = 40.0
_HALF_FOLD = [0, 0, -22.5, 0, 0, 0]   # a break, the mirror, a break: a 45-degree fold


def pivot_after_mirror_file(theta_deg, back=D):
    return zmx_file([_surf(disz="INFINITY"), _surf(disz=50.0, stop=True, diam=4.0),
                     _surf("COORDBRK", parms=_HALF_FOLD), _surf(glas="MIRROR", diam=20.0),
                     _surf("COORDBRK", disz=-(L_AFTER + D), parms=_HALF_FOLD),
                     _surf("COORDBRK", disz=back, parms=[0, 0, theta_deg, 0, 0, 0]),
                     _surf(curv=1 / 400.0, disz=80.0, glas="MIRROR", diam=20.0), _surf()],
                    **_SYSTEM)


def _read_noting(tmp_path, text, name):
    p = tmp_path / f"{name}.zmx"
    p.write_text(text)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lens = read_zmx(p).double()
    return lens, [str(w.message) for w in caught]


@pytest.mark.parametrize("theta", [-10.0, 7.5])
def test_after_a_flat_mirror_a_pivot_is_no_virtual_propagation(tmp_path, theta):
    """After a flat mirror a thickness against the direction of travel is read as OpticStudio's
    virtual propagation (a backward gap, with a note); the pivot's ``+D`` back to a scan mirror
    that lies ahead of the fold mirror is not one: no backward gap, no note, and every ray lands
    on the image plane where optiland's global trace of the same file lands it (1e-9 mm)."""
    text = pivot_after_mirror_file(theta)
    lens, notes = _read_noting(tmp_path, text, "pivot_after_mirror")
    assert lens.backward_gaps == frozenset()
    assert not [n for n in notes if "virtual propagation" in n]
    _assert_lands_as_optiland(tmp_path, text, lens)


def test_after_a_flat_mirror_a_surface_behind_the_beam_stays_virtual_propagation(tmp_path):
    """``+(L + D) + 30`` back puts the scan mirror 30 mm (about: the tilt) behind the fold mirror
    along the beam: that is OpticStudio's virtual propagation, read as before (a backward gap
    with one located note naming it)."""
    lens, notes = _read_noting(tmp_path, pivot_after_mirror_file(10.0, back=L_AFTER + D + 30),
                               "behind_after_mirror")
    assert lens.backward_gaps == frozenset({5})
    assert len([n for n in notes if "virtual propagation" in n]) == 1
