"""``TYPE ODDASPHE`` and ``TYPE EVENASPH`` with an r² term (``PARM 1`` != 0) in ``.zmx`` files:
read into :class:`~deeplens.optics.surfaces.OddAsphere` with the file's units, checked against
optiland's own reading of the same file (its odd/even asphere geometries, a test-only oracle),
written back, reported; an EVENASPH without ``PARM 1`` stays an :class:`Asphere`."""

from __future__ import annotations

import math
import re
import warnings

import pytest
import torch
from test_zmx import report, singlet, write
from test_zmx_corpus import _assert_rms_agrees, _first_order, _oracle, _rms_on_axis

from deeplens.optics.io import lens_to_dict
from deeplens.optics.io.zmx import ZemaxFileError, write_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Asphere, OddAsphere
from helpers import read_zmx_quiet

#: ODDASPHE PARM 1..5 (r¹..r⁵) and EVENASPH PARM 1..2 (r², r⁴), in a lens in millimetres
ODD = [2e-4, -5e-4, 1e-5, -2e-6, 3e-8]
EVEN = [1e-3, 1e-6]


def odd_file(unit="MM", s=1.0, odd=ODD, even=EVEN, bfl=85.5, field=3.0):
    """A singlet: a flat stop (EPD 10 mm), an ODDASPHE front (R 50 mm, k −0.5) and an EVENASPH
    back with an r² term, in ``unit`` (``s`` mm per unit; every value scaled so that the lens in
    mm is the same)."""
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME odd asphere", f"UNIT {unit} X W X CM MR CPMM",
             f"ENPD {10 / s!r}", "GCAT SCHOTT", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0", f"YFLN 0 {field}",
             "WAVM 1 0.5875618 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {2 / s!r}",
             f"  DIAM {5 / s!r} 1 0 0 1 \"\"",
             "SURF 2", "  TYPE ODDASPHE", f"  CURV {0.02 * s!r}", "  CONI -0.5",
             *[f"  PARM {i} {v * s ** (i - 1)!r}" for i, v in enumerate(odd, 1)],
             *[f"  PARM {i} 0" for i in range(len(odd) + 1, 9)],
             f"  DISZ {5 / s!r}", "  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0",
             f"  DIAM {6 / s!r} 1 0 0 1 \"\"",
             "SURF 3", "  TYPE EVENASPH", f"  CURV {-0.005 * s!r}",
             *[f"  PARM {i} {v * s ** (2 * i - 1)!r}" for i, v in enumerate(even, 1)],
             f"  DISZ {bfl / s!r}", f"  DIAM {6 / s!r} 1 0 0 1 \"\"",
             "SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", f"  DIAM {6 / s!r} 1 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


_read = read_zmx_quiet


def _folded(text):
    """The same file with every r² term folded into the curvature (``CURV + 2 PARM``: EVENASPH
    PARM 1, ODDASPHE PARM 2) and set to 0: the same vertex curvature, the paraxial data of the
    original (optiland's paraxial trace takes the base radius only)."""
    out = []
    for block in re.split(r"(?=^SURF )", text, flags=re.M):
        t = re.search(r"^\s+TYPE\s+(\S+)", block, re.M)
        j = {"EVENASPH": 1, "ODDASPHE": 2}.get(t.group(1) if t else "")
        m = j and re.search(rf"^\s+PARM {j} (\S+)$", block, re.M)
        if m:
            a2 = float(m.group(1))
            block = re.sub(r"^(\s+CURV )(\S+)", lambda c: f"{c.group(1)}{float(c.group(2)) + 2 * a2!r}",
                           block, flags=re.M)
            block = block.replace(m.group(0), m.group(0).replace(m.group(1), "0"))
        out.append(block)
    return "".join(out)


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_reads_every_term_in_its_place_with_the_units(tmp_path, unit, s):
    """ODDASPHE PARM i -> the r^i coefficient, EVENASPH PARM i -> r^(2i) (odd powers 0), scaled
    by (mm per unit)^(1−i); the curvature and conic as for any surface."""
    lens = _read(write(tmp_path, odd_file(unit, s), f"odd_{unit}.zmx"))
    front, back = lens.surfaces[1], lens.surfaces[2]
    assert type(front) is OddAsphere and type(back) is OddAsphere
    got = [float(v) for v in front.a]
    want = [v * s ** (i - 1) * s ** (1 - i) for i, v in enumerate(ODD, 1)]
    assert got == pytest.approx(want, rel=1e-14, abs=0)
    assert [float(v) for v in back.a] == pytest.approx([0.0, EVEN[0], 0.0, EVEN[1]], rel=1e-14,
                                                       abs=0)
    assert float(front.c) == pytest.approx(0.02, rel=1e-15) and float(front.k) == -0.5
    assert float(back.c) == pytest.approx(-0.005, rel=1e-15) and float(back.k) == 0.0


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_first_order_and_spot_match_optiland(tmp_path, unit, s):
    """optiland's reading of the file (its OddAsphere/EvenAsphere geometries, its own ray
    trace): on-axis RMS spot (paraxial pupil, hexapolar:12) within 0.5 % (in fact 1e-6); its
    first-order data (EFL, BFL, EPD, entrance pupil) to 1e-6 against the file with the r² terms
    folded into the curvatures (optiland's paraxial trace ignores them; deeplens' includes them,
    and reads the folded file to the same numbers)."""
    p = write(tmp_path, odd_file(unit, s), f"odd_{unit}.zmx")
    lens = _read(p)
    optic, s_mm = _oracle(str(p), lens)
    dl, ol = _rms_on_axis(lens, optic, s_mm, "paraxial", str(p))
    _assert_rms_agrees(dl, ol)
    assert dl == pytest.approx(ol, rel=1e-6)
    q = write(tmp_path, _folded(odd_file(unit, s)), f"folded_{unit}.zmx")
    folded = _read(q)
    assert float(paraxial(folded).efl) == pytest.approx(float(paraxial(lens).efl), rel=1e-12)
    optic_f, _ = _oracle(str(q), folded)
    numbers = _first_order(lens, optic_f, s_mm, str(q))
    for what, (a, b) in numbers.items():
        assert a == pytest.approx(b, rel=1e-6, abs=1e-9 * max(1.0, abs(a))), what
    # the r² terms matter: optiland's unfolded reading has another focal length
    assert abs(float(optic.paraxial.f2()) - numbers["EFL"][0]) > 1e-2 * abs(numbers["EFL"][0])


