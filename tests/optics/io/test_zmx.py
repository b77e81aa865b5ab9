"""Zemax .zmx files: the shipped double Gauss against its own table, round trips, bad input.

``tests/data/lenses/US02532751-1.zmx`` is a byte-identical copy of the public prescription
(UTF-16 with byte-order mark, as OpticStudio writes it).  The same lens in the paper authors'
table (``data/lenses/double_gauss.json``) differs from it in one number: the radius of the
surface after the stop is -7.026950 mm in the table and 1/-0.1423082396 = -7.026999 mm in the
Zemax file (and the wavelength is 587.5618 vs 587.562 nm); with those two made equal, the two
readings trace identically.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import warnings
from pathlib import Path

import helpers as H
import pytest
import torch

from deeplens.analysis.paraxial import paraxial
from deeplens.cli import main as cli_main
from deeplens.optics.io import (
    LensFileError,
    ZemaxFileError,
    ZemaxWarning,
    lens_to_dict,
    load_lens,
    read_zmx,
    save_lens,
    write_zmx,
)
from deeplens.optics.materials import GLASS_TABLE
from deeplens.optics.rays import Rays

REPO = Path(__file__).resolve().parents[3]
ZMX = REPO / "tests" / "data" / "lenses" / "US02532751-1.zmx"
JSON = REPO / "data" / "lenses" / "double_gauss.json"


def report(path, *extra):
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli_main(["report", str(path), "--json", *extra]) == 0
    return json.loads(buf.getvalue())


def air_normalised(d: dict) -> dict:
    """``lens_to_dict`` with VACUUM written as AIR (index 1 both; Zemax has one air)."""
    d = copy.deepcopy(d)
    d["object"]["medium"] = d["object"]["medium"].replace("VACUUM", "AIR")
    for s in d["surfaces"]:
        s["material"] = s["material"].replace("VACUUM", "AIR")
    return d


def trace_points(lens, field_deg=10.0, n=9):
    """Image points of a small fan of rays at 587.5618 nm (float64)."""
    lens = lens.double()
    t = math.radians(field_deg)
    y = torch.linspace(-2.0, 2.0, n, dtype=torch.float64)
    o = torch.stack([0.3 * torch.ones_like(y), y, torch.full_like(y, -5.0)], -1)
    d = torch.tensor([0.0, math.sin(t), math.cos(t)], dtype=torch.float64).expand(n, 3)
    rays = Rays(o, d, torch.full((n,), 587.5618, dtype=torch.float64))
    out = lens.trace_to_sensor(rays)
    return out.o[..., :2], out.valid


# --------------------------------------------------------------------------- the shipped lens
def test_shipped_zmx_is_the_table_lens():
    z, j = load_lens(ZMX), load_lens(JSON)
    dz, dj = air_normalised(lens_to_dict(z)), air_normalised(lens_to_dict(j))
    assert dz["stop"] == dj["stop"] == 5 and dz["elements"] == dj["elements"]
    assert dz["aperture"] == {"type": "stop"} and dz["fields_deg"] == [0.0, 7.0, 14.0, 21.0]
    assert dz["wavelengths_nm"] == [587.562] and dz["primary_wavelength_nm"] == 587.562
    assert dz["sensor"] == pytest.approx(dj["sensor"])
    assert dz["object"] == dj["object"] == {"distance_mm": "inf", "medium": "AIR"}
    for i, (a, b) in enumerate(zip(dz["surfaces"], dj["surfaces"])):
        assert a["type"] == b["type"] and a["material"] == b["material"], i
        for key in ("semi_diameter_mm", "distance_mm", "conic", "aspheric"):
            assert a.get(key, 0.0) == pytest.approx(b.get(key, 0.0), rel=1e-12, abs=1e-13), (i, key)
        tol = 1e-5 if i == 6 else 1e-12   # the one number in which the two files differ
        assert a.get("curvature_per_mm", 0.0) == pytest.approx(b.get("curvature_per_mm", 0.0),
                                                               rel=tol)


def test_shipped_zmx_report_matches_table():
    """`deeplens report` takes the .zmx directly: same EFL and spots as the table's lens."""
    opts = ("--pupil", "paraxial", "--sampling", "hexapolar:10")
    rz, rj = report(ZMX, *opts), report(JSON, *opts)
    assert rz["efl_mm"] == pytest.approx(27.4425, abs=1e-4)
    assert rz["efl_mm"] == pytest.approx(rj["efl_mm"], rel=1e-5)
    for a, b in zip(rz["fields"], rj["fields"]):
        assert a["field_deg"] == b["field_deg"] and a["n_rays"] == b["n_rays"]
        assert a["rms_spot_um"] == pytest.approx(b["rms_spot_um"], rel=5e-3)
        assert a["centroid_mm"] == pytest.approx(b["centroid_mm"], abs=1e-3)


