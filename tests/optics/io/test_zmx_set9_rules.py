"""Readings met by the ninth unseen set of real files (docs/guide/zemax.md), each on a synthetic
file checked by a closed form:

* an unset system aperture (``ENPD 0``: a short course's start file, every surface flat) is
  refused on its line saying what was found and why, in one line;
* an image plane at ``DISZ 0`` on a curved last surface that lies wholly before its vertex plane
  (a face concave towards the image: a short course's doublet before its thicknesses are set)
  loads, the sensor 1e-9 mm behind the vertex as for a flat face; one reaching behind the plane
  stays refused, saying how far;
* the direction of travel after a reflecting grating follows the order the file traces: a
  grating stretcher turns its frame onto the first order, which leaves near the incoming beam,
  not along the mirror's zeroth order (OpticStudio's ``Gratingstrecker`` sample, refused before
  as "distance ... is positive").
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import write

from deeplens.optics.io import ZemaxFileError, read_zmx
from deeplens.optics.io.zmx import ZemaxWarning
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Grating

_HEAD = """VERS 80915 20 20100
MODE SEQ
UNIT MM X W X CM MR CPMM
{aperture}
FTYP 0 0 1 1 0 0 0
YFLN 0
WAVM 1 {wav} 1
PWAV 1
"""


def _surf(k, *lines):
    return f"SURF {k}\n" + "".join(f"  {ln}\n" for ln in lines)


def _line(text, needle):
    return next(i for i, ln in enumerate(text.splitlines(), 1) if ln.strip() == needle)


def _quiet(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(path)
    return lens, [x.message for x in w if isinstance(x.message, ZemaxWarning)]


# --------------------------------------------------------------------------- an unset aperture
_FLAT = "".join([_surf(0, "TYPE STANDARD", "CURV 0", "DISZ 150"),
                 _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 5",
                       "GLAS BK7 0 0 1.5 4.0E+1 0 0 0 0 0 0"),
                 _surf(2, "TYPE STANDARD", "CURV 0", "DISZ 100"),
                 _surf(3, "TYPE STANDARD", "CURV 0", "DISZ 0")])


@pytest.mark.parametrize("aperture, what", [("ENPD 0", "ENPD 0: the system aperture's "
                                                       "entrance-pupil diameter must be > 0"),
                                             ("FNUM 0 0", "FNUM 0: the system aperture's "
                                                          "F-number must be > 0")])
def test_an_unset_system_aperture_is_refused_on_its_line(tmp_path, aperture, what):
    """``ENPD 0`` (OpticStudio's short-course start file ``relay1``: every surface flat, every
    semi-diameter 0) sizes no pupil: refused at the aperture's line, one line naming the
    record, the value and why; before, the message was the lens's generic "aperture epd: value
    must be a positive number"."""
    text = _HEAD.format(aperture=aperture, wav=0.55) + _FLAT
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == 4
    msg = str(e.value)
    assert what in msg and "unset aperture" in msg and "\n" not in msg, msg


# --------------------------------------------------------------- an image on a curved last vertex
#: a singlet: flat front face, back face of radius R2 (< 0: concave towards the image), centre
#: thickness T, model glass of index N; the image plane at DISZ 0 on the back vertex
R2, T, N, SD = -40.0, 4.0, 1.5, 6.0


def _singlet(curv2, sd=SD):
    return _HEAD.format(aperture="ENPD 8", wav=0.5875618) + "".join([
        _surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
        _surf(1, "STOP", "TYPE STANDARD", "CURV 0", f"DISZ {T}",
              f"GLAS ___BLANK 1 0 {N} 0 0 0 0 0 0 0", f"DIAM {sd} 1 0 0 1"),
        _surf(2, "TYPE STANDARD", f"CURV {curv2!r}", "DISZ 0", f"DIAM {sd} 1 0 0 1"),
        _surf(3, "TYPE STANDARD", "CURV 0", "DISZ 0")])