def test_off_axis_rays_land_where_optilands_do(tmp_path):
    """Chief and pupil rays of the 3° field (skew ones too), traced by optiland through its odd
    and even asphere geometries, land on the image plane where deeplens' do (1e-9 mm)."""
    from deeplens.optics.options import TraceOptions
    from deeplens.optics.sampling import field_rays

    p = write(tmp_path, odd_file())
    lens = _read(p)
    optic, _ = _oracle(str(p), lens)
    w = float(lens.spec.primary_wavelength_nm)
    par = paraxial(lens)
    r, z = 0.5 * float(par.entrance_pupil_diameter), float(par.entrance_pupil_z)
    pupil = [(0.0, 0.0), (0.0, 0.9), (0.0, -0.9), (0.8, 0.0), (0.5, 0.5), (-0.6, 0.3)]
    with torch.no_grad():
        xy = torch.tensor(pupil, dtype=lens.dtype) * r
        out = lens.trace_to_sensor(field_rays(lens, 3.0, w, xy, z),
                                   options=TraceOptions(clip_aperture=False))
    assert bool(out.valid.all())
    sign = None
    for (px, py), q in zip(pupil, out.o):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            optic.trace_generic(0.0, 1.0, px, py, w / 1000.0)
        sg = optic.surface_group
        x, y = (float(torch.as_tensor(c)[-1].reshape(-1)[0]) for c in (sg.x, sg.y))
        # deeplens' field angle points the other way in y (as its object heights): fix the
        # sign once, from the chief ray, then every ray must agree
        sign = sign or (1.0 if abs(float(q[1]) - y) < abs(float(q[1]) + y) else -1.0)
        assert [float(q[0]), float(q[1])] == pytest.approx([x, sign * y], abs=1e-9), (px, py)
    assert abs(float(out.o[0, 1])) > 1.0   # a real field height, not the axis


def test_paraxial_power_includes_the_r2_terms(tmp_path):
    """deeplens' EFL against a real ray 1e-4 mm from the axis (no r¹ term here: its cone would
    turn even that ray): the r² terms of both surfaces are in the paraxial power (1e-5)."""
    lens = _read(write(tmp_path, odd_file(odd=[0.0] + ODD[1:])))
    efl = float(paraxial(lens).efl)
    h = 1e-4
    z0 = float(lens.z_vertices()[0]) - 1.0
    rays = Rays(torch.tensor([[0.0, h, z0]], dtype=lens.dtype),
                torch.tensor([[0.0, 0.0, 1.0]], dtype=lens.dtype),
                float(lens.spec.primary_wavelength_nm))
    with torch.no_grad():
        last = lens.trace(rays)
    real = -h / (float(last.d[0, 1]) / float(last.d[0, 2]))
    assert real == pytest.approx(efl, rel=1e-5)
    folded_out = _read(write(tmp_path, _folded(odd_file(odd=[0.0] + ODD[1:])), "f.zmx"))
    assert float(paraxial(folded_out).efl) == pytest.approx(efl, rel=1e-12)
    plain = OddAsphere(0.02, 6.0, -0.5, [0.0, 0.0] + ODD[2:])   # without its r² term
    assert float(plain.paraxial_curvature()) == 0.02 != float(lens.surfaces[1].paraxial_curvature())