def test_shipped_zmx_traces_like_table_when_the_difference_is_removed():
    z, j = load_lens(ZMX), load_lens(JSON)
    with torch.no_grad():
        z.surfaces[6].c.copy_(j.surfaces[6].c)
    pz, vz = trace_points(z, 14.0)
    pj, vj = trace_points(j, 14.0)
    assert torch.equal(vz, vj) and bool(vz.any())
    torch.testing.assert_close(pz[vz], pj[vj], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- round trips
def test_shipped_zmx_round_trip(tmp_path):
    a = read_zmx(ZMX)
    for enc in ("utf-8", "utf-16"):
        p = tmp_path / f"rt_{enc}.zmx"
        write_zmx(a, p, encoding=enc)
        assert lens_to_dict(read_zmx(p)) == lens_to_dict(a)
    save_lens(a, tmp_path / "via_save.zmx")           # save_lens dispatches on .zmx
    assert lens_to_dict(load_lens(tmp_path / "via_save.zmx")) == lens_to_dict(a)


@pytest.mark.parametrize("name", ["wide_doublet", "edof_achromat", "double_gauss",
                                  "thorlabs_acl5040u"])
def test_project_lenses_round_trip(tmp_path, name):
    """Lenses written by the project's own writer (asphere, XY polynomial, catalogue and model
    glasses, F-number/EPD apertures) come back with the same prescription."""
    lens = load_lens(REPO / "data" / "lenses" / f"{name}.json")
    p = tmp_path / f"{name}.zmx"
    write_zmx(lens, p)
    back = read_zmx(p)
    assert air_normalised(lens_to_dict(back)) == air_normalised(lens_to_dict(lens))
    # and a second cycle is a fixed point, byte for byte
    write_zmx(back, tmp_path / "again.zmx")
    assert (tmp_path / "again.zmx").read_text() == p.read_text()


def test_misalignment_round_trip_through_coordinate_breaks(tmp_path):
    lens = load_lens(JSON)
    with torch.no_grad():
        lens.misalignments[1].dy.fill_(0.05)
        lens.misalignments[1].tilt_x.fill_(0.01)
        lens.misalignments[3].dx.fill_(-0.02)
        lens.misalignments[4].tilt_y.fill_(-0.004)
    p = tmp_path / "tilted.zmx"
    write_zmx(lens, p)
    text = p.read_text()
    assert text.count("TYPE COORDBRK") == 6
    back = read_zmx(p)
    da, db = lens_to_dict(lens), lens_to_dict(back)
    assert db["misalignment"] == da["misalignment"]
    for a, b in zip(da["surfaces"], db["surfaces"]):
        assert a["distance_mm"] == pytest.approx(b["distance_mm"], abs=1e-14)
    pa, va = trace_points(lens, 7.0)
    pb, vb = trace_points(back, 7.0)
    assert torch.equal(va, vb) and bool(va.any())
    torch.testing.assert_close(pa[va], pb[vb], rtol=0, atol=1e-12)
    # and the misalignment is not a no-op: the aligned lens lands elsewhere
    pc, vc = trace_points(load_lens(JSON), 7.0)
    assert (pc[vc & va] - pa[vc & va]).abs().max() > 1e-3


def test_model_glass_round_trip(tmp_path):
    lens = load_lens(JSON)
    from deeplens.optics.materials import ModelGlass
    lens.materials[1] = ModelGlass(1.7, 41.5)
    p = tmp_path / "model.zmx"
    write_zmx(lens, p)
    assert "GLAS ___BLANK 1 0 1.7 41.5" in p.read_text()
    back = read_zmx(p)
    assert isinstance(back.materials[1], ModelGlass)
    assert (back.materials[1].n_d, back.materials[1].v_d) == (1.7, 41.5)


# --------------------------------------------------------------------------- small files
def singlet(*, unit="MM", glass="GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0", ftyp="FTYP 0 0 2 2 0 0 0",
            yfln="YFLN 0 5", aperture="ENPD 10", obj="INFINITY", s1_type="EVENASPH",
            s1_extra=("PARM 1 0", "PARM 2 1e-05", "PARM 3 -2e-07"), curv1=0.02, curv2=-0.005,
            t=5.0, bfl=45.0, gcat="GCAT SCHOTT", extra_system=(), extra_s2=(), wav=(0.55, 0.65),
            pwav=2, k=-0.5, diam1=8.0):
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME test singlet", f"UNIT {unit} X W X CM MR CPMM",
             aperture, gcat, ftyp, "XFLN 0 0", yfln,
             *[f"WAVM {i + 1} {w} 1" for i, w in enumerate(wav)], f"PWAV {pwav}",
             *extra_system,
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0 0 0 0 0 \"\"", f"  DISZ {obj}",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 2", "  DIAM 5 1 0 0 1 \"\"",
             "SURF 2", f"  TYPE {s1_type}", f"  CURV {curv1}", f"  CONI {k}",
             *[f"  {x}" for x in s1_extra], f"  DISZ {t}", f"  {glass}", f"  DIAM {diam1} 1 0 0 1 \"\"",
             "SURF 3", "  TYPE STANDARD", f"  CURV {curv2}", f"  DISZ {bfl}", "  DIAM 8 1 0 0 1 \"\"",
             *[f"  {x}" for x in extra_s2],
             "SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 6 1 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


def write(tmp_path, text, name="t.zmx", encoding="utf-8"):
    p = tmp_path / name
    p.write_text(text, encoding=encoding)
    return p


def test_singlet_values(tmp_path):
    lens = read_zmx(write(tmp_path, singlet()))
    d = lens_to_dict(lens)
    assert d["wavelengths_nm"] == [550.0, 650.0] and d["primary_wavelength_nm"] == 650.0
    assert d["aperture"] == {"type": "epd", "value": 10.0}
    s = d["surfaces"][1]
    assert s["curvature_per_mm"] == 0.02 and s["conic"] == -0.5
    assert s["aspheric"] == [1e-05, -2e-07] and s["material"] == "N-BK7"
    assert d["surfaces"][1]["distance_mm"] == 2.0 and d["surfaces"][2]["distance_mm"] == 5.0
    assert d["sensor"] == {"distance_mm": 45.0, "semi_diameter_mm": 6.0}
    assert d["fields_deg"] == [0.0, 5.0]
    # the EPD aperture sized the stop: the paraxial entrance pupil is 10 mm
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(10.0, rel=1e-12)


def test_units_scale_every_length(tmp_path):
    """The same lens in centimetres: curvature, thickness, conic-free asphere terms, EPD."""
    mm = read_zmx(write(tmp_path, singlet(), "mm.zmx"))
    cm = read_zmx(write(tmp_path, singlet(unit="CM", curv1=0.2, curv2=-0.05, t=0.5, bfl=4.5,
                                          aperture="ENPD 1", diam1=0.8,
                                          s1_extra=("PARM 1 0", "PARM 2 1e-02", "PARM 3 -2e-02"))
                        .replace("DISZ 2", "DISZ 0.2").replace("DIAM 5 1", "DIAM 0.5 1")
                        .replace("DIAM 8 1", "DIAM 0.8 1").replace("DIAM 6 1", "DIAM 0.6 1"),
                        "cm.zmx"))
    a, b = lens_to_dict(mm), lens_to_dict(cm)
    for x, y in zip(a["surfaces"], b["surfaces"]):
        for key in ("distance_mm", "semi_diameter_mm", "curvature_per_mm"):
            assert y.get(key, 0.0) == pytest.approx(x.get(key, 0.0), rel=1e-12), key
        assert y.get("aspheric", []) == pytest.approx(x.get("aspheric", []), rel=1e-12)
    assert float(paraxial(cm).efl) == pytest.approx(float(paraxial(mm).efl), rel=1e-12)


def insert_after_stop(text: str, block: str) -> str:
    """Insert a SURF block after SURF 1 (the stop), renumbering the rest."""
    for k in (4, 3, 2):
        text = text.replace(f"SURF {k}\n", f"SURF {k + 1}\n")
    return text.replace("SURF 3\n", f"SURF 2\n{block}SURF 3\n", 1)


def test_dummy_surfaces_are_merged(tmp_path):
    ref = lens_to_dict(read_zmx(write(tmp_path, singlet(), "a.zmx")))
    text = singlet().replace("  DISZ 2\n", "  DISZ 0.5\n")
    dummy = "  TYPE STANDARD\n  CURV 0.0\n  DISZ 1.5\n  DIAM 3 0 0 0 1 \"\"\n"
    got = lens_to_dict(read_zmx(write(tmp_path, insert_after_stop(text, dummy), "b.zmx")))
    assert got == ref
    # a flat air surface with a fixed (user) semi-diameter clips rays: kept as an aperture
    fixed = dummy.replace("DIAM 3 0", "DIAM 3 1")
    got = lens_to_dict(read_zmx(write(tmp_path, insert_after_stop(text, fixed), "c.zmx")))
    assert [s["type"] for s in got["surfaces"]] == ["aperture", "aperture", "asphere", "asphere"]
    assert got["surfaces"][1]["semi_diameter_mm"] == 3.0
    assert [s["distance_mm"] for s in got["surfaces"]] == [0.0, 0.5, 1.5, 5.0]


def test_field_types(tmp_path):
    ang = read_zmx(write(tmp_path, singlet(), "a.zmx"))
    efl = float(paraxial(ang).efl)
    h = efl * math.tan(math.radians(5.0))
    img = read_zmx(write(tmp_path, singlet(ftyp="FTYP 2 0 2 2 0 0 0", yfln=f"YFLN 0 {h!r}"),
                         "i.zmx"))
    assert img.spec.fields_deg == pytest.approx([0.0, 5.0], abs=1e-12)
    # object heights: the stop on the rear lens surface, so the entrance pupil is not at 0
    text = singlet(ftyp="FTYP 1 0 2 2 0 0 0", yfln="YFLN 0 20", obj="500", aperture="FLOA")
    text = text.replace("  STOP\n", "").replace("SURF 3\n", "SURF 3\n  STOP\n")
    obj = read_zmx(write(tmp_path, text, "o.zmx"))
    ep = float(paraxial(obj).entrance_pupil_position)
    assert obj.spec.object_distance_mm == 500.0 and ep > 2.0
    assert obj.spec.fields_deg[1] == pytest.approx(math.degrees(math.atan(20 / (500 + ep))),
                                                   rel=1e-12)
    with pytest.warns(ZemaxWarning, match=r"xy.zmx:8: XFLN: x field components are combined"):
        xy = read_zmx(write(tmp_path, singlet(yfln="YFLN 0 4").replace("XFLN 0 0", "XFLN 0 3"),
                            "xy.zmx"))
    t = math.degrees(math.atan(math.hypot(math.tan(math.radians(3)), math.tan(math.radians(4)))))
    assert xy.spec.fields_deg == pytest.approx([0.0, t], rel=1e-12)


@pytest.mark.parametrize("ftyp,obj,match", [
    ("FTYP 3 0 2 2 0 0 0", "INFINITY", r":7: FTYP 3 \(real image height\) cannot be converted"),
    ("FTYP 4 0 2 2 0 0 0", "INFINITY", r":7: FTYP 4 \(theodolite angle\)"),
    ("FTYP 1 0 2 2 0 0 0", "INFINITY", (r":7: FTYP 1 \(object height\) with the object at "
                                       r"infinity cannot be converted")),
    ("FTYP 2 0 2 2 0 0 0", "300", r":7: FTYP 2 \(paraxial image height\) with a finite object"),
])
def test_unconvertible_field_types(tmp_path, ftyp, obj, match):
    with pytest.raises(ZemaxFileError, match=match):
        read_zmx(write(tmp_path, singlet(ftyp=ftyp, obj=obj)))


# --------------------------------------------------------------------------- glasses
def test_glass_not_found_names_glass_and_line(tmp_path):
    p = write(tmp_path, singlet(glass="GLAS N-BK7X 0 0 1.52 64 0 0 0 0 0 0"))
    ln = line_of(p.read_text(), "N-BK7X")
    with pytest.raises(ZemaxFileError, match=f"t.zmx:{ln}: glass 'N-BK7X' not found in the "
                                             r"catalogues searched \(SCHOTT \(deeplens built-in\)\)"):
        read_zmx(p)
    # never fuzzy: load_lens says the same
    with pytest.raises(LensFileError, match="N-BK7X"):
        load_lens(p)


def test_glass_only_in_the_catalogues_named(tmp_path):
    """PMMA is in deeplens' MISC catalogue, which this file does not name."""
    p = write(tmp_path, singlet(glass="GLAS PMMA 0 0 1.49 57.4 0 0 0 0 0 0"))
    with pytest.raises(ZemaxFileError, match=r"glass 'PMMA' not found"):
        read_zmx(p)
    ok = read_zmx(write(tmp_path, singlet(glass="GLAS PMMA 0 0 1.49 57.4 0 0 0 0 0 0",
                                          gcat="GCAT SCHOTT MISC"), "misc.zmx"))
    assert ok.materials[2].name == "PMMA"


def test_glass_fallback_only_on_request(tmp_path):
    p = write(tmp_path, singlet(glass="GLAS S-LAH66 0 0 1.7725 49.6 0 0 0 0 0 0",
                                gcat="GCAT OHARA"))
    with pytest.raises(ZemaxFileError, match=r"'S-LAH66' not found.*OHARA named on the GCAT "
                                             r"line were not given"):
        read_zmx(p)
    ln = line_of(p.read_text(), "S-LAH66")
    with pytest.warns(ZemaxWarning, match=f":{ln}: glass 'S-LAH66' not found.*fallback"):
        lens = read_zmx(p, glass_fallback="model")
    assert lens.materials[2].nd == pytest.approx(1.7725, abs=1e-12)
    assert lens.materials[2].vd == pytest.approx(49.6, rel=1e-12)
    with pytest.warns(ZemaxWarning):
        lens = load_lens(p, glass_fallback="1.8/40")
    assert lens.materials[2].nd == pytest.approx(1.8, abs=1e-12)


def test_vendor_glass_from_user_catalogue(tmp_path):
    bk7 = GLASS_TABLE["N-BK7"].coefficients
    agf = tmp_path / "OHARA.agf"
    agf.write_text("NM S-LAH66 2 0 1.5168 64.17 0 0 0\nCD " + " ".join(map(repr, bk7))
                   + "\nTD 0 0 0 0 0 0 20\nLD 0.33 2.1\n")
    p = write(tmp_path, singlet(glass="GLAS S-LAH66 0 0 1.7725 49.6 0 0 0 0 0 0",
                                gcat="GCAT OHARA"))
    with pytest.warns(ZemaxWarning, match="TD"):
        lens = load_lens(p, glass_catalogs=[agf])
    ref = load_lens(write(tmp_path, singlet(), "bk7.zmx"))
    assert float(paraxial(lens).efl) == pytest.approx(float(paraxial(ref).efl), rel=1e-13)
    # an .agf named like the GCAT entry next to the .zmx is found without being passed, also by
    # the command line
    (tmp_path / "nextto").mkdir()
    (tmp_path / "nextto" / "ohara.AGF").write_text(agf.read_text())
    (tmp_path / "nextto" / "lens.zmx").write_text(p.read_text())
    with pytest.warns(ZemaxWarning, match="TD"):
        near = read_zmx(tmp_path / "nextto" / "lens.zmx")
    assert float(paraxial(near).efl) == float(paraxial(lens).efl)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ZemaxWarning)
        rep = report(tmp_path / "nextto" / "lens.zmx", "--pupil", "paraxial", "--sampling",
                     "hexapolar:3")
    assert rep["efl_mm"] == pytest.approx(float(paraxial(lens).efl), rel=1e-12)
    # the written file names the vendor catalogue and the glass; reading it needs the .agf again
    write_zmx(lens, tmp_path / "out.zmx")
    text = (tmp_path / "out.zmx").read_text()
    assert "GCAT OHARA" in text and "GLAS S-LAH66 0 0" in text
    # a wavelength outside the glass's LD range: a clear error with the GLAS line
    q = write(tmp_path, singlet(glass="GLAS S-LAH66 0 0 1.7725 49.6 0 0 0 0 0 0",
                                gcat="GCAT OHARA", wav=(0.30, 0.65)), "uv.zmx")
    ln = line_of(q.read_text(), "S-LAH66")
    with pytest.raises(ZemaxFileError, match=f"uv.zmx:{ln}: wavelength 300 nm is outside the "
                                             r"valid range 330.2100 nm of material 'S-LAH66'"):
        read_zmx(q, glass_catalogs=[agf])


