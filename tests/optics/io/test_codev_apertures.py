"""CODE V rectangular apertures (:mod:`deeplens.optics.io.codev_apertures`): which rays pass
against hand geometry, rayoptics' ``threemir.seq`` (its off-axis mirrors' rectangles hold the
beam, and rayoptics' trace confirms the system), round trips through ``write_seq`` and located
refusals; with the reader's other changes for that file (``DIM`` after the surfaces, ``POL N``,
a bare ``CA``, a decentred image with a focus shift)."""

from __future__ import annotations

import itertools
import warnings
from pathlib import Path

import pytest
import torch

from deeplens.optics.errors import LensFileError
from deeplens.optics.io.codev import CodeVWarning, read_seq, write_seq
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture, Asphere

ROOT = Path(__file__).resolve().parents[3]
RAYOPTICS = ROOT / "tests" / "data" / "codev" / "rayoptics"
HEAD = "RDM Y\nDIM M\nWL 587.56\nEPD 12\nYAN 0\nSO 0 1e20\n"
EPS = 1e-6   # mm inside or outside an edge: far above float64 rounding of a hit point (~1e-15)


def _seq(tmp_path, body, name="t", head=HEAD):
    p = tmp_path / f"{name}.seq"
    p.write_text(head + body)
    return p


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_seq(path).double()


def _passes(lens, xy, z0=-1.0):
    """Which rays parallel to the axis, starting at ``(x, y, z0)``, reach the sensor (apertures
    applied)."""
    o = torch.tensor([(x, y, z0) for x, y in xy], dtype=torch.float64)
    d = torch.tensor([(0.0, 0.0, 1.0)] * len(xy), dtype=torch.float64)
    with torch.no_grad():
        r = lens.trace_to_sensor(Rays(o, d, float(lens.spec.primary_wavelength_nm)))
    return r.valid.tolist()


def _edges(c, h):
    """Coordinates just inside and just outside both edges ``c ± h`` and the centre."""
    return [c - h - EPS, c - h + EPS, c, c + h - EPS, c + h + EPS]


def test_a_decentred_rectangle_on_a_lens_surface_passes_the_rays_within_it(tmp_path):
    """``REX 3; REY 2; ADX 0.5; ADY -1`` on a lens's first surface (R 50): a ray parallel to the
    axis meets the surface at its own ``(x, y)``, so it passes exactly when
    ``|x - 0.5| <= 3`` and ``|y + 1| <= 2`` (half-widths about the ADX/ADY centre; the stop, 6 mm
    wide, and the lens's rear surface do not limit these rays)."""
    lens = _read(_seq(tmp_path, "S 0 5\n  STO\n  CIR 6\nS 50 4 517000.642000\n  REX 3; REY 2\n"
                                "  ADX 0.5; ADY -1\nS 0 30\n  CIR 8\nSI 0 0\n"))
    assert isinstance(lens.surfaces[1], Asphere)
    xy = list(itertools.product(_edges(0.5, 3.0), _edges(-1.0, 2.0)))
    want = [abs(x - 0.5) <= 3.0 and abs(y + 1.0) <= 2.0 for x, y in xy]
    assert _passes(lens, xy) == want
    assert sum(want) == 9 and len(want) == 25   # 3 x 3 inside, the rest just outside


def test_a_rectangle_on_a_flat_surface_in_air_is_a_rectangular_aperture(tmp_path):
    """``REX 1.5; REY 1; ADY 0.5`` on a flat surface in air (not the stop): an
    :class:`Aperture` of shape ``rect`` about ``(0, 0.5)``: a ray parallel to the axis passes
    exactly when ``|x| <= 1.5`` and ``|y - 0.5| <= 1``; without the rectangle the same surface
    would be a dummy."""
    lens = _read(_seq(tmp_path, "S 0 2\n  REX 1.5\n  REY 1\n  ADY 0.5\nS 0 5\n  STO\n  CIR 6\n"
                                "S 50 4 517000.642000\n  CIR 8\nS 0 30\n  CIR 8\nSI 0 0\n"))
    ap = lens.surfaces[0]
    assert isinstance(ap, Aperture) and ap.shape == "rect"
    xy = list(itertools.product(_edges(0.0, 1.5), _edges(0.5, 1.0)))
    want = [abs(x) <= 1.5 and abs(y - 0.5) <= 1.0 for x, y in xy]
    assert _passes(lens, xy, z0=-0.5) == want


