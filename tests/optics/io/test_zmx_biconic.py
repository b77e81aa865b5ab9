"""``TYPE BICONICX`` in ``.zmx`` files: read into :class:`~deeplens.optics.surfaces.Biconic` with
the file's units (``CURV``/``CONI`` the y section, ``PARM 1`` the x *radius*, 0 flat in x,
``PARM 2`` the x conic), checked against optiland (a test-only oracle: its own ray trace and
spot, through a geometry with OpticStudio's biconic sag, since optiland's reader has no
``BICONICX`` and its own ``BiconicGeometry`` is another surface, the sum of two conics, except
where one curvature is 0), written back, reported; what a biconic does not have is refused
with its line."""

from __future__ import annotations

import math
import re
import warnings

import pytest
import torch
from test_zmx import line_of, report, write
from test_zmx_corpus import _assert_rms_agrees, _oracle, _rms_on_axis

from deeplens.optics.io import lens_to_dict
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Biconic
from helpers import read_zmx_quiet

F64 = torch.float64
#: the biconic front surface in mm: y curvature and conic, x radius and conic
CY, KY, RX, KX = 0.02, -0.5, 40.0, 0.3


def biconic_file(unit="MM", s=1.0, rx=RX, kx=KX, cy=CY, extra=(), bfl=46.0):
    """A singlet: a flat stop (EPD 10 mm), a BICONICX front (R_y 50 mm, k_y −0.5, R_x 40 mm,
    k_x 0.3) and a spherical back, in ``unit`` (``s`` mm per unit, every length scaled so that
    the lens in mm is the same)."""
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME biconic", f"UNIT {unit} X W X CM MR CPMM",
             f"ENPD {10 / s!r}", "GCAT SCHOTT", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 3",
             "WAVM 1 0.5875618 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {2 / s!r}",
             f"  DIAM {5 / s!r} 1 0 0 1 \"\"",
             "SURF 2", "  TYPE BICONICX", f"  CURV {cy * s!r}", f"  CONI {KY}",
             f"  PARM 1 {rx / s!r}", f"  PARM 2 {kx!r}", *[f"  {x}" for x in extra],
             f"  DISZ {5 / s!r}", "  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0",
             f"  DIAM {6 / s!r} 1 0 0 1 \"\"",
             "SURF 3", "  TYPE STANDARD", f"  CURV {-0.005 * s!r}",
             f"  DISZ {bfl / s!r}", f"  DIAM {6 / s!r} 1 0 0 1 \"\"",
             "SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", f"  DIAM {6 / s!r} 1 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


_read = read_zmx_quiet


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_reads_the_x_and_y_sections_with_the_units(tmp_path, unit, s):
    """CURV/CONI -> c_y/k_y, PARM 1 (a radius, in lens units) -> c_x = 1/(PARM 1 · mm per unit),
    PARM 2 -> k_x; PARM 1 = 0 is flat in x.  Paraxial data take the y section."""
    lens = _read(write(tmp_path, biconic_file(unit, s), f"b_{unit}.zmx"))
    b = lens.surfaces[1]
    assert type(b) is Biconic
    assert float(b.c) == pytest.approx(CY, rel=1e-15) and float(b.k) == KY
    assert float(b.cx) == pytest.approx(1 / RX, rel=1e-15) and float(b.kx) == KX
    assert float(b.semi_diameter) == pytest.approx(6.0, rel=1e-15)
    flat_x = _read(write(tmp_path, biconic_file(unit, s, rx=0.0), f"c_{unit}.zmx")).surfaces[1]
    assert float(flat_x.cx) == 0.0 and float(flat_x.c) == pytest.approx(CY, rel=1e-15)
    # the y section sets the paraxial focal length: the same as with a STANDARD front
    std = re.sub(r"TYPE BICONICX", "TYPE STANDARD", biconic_file(unit, s))
    std = re.sub(r"^\s+PARM [12] .*\n", "", std, flags=re.M)
    plain = _read(write(tmp_path, std, f"s_{unit}.zmx"))
    assert float(paraxial(lens).efl) == pytest.approx(float(paraxial(plain).efl), rel=1e-13)