# --------------------------------------------------------------------------- bad input
def line_of(text: str, needle: str) -> int:
    """1-based number of the first line of ``text`` containing ``needle``."""
    return next(i for i, ln in enumerate(text.splitlines(), 1) if needle in ln)


@pytest.mark.parametrize("edit,needle,match", [
    (lambda t: t.replace("TYPE EVENASPH", "TYPE TOROIDAL"), "TOROIDAL",
     r"unknown surface type 'TOROIDAL' \(SURF 2\)"),
    (lambda t: t.replace("CURV 0.02", "CURV 0.0.2"), "0.0.2",
     r"CURV curvature: expected a number, got '0.0.2'"),
    (lambda t: t.replace("PARM 1 0", "PARM 1 0.001"), "PARM 1", r"EVENASPH PARM 1 \(the r² term\)"),
    (lambda t: t.replace("  DISZ 5.0\n", "  DISZ  \n"), "DISZ  ", r"DISZ line is truncated"),
    (lambda t: t.replace("GLAS N-BK7", "GLAS MIRROR"), None,  # a mirror, then DISZ > 0
     r"distance before surface 2 is positive \(5 mm\): sequential surfaces must be ordered "
     r"along -z, the direction of travel there \(after 1 mirror\)"),
    (lambda t: t.replace("ENPD 10", "OBNA 0.1 0"), "OBNA", r"OBNA"),
    (lambda t: t.replace("WAVM 1 0.55", "WAVM 1 550"), "WAVM 1", r"wavelength 550.0 µm"),
    (lambda t: t.replace("PWAV 2", "PWAV 3"), "PWAV", r"PWAV 3: the primary wavelength is not one"),
    (lambda t: t.replace("UNIT MM", "UNIT FURLONG"), "UNIT", r"UNIT: unknown lens unit 'FURLONG'"),
    (lambda t: t.replace("SURF 2", "SURF 7"), "SURF 7", r"SURF 7 out of order"),
    (lambda t: t.replace("  DIAM 8 1 0 0 1 \"\"\nSURF 4", "  SQAP 2 2\nSURF 4"), "SQAP",
     r"SQAP: non-circular apertures"),
    (lambda t: t.replace("CURV -0.005", "CURV -0.1").replace("DISZ 5.0", "DISZ 2.0"), None,
     r"surfaces 1 and 2 cross.*deeplens surface 1 is the SURF block on line "
     + str(line_of(singlet(), "SURF 2"))),
])
def test_bad_input_names_the_line(tmp_path, edit, needle, match):
    text = edit(singlet())
    p = write(tmp_path, text)
    prefix = f"t.zmx:{line_of(text, needle)}: " if needle else ""
    with pytest.raises(ZemaxFileError, match=prefix + match):
        read_zmx(p)


