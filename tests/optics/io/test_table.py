"""The paper authors' table format (.txt): the five published files (copies in tests/data/lenses)
convert to the shipped data/lenses/*.json, every row's numbers are read as written, and every
bad table gets an error naming the file, the line and what was expected."""

import importlib.util
import json
import math
import re
from pathlib import Path

import pytest
import torch

from deeplens.optics.paraxial import paraxial
from deeplens.optics.io import (LensFileError, lens_from_dict, lens_to_dict, load_lens,
                                read_table, table_to_dict)
from deeplens.optics.surfaces import Aperture, Asphere, BSpline, Plane, XYPolynomial

ROOT = Path(__file__).resolve().parents[3]


# the paper authors' tables, shipped with the tests (never read from outside the repository)
TABLE_DIR = ROOT / "tests" / "data" / "lenses"
TABLES = ["ACL5040U.txt", "LA1131.txt", "Nikon-z35-f1.8-JPA2019090949-example2.txt",
          "US02532751-1.txt", "end2end_edof.txt"]


def _convert_module():
    spec = importlib.util.spec_from_file_location("convert_lenses",
                                                  ROOT / "scripts" / "convert_lenses.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


CONVERSIONS = _convert_module().CONVERSIONS


# ------------------------------------------------------------------ the published tables
def test_every_table_and_every_shipped_lens_is_covered():
    assert sorted(src for src, _ in CONVERSIONS.values()) == sorted(TABLES)
    # data/lenses may hold lenses designed here as well; the converted ones must all be there
    shipped = {p.stem for p in (ROOT / "data" / "lenses").glob("*.json")}
    assert set(CONVERSIONS) <= shipped


@pytest.mark.parametrize("name", sorted(CONVERSIONS))
def test_converted_table_equals_shipped_json(name):
    src, opts = CONVERSIONS[name]
    lens = lens_from_dict(table_to_dict(TABLE_DIR / src, **opts), source=src)
    shipped = json.loads((ROOT / "data" / "lenses" / f"{name}.json").read_text())
    assert lens_to_dict(lens) == shipped
    # read_table (what load_lens uses for .txt) builds the same lens
    assert lens_to_dict(read_table(TABLE_DIR / src, **opts)) == shipped


@pytest.mark.parametrize("src", TABLES)
def test_load_lens_reads_tables(src):
    opts = {"stop_index": 0} if src in ("ACL5040U.txt", "LA1131.txt", "end2end_edof.txt") else {}
    lens = load_lens(TABLE_DIR / src, **opts)
    assert len(lens.surfaces) > 0 and lens.d_sensor.item() > 0


def _rows(path):
    """The surface rows of a table, split here (independently of the reader): ``[(type,
    [numbers...], material), ...]`` for every row after the header except O and I, and the I
    row's ``(distance, diameter)``."""
    rows, image = [], None
    for line in path.read_text().splitlines()[2:]:
        tok = line.split()
        if not tok or tok[0].startswith("#") or tok[0] == "O":
            continue
        if tok[0] == "I":
            image = (float(tok[1]), float(tok[3]))
            continue
        rows.append((tok[0], [float(t) for t in tok[1:4]], tok[4],
                     [float(t) for t in tok[5:]]))
    return rows, image


@pytest.mark.parametrize("src", TABLES)
def test_every_row_is_read_as_written(src):
    """Every row of every shipped table: distance, curvature 1/roc, conic and aspheric terms
    (signs included), XY-polynomial coefficients and the clear semi-diameter (diameter / 2),
    compared with the numbers split from the file here."""
    opts = {"stop_index": 0} if src in ("ACL5040U.txt", "LA1131.txt", "end2end_edof.txt") else {}
    lens = read_table(TABLE_DIR / src, **opts)
    rows, (d_img, diam_img) = _rows(TABLE_DIR / src)
    assert len(lens.surfaces) == len(rows)
    for k, ((kind, (dist, roc, diam), material, extra), surf) in enumerate(
            zip(rows, lens.surfaces)):
        where = f"{src} surface {k}"
        if k > 0:  # the first row's distance is the origin (z = 0)
            assert float(lens.distances[k]) == dist, where
        assert float(surf.semi_diameter) == diam / 2, where
        medium = lens.materials[k + 1]
        if "/" in material:  # a model glass n_d/V_d: its index at the d line is n_d
            nd = float(medium.n(torch.tensor(587.5618, dtype=torch.float64)))
            assert nd == pytest.approx(float(material.split("/")[0]), abs=1e-12), where
        else:
            assert medium.name.upper() == (
                "AIR" if material.upper() == "OCCLUDER" else material.upper()), where
        if kind == "A":
            assert isinstance(surf, Aperture) and lens.stop_index == k, where
        elif kind == "X":
            assert isinstance(surf, XYPolynomial), where
            assert float(surf.b) == extra[0], where
            assert [float(a) for a in surf.a] == extra[1:], where
        elif roc == 0 and not any(extra):
            assert isinstance(surf, Plane), where
        else:
            assert isinstance(surf, Asphere), where
            assert float(surf.c) == pytest.approx(1.0 / roc if roc else 0.0, rel=1e-15), where
            assert float(surf.k) == (extra[0] if extra else 0.0), where
            coeffs = [float(a) for a in surf.a] if surf.a is not None else []
            # even terms a4, a6, ... as written (trailing zeros may be dropped)
            assert coeffs + [0.0] * (len(extra[1:]) - len(coeffs)) == extra[1:], where
    assert float(lens.d_sensor) == d_img
    assert lens.sensor_semi_diameter == (diam_img / 2 if diam_img > 0 else None)


def test_table_contents_are_read_as_documented():
    dg = read_table(TABLE_DIR / "US02532751-1.txt")
    assert dg.stop_index == 5 and isinstance(dg.surfaces[5], Aperture)
    s0 = dg.surfaces[0]
    assert float(s0.c) == 1 / 13.354729316461547 and float(s0.k) == 0.005
    assert [float(a) for a in s0.a] == [1e-6, 1e-8, -3e-10]
    assert float(s0.semi_diameter) == 8.7
    assert isinstance(dg.surfaces[3], Plane)  # roc 0, no extras
    assert [m.name for m in dg.materials[:3]] == ["VACUUM", "SSK4", "VACUUM"]
    assert dg.materials[6].name == "AIR"  # the OCCLUDER stop plane is air
    assert float(dg.d_sensor) == 17.42769142705 and dg.sensor_semi_diameter == 10.332
    assert float(paraxial(dg).efl) == pytest.approx(27.44, rel=1e-4)

    acl = read_table(TABLE_DIR / "ACL5040U.txt", stop_index=0)
    assert float(acl.surfaces[0].k) == -0.6405 and float(acl.surfaces[0].a[0]) == 2e-6
    assert acl.materials[1].name == "B270"
    assert float(paraxial(acl).efl) == pytest.approx(40.0, rel=0.02)

    la = read_table(TABLE_DIR / "LA1131.txt", stop_index=0)
    assert float(paraxial(la).efl) == pytest.approx(50.0, rel=0.01)

    edof = read_table(TABLE_DIR / "end2end_edof.txt", stop_index=0)
    x = edof.surfaces[4]
    assert isinstance(x, XYPolynomial) and len(x.a) == 10 and x.order == 3
    assert [m.name for m in edof.materials[1:3]] == ["N-BK7", "SF5"]  # names are case-insensitive
    assert float(edof.d_sensor) == 96.0

    nikon = read_table(TABLE_DIR / "Nikon-z35-f1.8-JPA2019090949-example2.txt")
    nikon10 = read_table(TABLE_DIR / "Nikon-z35-f1.8-JPA2019090949-example2.txt", scale=10.0)
    assert float(paraxial(nikon).efl) == pytest.approx(1.574, rel=0.01)
    assert float(paraxial(nikon10).efl) == pytest.approx(10 * float(paraxial(nikon).efl),
                                                        rel=1e-12)
    s16, t16 = nikon.surfaces[16], nikon10.surfaces[16]
    assert float(t16.semi_diameter) == pytest.approx(10 * float(s16.semi_diameter), rel=1e-15)
    # a4 r^4 keeps its sag under r -> 10 r, z -> 10 z: a4 -> a4 / 1000
    assert float(t16.a[0]) == pytest.approx(float(s16.a[0]) / 1000, rel=1e-15)
    assert nikon.materials[1].name == "1.5168/64.12"


# ------------------------------------------------------------------ a small valid table
GOOD = """\
small test lens
type distance roc diameter material
O 0 0 0 AIR
S 0 50 20 N-BK7
S 5 -50 20 AIR
A 2 0 10 OCCLUDER
S 2 30 16 N-SF5 -0.5 1e-6
S 3 0 16 AIR
X 1 0 16 AIR 0.001 0 0 0 1e-4 0 2e-4
B 1 0 16 AIR 4 4 0 0 0 0 0 0.01 0.01 0 0 0.01 0.01 0 0 0 0 0
I 40 0 12 AIR
"""
LINE = {"S1": 4, "S2": 5, "A": 6, "S3": 7, "S4": 8, "X": 9, "B": 10, "I": 11}


def write(tmp_path, text, name="lens.txt"):
    p = tmp_path / name
    p.write_text(text)
    return p


def replace_line(text, line_no, new):
    lines = text.splitlines()
    lines[line_no - 1] = new
    return "\n".join(lines) + "\n"


def test_small_table_reads(tmp_path):
    lens = read_table(write(tmp_path, GOOD), wavelengths_nm=[486.1327, 587.5618, 656.2725])
    assert [type(s) for s in lens.surfaces] == [Asphere, Asphere, Aperture, Asphere, Plane,
                                                XYPolynomial, BSpline]
    assert lens.stop_index == 2
    assert float(lens.surfaces[5].b) == 0.001
    assert lens.surfaces[6].coefficients.shape == (4, 4)
    assert float(lens.surfaces[6].coefficients[1, 1]) == 0.01
    assert lens.sensor_semi_diameter == 6.0
    assert lens.name == "small test lens"


def test_utf16_table(tmp_path):
    p = tmp_path / "u16.txt"
    p.write_bytes(GOOD.encode("utf-16"))
    assert lens_to_dict(read_table(p)) == lens_to_dict(read_table(write(tmp_path, GOOD)))


def check_error(path, line, pattern, **options):
    with pytest.raises(LensFileError) as e:
        read_table(path, **options)
    msg = str(e.value)
    prefix = f"{path}:{line}: " if line is not None else f"{path}: "
    assert msg.startswith(prefix), f"expected {prefix!r} at the start of {msg!r}"
    assert re.search(pattern, msg), f"{pattern!r} not in {msg!r}"
    return msg


BAD_ROWS = [
    ("missing column", "S2", "S 5 -50 20",
     r"expected 5 columns \(type distance roc diameter material\), got 4; missing \['material'\]"),
    ("two missing columns", "S2", "S 5 -50",
     r"got 3; missing \['diameter', 'material'\]"),
    ("non-numeric roc", "S2", "S 5 -5O 20 AIR", r"column 'roc' must be a number, got '-5O'"),
    ("non-numeric distance", "A", "A two 0 10 OCCLUDER",
     r"column 'distance' must be a number, got 'two'"),
    ("non-numeric diameter", "S1", "S 0 50 20mm N-BK7",
     r"column 'diameter' must be a number, got '20mm'"),
    ("non-numeric extra", "S3", "S 2 30 16 N-SF5 -0.5 1e-6x",
     r"column 'extra 2' must be a number, got '1e-6x'"),
    ("nan", "S3", "S 2 nan 16 N-SF5", r"column 'roc' must be finite, got 'nan'"),
    ("unknown type", "S2", "Z 5 -50 20 AIR",
     r"unknown surface type 'Z'; expected one of O, S, A, X, B, I"),
    ("unknown glass", "S1", "S 0 50 20 N-BK77",
     r"unknown glass 'N-BK77'; closest known: N-BK7"),
    ("unknown glass 2", "S3", "S 2 30 16 NSF5",
     r"unknown glass 'NSF5'; closest known: .*N-SF5"),
    ("bad model glass", "S3", "S 2 30 16 1.7/abc", r"malformed material '1\.7/abc'"),
    ("zero diameter", "S2", "S 5 -50 0 AIR", r"diameter must be > 0 mm, got '0'"),
    ("X row count", "X", "X 1 0 16 AIR 0.001 0 0 0 1e-4",
     r"an X row needs b and \(J\+1\)\(J\+2\)/2 coefficients \(1, 3, 6, 10, \.\.\.\), got 4"),
    ("X row empty", "X", "X 1 0 16 AIR", r"an X row needs 'b a0 \[a1 \.\.\.\]'"),
    ("B row count", "B", "B 1 0 16 AIR 4 4 0 0 0",
     r"a B row with nx=4, ny=4 needs 16 coefficients, got 3"),
    ("B row knots", "B", "B 1 0 16 AIR 4.5 4 0 0",
     r"a B row needs 'nx ny c_00 \.\.\. ' .*knot vectors are not supported"),
    ("B row too small", "B", "B 1 0 16 AIR 3 3 0 0 0 0 0 0 0 0 0",
     r"BSpline: coefficients must be a 2-D grid of at least 4x4"),
    ("second stop", "S4", "A 3 0 16 AIR", r"a second aperture stop \(A row\)"),
    ("negative sensor diameter", "I", "I 40 0 -12 AIR", r"diameter must be >= 0 mm"),
    # geometry (checked on the built lens, reported at the surface's line)
    ("surfaces cross", "S2", "S 0.5 -50 20 AIR",
     r"surfaces 0 and 1 cross: at r = .* mm surface 1 lies .* mm before surface 0 .*\(surface 0 "
     r"is line 4, surface 1 is line 5\)"),
    ("negative thickness", "S2", "S -1 -50 20 AIR",
     r"distance before surface 1 is negative \(-1 mm\)"),
    ("beyond the conic's domain", "S3", "S 2 30 16 N-SF5 100",
     r"surface 3 \(Asphere\): semi-diameter 8 mm lies beyond the domain of the conic \(R = 30 "
     r"mm, k = 100\): the sag is only defined for r < 2\.98"),
    ("beyond the sphere", "S1", "S 0 5 20 N-BK7",
     r"surface 0 \(Asphere\): semi-diameter 10 mm lies beyond the domain of the conic \(R = 5 "
     r"mm, k = 0\): the sag is only defined for r < 5 mm"),
    ("sensor distance", "I", "I -3 0 12 AIR",
     r"sensor\.distance_mm: the sensor distance must be > 0 mm, got -3\.0"),
]


@pytest.mark.parametrize("row,new,pattern", [b[1:] for b in BAD_ROWS], ids=[b[0] for b in BAD_ROWS])
def test_bad_row_names_file_and_line(row, new, pattern, tmp_path):
    p = write(tmp_path, replace_line(GOOD, LINE[row], new), "bad_table.txt")
    check_error(p, LINE[row], pattern)


def test_good_table_is_valid(tmp_path):
    # every BAD_ROWS case differs from this valid table by its one row
    read_table(write(tmp_path, GOOD))


def test_no_stop(tmp_path):
    text = "\n".join(l for l in GOOD.splitlines() if not l.startswith("A ")) + "\n"
    p = write(tmp_path, text, "nostop.txt")
    check_error(p, None, r"no aperture stop \(no 'A' row\); pass stop_index")
    assert read_table(p, stop_index=0).stop_index == 0
    check_error(p, None, r"stop_index: 9 is not a surface index \(0\.\.5", stop_index=9)


def test_stop_index_conflicting_with_a_row(tmp_path):
    check_error(write(tmp_path, GOOD), LINE["A"], r"the file's A row is surface 2, but "
                                                  r"stop_index=0 was passed", stop_index=0)


@pytest.mark.parametrize("waves,pattern", [
    ([0.5876], r"wavelengths_nm: deeplens takes wavelengths in nanometres; got 0\.5876 .* did you "
               r"pass micrometres\? use 587\.6"),
    ([0.4861, 0.5876], r"wavelengths_nm: deeplens takes wavelengths in nanometres; got values in "
                       r"\[0\.4861, 0\.5876\]"),
    ([-500.0], r"wavelengths_nm: wavelengths must be finite and > 0 nm; got -500"),
])
def test_wavelength_in_wrong_unit(waves, pattern, tmp_path):
    check_error(write(tmp_path, GOOD), None, pattern, wavelengths_nm=waves)


def test_wavelength_outside_glass_data(tmp_path):
    # N-BK7 (line 4) has data for 300-2500 nm; N-SF5 (line 7) from 370 nm
    p = write(tmp_path, GOOD)
    check_error(p, LINE["S1"], r"wavelengths_nm: wavelength 2600 nm is outside the valid range "
                               r"300.2500 nm of material 'N-BK7'", wavelengths_nm=[587.6, 2600.0])
    check_error(p, LINE["S3"], r"wavelength 350 nm is outside the valid range 370.2500 nm of "
                               r"material 'N-SF5'", wavelengths_nm=[350.0, 587.6])


@pytest.mark.parametrize("text,line,pattern", [
    ("title only\n", None, r"expected a title line, a header line and surface rows, got 1 line"),
    ("t\ntype distance roc diameter material\n", None,
     r"expected a title line, a header line and surface rows, got 2 line"),
    ("t\nS 0 50 20 N-BK7\nS 5 -50 20 AIR\nI 40 0 12 AIR\n", 2,
     r"expected the header 'type distance roc diameter material' on line 2, got 'S 0 50 20"),
    ("t\ntype distance roc diameter material\nO 0 0 0 AIR\nI 40 0 12 AIR\n", None,
     r"no surface rows"),
    ("t\ntype distance roc diameter material\nS 0 50 20 N-BK7\nS 5 -50 20 AIR\n", None,
     r"no image \(I\) row: the sensor distance is unknown"),
    ("t\ntype distance roc diameter material\nS 0 50 20 N-BK7\nI 40 0 12 AIR\n"
     "S 5 -50 20 AIR\n", 5, r"a surface row after the image \(I\) row"),
    ("t\ntype distance roc diameter material\nA 0 0 5 AIR\nI 40 0 12 AIR\nI 1 0 12 AIR\n", 5,
     r"a second image \(I\) row"),
])
def test_bad_table_structure(text, line, pattern, tmp_path):
    check_error(write(tmp_path, text, "structure.txt"), line, pattern)


def test_comments_and_blank_lines_are_skipped(tmp_path):
    lines = GOOD.splitlines()
    text = "\n".join(lines[:3] + ["", "# a comment"] + lines[3:]) + "\n"
    assert lens_to_dict(read_table(write(tmp_path, text))) == lens_to_dict(
        read_table(write(tmp_path, GOOD, "good.txt")))
    # line numbers still refer to the file as written
    bad = replace_line(text, 6, "S 0 50 20 N-BK77")
    check_error(write(tmp_path, bad, "commented.txt"), 6, r"unknown glass 'N-BK77'")


def test_bad_scale(tmp_path):
    check_error(write(tmp_path, GOOD), None, r"scale must be a positive number, got -1",
                scale=-1.0)
    with pytest.raises(FileNotFoundError, match="missing.txt"):
        read_table(tmp_path / "missing.txt")


def test_sensor_diameter_zero_means_unbounded(tmp_path):
    lens = read_table(write(tmp_path, replace_line(GOOD, LINE["I"], "I 40 0 0 AIR")))
    assert lens.sensor_semi_diameter is None
    assert math.isfinite(float(lens.d_sensor))


def test_scale_is_a_similarity(tmp_path):
    """``scale=s`` magnifies the whole lens: every surface's sag at ``s (x, y)`` is ``s`` times
    the unscaled sag at ``(x, y)`` (conic, aspheric terms, XY polynomial with b, B-spline)."""
    import torch

    text = replace_line(GOOD, LINE["X"], "X 1 0 16 AIR 0.004 0 1e-3 -2e-3 0.01 3e-3 0.02")
    # 1.5 mm after it: at 1 mm this XY polynomial crosses the B-spline along -x (r = 7.1 mm),
    # which Lens.check finds since it samples more azimuths than y (issue 38)
    text = replace_line(text, LINE["B"], GOOD.splitlines()[LINE["B"] - 1].replace("B 1 ", "B 1.5 "))
    p = write(tmp_path, text)
    a, b = read_table(p), read_table(p, scale=10.0)
    assert float(b.d_sensor) == pytest.approx(10 * float(a.d_sensor), rel=1e-15)
    x = torch.tensor([0.0, 0.7, -1.9, 2.5], dtype=torch.float64)
    y = torch.tensor([0.0, 1.3, 0.4, -2.2], dtype=torch.float64)
    for i, (sa, sb) in enumerate(zip(a.surfaces, b.surfaces)):
        assert float(sb.semi_diameter) == pytest.approx(10 * float(sa.semi_diameter), rel=1e-15)
        za, zb = sa.sag(x, y), sb.sag(10 * x, 10 * y)
        assert torch.allclose(zb, 10 * za, rtol=1e-12, atol=1e-15), (i, zb, 10 * za)
    assert float(a.surfaces[5].b) != 0.0