class _ZemaxBiconic:
    """Built lazily (optiland is optional): an optiland Newton-Raphson geometry whose sag and
    normal are OpticStudio's biconic, written here from the manual's formula."""

    @staticmethod
    def make(cs, ry, rx, ky, kx):
        import optiland.backend as be
        from optiland.geometries.newton_raphson import NewtonRaphsonGeometry

        class ZemaxBiconic(NewtonRaphsonGeometry):
            def __init__(self):
                super().__init__(cs, ry, ky, tol=1e-14, max_iter=100)
                self.cx = 0.0 if rx == 0 or math.isinf(rx) else 1.0 / rx
                self.cy = 0.0 if ry == 0 or math.isinf(ry) else 1.0 / ry
                self.kx, self.ky = kx, ky
                self.is_symmetric = False

            def _nq(self, x, y):
                n = self.cx * x ** 2 + self.cy * y ** 2
                q = (1 + self.kx) * self.cx ** 2 * x ** 2 + (1 + self.ky) * self.cy ** 2 * y ** 2
                return n, be.sqrt(1 - q)

            def sag(self, x=0, y=0):
                x, y = be.asarray(x), be.asarray(y)
                n, r = self._nq(x, y)
                return n / (1 + r)

            def _surface_normal(self, x, y):
                x, y = be.asarray(x), be.asarray(y)
                n, r = self._nq(x, y)
                p = 1 + r
                w = n / (r * p ** 2)
                fx = 2 * self.cx * x / p + w * (1 + self.kx) * self.cx ** 2 * x
                fy = 2 * self.cy * y / p + w * (1 + self.ky) * self.cy ** 2 * y
                mag = be.sqrt(fx ** 2 + fy ** 2 + 1)
                return fx / mag, fy / mag, -1 / mag

            def __str__(self):
                return "ZemaxBiconic"

        return ZemaxBiconic()


def _optiland(tmp_path, text, lens, own_geometry=False):
    """optiland's reading of the file with the BICONICX front read as a STANDARD surface (its
    reader has none), then given the biconic geometry: OpticStudio's formula (above), or with
    ``own_geometry`` optiland's ``BiconicGeometry`` (the same surface when c_x or c_y is 0)."""
    pytest.importorskip("optiland")
    parm = dict((int(m.group(1)), float(m.group(2)))
                for m in re.finditer(r"^\s+PARM\s+(\d+)\s+(\S+)", text, re.M))
    curv = float(re.search(r"TYPE BICONICX\n\s+CURV (\S+)", text).group(1))
    std = re.sub(r"^\s+PARM .*\n", "", text.replace("TYPE BICONICX", "TYPE STANDARD"), flags=re.M)
    q = write(tmp_path, std, "oracle.zmx")
    optic, s_mm = _oracle(str(q), lens)
    surf = optic.surface_group.surfaces[2]
    ry = math.inf if curv == 0 else 1 / curv
    rx = math.inf if parm[1] == 0 else parm[1]
    if own_geometry:
        from optiland.geometries import BiconicGeometry

        surf.geometry = BiconicGeometry(surf.geometry.cs, rx, ry, parm[2], KY)
    else:
        surf.geometry = _ZemaxBiconic.make(surf.geometry.cs, ry, rx, KY, parm[2])
    return optic, s_mm


#: (Hx, Hy, Px, Py): chief and rim rays of skew fields, none of them meridional in both
SKEW = [(0.0, 0.0, 0.7, 0.5), (0.0, 0.0, -0.9, 0.2), (0.6, 0.8, 0.0, 0.0), (0.6, 0.8, 0.5, -0.6),
        (-1.0, 0.3, -0.3, 0.9), (0.4, -0.7, 0.8, 0.4)]