@pytest.mark.parametrize("edit,match", [
    (lambda t: t.split("SURF 2")[0], (r"expected an object surface, at least one lens surface "
                                     r"and an image surface; found 2 SURF")),
    (lambda t: "\n".join(t.splitlines()[:5]), r"no SURF line"),
    (lambda t: t.replace("  STOP\n", ""), r"no STOP line"),
])
def test_truncated_files(tmp_path, edit, match):
    with pytest.raises(ZemaxFileError, match=match):
        read_zmx(write(tmp_path, edit(singlet())))


def test_understood_but_unused_lines_warn_with_line(tmp_path):
    p = write(tmp_path, singlet(extra_system=("FOOB 1 2 3",)))
    with pytest.warns(ZemaxWarning, match=r"t.zmx:13: FOOB line not used"):
        read_zmx(p)


def test_coordinate_break_that_is_not_a_bracket(tmp_path):
    cb = ("SURF 2\n  TYPE COORDBRK\n  CURV 0.0\n  DISZ 0\n  PARM 1 0.1\n  PARM 2 0\n  PARM 3 0\n"
          "  PARM 4 0\n  PARM 5 0\n  PARM 6 0\n")
    text = singlet().replace("SURF 4", "SURF 5").replace("SURF 3", "SURF 4")
    text = text.replace("SURF 2\n", cb + "SURF 3\n", 1)
    with pytest.raises(ZemaxFileError, match=f":{line_of(text, 'COORDBRK') - 1}: this COORDBRK "
                                             f"is never undone"):
        read_zmx(write(tmp_path, text))
    tilt_z = text.replace("PARM 5 0", "PARM 5 2")
    with pytest.raises(ZemaxFileError, match=r"tilt about z is not supported"):
        read_zmx(write(tmp_path, tilt_z, "tz.zmx"))