def test_rectangles_round_trip_through_write_seq(tmp_path):
    """``.seq`` -> lens -> ``write_seq`` -> lens: the same surfaces (rectangles, their centres,
    the clear circles and semi-diameters that enclose them) and the same openings."""
    a = _read(_seq(tmp_path, "S 0 2\n  REX 1.5\n  REY 1\n  ADY 0.5\nS 0 5\n  STO\n  CIR 6\n"
                             "S 50 4 517000.642000\n  REX 3; REY 2; ADX 0.5; ADY -1\n"
                             "S 0 30\n  REX 2.5; REY 1.5\nSI 0 0\n"))
    write_seq(a, tmp_path / "out.seq")
    text = (tmp_path / "out.seq").read_text()
    assert text.count("REX") == 3 and "ADX 0.5" in text and "ADY -1.0" in text
    b = _read(tmp_path / "out.seq")
    assert [s.to_dict() for s in a.surfaces] == [s.to_dict() for s in b.surfaces]
    assert [repr(s.opening) for s in a.surfaces] == [repr(s.opening) for s in b.surfaces]


# --------------------------------------------------------------------------- threemir
def _beam_passes(lens, free):
    """Per field, how many rays of the beam that the stop passes reach ``lens``'s sensor with
    its apertures applied: the ``hexapolar:6`` pattern (127 rays) over 99 % of the entrance pupil
    that deeplens' traced pupil search finds in ``free``, the same system without the
    rectangles (its mirrors as large as the beam: the stop alone limits it)."""
    from deeplens.analysis.spot import find_pupil
    from deeplens.optics.sampling import field_rays, pupil_pattern

    w = float(lens.spec.primary_wavelength_nm)
    unit = pupil_pattern("hexapolar:6", dtype=torch.float64) * 0.99
    out = []
    for f in dict.fromkeys(lens.spec.fields_deg):   # +2, 0, -2 degrees (the file repeats them)
        reg = find_pupil(free, float(f), w)
        rays = field_rays(lens, float(f), w, reg.points(unit), reg.z)
        with torch.no_grad():
            out.append(int(lens.trace_to_sensor(rays).valid.sum()))
    return out, len(unit)


def test_threemir_mirror_rectangles_hold_the_beam_about_their_ady(tmp_path):
    """rayoptics' ``threemir.seq`` (three off-axis conic and aspheric mirrors, DAR decenters,
    ``REX``/``REY``/``ADY`` on each, a tilted image with a focus shift; its x fields set to 0):
    the beam of every field that the stop passes passes every rectangle too.  The designer
    centred each rectangle on its mirror's beam: with the primary's ``ADY`` negated (the
    rectangle about ``-99.6``) no ray passes, and with its ``REX``/``REY`` read as full widths
    (halved) part of the beams of the +-2 degree fields is cut (observed: 80 of 127 pass).
    (The beam the stop passes, deeplens' traced pupil, is about 44 x 95 mm and off the axis:
    the stop is decentred and tilted, and its size comes from the paraxial trace along the local
    axes.)"""
    text = (RAYOPTICS / "threemir_y.seq").read_text()
    free_path = tmp_path / "free.seq"
    free_path.write_text("\n".join(ln for ln in text.splitlines() if not ln.startswith("REX")))
    free = _read(free_path)
    lens = _read(RAYOPTICS / "threemir_y.seq")
    prim = lens.surfaces[1]
    assert clear_rect(prim) == pytest.approx((75.734236, 78.538674), abs=1e-12)
    assert prim.clear_decenter.tolist() == [0.0, 99.602384]
    got, n = _beam_passes(lens, free)
    assert got == [n] * 3
    flipped = _read(_seq(tmp_path, "", "flipped", head=text.replace("ADY 99.602384",
                                                                    "ADY -99.602384")))
    assert _beam_passes(flipped, free)[0] == [0] * 3
    full = _read(_seq(tmp_path, "", "full", head=text.replace(
        "REX 75.734236; REY 78.538674", "REX 37.867118; REY 39.269337")))
    cut = _beam_passes(full, free)[0]
    assert all(g > 0 for g in cut) and min(cut) < n   # the +-2 deg beams are 95 mm tall


def clear_rect(s):
    from deeplens.optics.surfaces.base import clear_rect_of

    return clear_rect_of(s)