def _both(lens, optic, s_mm, H):
    """One ray traced by optiland from the object, and by deeplens from where optiland's ray
    meets the stop (file SURF 1, deeplens surface 0) on: ``(deeplens (x, y, L, M, N) on the
    image, optiland's)``, lengths in the file's unit."""
    w = float(lens.spec.primary_wavelength_nm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        optic.trace_generic(Hx=H[0], Hy=H[1], Px=H[2], Py=H[3], wavelength=w / 1000.0)
    sg = optic.surface_group

    def at(a, i):
        return float(torch.as_tensor(a)[i].reshape(-1)[0])

    z0 = float(sg.surfaces[1].geometry.cs.z)
    p = torch.tensor([at(sg.x, 1), at(sg.y, 1), at(sg.z, 1) - z0], dtype=F64) * s_mm
    p[2] += float(lens.z_vertices()[0])
    d = torch.tensor([at(sg.L, 0), at(sg.M, 0), at(sg.N, 0)], dtype=F64)
    out = lens.trace_to_sensor(Rays((p - d)[None], d[None], w),
                               options=TraceOptions(clip_aperture=False))
    assert bool(out.valid[0])
    dl = [float(out.o[0, 0]) / s_mm, float(out.o[0, 1]) / s_mm] + out.d[0].tolist()
    ol = [at(sg.x, -1), at(sg.y, -1), at(sg.L, -1), at(sg.M, -1), at(sg.N, -1)]
    return dl, ol


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_skew_rays_and_spot_match_optiland(tmp_path, unit, s):
    """Skew rays (x and y both off the axis) land on the image where optiland's do, with its
    directions (1e-9 mm, 1e-11; in fact 2e-15 mm, 5e-16), and the on-axis RMS spot (paraxial
    pupil, hexapolar:12) is optiland's within 0.5 % (in fact 1e-12).  A reading with x and y
    swapped would not: checked against a file whose x radius and y curvature are exchanged."""
    text = biconic_file(unit, s)
    lens = _read(write(tmp_path, text, f"b_{unit}.zmx"))
    optic, s_mm = _optiland(tmp_path, text, lens)
    for H in SKEW:
        dl, ol = _both(lens, optic, s_mm, H)
        assert dl[:2] == pytest.approx(ol[:2], abs=1e-9 / s_mm), H
        assert dl[2:] == pytest.approx(ol[2:], abs=1e-11), H
    dl, ol = _rms_on_axis(lens, optic, s_mm, "paraxial", str(tmp_path / f"b_{unit}.zmx"))
    _assert_rms_agrees(dl, ol)
    assert dl == pytest.approx(ol, rel=1e-9)
    # x and y exchanged: another lens (its skew rays land elsewhere)
    swapped = _read(write(tmp_path, biconic_file(unit, s, rx=1 / CY, cy=1 / RX), "sw.zmx"))
    dl_sw, _ = _both(swapped, optic, s_mm, SKEW[3])
    dl, ol = _both(lens, optic, s_mm, SKEW[3])
    assert abs(dl_sw[0] - ol[0]) + abs(dl_sw[1] - ol[1]) > 1e-3 / s_mm


@pytest.mark.parametrize("rx,cy", [(0.0, CY), (RX, 0.0)])
def test_cylinders_match_optilands_own_biconic(tmp_path, rx, cy):
    """With c_x or c_y = 0 (a cylinder lens, curved in y or in x) OpticStudio's biconic and
    optiland's ``BiconicGeometry`` are the same surface: skew rays and the on-axis spot agree
    with optiland's own geometry."""
    text = biconic_file(rx=rx, cy=cy, bfl=46.0 if cy else 66.0)
    lens = _read(write(tmp_path, text, "cyl.zmx"))
    optic, s_mm = _optiland(tmp_path, text, lens, own_geometry=True)
    for H in SKEW:
        dl, ol = _both(lens, optic, s_mm, H)
        assert dl[:2] == pytest.approx(ol[:2], abs=1e-9), H
        assert dl[2:] == pytest.approx(ol[2:], abs=1e-11), H
    dl, ol = _rms_on_axis(lens, optic, s_mm, "paraxial", str(tmp_path / "cyl.zmx"))
    _assert_rms_agrees(dl, ol)


def test_writes_back_the_same_lens(tmp_path):
    """write_zmx writes TYPE BICONICX with PARM 1 the x radius and PARM 2 the x conic; read back,
    the same prescription (c_x to one rounding of 1/(1/c_x)) and the same rays; an inch file
    comes back in mm; flat in x is written PARM 1 0."""
    for unit, s, rx in (("MM", 1.0, RX), ("IN", 25.4, RX), ("MM", 1.0, 0.0)):
        lens = _read(write(tmp_path, biconic_file(unit, s, rx=rx), f"in_{unit}.zmx"))
        out = tmp_path / f"out_{unit}_{rx}.zmx"
        write_zmx(lens, out)
        text = out.read_text()
        assert "TYPE BICONICX" in text
        assert re.search(rf"^\s*PARM 1 {0 if rx == 0 else repr(RX)}$", text, re.M), text
        assert re.search(rf"^\s*PARM 2 {KX!r}$", text, re.M)
        back = _read(out)
        a, b = lens_to_dict(lens), lens_to_dict(back)
        a.pop("name", None), b.pop("name", None)
        ca = a["surfaces"][1].pop("curvature_x_per_mm")
        cb = b["surfaces"][1].pop("curvature_x_per_mm")
        assert cb == pytest.approx(ca, rel=2e-16, abs=0)
        assert a == b
        with torch.no_grad():
            o = torch.tensor([[1.5, -2.0, -1.0], [-3.0, 2.5, -1.0]], dtype=F64)
            d = torch.tensor([[0.01, 0.02, 1.0], [0.0, -0.03, 1.0]], dtype=F64)
            d = d / d.norm(dim=-1, keepdim=True)
            ra = lens.trace_to_sensor(Rays(o, d, 587.6))
            rb = back.trace_to_sensor(Rays(o, d, 587.6))
        assert ra.valid.all() and (ra.o - rb.o).abs().max() < 1e-12


def test_report_prints_numbers(tmp_path):
    p = write(tmp_path, biconic_file())
    lens = _read(p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rep = report(p, "--pupil", "paraxial", "--sampling", "hexapolar:3")
    assert rep["efl_mm"] == pytest.approx(float(paraxial(lens).efl), rel=1e-12)
    spots = [f["rms_spot_um"] for f in rep["fields"]]
    assert len(spots) == 2 and all(math.isfinite(v) and v > 0 for v in spots)


@pytest.mark.parametrize("extra,needle,what", [
    (("PARM 3 0.5",), "PARM 3 0.5", r"BICONICX PARM 3 = 0.5 is not read"),
    (("XDAT 1 2",), "XDAT 1 2", r"BICONICX XDAT 1 = 2 is not read"),
    (("OBSC 0 1 0",), "OBSC 0 1 0", r"OBSC, a central obscuration on a lens surface"),
])
def test_what_a_biconic_lacks_is_refused_with_its_line(tmp_path, extra, needle, what):
    """A PARM beyond 2 (OpticStudio's biconic has PARM 1 and 2 only; a Biconic Zernike's terms),
    extra data or an obscuration on it: one error naming file and line (a rectangular aperture
    is read: tests/optics/io/test_zmx_sqap_any_surface.py).
    Zero-valued PARM lines (OpticStudio writes them) are accepted."""
    text = biconic_file(extra=extra)
    p = write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=what) as e:
        read_zmx(p)
    assert e.value.line == line_of(text, needle)
    ok = _read(write(tmp_path, biconic_file(extra=("PARM 3 0", "PARM 4 0")), "zeros.zmx"))
    assert type(ok.surfaces[1]) is Biconic


def test_a_semi_diameter_beyond_the_domain_is_refused_with_its_line(tmp_path):
    text = biconic_file(rx=5.0, kx=0.0)   # the x section ends at 5 mm; DIAM 6
    p = write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=r"beyond the domain of the biconic.*along x"):
        read_zmx(p)