def test_utf16_and_utf8_read_the_same(tmp_path):
    a = read_zmx(write(tmp_path, singlet(), "a.zmx"))
    b = read_zmx(write(tmp_path, singlet(), "b.zmx", encoding="utf-16"))
    assert lens_to_dict(a) == lens_to_dict(b)


# --------------------------------------------------------------------------- optiland oracle
def _optiland(path, indices, stop_semi_diameter):
    """optiland's own reading of ``path``, with two documented corrections.

    1. Glasses: optiland resolves SK1 and F15 of this file to other vendors' glasses of the same
       name (n_d 1.6228 and 1.6990, not the 1.6103 and 1.6057 of the old SCHOTT glasses the lens
       uses), so each medium is set to an ideal material with *our* index; the geometry stays
       optiland's reading.
    2. Aperture: for a floating stop optiland takes the stop's ``DIAM`` as the stop *diameter*;
       ``DIAM`` is a semi-diameter in Zemax (the table's stop diameter 4.886 mm is ``DIAM
       2.443`` in the file), so the aperture is set to twice it.
    """
    from optiland.fileio import load_zemax_file
    from optiland.materials import IdealMaterial

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        op = load_zemax_file(str(path))
    # optiland keeps the shipped file's dummy surface (no aperture); ours are the others
    real = list(range(1, len(op.surfaces) - 1))
    if len(real) > len(indices) - 1:
        real = [j for j in real if op.surfaces[j].aperture is not None or op.surfaces[j].is_stop]
    assert len(real) == len(indices) - 1
    for k, j in enumerate(real):
        op.surfaces[j].material_post = IdealMaterial(indices[k + 1])
    op.set_aperture(aperture_type="float_by_stop_size", value=2.0 * stop_semi_diameter)
    op.ray_tracer.set_aiming("paraxial")
    return op


