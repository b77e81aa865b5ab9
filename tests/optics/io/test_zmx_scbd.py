"""``SCBD`` records (OpticStudio's surface Tilt/Decenter, decoded from real files:
``deeplens.optics.io.zmx_scbd``): a surface's tilt/decenter is read as a coordinate break
before it and one after it (reverse, pickup or explicit), the coordinate return on a break is
noted, anything else is refused at its line."""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import line_of, singlet, trace_points, write

from deeplens.optics.errors import ZemaxFileError
from deeplens.optics.io import ZemaxWarning, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import CoordinateBreak


def _notes(path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lens = read_zmx(path)
    return lens, [str(w.message) for w in caught if issubclass(w.category, ZemaxWarning)]


def _same_trace(a, b, fields=(0.0, 1.0)):
    for f in fields:
        pa, va = trace_points(a, f)
        pb, vb = trace_points(b, f)
        assert torch.equal(va, vb) and int(va.sum()) >= 5
        torch.testing.assert_close(pb[vb], pa[va], rtol=0, atol=1e-12)


def _cb(vals, order, disz):
    return (["  TYPE COORDBRK", "  CURV 0.0"] + [f"  PARM {i} {v!r}" for i, v in
                                                  enumerate(vals, 1)]
            + [f"  PARM 6 {order}", f"  DISZ {disz!r}"])


def _file(blocks):
    """A file of ``SURF`` bodies (lists of lines), numbered in order."""
    head = ["VERS 170912 299 123456", "MODE SEQ", "NAME scbd", "UNIT MM X W X CM MR CPMM",
            "ENPD 8", "GCAT SCHOTT", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 1",
            "WAVM 1 0.55 1", "WAVM 2 0.65 1", "PWAV 1"]
    out = list(head)
    for k, b in enumerate(blocks):
        out += [f"SURF {k}", *b]
    return "\n".join(out) + "\n"


_OBJ = ["  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY"]
_STOP = ["  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 20", "  DIAM 4 1 0 0 1 \"\""]
_IMG = ["  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 30 1 0 0 1 \"\""]


def _scbd(vals, after=None):
    """The SCBD lines of a before break ``vals`` (order 0) and an after record (``after``:
    ``(order, status, values)``; reverse of ``vals`` when None)."""
    if after is None:
        after = (1, 2, tuple(-v for v in vals))
    o, st, a = after
    return [f"  SCBD 1 0 0 {' '.join(repr(v) for v in vals)}",
            f"  SCBD 2 {o} {st} {' '.join(repr(v) for v in a)}"]


def test_folded_mirror_scbd_is_the_explicit_breaks(tmp_path):
    """A concave mirror tilted 45° by its own tilt/decenter (reverse after it), the beam then
    followed by a 90° break (the reverse returns the incoming frame; the beam leaves at 90° to
    it): exactly the same landing points as the file with the breaks written out (break, mirror
    of thickness 0, the inverse break), and those of OpticStudio's usual fold (break 45°,
    mirror, break 45°)."""
    mirror = ["  TYPE STANDARD", "  CURV -0.01", "  GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0",
              "  DIAM 10 1 0 0 1 \"\""]
    follow = _cb((0.0, 0.0, 90.0, 0.0, 0.0), 0, -50.0)
    t = (0.0, 0.0, 45.0, 0.0, 0.0)
    a = read_zmx(write(tmp_path, _file([_OBJ, _STOP, mirror + _scbd(t) + ["  DISZ 0"],
                                         follow, _IMG]), "a.zmx"))
    b = read_zmx(write(tmp_path, _file([_OBJ, _STOP, _cb(t, 0, 0.0), mirror + ["  DISZ 0"],
                                         _cb(tuple(-v for v in t), 1, 0.0), follow, _IMG]),
                       "b.zmx"))
    assert sum(isinstance(s, CoordinateBreak) for s in a.surfaces) == 3
    _same_trace(a, b)
    fold = read_zmx(write(tmp_path, _file([_OBJ, _STOP, _cb(t, 0, 0.0), mirror + ["  DISZ 0"],
                                            _cb(t, 0, -50.0), _IMG]), "c.zmx"))
    for f in (0.0, 1.0):
        pa, va = trace_points(a, f)
        pc, vc = trace_points(fold, f)
        assert torch.equal(va, vc) and int(va.sum()) >= 5
        torch.testing.assert_close(pa[va], pc[vc], rtol=0, atol=1e-9)
    # the fold sends the on-axis beam near the image vertex (a 45° spherical mirror's coma)
    p, v = trace_points(a, 0.0)
    assert p[v].abs().max() < 1.5


def _lens(decentred, explicit):
    """A singlet whose two faces are decentred and tilted by their own tilt/decenter
    (``decentred``: dx dy tx ty tz, reverse after each), or the same written out as breaks."""
    g = "  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0"
    f1 = ["  TYPE STANDARD", "  CURV 0.02", "  DIAM 8 1 0 0 1 \"\""]
    f2 = ["  TYPE STANDARD", "  CURV -0.005", "  DIAM 8 1 0 0 1 \"\""]
    inv = tuple(-v for v in decentred)
    if explicit:
        mid = [_cb(decentred, 0, 0.0), f1 + ["  DISZ 0", g], _cb(inv, 1, 5.0),
               _cb(decentred, 0, 0.0), f2 + ["  DISZ 0"], _cb(inv, 1, 45.0)]
    else:
        mid = [f1 + _scbd(decentred) + ["  DISZ 5", g], f2 + _scbd(decentred) + ["  DISZ 45"]]
    return _file([_OBJ, _STOP, *mid, _IMG])


@pytest.mark.parametrize("dec", [(0.0, 0.3, 0.0, 0.0, 0.0), (0.2, -0.3, 1.5, -2.0, 30.0)])
def test_decentred_lens_scbd_is_the_explicit_breaks(tmp_path, dec):
    """A decentred (and tilted) singlet: the same landing points as its explicit breaks, and
    not those of the centred lens (the tilt/decenter is applied)."""
    a = read_zmx(write(tmp_path, _lens(dec, False), "a.zmx"))
    b = read_zmx(write(tmp_path, _lens(dec, True), "b.zmx"))
    _same_trace(a, b)
    c = read_zmx(write(tmp_path, _lens((0.0,) * 5, False), "c.zmx"))
    pa, va = trace_points(a, 1.0)
    pc, vc = trace_points(c, 1.0)
    assert (pa[va & vc] - pc[va & vc]).abs().max() > 1e-3


def test_reverse_is_the_exact_inverse(tmp_path):
    """A decenter and compound tilt on a dummy plane in air, reversed after it, changes
    nothing (the two breaks compose to the identity only with the values negated and the order
    flipped); a pickup after it (the same break twice) does change the image."""
    dec = (0.2, -0.3, 5.0, -3.0, 20.0)
    base = singlet(bfl=20.0)
    rest = ["SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 25", "  DIAM 8 1 0 0 1 \"\""]

    def with_dummy(lines):
        t = base.replace("SURF 4\n", "\n".join(rest + [*lines, "SURF 5", ""]))
        return t

    plain = read_zmx(write(tmp_path, with_dummy([]), "plain.zmx"))
    rev = read_zmx(write(tmp_path, with_dummy(_scbd(dec)), "rev.zmx"))
    pick = read_zmx(write(tmp_path, with_dummy(_scbd(dec, (0, 1, (0.0,) * 5))), "pick.zmx"))
    assert sum(isinstance(s, CoordinateBreak) for s in rev.surfaces) == 2
    _same_trace(plain, rev, fields=(0.0, 3.0))
    pa, va = trace_points(plain, 3.0)
    pb, vb = trace_points(pick, 3.0)
    assert (pa[va & vb] - pb[va & vb]).abs().max() > 1e-3


def _prism(scbd=True):
    """OpticStudio's sample-like 30° N-BK7 prism (faces tilted +15° and -15° by their own
    tilt/decenter, reverse after each), then the chief-ray-following break the file carries
    (OpticStudio's solve: 16.601464621191919° about x, y decenter -2.5680158104125721)."""
    def face(t):
        return ["  TYPE STANDARD", "  CURV 0.0", "  DIAM 10 1 0 0 1 \"\""] + (
            _scbd((0.0, 0.0, t, 0.0, 0.0)) if scbd else [])
    return _file([_OBJ, ["  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 30",
                         "  DIAM 4 1 0 0 1 \"\""],
                  face(15.0) + ["  DISZ 30", "  GLAS N-BK7 0 0 1.5 40 0 0 0 0 0 0"],
                  face(-15.0) + ["  DISZ 0"],
                  _cb((0.0, -2.5680158104125721, 16.601464621191919, 0.0, 0.0), 0, 30.0),
                  _IMG]).replace("WAVM 1 0.55 1", "WAVM 1 0.55000000000000004 1")


def test_prism_deviation_matches_closed_form_and_opticstudio(tmp_path):
    """The chief ray through the 30° prism leaves deviated by the closed-form deviation
    (faces at ±15°, incidence 15°: δ = 15° + asin(n sin(30° − asin(sin 15° / n))) − 30°, n of
    N-BK7 at 550 nm): in the frame of OpticStudio's chief-ray-following break it travels along
    z, turned by δ − 16.601464621191919°, and lands on the image vertex; untilted faces (the
    records ignored) land millimetres away."""
    lens = read_zmx(write(tmp_path, _prism(), "prism.zmx")).double()
    n = float(lens.materials[3].n(torch.tensor(550.0, dtype=torch.float64)))
    s15, a = math.sin(math.radians(15.0)), math.radians(30.0)
    dev = math.radians(15.0) + math.asin(n * math.sin(a - math.asin(s15 / n))) - a
    o = torch.tensor([[0.0, 0.0, -1.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    out = lens.trace_to_sensor(Rays(o, d, torch.full((1,), 550.0, dtype=torch.float64)))
    assert bool(out.valid.all())
    turned = math.atan2(float(out.d[0, 1]), float(out.d[0, 2]))
    # the sign: the traced turn is the closed form's excess over OpticStudio's solve
    assert abs(turned + (dev - math.radians(16.601464621191919))) < 1e-12
    # deeplens' N-BK7 and OpticStudio's agree: δ to 1e-6 degree, the landing to 1e-4 mm
    assert abs(math.degrees(dev) - 16.601464621191919) < 1e-6
    assert float(out.o[0, :2].abs().max()) < 1e-4
    flat = read_zmx(write(tmp_path, _prism(scbd=False), "flat.zmx")).double()
    out = flat.trace_to_sensor(Rays(o, d, torch.full((1,), 550.0, dtype=torch.float64)))
    assert float(out.o[0, 1].abs()) > 1.0


def test_scbd_round_trip_as_explicit_breaks(tmp_path):
    """write_zmx writes a surface's tilt/decenter as explicit COORDBRK surfaces, which read back
    as the same lens."""
    lens = read_zmx(write(tmp_path, _lens((0.2, -0.3, 1.5, -2.0, 30.0), False)))
    p = tmp_path / "back.zmx"
    write_zmx(lens, p)
    text = p.read_text()
    assert "SCBD" not in text and text.count("TYPE COORDBRK") == 4
    back = read_zmx(p)
    assert lens_to_dict(back) == {**lens_to_dict(lens), "name": lens_to_dict(back)["name"]}
    _same_trace(lens, back)


def test_scbd_notes_say_what_is_read(tmp_path):
    """One located note per surface with the decode and its source; all-zero data is noted as
    nothing to apply; the lens is then the same as without it."""
    rec = ("SCBD 1 0 0 0 0 1.5E+1 0 0", "SCBD 2 1 2 -0 -0 -1.5E+1 -0 -0")
    text = singlet(extra_s2=rec)
    lens, notes = _notes(write(tmp_path, text))
    ln = line_of(text, "SCBD 1")
    mine = [m for m in notes if "SCBD" in m]
    assert len(mine) == 1 and f"t.zmx:{ln}: SCBD on SURF 3: surface tilt/decenter read as a " \
        f"coordinate break before the surface (dx dy tx ty tz = 0 0 15 0 0, order 0) and one " \
        f"after it (reverse: -0 -0 -15 -0 -0, order 1)" in mine[0]
    assert "no OpticStudio text gives it" in mine[0]
    assert sum(isinstance(s, CoordinateBreak) for s in lens.surfaces) == 2
    zero = singlet(extra_s2=("SCBD 1 0 0 0 0 0 0 0", "SCBD 2 1 2 -0 -0 -0 -0 -0"))
    lens, notes = _notes(write(tmp_path, zero, "z.zmx"))
    assert [m for m in notes if "SCBD" in m] == [
        f"{tmp_path / 'z.zmx'}:{line_of(zero, 'SCBD 1')}: SCBD on SURF 3: surface "
        f"tilt/decenter data, all 0: nothing to apply"]
    bare = read_zmx(write(tmp_path, singlet(), "bare.zmx"))
    assert lens_to_dict(lens) == {**lens_to_dict(bare), "name": lens_to_dict(lens)["name"]}


def test_coordinate_return_note(tmp_path):
    """``SCBD 3 mode N`` on a COORDBRK: noted (the saved PARM values are read as written)."""
    brk = _file([_OBJ, _STOP, ["  TYPE STANDARD", "  CURV 0.02", "  DISZ 5",
                               "  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0"],
                 ["  TYPE STANDARD", "  CURV -0.005", "  DISZ 0"],
                 _cb((0.0, 0.0, 0.0, 0.0, 0.0), 1, 45.0)[:-1] + ["  SCBD 3 3 1", "  DISZ 45"],
                 _IMG])
    _, notes = _notes(write(tmp_path, brk))
    ln = line_of(brk, "SCBD 3")
    assert [m for m in notes if "SCBD" in m] == [
        f"{tmp_path / 't.zmx'}:{ln}: SCBD on SURF 4: a coordinate return to SURF 1 (mode 3): "
        f"OpticStudio saves the solve's result as the break's PARM values (mode 3: and DISZ), "
        f"which deeplens reads as written (they are not solved again)"]


@pytest.mark.parametrize("rec, needle", [
    ("SCBD 1 0 0 0 0 15 0", "(9 fields), got 8; this layout is not decoded"),
    ("SCBD 2 1 3 0 0 0 0 0", "the after-surface status (0 explicit, 1 pickup, 2 reverse) must"),
    ("SCBD 1 2 0 0 0 0 0 0", "the order (0 decenter then tilt, 1 tilt then decenter) must"),
    ("SCBD 4 0 0 0 0 0 0 0", "the first field"),
    ("SCBD 3 3 1", "a coordinate return (SCBD 3) on a surface that is not a COORDBRK"),
    ("SCBD 1 0 0 0 0 nan 0 0", "tilt_x must be finite"),
])
def test_undecoded_records_are_refused(tmp_path, rec, needle):
    text = singlet(extra_s2=(rec,))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, rec) and needle in str(e.value)


def test_tilt_on_a_break_is_refused(tmp_path):
    brk = _file([_OBJ, _STOP, ["  TYPE STANDARD", "  CURV 0.02", "  DISZ 5",
                               "  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0"],
                 ["  TYPE STANDARD", "  CURV -0.005", "  DISZ 0"],
                 _cb((0.0, 0.0, 1.0, 0.0, 0.0), 0, 45.0)[:-1]
                 + ["  SCBD 1 0 0 0 0 2 0 0", "  DISZ 45"], _IMG])
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(write(tmp_path, brk))
    assert e.value.line == line_of(brk, "SCBD 1") and "OpticStudio does not allow" in str(e.value)


def test_pair_around_a_tilted_face_is_no_misalignment(tmp_path):
    """A COORDBRK pair (decenter, then its inverse) around a singlet whose front face has its
    own tilt: not an element misalignment (a break stands inside it), read as breaks, and
    traced exactly as the file with every break written out."""
    g = "  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0"
    f1 = ["  TYPE STANDARD", "  CURV 0.02", "  DIAM 8 1 0 0 1 \"\""]
    f2 = ["  TYPE STANDARD", "  CURV -0.005", "  DIAM 8 1 0 0 1 \"\"", "  DISZ 0"]
    pair = (0.0, 0.1, 0.0, 0.0, 0.0)
    tilt = (0.0, 0.0, 2.0, 0.0, 0.0)
    back = tuple(-v for v in pair)
    a = _file([_OBJ, _STOP, _cb(pair, 0, 0.0), f1 + _scbd(tilt) + ["  DISZ 5", g], f2,
               _cb(back, 1, 45.0), _IMG])
    b = _file([_OBJ, _STOP, _cb(pair, 0, 0.0), _cb(tilt, 0, 0.0), f1 + ["  DISZ 0", g],
               _cb(tuple(-v for v in tilt), 1, 5.0), f2, _cb(back, 1, 45.0), _IMG])
    la, lb = read_zmx(write(tmp_path, a, "a.zmx")), read_zmx(write(tmp_path, b, "b.zmx"))
    assert all(m.is_identity() for m in la.misalignments)
    assert sum(isinstance(s, CoordinateBreak) for s in la.surfaces) == 4
    _same_trace(la, lb)