def test_threemir_lands_where_rayoptics_traces_it():
    """The same file through the benchmark's oracle: its surfaces lie where rayoptics puts them
    (the image plane at SI's focus shift along the tilted image axis) and 4 rays per field land
    at the same points in the same directions (rayoptics' trace, apertures not applied)."""
    pytest.importorskip("rayoptics")
    from codev_oracle import ray_agrees, ray_landings

    path = RAYOPTICS / "threemir_y.seq"
    lens = _read(path)
    r = ray_landings(path, lens)
    assert r["rays"] == 20 and not r["failed"]
    assert ray_agrees(r["dp"], r["dd"], r["length"])


def test_threemir_itself_is_refused_at_its_x_fields():
    """deeplens' fields lie in the y-z plane: the file's ``XAN 2`` fields are refused at their
    line, after every other command has been read."""
    with pytest.raises(LensFileError, match="XAN: x field components") as e:
        _read(RAYOPTICS / "threemir.seq")
    assert e.value.line == 48


def test_dim_after_the_surfaces_pol_and_ca(tmp_path):
    """``DIM`` after the surfaces is the unit of every length (threemir writes it there):
    ``DIM C`` at the end scales the lens by 10 like ``DIM C`` at the start; a second, different
    ``DIM`` is refused; ``POL N`` is read, ``POL Y`` refused; a bare ``CA`` warns."""
    body = "S 0 5\n  STO\n  CIR 0.6\nS 5 0.4 517000.642000\n  CIR 0.8\nS -5 3\nSI 0 0\n"
    head = HEAD.replace("DIM M\n", "").replace("EPD 12", "EPD 1.2")
    a = _read(_seq(tmp_path, body + "DIM C\nPOL N\n", "a", head=head))
    b = _read(_seq(tmp_path, body, "b", head=head.replace("RDM Y\n", "RDM Y\nDIM C\n")))
    assert [float(x) for x in a.distances] == [float(x) for x in b.distances]
    assert float(a.surfaces[1].c) == float(b.surfaces[1].c) == pytest.approx(0.02)
    with pytest.raises(LensFileError, match="a second, different unit") as e:
        read_seq(_seq(tmp_path, body + "DIM M\n", "c", head=head.replace("RDM Y\n",
                                                                          "RDM Y\nDIM C\n")))
    assert e.value.line == 14
    with pytest.raises(LensFileError, match="expected POL N"):
        read_seq(_seq(tmp_path, body + "POL Y\n", "d", head=head))
    with pytest.warns(CodeVWarning, match="CA .no value.: read and not used"):
        read_seq(_seq(tmp_path, body + "CA\n", "e", head=head))


# --------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("mods,match", [
    ("  ELX 3; ELY 2; REX 3; REY 2\n", "REX/REY and ELX/ELY on one surface"),
    ("  REX OBS 3\n", "REX OBS: a rectangular or elliptical obscuration"),
    ("  REX 3; REY 2; ARO 10\n", "ARO 10.0: a rotated aperture"),
    ("  REX 3\n", "needs both REX and REY"),
    ("  ADX 1\n", "ADX: an aperture decenter with no rectangle"),
    ("  CIR 4; REX 3; REY 2\n", "CIR and REX/REY on one surface"),
    ("  REX 0; REY 2\n", "REX: expected a half-width > 0"),
])
def test_refusals_name_the_line(tmp_path, mods, match):
    p = _seq(tmp_path, "S 0 5\n  STO\n  CIR 6\nS 50 4 517000.642000\n" + mods +
             "S 0 30\n  CIR 8\nSI 0 0\n")
    with pytest.raises(LensFileError, match=match) as e:
        read_seq(p)
    assert e.value.source == str(p) and e.value.line == 11


def test_a_decentred_rectangular_stop_and_a_rectangle_on_si_are_refused(tmp_path):
    p = _seq(tmp_path, "S 0 5\n  STO\n  REX 3; REY 2; ADY 1\nS 50 4 517000.642000\n  CIR 8\n"
                       "S 0 30\n  CIR 8\nSI 0 0\n")
    with pytest.raises(LensFileError, match="decentred aperture stop") as e:
        read_seq(p)
    assert e.value.line == 9
    p = _seq(tmp_path, "S 0 5\n  STO\n  CIR 6\nS 50 4 517000.642000\n  CIR 8\nS 0 30\n"
                       "  CIR 8\nSI 0 0\n  REX 3; REY 2\n", "si")
    with pytest.raises(LensFileError, match="rectangular aperture on SI") as e:
        read_seq(p)
    assert e.value.line == 15