def test_optiland_reads_the_shipped_zmx_like_us():
    pytest.importorskip("optiland")
    import numpy as np

    lens = read_zmx(ZMX)
    w = torch.tensor(587.562, dtype=torch.float64)
    indices = [float(m.n(w)) for m in lens.materials]
    op = _optiland(ZMX, indices, float(lens.stop.semi_diameter))
    assert float(np.ravel(op.paraxial.f2())[0]) == pytest.approx(float(paraxial(lens).efl),
                                                                 rel=1e-12)
    rings = 12
    rep = report(ZMX, "--pupil", "paraxial", "--sampling", f"hexapolar:{rings}")
    px, py = H.hexapolar_unit(rings)
    for row in rep["fields"]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = op.trace_generic(0.0, row["field_deg"] / 21.0, px, py, 0.587562)
        x, y, i = (np.asarray(v, dtype=float) for v in (r.x, r.y, r.i))
        ok = (i > 0) & np.isfinite(x) & np.isfinite(y)
        pts = np.stack([x[ok], y[ok]], -1)
        c = pts.mean(0)
        rms_um = 1e3 * math.sqrt(((pts - c) ** 2).sum(-1).mean())
        assert row["n_rays"] == int(ok.sum())          # the same rays are vignetted
        assert row["rms_spot_um"] == pytest.approx(rms_um, rel=1e-5)
        assert row["centroid_mm"] == pytest.approx(c.tolist(), abs=1e-6)