def test_writes_back_the_same_lens(tmp_path):
    """write_zmx: ODDASPHE for the odd asphere, EVENASPH with PARM 1 for the even one with an
    r² term; read back, the same prescription bit for bit; an inch file comes back in mm."""
    for unit, s in (("MM", 1.0), ("IN", 25.4)):
        lens = _read(write(tmp_path, odd_file(unit, s), f"in_{unit}.zmx"))
        write_zmx(lens, tmp_path / f"out_{unit}.zmx")
        text = (tmp_path / f"out_{unit}.zmx").read_text()
        assert "TYPE ODDASPHE" in text and "TYPE EVENASPH" in text
        assert re.search(r"^\s*PARM 1 0\.001$" if unit == "MM" else r"^\s*PARM 1 0\.00",
                         text, re.M)
        back = _read(tmp_path / f"out_{unit}.zmx")
        a, b = lens_to_dict(lens), lens_to_dict(back)
        a.pop("name", None), b.pop("name", None)
        assert a == b
        assert float(paraxial(back).efl) == float(paraxial(lens).efl)


def test_report_prints_numbers(tmp_path):
    p = write(tmp_path, odd_file())
    lens = _read(p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rep = report(p, "--pupil", "paraxial", "--sampling", "hexapolar:3")
    assert rep["efl_mm"] == pytest.approx(float(paraxial(lens).efl), rel=1e-12)
    spots = [f["rms_spot_um"] for f in rep["fields"]]
    assert len(spots) == 2 and all(math.isfinite(v) and v > 0 for v in spots)
    assert all(f["n_rays"] == f["n_launched"] for f in rep["fields"])


def test_even_asphere_without_r2_stays_the_asphere(tmp_path):
    """PARM 1 written as 0 (any spelling) keeps the even asphere an Asphere, its terms from r⁴."""
    for zero in ("0", "0.000000000000E+000", "-0"):
        lens = _read(write(tmp_path, singlet(s1_extra=(f"PARM 1 {zero}", "PARM 2 1e-05",
                                                       "PARM 3 -2e-07"))))
        s = lens.surfaces[1]
        assert type(s) is Asphere and [float(v) for v in s.a] == [1e-05, -2e-07]


def test_odd_asphere_without_terms_is_its_conic(tmp_path):
    text = odd_file(odd=[])
    lens = _read(write(tmp_path, text))
    assert type(lens.surfaces[1]) is Asphere and len(lens.surfaces[1].a) == 0


def test_obscuration_on_an_odd_asphere_is_refused_at_its_line(tmp_path):
    text = odd_file().replace("  GLAS N-BK7", "  OBSC 0 1 0\n  GLAS N-BK7")
    p = write(tmp_path, text)
    with pytest.raises(ZemaxFileError) as e:
        _read(p)
    assert text.splitlines()[e.value.line - 1].split()[0] == "OBSC"
    assert "OBSC, a central obscuration on a lens surface (OddAsphere)" in str(e.value)


def test_odd_asphere_mirror_matches_optiland(tmp_path):
    """A paraboloid mirror (R −100 mm, k −1) with r¹, r³, r⁴ terms (``GLAS MIRROR``): first-order
    data exact and on-axis RMS within 1e-6 of optiland's reading."""
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME odd mirror", "UNIT MM X W X CM MR CPMM",
             "ENPD 20", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 0.5", "WAVM 1 0.5875618 1",
             "PWAV 1", "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 20",
             "  DIAM 10 1 0 0 1 \"\"",
             "SURF 2", "  TYPE ODDASPHE", "  CURV -0.01", "  CONI -1", "  PARM 1 1e-4",
             "  PARM 3 2e-6", "  PARM 4 -1e-7", "  DISZ -49.5", "  GLAS MIRROR",
             "  DIAM 11 1 0 0 1 \"\"",
             "SURF 3", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 5 1 0 0 1 \"\""]
    p = write(tmp_path, "\n".join(lines) + "\n", "mirror.zmx")
    lens = _read(p)
    assert type(lens.surfaces[1]) is OddAsphere and 1 in lens.mirrors
    optic, s_mm = _oracle(str(p), lens)
    for what, (a, b) in _first_order(lens, optic, s_mm, str(p)).items():
        assert a == pytest.approx(b, rel=1e-6, abs=1e-9 * max(1.0, abs(a))), what
    dl, ol = _rms_on_axis(lens, optic, s_mm, "paraxial", str(p))
    assert ol > 1e-3 and dl == pytest.approx(ol, rel=1e-6)