def test_image_on_a_curved_vertex_that_lies_before_its_plane_loads(tmp_path):
    """The back face is concave towards the image (its sag, ``R2 < 0``, runs against the
    direction of travel), so the whole face lies before its vertex plane, where OpticStudio's
    thickness 0 puts the image plane: the sensor goes 1e-9 mm behind the vertex, as for a flat
    face, with one note on the image's ``SURF`` line.  The EFL is the plano-convex lensmaker's
    ``R2 / (1 − n)`` (a flat front face adds no power); the back focal distance from the last
    vertex equals the EFL (the principal plane on the curved vertex);
    a parallel ray at height h lands on the sensor where its refracted line meets the vertex
    plane, ``z_hit = sag(h)`` before it (the sensor 1e-9 mm further: < 1e-9 mm off)."""
    f = write(tmp_path, _singlet(1.0 / R2))
    lens, notes = _quiet(f)
    line = _line(f.read_text(), "SURF 3")
    mine = [n for n in notes if "last surface's vertex" in str(n)]
    assert len(mine) == 1 and mine[0].line == line, [str(n) for n in notes]
    assert float(lens.d_sensor) == 1e-9
    efl = R2 / (1.0 - N)
    p = paraxial(lens.double())
    assert float(p.efl) == pytest.approx(efl, rel=1e-12)
    assert float(p.bfl) == pytest.approx(efl, rel=1e-12)   # from the last vertex
    # real rays: parallel to the axis at heights h, refracted by the back face (the front face is
    # flat and normal to them), then carried to the vertex plane
    lens = lens.double()
    h = torch.tensor([0.5, 2.0, 3.0, 3.9], dtype=torch.float64)   # inside the 8 mm pupil
    o = torch.stack([torch.zeros_like(h), h, torch.full_like(h, -1.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(4, 3)
    out = lens.trace_to_sensor(Rays(o, d, torch.full((4,), 587.5618, dtype=torch.float64)))
    assert bool(out.valid.all())
    R = abs(R2)
    for k, hk in enumerate(h.tolist()):
        sag = R - math.sqrt(R * R - hk * hk)        # the face lies |sag| before its vertex
        inc = math.asin(hk / R)                     # angle of incidence on the sphere
        out_angle = math.asin(N * math.sin(inc))    # Snell's law, n -> 1
        slope = math.tan(out_angle - inc)           # towards the axis
        y = hk - slope * (sag + 1e-9)
        assert float(out.o[k, 1]) == pytest.approx(y, abs=1e-9), k


def test_image_on_a_curved_vertex_reaching_behind_its_plane_is_refused(tmp_path):
    """A back face convex towards the image (``c > 0`` here: its rim lies behind the vertex
    plane) would be cut by the flat sensor: refused at the image's ``SURF`` line, saying how far
    it reaches behind the plane (the sphere's sag at the semi-diameter, ``R − sqrt(R² − r²)``)."""
    R = 60.0
    f = write(tmp_path, _singlet(1.0 / R))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(f)
    assert e.value.line == _line(f.read_text(), "SURF 3")
    sag = R - math.sqrt(R * R - SD * SD)
    assert f"reaches {sag:.4g} mm behind its vertex plane" in str(e.value), str(e.value)


# ------------------------------------------------------------------ a grating's order in the axis
#: a flat reflecting grating of T lines/µm used in order M at λ (µm), lit at THETA_I from its
#: normal; the breaks turn the frame onto the diffracted beam, which leaves at theta_d on the
#: same side as the incoming one: sin θd = M λ T − sin θi (OpticStudio's Gratingstrecker sample:
#: 1.74 lines/µm, 1.03 µm, 59.1° in, 69.09° out)
T_LINES, M, LAMBDA_UM, THETA_I, L = 1.74, 1, 1.03, 59.1, 100.0


def _stretcher():
    theta_d = math.degrees(math.asin(M * LAMBDA_UM * T_LINES - math.sin(math.radians(THETA_I))))

    def brk(k, tilt, disz):
        return _surf(k, "TYPE COORDBRK", "CURV 0", "PARM 1 0", "PARM 2 0", f"PARM 3 {tilt!r}",
                     "PARM 4 0", "PARM 5 0", "PARM 6 0", f"DISZ {disz}")

    return _HEAD.format(aperture="ENPD 4", wav=LAMBDA_UM) + "".join([
        _surf(0, "TYPE STANDARD", "CURV 0", "DISZ INFINITY"),
        _surf(1, "STOP", "TYPE STANDARD", "CURV 0", "DISZ 50"),
        brk(2, -THETA_I, 0),
        _surf(3, "TYPE DGRATING", "CURV 0", f"PARM 1 {T_LINES}", f"PARM 2 {M}", "DISZ 0",
              "GLAS MIRROR 0 0 1.5 4.0E+1 0 0 0 0 0 0"),
        brk(4, theta_d, -L),
        _surf(5, "TYPE STANDARD", "CURV 0", "DISZ 0")]), theta_d


def test_the_axis_leaves_a_grating_in_its_order(tmp_path):
    """After the grating the breaks turn the frame onto the first order, so light travels along
    the local ``−z`` axis and the image ``L`` before the break (``DISZ −L``) is a real image
    plane.  Taken as the mirror's zeroth order, the axis would leave at ``θi + θd`` (128°) from
    the local ``−z`` axis, towards ``+z``, and the file was refused ("the image plane lies
    100 mm before the last surface's vertex").  Real rays of a collimated beam land where the
    grating's anamorphic map puts them: ``x' = x``, ``y' = y cos θd / cos θi`` (each ray meets
    the tilted grating ``y / cos θi`` from the vertex; the diffracted beam's width across its
    direction is that times ``cos θd``; near-Littrow, the beam comes back on the side it went
    in), travelling exactly along ``−z`` of the last frame."""
    text, theta_d = _stretcher()
    lens, _ = _quiet(write(tmp_path, text))
    assert lens.directions()[-1] == -1 and float(lens.d_sensor) == -L
    lens = lens.double()
    x = torch.tensor([0.0, 0.0, 0.0, 1.2, -0.4], dtype=torch.float64)
    y = torch.tensor([0.0, 1.0, -1.5, 0.0, 0.7], dtype=torch.float64)
    o = torch.stack([x, y, torch.full_like(y, -5.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(5, 3)
    out = lens.trace_to_sensor(Rays(o, d, torch.full((5,), LAMBDA_UM * 1e3,
                                                     dtype=torch.float64)))
    assert bool(out.valid.all())
    k = math.cos(math.radians(theta_d)) / math.cos(math.radians(THETA_I))
    torch.testing.assert_close(out.o[:, 0], x, rtol=0, atol=1e-12)
    torch.testing.assert_close(out.o[:, 1], y * k, rtol=0, atol=1e-12)
    torch.testing.assert_close(out.d, torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
                               .expand(5, 3), rtol=0, atol=1e-12)


def test_the_axis_is_diffracted_in_the_surface_own_dtype_and_device(tmp_path, monkeypatch):
    """The traced axis (:meth:`Lens.directions`, called by every paraxial computation) is sent
    through the grating's own ``diffract`` with tensors in the surface's dtype and on its device:
    tensors made as float64 on the CPU mix devices in a lens moved to a GPU (an error there) and
    dtypes in a float32 one (checked here, where no GPU is).  The signs are the same in float32
    and float64."""
    text, _ = _stretcher()
    lens, _ = _quiet(write(tmp_path, text))
    seen = []
    diffract = Grating.diffract

    def strict(self, x, d, wavelength_nm, n_after, valid):
        ts = (x, d, wavelength_nm, n_after)
        seen.append([(t.dtype, t.device) for t in ts])
        assert all(t.dtype == self.T.dtype and t.device == self.T.device for t in ts), seen[-1]
        return diffract(self, x, d, wavelength_nm, n_after, valid)

    monkeypatch.setattr(Grating, "diffract", strict)
    signs = lens.double().directions()
    assert lens.float().directions() == signs and signs[-1] == -1
    assert len(seen) == 2 and seen[1][0][0] == torch.float32
