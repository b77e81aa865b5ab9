"""A stop with no semi-diameter under ``FLOA`` (float by stop size), every other surface with a
fixed ``DIAM`` (two real files of the unseen sets, written by another lens tool that omits the
stop's ``DIAM``): the file alone does not size the beam.  deeplens floats the stop to the
largest on-axis beam the fixed apertures pass (paraxial marginal-ray scaling,
``deeplens/optics/io/zmx_stop_size.py``), with one located warning naming the choice and the
flag that flips it (``stop_size="refuse"``, ``--stop-size refuse``).

Checked on a hand-written singlet (object at infinity) with a flat stop 5 mm behind it:

* the front face limits (``DIAM a``): the entering beam is ``2a`` wide, ``EPD = 2a``;
* the back face limits (``DIAM b``): the parallel marginal ray of height ``y1`` reaches
  ``y2 = y1 (1 - t (n - 1) c1 / n)`` there, so ``EPD = 2 b / (1 - t (n - 1) c1 / n)``;
* a finite object: the ray from the axial object point limited by the front face (``y1 = a``)
  reaches the stop at the height the thick-lens transfer gives, worked out here by hand;
* the warning is one, at the stop's ``SURF`` line, and names the size and the limiting ``SURF``;
  ``stop_size="refuse"`` (``read_zmx``, ``load_lens``, the command line) refuses there; with no
  fixed semi-diameter anywhere the file is refused either way.
"""

from __future__ import annotations

import warnings

import pytest

from deeplens.optics.io import load_lens
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx
from deeplens.optics.paraxial import paraxial

N, C1, C2, T, GAP = 1.5, 0.02, -0.005, 5.0, 5.0

SINGLET = """VERS 190513 80 123457
MODE SEQ
NAME floating stop
UNIT MM X W X CM MR CPMM
FLOA
GCAT SCHOTT
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ {obj}
SURF 1
  TYPE STANDARD
  CURV {c1}
  DISZ {t}
  GLAS ___BLANK 1 0 {n} 0
  DIAM {a} 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV {c2}
  DISZ {gap}
  DIAM {b} 1 0 0 1 ""
SURF 3
  STOP
  TYPE STANDARD
  CURV 0.0
  DISZ 60
SURF 4
  TYPE STANDARD
  CURV 0.0
  DISZ 0
"""


def _file(tmp_path, a=4.0, b=8.0, obj="INFINITY", fixed="1"):
    text = SINGLET.format(obj=obj, c1=C1, c2=C2, t=T, n=N, a=a, b=b, gap=GAP)
    if fixed != "1":
        text = text.replace(' 1 0 0 1 ""', f' {fixed} 0 0 1 ""')
    f = tmp_path / f"floating_{fixed}.zmx"
    f.write_text(text)
    return f, text.splitlines().index("SURF 3") + 1


def _read(f, **kw):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        lens = read_zmx(f, **kw)
    notes = [w.message for w in rec if isinstance(w.message, ZemaxWarning)
             and "no semi-diameter under FLOA" in str(w.message)]
    return lens, notes


def test_front_face_limits_the_beam_epd_is_its_diameter(tmp_path):
    f, line = _file(tmp_path, a=4.0, b=8.0)
    lens, notes = _read(f)
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(8.0, rel=1e-12)
    assert len(notes) == 1
    w = notes[0]
    assert w.source == str(f) and w.line == line
    msg = str(w)
    assert msg.startswith(f"{f}:{line}: the stop (SURF 3) has no semi-diameter under FLOA")
    for part in ("SURF 1 limits", "semi-diameter 4 mm", "stop_size='refuse'",
                 "--stop-size refuse"):
        assert part in msg, msg
    # the stop's size is the marginal ray's height there, y1 = 4 through the thick lens
    y2 = 4.0 * (1 - T * (N - 1) * C1 / N)
    u2 = -4.0 * (N - 1) * C1 - y2 * (1 - N) * C2   # n' u' = n u - y c (n' - n), n u1 first
    stop = y2 + GAP * u2
    assert float(lens.stop.semi_diameter) == pytest.approx(abs(stop), rel=1e-12)
    assert f"set to {abs(stop):.6g} mm" in msg


def test_back_face_limits_the_beam(tmp_path):
    b = 2.0
    f, _ = _file(tmp_path, a=8.0, b=b)
    lens, notes = _read(f)
    epd = 2 * b / (1 - T * (N - 1) * C1 / N)
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(epd, rel=1e-12)
    assert len(notes) == 1 and "SURF 2 limits" in str(notes[0])