@pytest.mark.parametrize("element,param,value", [(1, "dy", 0.05), (1, "tilt_x", 0.01),
                                                 (1, "tilt_y", 0.01), (3, "dx", -0.03)])
def test_coordinate_breaks_match_optiland(tmp_path, element, param, value):
    """Our COORDBRK brackets, read by optiland, trace ray for ray like our misalignment."""
    pytest.importorskip("optiland")
    import numpy as np

    lens = load_lens(JSON).double()
    with torch.no_grad():
        getattr(lens.misalignments[element], param).fill_(value)
    p = tmp_path / "mis.zmx"
    write_zmx(lens, p)
    w = torch.tensor(587.5618, dtype=torch.float64)
    op = _optiland(p, [float(m.n(w)) for m in lens.materials], float(lens.stop.semi_diameter))
    px, py = H.hexapolar_unit(6)
    field = 7.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = op.trace_generic(0.0, field / 21.0, px, py, 0.5875618)
    x, y, i = (np.asarray(v, dtype=float) for v in (r.x, r.y, r.i))
    par = paraxial(lens)
    epd, zep = float(par.entrance_pupil_diameter), float(par.entrance_pupil_z)
    t = math.radians(field)
    d = torch.tensor([0.0, math.sin(t), math.cos(t)], dtype=torch.float64).expand(len(px), 3)
    on_ep = torch.tensor([[a * epd / 2, b * epd / 2, zep] for a, b in zip(px, py)],
                         dtype=torch.float64)
    out = lens.trace_to_sensor(Rays(on_ep - d * (zep + 5.0), d,
                                    torch.full((len(px),), 587.5618, dtype=torch.float64)))
    ok = out.valid.numpy() & (i > 0)
    assert ok.sum() > 0.8 * len(px)
    assert np.abs(x[ok] - out.o[ok, 0].numpy()).max() < 2e-6    # optiland's asphere tolerance
    assert np.abs(y[ok] - out.o[ok, 1].numpy()).max() < 2e-6
    # and the perturbation is seen: the aligned lens lands > 10x that tolerance elsewhere
    ref = load_lens(JSON).double().trace_to_sensor(
        Rays(on_ep - d * (zep + 5.0), d, torch.full((len(px),), 587.5618, dtype=torch.float64)))
    assert (ref.o[ok, :2] - out.o[ok, :2]).abs().max() > 1e-4