def test_x_fields_on_a_biconic_lens_warn_that_they_are_not_exact(tmp_path):
    """An x field component (XFLN) is combined with y into a radial field, exact only for a
    rotationally symmetric lens: on a biconic lens the warning says it is not exact here."""
    from deeplens.optics.io.zmx import ZemaxWarning

    p = write(tmp_path, biconic_file().replace("XFLN 0 0", "XFLN 0 2"))
    with pytest.warns(ZemaxWarning, match=r"NOT exact for this lens \(surface 1, a Biconic"):
        read_zmx(p)


def mirror_file():
    """A concave biconic mirror (R_y −100 mm, k_y −0.5, R_x −120 mm, k_x 0.3) behind a flat stop
    (EPD 10 mm), imaging on a plane 50 mm back (the negative thickness after the mirror)."""
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME biconic mirror", "UNIT MM X W X CM MR CPMM",
             "ENPD 10", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 1",
             "WAVM 1 0.5875618 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 20",
             "  DIAM 5 1 0 0 1 \"\"",
             "SURF 2", "  TYPE BICONICX", f"  CURV {-0.01!r}", f"  CONI {KY}",
             "  PARM 1 -120.0", f"  PARM 2 {KX!r}", "  DISZ -50", "  GLAS MIRROR",
             "  DIAM 8 1 0 0 1 \"\"",
             "SURF 3", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 8 1 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


def test_a_biconic_mirror_matches_optiland(tmp_path):
    """GLAS MIRROR on a BICONICX: skew rays reflected onto the image where optiland's trace
    through OpticStudio's sag puts them (1e-9 mm, directions 1e-11), on-axis RMS within 0.5 %
    (an astigmatic spot: the x and y sections focus 10 mm apart)."""
    text = mirror_file()
    lens = _read(write(tmp_path, text, "mirror.zmx"))
    assert type(lens.surfaces[1]) is Biconic and 1 in lens.mirrors
    optic, s_mm = _optiland(tmp_path, text, lens)
    for H in SKEW:
        dl, ol = _both(lens, optic, s_mm, H)
        assert dl[:2] == pytest.approx(ol[:2], abs=1e-9), H
        assert dl[2:] == pytest.approx(ol[2:], abs=1e-11), H
    dl, ol = _rms_on_axis(lens, optic, s_mm, "paraxial", str(tmp_path / "mirror.zmx"))
    _assert_rms_agrees(dl, ol)
    assert dl > 0.1


def test_report_on_a_refused_biconic_prints_one_located_line(tmp_path, capsys):
    """`deeplens report` on a file whose biconic has a term it lacks: exit 2, nothing on
    stdout, one line on stderr naming the file, the line and the feature."""
    from deeplens.cli import main

    text = biconic_file(extra=("PARM 5 1e-3",))
    p = write(tmp_path, text)
    rc = main(["report", str(p), "--sampling", "hexapolar:3"])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1
    assert f"{p}:{line_of(text, 'PARM 5')}" in lines[0] and "BICONICX PARM 5" in lines[0]
