"""``TYPE TILTSURF`` (OpticStudio's "Tilted" surface: the plane ``z = x tan θ_x + y tan θ_y``,
``PARM 1`` = ``tan θ_x``, ``PARM 2`` = ``tan θ_y``; OpticStudio User Guide, "Tilted"): with both
tangents zero it is the flat STANDARD surface (the same lens), otherwise a plane of those slopes
that rays meet where the closed form puts it and leave by Snell's law about its normal; refused
data name their line."""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import line_of, singlet, write

from deeplens.optics.io import ZemaxFileError, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.options import TraceOptions
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import XYPolynomial

F64 = torch.float64


def _tilted_back(tx="0.05", ty="-0.1", extra=(), curv1=0.02):
    """The singlet (``curv1`` its front curvature) with its flat back face (glass to air) a
    TILTSURF of tangents ``tx``, ``ty``."""
    kw = {} if curv1 else dict(curv1=0.0, s1_type="STANDARD", s1_extra=(), k=0.0)
    text = singlet(curv2=0.0, **kw)
    old = "SURF 3\n  TYPE STANDARD\n  CURV 0.0\n"
    assert old in text
    return text.replace(old, "SURF 3\n  TYPE TILTSURF\n  CURV 0.0\n" + "".join(
        f"  {x}\n" for x in (f"PARM 1 {tx}", f"PARM 2 {ty}", *extra)))


def test_zero_tangents_are_the_flat_standard_surface(tmp_path):
    """The fresh file's case (a TILTSURF with both tangents 0 in an air gap): the same lens as
    the file with a flat STANDARD surface there, also when it is an interface."""
    for where in ("gap", "interface"):
        if where == "interface":
            flat, tilted = singlet(curv2=0.0), _tilted_back("0", "0")
        else:
            base = singlet()
            block = 'SURF 4\n  TYPE {t}\n  CURV 0.0\n  PARM 1 0\n  PARM 2 0\n  DISZ 20\nSURF 5\n'
            base = base.replace("  DISZ 45.0\n", "  DISZ 25.0\n", 1)
            flat = base.replace("SURF 4\n", block.format(t="STANDARD"), 1)
            tilted = base.replace("SURF 4\n", block.format(t="TILTSURF"), 1)
        a = read_zmx(write(tmp_path, flat, f"a_{where}.zmx"))
        b = read_zmx(write(tmp_path, tilted, f"b_{where}.zmx"))
        assert lens_to_dict(a) == lens_to_dict(b)


def test_tilted_face_has_the_closed_form_sag_and_refracts_about_its_normal(tmp_path):
    """PARM 1 0.05, PARM 2 -0.1 on the glass-to-air back face of a plano-parallel plate: the
    surface's sag is 0.05 x - 0.1 y (x from PARM 1, y from PARM 2: swapping them fails); an
    axial ray at (1.5, -2) meets it at that height and leaves along the direction Snell's law
    gives about the normal (0.05, -0.1, -1) (to 1e-12)."""
    lens = read_zmx(write(tmp_path, _tilted_back(curv1=0.0))).double()
    i = len(lens.surfaces) - 1
    s = lens.surfaces[i]
    assert isinstance(s, XYPolynomial)
    x = torch.tensor([0.0, 1.5, -3.0, 2.0], dtype=F64)
    y = torch.tensor([0.0, -2.0, 1.0, 2.5], dtype=F64)
    assert s.sag(x, y).tolist() == pytest.approx((0.05 * x - 0.1 * y).tolist(), abs=1e-15)
    assert not torch.allclose(s.sag(x, y), 0.05 * y - 0.1 * x)
    wl = float(lens.spec.primary_wavelength_nm)
    rays = Rays(torch.tensor([[1.5, -2.0, -1.0]], dtype=F64),
                torch.tensor([[0.0, 0.0, 1.0]], dtype=F64), wl)
    with torch.no_grad():
        out = lens.trace(rays, options=TraceOptions(clip_aperture=False))
    assert bool(out.valid.all())
    z_hit = float(lens.z_vertices()[i]) + 0.05 * 1.5 - 0.1 * -2.0
    assert out.o[0].tolist() == pytest.approx([1.5, -2.0, z_hit], abs=1e-12)
    n1 = float(lens.materials[i].n(torch.tensor(wl, dtype=F64)))
    n2 = float(lens.materials[i + 1].n(torch.tensor(wl, dtype=F64)))
    assert n1 > 1.4 and n2 == pytest.approx(1.0, abs=1e-3)
    nrm = torch.tensor([0.05, -0.1, -1.0], dtype=F64)
    nrm = nrm / nrm.norm()
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    c = -float(d @ nrm)
    eta = n1 / n2
    want = eta * d + (eta * c - math.sqrt(1 - eta * eta * (1 - c * c))) * nrm
    assert out.d[0].tolist() == pytest.approx(want.tolist(), abs=1e-12)


def test_tangents_are_dimensionless_and_write_back_as_the_same_plane(tmp_path):
    """In centimetres the same tangents give the same plane (slopes have no unit); written
    back, the tilted face is an XPOLYNOM of the same sag, read again the same lens."""
    mm = read_zmx(write(tmp_path, _tilted_back(), "mm.zmx"))
    cm_text = singlet(unit="CM", curv1=0.2, curv2=0.0, t=0.5, bfl=4.5, aperture="ENPD 1",
                      diam1=0.8, s1_extra=("PARM 1 0", "PARM 2 1e-02", "PARM 3 -2e-02"))
    cm_text = cm_text.replace("DISZ 2\n", "DISZ 0.2\n").replace("DIAM 5 1", "DIAM 0.5 1") \
        .replace("DIAM 8 1", "DIAM 0.8 1").replace("DIAM 6 1", "DIAM 0.6 1")
    cm_text = cm_text.replace("SURF 3\n  TYPE STANDARD\n  CURV 0.0\n",
                              "SURF 3\n  TYPE TILTSURF\n  CURV 0.0\n  PARM 1 0.05\n"
                              "  PARM 2 -0.1\n")
    cm = read_zmx(write(tmp_path, cm_text, "cm.zmx"))
    x = torch.tensor([0.5, -3.0], dtype=F64)
    y = torch.tensor([2.0, 1.0], dtype=F64)
    a, b = mm.surfaces[-1], cm.surfaces[-1]
    assert b.sag(x, y).tolist() == pytest.approx(a.sag(x, y).tolist(), abs=1e-14)
    p = tmp_path / "back.zmx"
    write_zmx(mm, p)
    assert "TYPE XPOLYNOM" in p.read_text()
    back = read_zmx(p)
    assert back.surfaces[-1].sag(x, y).tolist() == pytest.approx(a.sag(x, y).tolist(),
                                                                 abs=1e-14)


@pytest.mark.parametrize("edit,needle,match", [
    (lambda: _tilted_back(extra=("PARM 3 0.2",)), "PARM 3 0.2",
     r"SURF 3: TILTSURF PARM 3 = 0.2 is not read \(PARM 1 and 2 are the x and y tangents\)"),
    (lambda: _tilted_back().replace("TYPE TILTSURF\n  CURV 0.0", "TYPE TILTSURF\n  CURV 0.01"),
     "CURV 0.01", r"SURF 3: a TILTSURF \(a tilted plane\) has no curvature, got CURV 0.01"),
])
def test_tilted_data_deeplens_does_not_read_are_refused_with_their_line(tmp_path, edit, needle,
                                                                        match):
    text = edit()
    ln = line_of(text, needle)
    with pytest.raises(ZemaxFileError, match=f"t.zmx:{ln}: {match}"):
        read_zmx(write(tmp_path, text))