def test_finite_object_the_cone_the_front_face_passes(tmp_path):
    s = 200.0
    f, _ = _file(tmp_path, a=4.0, b=8.0, obj=str(s))
    lens, notes = _read(f)
    # the ray from the axial object point meets the front face at 4: slope u0 = 4 / s
    u0 = 4.0 / s
    u1 = (u0 - 4.0 * (N - 1) * C1) / N
    y2 = 4.0 + T * u1
    u2 = N * u1 - y2 * (1 - N) * C2
    stop = y2 + GAP * u2
    assert float(lens.stop.semi_diameter) == pytest.approx(abs(stop), rel=1e-12)
    assert len(notes) == 1 and "SURF 1 limits" in str(notes[0])


def test_refuse_flag_and_nothing_to_limit_the_beam(tmp_path, capsys):
    f, line = _file(tmp_path)
    for call in (lambda: read_zmx(f, stop_size="refuse"),
                 lambda: load_lens(f, stop_size="refuse")):
        with pytest.raises(ZemaxFileError) as e:
            call()
        assert e.value.line == line
        assert "no semi-diameter" in str(e.value) and "stop_size='limiting'" in str(e.value)
    with pytest.raises(ValueError, match="stop_size must be one of"):
        read_zmx(f, stop_size="auto")
    # automatic DIAMs (flag 0) fix nothing: refused under either reading
    g, line = _file(tmp_path, fixed="0")
    for opt, why in (("limiting", "no other surface fixes its semi-diameter"),
                     ("refuse", "refused \\(stop_size='refuse'\\)")):
        with pytest.raises(ZemaxFileError, match=why) as e:
            read_zmx(g, stop_size=opt)
        assert e.value.line == line
    # on the command line
    from deeplens.cli import main

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["report", str(f), "--stop-size", "refuse", "--sampling", "hexapolar:3"])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == 2 and out == "" and len(lines) == 1 and f"{f}:{line}:" in lines[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["report", str(f), "--stop-size", "limiting", "--sampling", "hexapolar:3"])
    assert rc == 0 and "EFL" in capsys.readouterr().out
    # a reading option of .zmx files only (as --qbfs-conic): refused for another lens file
    for flag, value in (("--stop-size", "refuse"), ("--qbfs-conic", "refuse")):
        rc = main(["report", "double_gauss", flag, value])
        err = capsys.readouterr().err
        assert rc == 2 and f"{flag} applies to Zemax files (.zmx) only; double_gauss" in err


def test_both_oracles_confirm_under_the_floated_stop_size(tmp_path, monkeypatch):
    """The singlet laid out as the tool behind the two real files writes it (every line but
    ``VERS`` indented, the image's ``DIAM`` without its flag): the oracles read
    test_zmx_corpus.oracle_text's copy, given deeplens' stop radius as the stop's ``DIAM``
    (floating_stop_text; without it optiland refuses the floating stop and rayoptics cannot
    size its pupil), and give deeplens' EFL, EPD, pupil position and back focus."""
    pytest.importorskip("optiland")
    pytest.importorskip("rayoptics")
    import test_zmx_corpus as tc
    import test_zmx_corpus_rayoptics as tr

    text = SINGLET.format(obj="INFINITY", c1=C1, c2=C2, t=T, n=N, a=4.0, b=8.0, gap=GAP)
    text = text.replace("  DISZ 0\n", "  DISZ 0\n  DIAM 21.6\n")
    text = "".join(ln if ln.startswith("VERS") else "    " + ln.lstrip()
                   for ln in text.splitlines(keepends=True))
    raw, copies = tmp_path / "raw", tmp_path / "copies"
    raw.mkdir()
    copies.mkdir()
    (raw / "w.zmx").write_text(text)
    lens, _ = _read(raw / "w.zmx")
    monkeypatch.setattr(tc, "CORPUS", tc.oracle_folder(raw, copies))
    monkeypatch.setattr(tr, "CORPUS", copies)
    given = tc.floating_stop_text((copies / "w.zmx").read_text(), lens, 1.0)
    assert given is not None and tc.floating_stop_text(given, lens, 1.0) is None
    (copies / "w.zmx").write_text(given)
    optic, s_mm = tc._oracle("w.zmx", lens)
    scratch = tmp_path / "ro"
    scratch.mkdir()
    opm = tr._rayoptics("w.zmx", lens, monkeypatch, scratch)
    for oracle, got in (("optiland", tc._first_order(lens, optic, s_mm, "w.zmx")),
                        ("rayoptics", tr._numbers("w.zmx", lens, opm))):
        for what, (dl, ol) in got.items():
            assert dl == pytest.approx(ol, rel=1e-9 if oracle == "rayoptics" else 1e-6,
                                       abs=1e-9 * max(1.0, abs(dl))), (oracle, what)
    assert got["EPD"][0] == pytest.approx(8.0, rel=1e-12)