def test_xypolynom_terms_and_normalisation(tmp_path):
    """XYPOLYNOM (CURV 0): z = Σ A_j x^m y^n / R^(m+n), terms x, y, x², xy, y², x³, ..."""
    xy = ("XDAT 1 9", "XDAT 2 4.0", "XDAT 3 0.02", "XDAT 7 0.5", "XDAT 11 -0.03")
    text = singlet(s1_type="XYPOLYNOM", s1_extra=xy, curv1=0.0, k=0.0)
    lens = read_zmx(write(tmp_path, text))
    s = lens.surfaces[1]
    x = torch.tensor([1.5, -2.0, 0.7], dtype=torch.float64)
    y = torch.tensor([0.5, 1.0, -2.5], dtype=torch.float64)
    R = 4.0
    # term 1 = x, term 5 = y², term 9 = y³ (the 4 cubic terms run x³, x²y, xy², y³)
    want = 0.02 * x / R + 0.5 * y ** 2 / R ** 2 - 0.03 * y ** 3 / R ** 3
    torch.testing.assert_close(s.sag(x, y), want, rtol=0, atol=1e-15)
    assert s.order == 3
    with pytest.raises(ZemaxFileError, match=r"XYPOLYNOM with a base curvature"):
        read_zmx(write(tmp_path, singlet(s1_type="XYPOLYNOM", s1_extra=xy, k=0.0), "c.zmx"))


def test_leading_dummy_adds_to_the_object_distance(tmp_path):
    text = singlet(obj="100")
    for k in (4, 3, 2, 1):
        text = text.replace(f"SURF {k}\n", f"SURF {k + 1}\n")
    dummy = "SURF 1\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 20\n"
    lens = read_zmx(write(tmp_path, text.replace("SURF 2\n", dummy + "SURF 2\n", 1)))
    assert lens.spec.object_distance_mm == 120.0
    assert float(lens.distances[0]) == 0.0 and len(lens.surfaces) == 3


@pytest.mark.parametrize("glass,line", [("FUSED_SILICA", "GLAS F_SILICA"),
                                        ("PC", "GLAS POLYCARB"), ("B270", "GLAS B270"),
                                        ("SSK4", "GLAS SSK4")])
def test_catalogue_glasses_written_under_zemax_names(tmp_path, glass, line):
    from deeplens.optics.materials import get_material

    lens = load_lens(REPO / "data" / "lenses" / "thorlabs_la1131.json")
    lens.materials[1] = get_material(glass)
    write_zmx(lens, tmp_path / "g.zmx")
    assert line + " 0 0" in (tmp_path / "g.zmx").read_text()
    assert read_zmx(tmp_path / "g.zmx").materials[1].to_spec() == glass


def test_vignetting_factors_and_environment_are_reported(tmp_path):
    p = write(tmp_path, singlet(extra_system=("VDYN 0 0.1", "ENVD 35 1 0")))
    with pytest.warns(ZemaxWarning) as rec:
        read_zmx(p)
    msgs = [str(r.message) for r in rec]
    assert any(":13: VDYN: vignetting factors are ignored" in m for m in msgs)
    assert any(":14: ENVD: temperature 35 °C" in m for m in msgs)


def test_old_field_operands(tmp_path):
    old = singlet(yfln="YFLD 0 5").replace("XFLN 0 0", "XFLD 0 0")
    assert read_zmx(write(tmp_path, old)).spec.fields_deg == [0.0, 5.0]
