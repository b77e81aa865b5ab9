"""CODE V ``.seq`` files (:mod:`deeplens.optics.io.codev`): the hand-written files in
``tests/data/codev`` against the same lenses shipped as JSON, round trips through ``.seq``,
``.zmx`` and JSON, rayoptics' CODE V reader as an independent oracle, and located refusals."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from deeplens.analysis.spot import spot_diagram
from deeplens.optics.errors import LensFileError
from deeplens.optics.io import load_lens, save_lens
from deeplens.optics.io.codev import CodeVWarning, read_seq, write_seq
from deeplens.optics.io.lensfile import lens_to_dict
from deeplens.optics.paraxial import paraxial

ROOT = Path(__file__).resolve().parents[3]
SEQ = ROOT / "tests" / "data" / "codev"
LENSES = ROOT / "data" / "lenses"
ZMX = ROOT / "tests" / "data" / "zmx_opticstudio"

# (seq file, the same lens as JSON); the JSON lenses' aperture is their stop's size, the files
# give the EPD that stop makes
PAIRS = [("cooke_triplet", "cooke_triplet"), ("singlet", "thorlabs_la1131"),
         ("asphere", "thorlabs_acl5040u")]


def _numbers(lens):
    with torch.no_grad():
        p = paraxial(lens)
        rms = [float(spot_diagram(lens, float(f), float(lens.spec.primary_wavelength_nm),
                                  sampling="hexapolar:6").rms_radius) for f in lens.spec.fields_deg]
    return float(p.efl), float(p.bfl), float(p.entrance_pupil_diameter), rms


def _indices(lens):
    w = torch.tensor(lens.spec.wavelengths_nm, dtype=torch.float64)
    with torch.no_grad():
        return [m.n(w).tolist() for m in lens.materials]


@pytest.mark.parametrize("seq,json_name", PAIRS)
def test_seq_file_matches_the_json_lens(seq, json_name):
    """EFL, BFL, EPD and the RMS spot of every field equal the JSON lens's.  The prescriptions
    are the same numbers (radii typed as 1/c), so EFL/BFL agree to float64 rounding (1e-12);
    the singlet's N-BK7 is SCHOTT's catalogue entry instead of deeplens' (the same Sellmeier
    coefficients: indices within 1e-9); the RMS spots come from the same rays through the same
    surfaces (1e-6 relative: float64 traces, Newton-converged intersections)."""
    a, b = load_lens(SEQ / f"{seq}.seq"), load_lens(LENSES / f"{json_name}.json")
    assert len(a.surfaces) == len(b.surfaces) and a.stop_index == b.stop_index
    assert float(a.d_sensor) == pytest.approx(float(b.d_sensor), rel=1e-12)
    assert a.spec.fields_deg == pytest.approx(b.spec.fields_deg)
    assert a.spec.wavelengths_nm == b.spec.wavelengths_nm
    for na, nb in zip(_indices(a), _indices(b)):
        assert na == pytest.approx(nb, abs=1e-9)
    efl_a, bfl_a, epd_a, rms_a = _numbers(a)
    efl_b, bfl_b, epd_b, rms_b = _numbers(b)
    assert efl_a == pytest.approx(efl_b, rel=1e-12)
    assert bfl_a == pytest.approx(bfl_b, rel=1e-12)
    assert epd_a == pytest.approx(epd_b, rel=1e-12)
    assert rms_a == pytest.approx(rms_b, rel=1e-6)
    assert a.spec.aperture_type == "epd"


def test_asphere_terms_are_read():
    lens = read_seq(SEQ / "asphere.seq")
    s = lens.surfaces[0]
    assert float(s.c) == 0.047794293361372656 and float(s.k) == -0.6405
    assert [float(v) for v in s.a] == [2e-6]   # A only: the B and C zeros are trailing


@pytest.mark.parametrize("seq", [p for p, _ in PAIRS] + ["paraboloid"])
def test_seq_round_trip_is_identical(seq, tmp_path):
    """.seq -> Lens -> .seq -> Lens: the same lens file dictionary, bit for bit."""
    a = read_seq(SEQ / f"{seq}.seq")
    write_seq(a, tmp_path / "a.seq")
    b = read_seq(tmp_path / "a.seq")
    da, db = lens_to_dict(a), lens_to_dict(b)
    assert da == db
    write_seq(b, tmp_path / "b.seq")
    assert (tmp_path / "a.seq").read_text() == (tmp_path / "b.seq").read_text()


def _same_prescription(a, b, rel=0.0):
    assert a.stop_index == b.stop_index and len(a.surfaces) == len(b.surfaces)
    for sa, sb in zip(a.surfaces, b.surfaces):
        assert float(getattr(sa, "c", 0.0)) == pytest.approx(float(getattr(sb, "c", 0.0)),
                                                              rel=rel, abs=0)
        assert float(sa.semi_diameter) == pytest.approx(float(sb.semi_diameter), rel=1e-12)
    assert [float(d) for d in a.distances] == pytest.approx([float(d) for d in b.distances],
                                                            rel=rel, abs=0)
    assert float(a.d_sensor) == pytest.approx(float(b.d_sensor), rel=rel)
    for na, nb in zip(_indices(a), _indices(b)):
        assert na == pytest.approx(nb, rel=0, abs=0)
    assert a.spec.aperture_type == b.spec.aperture_type
    assert a.spec.aperture_value == pytest.approx(b.spec.aperture_value, rel=1e-12)
    assert a.spec.fields_deg == b.spec.fields_deg
    assert a.spec.wavelengths_nm == b.spec.wavelengths_nm
    assert a.spec.primary_wavelength_nm == b.spec.primary_wavelength_nm


@pytest.mark.parametrize("zmx", ["cooke_triplet.zmx", "double_gauss_schott.zmx"])
def test_zmx_to_seq_keeps_the_prescription(zmx, tmp_path):
    """.zmx -> Lens -> .seq -> Lens: the same curvatures, gaps, glasses (SCHOTT's ``N-SSK2``
    written ``NSSK2_SCHOTT`` and found again; HIKARI's ``SK16``), semi-diameters, aperture
    (``ENPD`` -> ``EPD``, ``FNUM`` -> ``FNO``), fields and wavelengths."""
    a = load_lens(ZMX / zmx)
    save_lens(a, tmp_path / "a.seq")
    b = load_lens(tmp_path / "a.seq")
    _same_prescription(a, b)


def test_json_to_seq_to_json(tmp_path):
    """JSON -> .seq -> Lens -> JSON -> Lens: the Cooke triplet keeps its prescription; its
    stop-sized aperture becomes the EPD that stop gives (the stop keeps its size)."""
    a = load_lens("cooke_triplet")
    save_lens(a, tmp_path / "a.seq")
    b = load_lens(tmp_path / "a.seq")
    save_lens(b, tmp_path / "b.json")
    c = load_lens(tmp_path / "b.json")
    assert lens_to_dict(b) == lens_to_dict(c)
    assert float(c.surfaces[c.stop_index].semi_diameter) == pytest.approx(10.3, rel=1e-12)
    for sa, sc in zip(a.surfaces, c.surfaces):
        assert float(getattr(sa, "c", 0.0)) == float(getattr(sc, "c", 0.0))


# --------------------------------------------------------------------------- rayoptics oracle
def _rayoptics(path, monkeypatch, tmp_path):
    # rayoptics' reader opens a log file in the working folder of its import: a scratch one
    monkeypatch.chdir(tmp_path)
    cmdproc = pytest.importorskip("rayoptics.codev.cmdproc")
    opm, (_, not_found) = cmdproc.read_lens(Path(path))
    assert not not_found, f"rayoptics did not find {not_found}"
    sm = opm["seq_model"]
    surfs = [(float(i.profile.cv), float(g.thi)) for i, g in zip(sm.ifcs[1:], sm.gaps[1:])]
    return float(opm["analysis_results"]["parax_data"].fod.efl), surfs


def _merged(surfs):
    """rayoptics keeps dummy surfaces: fold flat ones with no power into the previous gap."""
    out = []
    for c, t in surfs:
        if out and c == 0.0 and out[-1][0] == 0.0 and len(out) > 1:
            out[-1] = (0.0, out[-1][1] + t)
        else:
            out.append((c, t))
    return out


@pytest.mark.parametrize("seq", ["cooke_triplet", "singlet"])
def test_rayoptics_reads_the_same_lens(seq, monkeypatch, tmp_path):
    """rayoptics' own CODE V reader (test-only oracle) gives the same EFL (float64 paraxial
    traces of the same numbers: 1e-12) and the same curvatures."""
    lens = read_seq(SEQ / f"{seq}.seq")
    efl, surfs = _rayoptics(SEQ / f"{seq}.seq", monkeypatch, tmp_path)
    assert efl == pytest.approx(float(paraxial(lens).efl), rel=1e-12)
    curv = [c for c, _ in surfs if c != 0]
    assert curv == pytest.approx([float(s.c) for s in lens.surfaces if float(getattr(s, "c", 0))])


@pytest.mark.parametrize("src", ["cooke_triplet", "double_gauss_schott.zmx"])
def test_rayoptics_reads_what_write_seq_writes(src, monkeypatch, tmp_path):
    """A file write_seq made (curvature mode, fictitious or SCHOTT catalogue glasses) reads in
    rayoptics to the same EFL and the same curvatures and gaps, surface by surface."""
    lens = load_lens(ZMX / src if src.endswith(".zmx") else src)
    out = tmp_path / "w.seq"
    write_seq(lens, out)
    efl, surfs = _rayoptics(out, monkeypatch, tmp_path)
    with torch.no_grad():
        assert efl == pytest.approx(float(paraxial(lens).efl), rel=1e-9)
    gaps = [float(d) for d in lens.distances[1:]] + [float(lens.d_sensor)]
    assert [c for c, _ in surfs] == [float(getattr(s, "c", 0.0)) for s in lens.surfaces]
    assert [t for _, t in surfs] == gaps


def test_asphere_geometry_in_rayoptics(monkeypatch, tmp_path):
    """rayoptics reads asphere.seq's ASP, K and A as we do (its B270 is not in its catalogues,
    so only the geometry is compared)."""
    monkeypatch.chdir(tmp_path)   # (see _rayoptics)
    cmdproc = pytest.importorskip("rayoptics.codev.cmdproc")
    opm, _ = cmdproc.read_lens(SEQ / "asphere.seq")
    prof = opm["seq_model"].ifcs[1].profile
    s = read_seq(SEQ / "asphere.seq").surfaces[0]
    assert (prof.cv, prof.cc) == (float(s.c), float(s.k))
    assert prof.coefs[1] == float(s.a[0]) and not any(prof.coefs[2:])


# --------------------------------------------------------------------------- syntax
_HEAD = "DIM M\nWL 587.5618\nEPD 10\nYAN 0 5\nSO 0 1e10\n"


def _seq(tmp_path, body, head=_HEAD, name="t.seq"):
    p = tmp_path / name
    p.write_text(head + body)
    return p


def test_radius_mode_is_the_default_and_units_scale(tmp_path):
    body = "S 50 5 NBK7_SCHOTT\n  STO\nS -50 45\nSI 0 0\n"
    a = read_seq(_seq(tmp_path, body))
    b = read_seq(_seq(tmp_path, "RDM N\n" + body.replace("50 5", "0.02 5").replace("-50", "-0.02"),
                      name="b.seq"))
    assert float(a.surfaces[0].c) == pytest.approx(0.02, rel=1e-15)
    assert lens_to_dict(a)["surfaces"] == lens_to_dict(b)["surfaces"]
    c = read_seq(_seq(tmp_path, body.replace("50 5", "5 0.5").replace("-50 45", "-5 4.5"),
                      head=_HEAD.replace("DIM M", "DIM C").replace("EPD 10", "EPD 1"),
                      name="c.seq"))
    assert float(c.surfaces[0].c) == pytest.approx(0.02, rel=1e-15)
    assert float(c.distances[1]) == pytest.approx(5.0) and c.spec.aperture_value == 10.0


def test_fictitious_glass_code():
    from deeplens.optics.io.codev import _fictitious

    g = _fictitious("517000.642000")
    assert (g.n_d, g.v_d) == (1.517, 64.2)
    g = _fictitious("500.700")
    assert (g.n_d, g.v_d) == (1.5, 70.0)


def test_image_heights_and_object_heights(tmp_path):
    """YIM at infinity: θ = atan(h'/f); YOB at a finite object: θ = -atan(h / (s + z_EP)), with
    the stop on the first vertex (z_EP = 0)."""
    body = "S 50 5 NBK7_SCHOTT\n  STO\nS -50 45\nSI 0 0\n"
    lens = read_seq(_seq(tmp_path, body, head=_HEAD.replace("YAN 0 5", "YIM 0 2")))
    f = float(paraxial(lens).efl)
    assert lens.spec.fields_deg == pytest.approx([0.0, math.degrees(math.atan(2 / f))],
                                                 rel=1e-14)
    lens = read_seq(_seq(tmp_path, body, head=_HEAD.replace("YAN 0 5", "YOB 0 10")
                         .replace("SO 0 1e10", "SO 0 200"), name="b.seq"))
    assert lens.spec.object_distance_mm == 200.0
    # the object point (0, +10): a negative field angle (its chief ray falls to the axis)
    assert lens.spec.fields_deg == pytest.approx([0.0, -math.degrees(math.atan(10 / 200))])


def test_vignetting_factors_warn(tmp_path):
    body = "S 50 5 NBK7_SCHOTT\n  STO\nS -50 45\nSI 0 0\n"
    with pytest.warns(CodeVWarning, match=r"t\.seq:2: VUY"):
        read_seq(_seq(tmp_path, body, head="DIM M\nVUY 0 0.2\n" + _HEAD[6:]))


def test_automatic_semi_diameters(tmp_path):
    """A surface without CIR gets the paraxial 1.05 (|y_m| + |y_c|): with the stop on the first
    surface y_c = 0 there, and y_m = EPD/2."""
    lens = read_seq(_seq(tmp_path, "S 50 5 NBK7_SCHOTT\n  STO\nS -50 45\nSI 0 0\n",
                         head=_HEAD.replace("S 50", "S 50")))
    assert float(lens.surfaces[0].semi_diameter) == pytest.approx(5.0, rel=1e-12)
    assert float(lens.surfaces[1].semi_diameter) > 5.0


@pytest.mark.parametrize("body,line,match", [
    ("S 50 5 NBK7_SCHOTT\n  STO\n  XDE 1\n  RET S1\nS -50 45\nSI 0 0\n", 8, "RET with XDE"),
    ("S 50 5 NBK7_SCHOTT\n  STO\nS -50 45\n  ADE 3\n  BDE 2\n  BEN\nSI 0 0\n", 11,
     "BEN with both ADE and BDE"),
    ("S 50 5 NBK7_SCHOTT\n  STO\n  K -1\nS -50 45\nSI 0 0\n", 8, "expected CON or ASP"),
    ("S 50 5 NOSUCH_SCHOTT\n  STO\nS -50 45\nSI 0 0\n", 6, "NOSUCH not found in the SCHOTT"),
    ("S 50 5 517642\n  STO\nS -50 45\nSI 0 0\n", 6, "ambiguous"),
    ("S 50 x NBK7_SCHOTT\n  STO\nS -50 45\nSI 0 0\n", 6, "S thickness: expected a number"),
    ("S 0 -0.3\n  STO\n  CIR 4\nS 50 5 NBK7_SCHOTT\nS -50 45\nSI 0 0\n", 8,
     "narrower than the beam .* here they cannot"),
    ("S 50 5 NBK7_SCHOTT\n  STO\n  CIR OBS 60\nS -50 45\nSI 0 0\n", 8, "CIR OBS .*below"),
    ("S 50 5 NBK7_SCHOTT\n  STO\n  CIR RHO 1\nS -50 45\nSI 0 0\n", 8, "CIR RHO"),
    ("S 50 5 NBK7_SCHOTT\n  STO S1\nS -50 45\nSI 0 0\n", 7, "STO"),
    ("S 50 5 NBK7_SCHOTT\n  STO\n  AC 1\nS -50 45\nSI 0 0\n", 8, "AC other than 0"),
    ("S 50 5 NBK7_SCHOTT\n  STO\nS -50 45\nSI -100 0\n", 9, "SI .*flat"),
    ("S 50 5 NBK7_SCHOTT\n  STO\nS -50 &\n", 8, "continuation"),
])
def test_refusals_name_file_and_line(tmp_path, body, line, match):
    p = _seq(tmp_path, body)
    with pytest.raises(LensFileError, match=match) as e:
        read_seq(p)
    assert e.value.source == str(p) and e.value.line == line


@pytest.mark.parametrize("head,line,match", [
    (_HEAD.replace("EPD 10", "NA 0.1"), 3, "NA"),
    (_HEAD.replace("EPD 10", ""), None, "no system aperture"),
    (_HEAD.replace("YAN 0 5", "XAN 0 1; YAN 0 5"), 4, "XAN"),
    (_HEAD.replace("WL 587.5618", "WL 486 587\nPRV\nPWL 400 500\n'G' 1.5\nEND"), 5,
     "1 indices for the 2 PWL"),
    (_HEAD.replace("WL 587.5618", "WL 587; REF 3"), 2, "REF 3"),
    (_HEAD.replace("DIM M", "DIM Q"), 1, "DIM"),
    (_HEAD.replace("SO 0 1e10", "SO 0 100").replace("EPD 10", "FNO -4"), 3, "FNO -4"),
])
def test_system_refusals(tmp_path, head, line, match):
    p = _seq(tmp_path, "S 50 5 NBK7_SCHOTT\n  STO\nS -50 45\nSI 0 0\n", head=head)
    with pytest.raises(LensFileError, match=match) as e:
        read_seq(p)
    assert e.value.line == line


def test_writer_refuses_what_it_cannot_write(tmp_path):
    lens = load_lens("cooke_triplet")
    with torch.no_grad():
        lens.misalignments[0].dx.fill_(0.1)
    with pytest.raises(LensFileError, match="misaligned"):
        write_seq(lens, tmp_path / "m.seq")



def test_writer_refuses_a_subclass_its_type_handler_does_not_write(tmp_path):
    """The writer asks the surface's own handler (the most derived registered class), not a
    base class's: an IdealLens (a Plane subclass) has no CODE V record and is refused naming
    the surface, where the isinstance chain once wrote it as a flat plane (f = 50 mm lost)."""
    from deeplens.optics.lens import Lens
    from deeplens.optics.materials import Air
    from deeplens.optics.surfaces import Aperture, IdealLens

    air = Air()
    lens = Lens([Aperture(1.5), IdealLens(50.0, 10.0)], [air, air, air], [0.0, 2.0], 48.0, 0)
    with pytest.raises(LensFileError, match="surface 1: IdealLens has no CODE V") as e:
        write_seq(lens, tmp_path / "ideal.seq")
    assert e.value.surfaces == (1,)
    assert not (tmp_path / "ideal.seq").exists()

@pytest.mark.parametrize("kind", ["ZernikeFringePhase", "ExtendedPolynomial"])
def test_new_lens_file_types_are_refused_not_written_as_their_base(kind, tmp_path):
    """A Zernike Fringe phase (a Binary 2, so an Asphere subclass) and an Extended Polynomial
    (an even-base sag) have no CODE V record: refused naming the surface, never written as
    their conic base (the phase or the polynomial lost)."""
    from deeplens.optics.lens import Lens
    from deeplens.optics.materials import Air
    from deeplens.optics.surfaces import Aperture, ExtendedPolynomial, ZernikeFringePhase

    s = (ZernikeFringePhase(-0.02, 6.0, 4.0, [0.0, 0.0, 0.0, 0.5]) if kind == "ZernikeFringePhase"
         else ExtendedPolynomial(-0.02, 6.0, 4.0, [0.0, 0.0, 0.01]))
    lens = Lens([Aperture(3.0), s], [Air(), Air(), Air()], [0.0, 2.0], 48.0, 0)
    with pytest.raises(LensFileError, match=f"surface 1: {kind} has no CODE V") as e:
        write_seq(lens, tmp_path / "new.seq")
    assert e.value.surfaces == (1,)
    assert not (tmp_path / "new.seq").exists()


def test_mirror(monkeypatch, tmp_path):
    """REFL: an f/1 paraboloid (R = -200 mm, K = -1) has EFL |R|/2 = 100 mm, its focus 100 mm
    in front of it (the negative thickness kept) and a perfect on-axis image (float64 rays:
    below 1e-9 mm); rayoptics reads the file, and the one write_seq makes, to the same focal
    length (its sign convention for a mirror's EFL is the opposite one)."""
    lens = read_seq(SEQ / "paraboloid.seq")
    assert lens.mirrors == frozenset({0})
    with torch.no_grad():
        p = paraxial(lens)
        assert float(p.efl) == pytest.approx(100.0, rel=1e-12)
        assert float(lens.d_sensor) == -100.0
        assert float(spot_diagram(lens, 0.0, 550.0).rms_radius) < 1e-9
    efl, _ = _rayoptics(SEQ / "paraboloid.seq", monkeypatch, tmp_path)
    assert abs(efl) == pytest.approx(100.0, rel=1e-12)
    write_seq(lens, tmp_path / "w.seq")
    assert "S -0.005 -100.0 REFL" in (tmp_path / "w.seq").read_text()
    efl, _ = _rayoptics(tmp_path / "w.seq", monkeypatch, tmp_path)
    assert abs(efl) == pytest.approx(100.0, rel=1e-12)


def test_utf16_and_load_lens_dispatch(tmp_path):
    """A UTF-16 file (with its byte-order mark) reads as its UTF-8 twin; load_lens and
    save_lens choose the CODE V reader and writer by the .seq suffix."""
    text = (SEQ / "singlet.seq").read_text()
    (tmp_path / "u16.seq").write_bytes(text.encode("utf-16"))
    a, b = load_lens(tmp_path / "u16.seq"), read_seq(SEQ / "singlet.seq")
    assert lens_to_dict(a) == lens_to_dict(b)
    save_lens(a, tmp_path / "out.seq")
    assert (tmp_path / "out.seq").read_text().startswith("RDM N\n")


def test_quotes_comments_and_continuations(tmp_path):
    """``!`` and ``;`` inside quotes are text; a title keeps its apostrophe; an unclosed quote
    is refused at its line."""
    head = ('RDM; LEN "VERSION: 11.2; LENS ! 84"\nTIT "Smith\'s lens ! not a comment"\n'
            + _HEAD)
    lens = read_seq(_seq(tmp_path, "S 50 5 NBK7_SCHOTT\n  STO\nS -50 &\n 45\nSI 0 0\n",
                         head=head))
    assert lens.name == "Smith's lens ! not a comment"
    assert float(lens.d_sensor) == 45.0
    with pytest.raises(LensFileError, match="unbalanced quote") as e:
        read_seq(_seq(tmp_path, "S 50 5 NBK7_SCHOTT\n", head="TIT 'open\n" + _HEAD, name="q.seq"))
    assert e.value.line == 1


def test_estimated_semi_diameters_stop_where_surfaces_meet(tmp_path):
    """Two surfaces without CIR whose paraxial estimates cross (a thin biconvex lens, a wide
    beam) are limited to where they meet: sags 20 - sqrt(400 - r²) summing to the 1 mm centre
    thickness, r = sqrt(400 - 19.5²); with CIR given the crossing is refused at its line."""
    body = "S 0 1\n  STO\nS 20 1 NBK7_SCHOTT\nS -20 30\nSI 0 0\n"
    lens = read_seq(_seq(tmp_path, body, head=_HEAD.replace("EPD 10", "EPD 30")))
    r = math.sqrt(400 - 19.5 ** 2)
    for i in (1, 2):
        assert float(lens.surfaces[i].semi_diameter) == pytest.approx(r, rel=1e-5)
    body = "S 0 1\n  STO\nS 20 1 NBK7_SCHOTT\n  CIR 6\nS -20 30\n  CIR 6\nSI 0 0\n"
    with pytest.raises(LensFileError, match="cross") as e:
        read_seq(_seq(tmp_path, body, head=_HEAD.replace("EPD 10", "EPD 30"), name="b.seq"))
    assert e.value.line == 8


def test_stop_spelled_out(tmp_path):
    lens = read_seq(_seq(tmp_path, "S 50 5 NBK7_SCHOTT\nS -50 45\n  STOP\nSI 0 0\n"))
    assert lens.stop_index == 1


def test_flat_stop_clear_aperture_narrower_than_the_pupil(tmp_path):
    """A CIR 4 on a flat stop in air before the lens under EPD 10 (refused before branch
    ``stopclap``): the stop is read as a flat ``Asphere`` keeping the paraxial radius 5 as its
    semi-diameter (EPD 10) with clear radius 4; on-axis, exactly the pattern points within
    4 mm of the axis pass (the stop is the entrance pupil); written and read back the same."""
    from deeplens.optics.paraxial import paraxial
    from deeplens.optics.sampling import pupil_pattern

    lens = read_seq(_seq(tmp_path, "S 0 1\n  STO\n  CIR 4\nS 50 5 NBK7_SCHOTT\nS -50 45\n"
                                   "SI 0 0\n"))
    stop = lens.surfaces[0]
    assert type(stop).__name__ == "Asphere" and float(stop.c) == 0.0
    assert float(stop.semi_diameter) == pytest.approx(5.0, rel=1e-12)
    assert float(stop.clear_radius) == 4.0
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(10.0, rel=1e-12)
    r = 5.0 * torch.linalg.vector_norm(pupil_pattern("hexapolar:9"), dim=-1)
    with torch.no_grad():
        spot = spot_diagram(lens, 0.0, 587.5618, "hexapolar:9", pupil="paraxial")
    assert spot.n_rays == int((r <= 4.0).sum()) < spot.n_launched
    write_seq(lens, tmp_path / "w.seq")
    assert lens_to_dict(read_seq(tmp_path / "w.seq")) == lens_to_dict(lens)


def test_stop_clear_aperture_narrower_than_the_pupil(tmp_path):
    """A CIR on a lens-surface stop narrower than the EPD's beam (CODE V keeps the pupil and
    vignettes its rim): the stop keeps the paraxial radius 12.5 mm as its semi-diameter and
    CIR 12 becomes its clear radius, which cuts the rim rays; written and read back the same."""
    body = ("S 61.47 6 NBK7_SCHOTT\n  STO\n  CIR 12\nS -44.64 2.5 NSF5_SCHOTT\nS -129.94 96\n"
            "SI 0 0\n")
    p = _seq(tmp_path, body, head=_HEAD.replace("EPD 10", "EPD 25"))
    lens = read_seq(p)
    stop = lens.surfaces[0]
    assert float(stop.semi_diameter) == pytest.approx(12.5, rel=1e-12)
    assert float(stop.clear_radius) == 12.0
    with torch.no_grad():
        spot = spot_diagram(lens, 0.0, 587.5618, pupil="paraxial")
    assert spot.n_rays < spot.n_launched
    write_seq(lens, tmp_path / "w.seq")
    assert lens_to_dict(read_seq(tmp_path / "w.seq")) == lens_to_dict(lens)
