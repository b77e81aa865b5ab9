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
import re
import warnings
from pathlib import Path

import helpers as H
import pytest
import torch

from deeplens.optics.paraxial import paraxial
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
from deeplens.optics.misalignment import Misalignment
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture

REPO = Path(__file__).resolve().parents[3]
ZMX = REPO / "tests" / "data" / "lenses" / "US02532751-1.zmx"
JSON = REPO / "data" / "lenses" / "double_gauss.json"


def report(path, *extra):
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli_main(["report", str(path), "--json", *extra]) == 0
    return json.loads(buf.getvalue())


def air_normalised(d: dict) -> dict:
    """``lens_to_dict`` with VACUUM written as AIR (index 1 both; Zemax has one air), and a
    glass written with its formula (a catalogue the built-in table does not hold, or holds
    with other indices: the .zmx's previous-catalogue SSK4 against the table's rounded n_d/V_d)
    named by its glass name."""
    d = copy.deepcopy(d)

    def name(m):
        return m["glass"] if isinstance(m, dict) else m.replace("VACUUM", "AIR")

    d["object"]["medium"] = name(d["object"]["medium"])
    for s in d["surfaces"]:
        s["material"] = name(s["material"])
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
    # the .zmx gets SSK4, SK1, F15 and SK16 from the previous SCHOTT catalogue, the table its
    # authors' rounded n_d / V_d: EFL 27.4400 against 27.4425 mm
    assert rz["efl_mm"] == pytest.approx(27.4400, abs=1e-4)
    assert rz["efl_mm"] == pytest.approx(rj["efl_mm"], rel=2e-4)
    for a, b in zip(rz["fields"], rj["fields"]):
        assert a["field_deg"] == b["field_deg"] and a["n_rays"] == b["n_rays"]
        # catalogue SK1/F15/SK16 against the table's rounded model glasses: up to 5 % off-axis
        assert a["rms_spot_um"] == pytest.approx(b["rms_spot_um"], rel=0.1)
        assert a["centroid_mm"] == pytest.approx(b["centroid_mm"], abs=1e-3)


def test_shipped_zmx_traces_like_table_when_the_difference_is_removed():
    z, j = load_lens(ZMX), load_lens(JSON)
    with torch.no_grad():
        z.surfaces[6].c.copy_(j.surfaces[6].c)
    for k, m in enumerate(j.materials):   # and the table's rounded model glasses
        z.materials[k] = m
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


@pytest.mark.parametrize("edit,needle,feature,surf,surfaces", [
    (lambda t: t.replace("TYPE EVENASPH", "TYPE GRINSUR9"), "GRINSUR9", "TYPE", 2, ()),
    (lambda t: t.replace("CURV 0.02", "CURV 0.0.2"), "0.0.2", "CURV", 2, ()),
    (lambda t: t.replace("UNIT MM", "UNIT FURLONG"), "UNIT", "UNIT", None, ()),
    (lambda t: t.replace("GLAS N-BK7", "GLAS N-BK7X"), "N-BK7X", "GLAS", 2, ()),
    # an error of the built lens: located at the block of the last deeplens surface it names
    # (a CLAP, a surface aperture, is never limited where the faces cross)
    (lambda t: t.replace("CURV -0.005", "CURV -0.1").replace("DISZ 5.0", "DISZ 2.0").replace(
        '  DIAM 8 1 0 0 1 ""', '  DIAM 8 1 0 0 1 ""\n  CLAP 0 8 0'), "SURF 3", "SURF", 3, (1, 2)),
    # an error about the sensor: at the image surface's block
    (lambda t: t.replace("CURV -0.005", "CURV 0.02").replace("DISZ 45.0", "DISZ 0.3"), "SURF 4",
     "SURF", 4, ()),
    (lambda t: t.replace("  STOP\n", ""), None, None, None, ()),
])
def test_error_location_is_structured(tmp_path, edit, needle, feature, surf, surfaces):
    """The location is in the error's attributes (what callers read), and the message is
    formatted from them: ``SOURCE[:LINE]: MESSAGE``."""
    text = edit(singlet())
    p = write(tmp_path, text)
    with pytest.raises(ZemaxFileError) as info:
        read_zmx(p)
    e = info.value
    assert e.source == str(p)
    assert e.line == (line_of(text, needle) if needle else None)
    assert (e.feature, e.surf, e.surfaces) == (feature, surf, surfaces)
    where = f"{e.source}:{e.line}" if e.line else e.source
    assert str(e) == f"{where}: {e.message}"


def test_warning_location_is_structured(tmp_path):
    p = write(tmp_path, singlet(extra_system=("FOOB 1 2 3",)))
    with pytest.warns(ZemaxWarning) as rec:
        read_zmx(p)
    w = next(r.message for r in rec if "FOOB" in str(r.message))
    assert (w.source, w.line, w.feature) == (str(p), 13, "FOOB")
    assert str(w) == f"{p}:13: {w.message}"


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
    # a flat air surface with a fixed (user) semi-diameter: kept, but it does not clip (in
    # OpticStudio a floating aperture is for a surface with power and no surface aperture;
    # User Guide, "Semi-Diameters"): its semi-diameter is the beam's extent, 1.02 (5 + 0.5
    # tan 5°) (the 10 mm pupil on the stop 0.5 mm before it, the 5° field), with a note
    fixed = dummy.replace("DIAM 3 0", "DIAM 3 1")
    with pytest.warns(ZemaxWarning, match=r"c.zmx:\d+: SURF 2: the fixed DIAM 3 of a flat "
                                          r"surface .* does not clip rays"):
        got = lens_to_dict(read_zmx(write(tmp_path, insert_after_stop(text, fixed), "c.zmx")))
    assert [s["type"] for s in got["surfaces"]] == ["aperture", "aperture", "asphere", "asphere"]
    beam = 1.02 * (5.0 + 0.5 * math.tan(math.radians(5.0)))
    assert got["surfaces"][1]["semi_diameter_mm"] == pytest.approx(beam, rel=1e-3)
    assert [s["distance_mm"] for s in got["surfaces"]] == [0.0, 0.5, 1.5, 5.0]
    # a CLAP (a surface aperture) makes it an opening of that size
    clap = fixed + "  CLAP 0 3 0\n"
    got = lens_to_dict(read_zmx(write(tmp_path, insert_after_stop(text, clap), "d.zmx")))
    assert got["surfaces"][1]["semi_diameter_mm"] == 3.0


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
    # the object point (0, +20): its chief ray falls towards the axis, a negative field angle
    # (OpticStudio's convention; tests/optics/io/test_zmx_object_height_sign.py)
    assert obj.spec.fields_deg[1] == pytest.approx(-math.degrees(math.atan(20 / (500 + ep))),
                                                   rel=1e-12)
    with pytest.warns(ZemaxWarning, match=r"xy.zmx:8: XFLN: x field components are combined"):
        xy = read_zmx(write(tmp_path, singlet(yfln="YFLN 0 4").replace("XFLN 0 0", "XFLN 0 3"),
                            "xy.zmx"))
    t = math.degrees(math.atan(math.hypot(math.tan(math.radians(3)), math.tan(math.radians(4)))))
    assert xy.spec.fields_deg == pytest.approx([0.0, t], rel=1e-12)


@pytest.mark.parametrize("ftyp,obj,match", [
    ("FTYP 3 0 2 2 0 0 0", "INFINITY", r":7: FTYP 3 \(real image height\): no chief ray reaches "
                                       r"image height 500 mm"),
    ("FTYP 1 0 2 2 0 0 0", "INFINITY", (r":7: FTYP 1 \(object height\) with the object at "
                                       r"infinity cannot be converted")),
])
def test_unconvertible_field_types(tmp_path, ftyp, obj, match):
    yfln = "YFLN 0 500" if ftyp.startswith("FTYP 3") else "YFLN 0 5"
    # (FTYP 3: a singlet whose chief rays stay below 15 mm and miss its rear surface
    # beyond about 65 deg)
    kw = (dict(curv1=0.05, curv2=-0.1, t=8, bfl=20, s1_extra=(), k=0, diam1=6)
          if ftyp.startswith("FTYP 3") else {})
    with pytest.raises(ZemaxFileError, match=match):
        read_zmx(write(tmp_path, singlet(ftyp=ftyp, obj=obj, yfln=yfln, **kw)))


def test_theodolite_fields(tmp_path):
    """FTYP 4 with one non-zero component is that field angle; both together are refused."""
    lens = read_zmx(write(tmp_path, singlet(ftyp="FTYP 4 0 2 2 0 0 0", yfln="YFLN 0 5")))
    assert lens.spec.fields_deg == [0.0, 5.0]
    text = singlet(ftyp="FTYP 4 0 2 2 0 0 0", yfln="YFLN 0 5").replace("XFLN 0 0", "XFLN 0 3")
    with pytest.raises(ZemaxFileError, match=r":7: FTYP 4 \(theodolite angles\) with both x and y"):
        read_zmx(write(tmp_path, text, "both.zmx"))


# --------------------------------------------------------------------------- glasses
def test_glass_not_found_names_glass_and_line(tmp_path):
    """One short line; every catalogue searched is in the error's details."""
    p = write(tmp_path, singlet(glass="GLAS N-BK7X 0 0 1.52 64 0 0 0 0 0 0"))
    ln = line_of(p.read_text(), "N-BK7X")
    with pytest.raises(ZemaxFileError, match=f"t.zmx:{ln}: glass 'N-BK7X' is not in the shipped "
                                             r"SCHOTT catalogue; pass the vendor's \.agf that "
                                             r"has it with --glass-catalog$") as e:
        read_zmx(p)
    assert "\n" not in str(e.value)
    assert re.search(r"catalogues searched by exact name: SCHOTT \(current vendor catalogue, 123 "
                     r"glasses\); SCHOTT \(deeplens built-in, 22 glasses\); SCHOTT archived "
                     r"\(the vendor's \.agf as refractiveindex\.info keeps it, \d+ glasses\); "
                     r"SCHOTT withdrawn \(1 glass\(es\) with published Sellmeier coefficients\); "
                     r"SCHOTT previous", e.value.details)
    assert "DEEPLENS_GLASS_PATH" in e.value.details
    # never fuzzy: load_lens says the same
    with pytest.raises(LensFileError, match="N-BK7X"):
        load_lens(p)


def test_glass_only_in_the_catalogues_named(tmp_path):
    """PMMA is in deeplens' MISC catalogue, which this file does not name."""
    p = write(tmp_path, singlet(glass="GLAS PMMA 0 0 1.49 57.4 0 0 0 0 0 0"))
    with pytest.raises(ZemaxFileError, match=r"glass 'PMMA' is not in the shipped SCHOTT catalogue"):
        read_zmx(p)
    ok = read_zmx(write(tmp_path, singlet(glass="GLAS PMMA 0 0 1.49 57.4 0 0 0 0 0 0",
                                          gcat="GCAT SCHOTT MISC"), "misc.zmx"))
    assert ok.materials[2].name == "PMMA"


def test_glass_fallback_only_on_request(tmp_path):
    p = write(tmp_path, singlet(glass="GLAS ACME-66 0 0 1.7725 49.6 0 0 0 0 0 0",
                                gcat="GCAT ACME"))
    ln = line_of(p.read_text(), "ACME-66")
    with pytest.raises(ZemaxFileError, match=rf"t\.zmx:{ln}: glass 'ACME-66' \(catalogue ACME\) "
                                             r"is not shipped; pass --glass-catalog ACME\.agf$"):
        read_zmx(p)
    # the fallback is never silent: one located warning naming the glass, the values used and
    # how to give the catalogue
    with pytest.warns(ZemaxWarning, match=rf":{ln}: glass 'ACME-66' \(catalogue ACME\) is not "
                                          r"shipped; using the GLAS line's model values n_d "
                                          r"1\.7725, V_d 49\.6 .*stale.*; for the glass itself "
                                          r"pass --glass-catalog ACME\.agf$"):
        lens = read_zmx(p, glass_fallback="model")
    assert lens.materials[2].nd == pytest.approx(1.7725, abs=1e-12)
    assert lens.materials[2].vd == pytest.approx(49.6, rel=1e-12)
    with pytest.warns(ZemaxWarning, match=r"'ACME-66' \(catalogue ACME\) is not shipped; using "
                                          r"the requested fallback '.*' \(n_d 1\.8, V_d 40\)"):
        lens = load_lens(p, glass_fallback="1.8/40")
    assert lens.materials[2].nd == pytest.approx(1.8, abs=1e-12)


def test_model_fallback_refuses_the_placeholder(tmp_path):
    """OpticStudio writes n_d/V_d = 1.5/40 on a catalogue GLAS line it has not evaluated."""
    p = write(tmp_path, singlet(glass="GLAS ACME-66 0 0 1.5 40 0 0 0 0 0 0", gcat="GCAT ACME"))
    ln = line_of(p.read_text(), "ACME-66")
    with pytest.raises(ZemaxFileError, match=f":{ln}: glass 'ACME-66' .*not shipped.*placeholder"):
        read_zmx(p, glass_fallback="model")


def test_vendor_catalogues_answer_for_their_names(tmp_path):
    """S-LAH66 is in OHARA's own catalogue (shipped by opticalglass); BK7 in SCHOTT's withdrawn entries."""
    lens = read_zmx(write(tmp_path, singlet(glass="GLAS S-LAH66 0 0 1.5 40 0 0 0 0 0 0",
                                            gcat="GCAT OHARA")))
    assert lens.materials[2].nd == pytest.approx(1.77250, abs=5e-5)
    assert lens.materials[2].vd == pytest.approx(49.60, abs=0.05)
    with pytest.warns(ZemaxWarning, match="withdrawn SCHOTT catalogue"):
        lens = read_zmx(write(tmp_path, singlet(glass="GLAS BK7 0 0 1.5 40 0 0 0 0 0 0"), "b.zmx"))
    assert lens.materials[2].nd == pytest.approx(1.51680, abs=5e-6)


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


def assert_refused_on_line(tmp_path, text: str, needle: str, match: str) -> None:
    """Reading the ``.zmx`` ``text`` fails with ``match`` (a regular expression) located at the
    first line holding ``needle``, the message naming the file."""
    p = write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(p)
    assert e.value.line == line_of(text, needle)
    assert str(p) in str(e.value)


def assert_written_back(tmp_path, lens, needles) -> str:
    """``lens`` written to ``.zmx`` holds every string of ``needles`` and reads back as the same
    lens (its lens-file dict, the name aside); returns the written text."""
    write_zmx(lens, tmp_path / "out.zmx")
    text = (tmp_path / "out.zmx").read_text()
    for needle in needles:
        assert needle in text, needle
    back = H.read_zmx_quiet(tmp_path / "out.zmx")
    a, b = lens_to_dict(lens), lens_to_dict(back)
    a.pop("name", None), b.pop("name", None)
    assert a == b
    return text


@pytest.mark.parametrize("edit,needle,match", [
    (lambda t: t.replace("TYPE EVENASPH", "TYPE QTYPEASP"), "QTYPEASP",
     r"surface type 'QTYPEASP' \(SURF 2, a Q-type \(Forbes\) asphere\) is not supported"),
    (lambda t: t.replace("TYPE EVENASPH", "TYPE QED_TYPE"), "QED_TYPE",
     r"SURF 2: QED_TYPE XDAT 3 \(the normalisation radius\) must be > 0, got 0.0"),
    (lambda t: t.replace("TYPE EVENASPH", "TYPE TOROIDAL").replace("PARM 1 0", "PARM 1 3"),
     "SURF 2", r"SURF 2 \(Toroid, deeplens surface 1\): the clear aperture \(x up to 8 mm\) "
               r"lies beyond the toroid's radius of rotation \(3 mm\)"),
    (lambda t: t.replace("CURV 0.02", "CURV 0.0.2"), "0.0.2",
     r"CURV curvature: expected a number, got '0.0.2'"),
    (lambda t: t.replace("PARM 1 0", "PARM 9 0.001"), "PARM 9",
     r"SURF 2: EVENASPH PARM 9 = 0.001 is not read \(Zemax's even asphere has PARM 1-8\)"),
    (lambda t: t.replace("TYPE EVENASPH", "TYPE ODDASPHE").replace("PARM 1 0", "PARM 9 0.1"),
     "PARM 9", r"SURF 2: ODDASPHE PARM 9 = 0.1 is not read \(Zemax's odd asphere has PARM "
               r"1-8\)"),
    (lambda t: t.replace("  DISZ 5.0\n", "  DISZ  \n"), "DISZ  ", r"DISZ line is truncated"),
    (lambda t: t.replace("GLAS N-BK7", "GLAS MIRROR"), None,  # a mirror, then DISZ > 0
     r"distance before surface 2 is positive \(5 mm\): sequential surfaces must be ordered "
     r"along -z, the direction of travel there \(after 1 mirror\)"),
    (lambda t: t.replace("ENPD 10", "OBNA 0.1 0"), "OBNA", r"OBNA"),
    # a wave beyond 100 µm (WAVM states µm) is refused where a medium is not defined there:
    # at that glass's line, with its range and the nanometre slip
    (lambda t: t.replace("WAVM 1 0.55", "WAVM 1 550"), "GLAS N-BK7",
     r"wavelength 550000 nm is outside the valid range 310–2500 nm of material 'N-BK7' "
     r"\(glass of SURF 2, catalogue SCHOTT\); the wavelength is WAVM 550 µm \(WAVM values are "
     r"micrometres\): "
     r"a wave beyond 100 µm loads where every medium of the lens is defined there .*; if 550 "
     r"is in nanometres, write 0.55$"),
    (lambda t: t.replace("WAVM 1 0.55", "WAVM 1 3000"), "GLAS N-BK7",   # a millimetre wave
     r"wavelength 3e\+06 nm is outside the valid range 310–2500 nm of material 'N-BK7' "
     r"\(glass of SURF 2, catalogue SCHOTT\); the wavelength is WAVM 3000 µm \(3 mm: a millimetre "
     r"or terahertz wave\) \(WAVM values are micrometres\): a wave beyond 100 µm loads where "
     r"every medium of the lens is defined there \(a constant index, a model glass with V_d 0, or a "
     r"catalogue glass whose range reaches it\)$"),
    (lambda t: t.replace("PWAV 2", "PWAV 3"), "PWAV", r"PWAV 3: the primary wavelength is not one"),
    (lambda t: t.replace("UNIT MM", "UNIT FURLONG"), "UNIT", r"UNIT: unknown lens unit 'FURLONG'"),
    (lambda t: t.replace("SURF 2", "SURF 7"), "SURF 3",
     r"SURF 3 out of order: expected SURF 8 \(the numbers skip from 1 to 7 at line "),
    (lambda t: t.replace("  DIAM 8 1 0 0 1 \"\"\nSURF 4", "  CLAP 0 3 0\n  SQAP 2 2\nSURF 4"),
     "SQAP", r"SQAP on SURF 3: a rectangular aperture on a Asphere surface with a CLAP is not "
             r"supported"),
    (lambda t: t.replace("CURV -0.005", "CURV -0.1").replace("DISZ 5.0", "DISZ 2.0").replace(
        '  DIAM 8 1 0 0 1 ""', '  DIAM 8 1 0 0 1 ""\n  CLAP 0 8 0'), "SURF 3",
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
    """A decenter that is never undone shifts every following surface: read as a
    CoordinateBreak, the lens images a ray fan exactly as the centred lens images the fan
    shifted by -dx, with the image (in the shifted frame) shifted by -dx too."""
    cb = ("SURF 2\n  TYPE COORDBRK\n  CURV 0.0\n  DISZ 0\n  PARM 1 0.1\n  PARM 2 0\n  PARM 3 0\n"
          "  PARM 4 0\n  PARM 5 0\n  PARM 6 0\n")
    text = singlet().replace("SURF 4", "SURF 5").replace("SURF 3", "SURF 4")
    text = text.replace("SURF 2\n", cb + "SURF 3\n", 1)
    from deeplens.optics.surfaces import CoordinateBreak

    lens = read_zmx(write(tmp_path, text)).double()
    plain = read_zmx(write(tmp_path, singlet(), "plain.zmx")).double()
    assert [type(s).__name__ for s in lens.surfaces][:2] == ["Aperture", "CoordinateBreak"]
    assert float(lens.surfaces[1].dx) == 0.1
    y = torch.linspace(-2.0, 2.0, 9, dtype=torch.float64)
    o = torch.stack([torch.zeros_like(y), y, torch.full_like(y, -1.0)], -1)
    d = torch.tensor([0.05, 0.1, 1.0], dtype=torch.float64)
    d = (d / d.norm()).expand(9, 3)
    w = torch.full((9,), 587.5618, dtype=torch.float64)
    a = lens.trace_to_sensor(Rays(o, d, w))
    shift = torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64)
    b = plain.trace_to_sensor(Rays(o - shift, d, w))
    assert bool(a.valid.all()) and isinstance(lens.surfaces[1], CoordinateBreak)
    torch.testing.assert_close(a.o, b.o, rtol=0, atol=1e-12)


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


def _with_tilts(tmp_path, tilts, name="mis.zmx"):
    """The table lens with element 1 decentred and bracketed by COORDBRKs carrying ``tilts``
    (degrees about x, y, z; the returning break negated, order flag 1)."""
    lens = load_lens(JSON).double()
    with torch.no_grad():
        lens.misalignments[1].tilt_x.fill_(0.01)   # a bracket to edit
        lens.misalignments[1].dy.fill_(0.03)
    p = tmp_path / name
    write_zmx(lens, p)
    lines = p.read_text().splitlines()
    cbs = [i for i, t in enumerate(lines) if t.strip() == "TYPE COORDBRK"]
    assert len(cbs) == 2
    for i, sign in zip(cbs, (1.0, -1.0)):
        for k, v in zip((3, 4, 5), tilts):
            j = next(j for j in range(i, i + 12) if lines[j].strip().startswith(f"PARM {k} "))
            lines[j] = f"  PARM {k} {sign * v!r}"
    p.write_text("\n".join(lines) + "\n")
    return p


@pytest.mark.parametrize("tilts", [(0.6, 0.9, 0.0), (-0.5, 0.4, 30.0), (0.7, 0.0, -20.0)])
def test_coordinate_breaks_with_two_tilts(tmp_path, tilts):
    """Tolerancing files tilt about x and y together (and about z).  OpticStudio's order flag 0
    tilts about x, then the new y, then the new z (``R = R_x R_y R_z``, as ray-optics reads it:
    transforms3d ``rxyz``); a rotationally symmetric element is then the element whose axis is
    ``R e_z``, which deeplens' two tilts reproduce exactly.  (optiland 0.6 composes the tilts as
    ``R_z R_y R_x`` and ignores the returning break's order flag, so it is no oracle here.)"""
    back = read_zmx(_with_tilts(tmp_path, tilts))
    m = back.misalignments[1]
    a, b = (math.radians(v) for v in tilts[:2])
    zero = torch.zeros((), dtype=torch.float64)
    axis = m.rotation(zero) @ torch.tensor([0.0, 0, 1], dtype=torch.float64)
    # R_x(a) R_y(b) e_z with deeplens' own single-axis matrices (R_z leaves e_z alone)
    rx = Misalignment(tilt_x=a).rotation(zero)
    ry = Misalignment(tilt_y=b).rotation(zero)
    want = rx @ ry @ torch.tensor([0.0, 0, 1], dtype=torch.float64)
    torch.testing.assert_close(axis, want, rtol=0, atol=1e-15)
    assert float(m.dy) == pytest.approx(0.03, abs=1e-15)


def test_coordinate_break_about_z_only_turns_the_element_about_its_axis(tmp_path):
    """A tilt about z alone turns a rotationally symmetric element about its own axis: the
    lens traces exactly as with the decenter alone."""
    turned = read_zmx(_with_tilts(tmp_path, (0.0, 0.0, 35.0), "z.zmx"))
    plain = read_zmx(_with_tilts(tmp_path, (0.0, 0.0, 0.0), "plain.zmx"))
    pa, va = trace_points(turned, 7.0)
    pb, vb = trace_points(plain, 7.0)
    assert torch.equal(va, vb) and bool(va.any())
    torch.testing.assert_close(pa[va], pb[vb], rtol=0, atol=1e-14)


def test_two_tilts_around_a_freeform_are_coordinate_breaks(tmp_path):
    """A freeform between breaks tilting about x and y: no misalignment of deeplens expresses
    OpticStudio's R_x R_y about a surface that is not rotationally symmetric, so the two breaks
    are read as CoordinateBreak surfaces (exact); the returning break (order flag 1) puts the
    frame back where it was."""
    text = singlet(s1_type="XYPOLYNOM", s1_extra=("XDAT 1 2", "XDAT 2 4.0", "XDAT 3 0.01"),
                   curv1=0.0, k=0.0)
    lines = text.splitlines()
    i = lines.index("SURF 2")
    cb = ["SURF 2", "  TYPE COORDBRK", "  DISZ 0", "  PARM 3 0.5", "  PARM 4 0.5"]
    back = ["SURF 4", "  TYPE COORDBRK", "  DISZ 5", "  PARM 3 -0.5", "  PARM 4 -0.5",
            "  PARM 6 1"]
    j = lines.index("SURF 3")
    body = lines[i:j]
    body = [("SURF 3" if t == "SURF 2" else t) for t in body]
    rest = lines[j:]
    rest = [t.replace("SURF 3", "SURF 5").replace("SURF 4", "SURF 6") for t in rest]
    rest[rest.index("  DISZ 45.0")] = "  DISZ 40.0"
    body[body.index("  DISZ 5.0")] = "  DISZ -0.0"
    s3 = [t.replace("SURF 5", "SURF 4") for t in rest[:rest.index("SURF 6")]]
    s3[s3.index("  DISZ 40.0")] = "  DISZ 0"
    out = lines[:i] + cb + body + s3 + [t.replace("SURF 4", "SURF 5") for t in back] + \
        rest[rest.index("SURF 6"):]
    text2 = "\n".join(out) + "\n"
    # a 5 mm thick element, back to the pivot (-5), the image 45 mm after it
    text2 = (text2.replace("  DISZ -0.0\n", "  DISZ 5.0\n")
             .replace("  DISZ 0\n  DIAM 8", "  DISZ -5.0\n  DIAM 8")
             .replace("  DISZ 5\n  PARM 3 -0.5", "  DISZ 45\n  PARM 3 -0.5"))
    from deeplens.optics.frames import local_frames
    from deeplens.optics.surfaces import CoordinateBreak

    lens = read_zmx(write(tmp_path, text2)).double()
    kinds = [type(s).__name__ for s in lens.surfaces]
    assert kinds == ["Aperture", "CoordinateBreak", "XYPolynomial", "Asphere", "CoordinateBreak"]
    assert [s.order for s in lens.surfaces if isinstance(s, CoordinateBreak)] == [0, 1]
    A, b = local_frames(lens)[-1]
    torch.testing.assert_close(A, torch.eye(3, dtype=torch.float64), rtol=0, atol=1e-15)
    torch.testing.assert_close(b, torch.zeros(3, dtype=torch.float64), rtol=0, atol=1e-13)
    assert bool(trace_points(lens, 0.0)[1].all())


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
                                        ("SSK4", "GLAS SSK4 1")])
def test_catalogue_glasses_written_under_zemax_names(tmp_path, glass, line):
    """Catalogue entries under their Zemax names; SSK4, a model glass of deeplens' table (the
    paper authors' n_d / V_d), as a named model glass (code 1), so that it comes back as itself
    rather than as the previous catalogue's SSK4."""
    from deeplens.optics.materials import get_material

    lens = load_lens(REPO / "data" / "lenses" / "thorlabs_la1131.json")
    lens.materials[1] = get_material(glass)
    write_zmx(lens, tmp_path / "g.zmx")
    assert line + (" 0 " if glass == "SSK4" else " 0 0") in (tmp_path / "g.zmx").read_text()
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


def _paraxial_file(f="50", glass=""):
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "UNIT MM X W X CM MR CPMM", "ENPD 10",
        "GCAT SCHOTT", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 5", "WAVM 1 0.55 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  CURV 0", "  DISZ 100",
        "SURF 1", "  STOP", "  TYPE PARAXIAL", "  CURV 0", f"  PARM 1 {f}", "  PARM 2 1",
        "  DISZ 100", *([f"  {glass}"] if glass else []), "  DIAM 6 1 0 0 1 \"\"",
        "SURF 2", "  TYPE STANDARD", "  CURV 0", "  DISZ 0", "  DIAM 6 1 0 0 1 \"\""]) + "\n"


def test_paraxial_surface_is_an_ideal_lens(tmp_path):
    """PARAXIAL f = 50 mm, object at 100 mm: EFL 50, the image at 100 mm is a point (closed
    form 1/v = 1/f - 1/s), for every field; written back as PARAXIAL."""
    from deeplens.analysis.spot import spot_diagram
    from deeplens.optics.surfaces import IdealLens

    lens = read_zmx(write(tmp_path, _paraxial_file()))
    assert isinstance(lens.surfaces[0], IdealLens)
    p = paraxial(lens)
    assert float(p.efl) == pytest.approx(50.0, rel=1e-12)
    assert float(p.image_distance) == pytest.approx(100.0, rel=1e-12)
    for field in (0.0, 5.0):
        s = spot_diagram(lens, field, 550.0, "hexapolar:4", pupil="paraxial")
        assert float(s.rms_radius) < 1e-9 and s.n_rays == s.n_launched
    write_zmx(lens, tmp_path / "back.zmx")
    assert "TYPE PARAXIAL" in (tmp_path / "back.zmx").read_text()
    assert lens_to_dict(read_zmx(tmp_path / "back.zmx")) == lens_to_dict(lens)


@pytest.mark.parametrize("f,glass,match", [
    ("0", "", r":17: SURF 1: a PARAXIAL surface needs a non-zero focal length"),
    ("50", "GLAS N-BK7 0 0 1.5 40", r"SURF 1: a PARAXIAL surface between glasses"),
])
def test_paraxial_surface_refusals(tmp_path, f, glass, match):
    with pytest.raises(ZemaxFileError, match=match):
        read_zmx(write(tmp_path, _paraxial_file(f, glass)))


def test_two_tilts_round_trip(tmp_path):
    """deeplens' R_y(b) R_x(a) is written as OpticStudio's x-then-y tilts that point the element
    the same way, and read back to the same tilts and rays."""
    lens = load_lens(JSON).double()
    with torch.no_grad():
        lens.misalignments[1].tilt_x.fill_(0.012)
        lens.misalignments[1].tilt_y.fill_(-0.02)
        lens.misalignments[1].dx.fill_(0.01)
    write_zmx(lens, tmp_path / "two.zmx")
    back = read_zmx(tmp_path / "two.zmx")
    m0, m1 = lens.misalignments[1], back.misalignments[1]
    for k in ("dx", "dy", "tilt_x", "tilt_y"):
        assert float(getattr(m1, k)) == pytest.approx(float(getattr(m0, k)), abs=1e-15), k
    text = (tmp_path / "two.zmx").read_text()
    assert "PARM 3 0.0" not in text and "PARM 4 0.0" not in text   # both tilts written
    pa, va = trace_points(lens, 7.0)
    pb, vb = trace_points(back, 7.0)
    assert torch.equal(va, vb) and bool(va.any())
    torch.testing.assert_close(pa[va], pb[vb], rtol=0, atol=1e-12)


def test_image_plane_on_the_last_flat_vertex(tmp_path):
    """A plano-convex lens focusing onto its own flat back face (image DISZ 0 after it): the
    sensor sits 1e-9 mm behind the face, with a warning; a curved last surface whose rim lies
    behind its vertex plane (convex towards the image) is refused (one lying wholly before it
    loads: test_zmx_set9_rules)."""
    # R = 25 mm front, n ~ 1.5168: the paraxial focus inside the glass at n R / (n - 1)
    n = 1.5168
    t = n * 25.0 / (n - 1.0)
    text = singlet(curv1=0.04, k=0.0, s1_type="STANDARD", s1_extra=(), t=t, curv2=0.0, bfl=0,
                   wav=(0.5875618,), pwav=1, aperture="ENPD 2",
                   glass="GLAS ___BLANK 1 0 1.5168 1e9 0 0 0 0 0 0", diam1=3.0)
    ln = line_of(text, "SURF 4")
    with pytest.warns(ZemaxWarning, match=f":{ln}: the image plane lies on the last"):
        lens = read_zmx(write(tmp_path, text))
    assert float(lens.d_sensor) == 1e-9
    assert abs(float(paraxial(lens).bfl)) < 1e-9    # the focus is on the face
    with pytest.raises(ZemaxFileError, match=f":{ln}: the image plane lies on the vertex of the "
                                             f"last surface, which is curved"):
        read_zmx(write(tmp_path, text.replace("CURV 0.0\n  DISZ 0\n", "CURV 0.001\n  DISZ 0\n", 1),
                       "curved.zmx"))


def test_unknown_lines_reported_once_per_keyword(tmp_path):
    """Editor-state records (SSID on every surface, AUTH, ...) are silent; an unknown keyword is
    one warning with its first line and count, not one per line."""
    text = singlet(extra_system=("AUTH someone", "FOOB 1", "FOOB 2", "FOOB 3"))
    text = text.replace("SURF 2\n", "SURF 2\n  SSID 7\n")
    ln = line_of(text, "FOOB 1")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        read_zmx(write(tmp_path, text))
    msgs = [str(x.message) for x in w]
    assert msgs == [f"{tmp_path / 't.zmx'}:{ln}: FOOB line not used by deeplens (ignored); "
                    f"3 such lines"]


@pytest.mark.parametrize("ftyp,aperture,obj,match", [
    ("FTYP 1 1 2 2 0 0 0", "ENPD 10", "INFINITY", r":7: FTYP: object-space telecentric "
                                                     r"\(second value 1\) with the object at infinity"),
    ("FTYP 0 1 2 2 0 0 0", "OBNA 0.1 0", "100", r":7: FTYP 0 \(angle\) fields with object-space "
                                                r"telecentric"),
    ("FTYP 1 1 2 2 0 0 0", "ENPD 10", "100", r":5: object-space telecentric .*\(OBNA\)"),
])
def test_telecentric_modes_refused(tmp_path, ftyp, aperture, obj, match):
    """Telecentric object space loads with an object at a finite distance, height fields and
    an OBNA aperture (tests/optics/io/test_zmx_corpus.py); otherwise the refusal names the line."""
    with pytest.raises(ZemaxFileError, match=match):
        read_zmx(write(tmp_path, singlet(ftyp=ftyp, aperture=aperture, obj=obj)))


def test_afocal_image_space_loads_the_same_prescription_with_a_located_warning(tmp_path):
    """FTYP's seventh value 1 (OpticStudio's afocal image space: aberrations reported as
    angles) changes no surface, pupil or field: the lens is the one read without the flag, with
    one warning at the FTYP line that names what deeplens does instead."""
    plain = read_zmx(write(tmp_path, singlet(ftyp="FTYP 0 0 2 2 0 0 0"), "plain.zmx"))
    with pytest.warns(ZemaxWarning) as rec:
        lens = read_zmx(write(tmp_path, singlet(ftyp="FTYP 0 0 2 2 0 0 1")))
    notes = [str(r.message) for r in rec if "afocal image space" in str(r.message)]
    assert notes == [f"{tmp_path / 't.zmx'}:7: FTYP: afocal image space (seventh value 1): "
                     "OpticStudio reports this system's aberrations as angles in image space; "
                     "deeplens reads the same prescription and images onto the image surface at "
                     "the file's distance (spots in mm there, not angles), and writes it so"]
    a, b = lens_to_dict(lens), lens_to_dict(plain)
    a.pop("name", None), b.pop("name", None)
    assert a == b


@pytest.mark.parametrize("line", ["OBSC 0 2.25 0", "CLAP 2.25 5 0"])
def test_central_obscuration_on_the_stop(tmp_path, line):
    """OBSC (or an annular CLAP) on the flat stop in front of a singlet: the stop is the entrance
    pupil, so exactly the pattern points with pupil radius >= 2.25/5 pass; written back as OBSC."""
    from deeplens.analysis.spot import spot_diagram
    from deeplens.optics.sampling import pupil_pattern

    text = singlet(aperture="FLOA").replace('  DISZ 2\n  DIAM 5 1 0 0 1 ""\n',
                                           f'  DISZ 2\n  DIAM 5 1 0 0 1 ""\n  {line}\n', 1)
    lens = read_zmx(write(tmp_path, text))
    stop = lens.surfaces[lens.stop_index]
    assert isinstance(stop, Aperture) and float(stop.obscuration) == 2.25
    s = spot_diagram(lens, 0.0, 550.0, "hexapolar:10", pupil="paraxial")
    r = torch.linalg.vector_norm(pupil_pattern("hexapolar:10"), dim=-1)
    assert s.n_rays == int((r >= 0.45).sum()) < s.n_launched
    write_zmx(lens, tmp_path / "back.zmx")
    assert "OBSC 0 2.25 0" in (tmp_path / "back.zmx").read_text()
    assert lens_to_dict(read_zmx(tmp_path / "back.zmx")) == lens_to_dict(lens)


def test_obscuration_on_a_lens_surface(tmp_path):
    """OBSC on a curved lens surface is that surface's obscuration (written back); on a flat
    surface between glass and air it is refused with its line."""
    text = singlet().replace('  DIAM 8 1 0 0 1 ""\nSURF 4', '  DIAM 8 1 0 0 1 ""\n  OBSC 0 1 0\nSURF 4')
    lens = read_zmx(write(tmp_path, text))
    assert [float(getattr(s, "obscuration", 0.0)) for s in lens.surfaces] == [0.0, 0.0, 1.0]
    write_zmx(lens, tmp_path / "back.zmx")
    assert lens_to_dict(read_zmx(tmp_path / "back.zmx")) == lens_to_dict(lens)
    flat = singlet(curv2=0.0).replace('  DIAM 8 1 0 0 1 ""\nSURF 4',
                                      '  DIAM 8 1 0 0 1 ""\n  OBSC 0 1 0\nSURF 4')
    ln = line_of(flat, "OBSC")
    with pytest.raises(ZemaxFileError, match=f":{ln}: SURF 3: OBSC, a central obscuration on a "
                                             f"flat surface between two media"):
        read_zmx(write(tmp_path, flat, "flat.zmx"))


def test_paraxial_image_height_at_a_finite_object(tmp_path):
    """FTYP 2 at a finite conjugate: an ideal lens f = 50 mm at 1:1 (object at 100 mm, m = -1):
    image height 5 mm is object height 5 mm, seen from the stop at the lens under
    atan(5 / 100); and the chief ray of that angle lands at -5 mm on the paraxial image."""
    from deeplens.analysis.spot import chief_ray

    text = _paraxial_file().replace("FTYP 0 0 2 1 0 0 0", "FTYP 2 0 2 1 0 0 0")
    lens = read_zmx(write(tmp_path, text))
    want = math.degrees(math.atan(5.0 / 100.0))
    assert lens.spec.fields_deg == pytest.approx([0.0, want], rel=1e-12)
    y, _ = chief_ray(lens, lens.spec.fields_deg[1], 550.0, image_plane="paraxial")
    assert abs(float(y)) == pytest.approx(5.0, rel=1e-9)


def test_glass_air_is_air(tmp_path):
    text = singlet().replace('SURF 3\n  TYPE STANDARD\n', 'SURF 3\n  TYPE STANDARD\n  GLAS AIR\n', 1)
    assert "GLAS AIR" in text
    lens = read_zmx(write(tmp_path, text))
    assert lens_to_dict(lens) == lens_to_dict(read_zmx(write(tmp_path, singlet(), "plain.zmx")))


def test_multi_configuration_is_reported(tmp_path):
    text = singlet(extra_system=("MNUM 3 2",))
    ln = line_of(text, "MNUM")
    with pytest.warns(ZemaxWarning, match=f":{ln}: multi-configuration file \\(3 configurations\\)"
                                          f": the surface data as saved \\(configuration 2"):
        read_zmx(write(tmp_path, text))


def _stop_on_the_lens(sqap="SQAP 3.1 4.1 0", aperture="ENPD 10"):
    """The singlet with its stop on the first lens surface (SURF 2) carrying ``sqap``."""
    text = singlet(aperture=aperture).replace("SURF 1\n  STOP\n", "SURF 1\n", 1)
    return text.replace("SURF 2\n", "SURF 2\n  STOP\n", 1).replace(
        '  DIAM 8.0 1 0 0 1 ""\nSURF 3', f'  DIAM 8.0 1 0 0 1 ""\n  {sqap}\nSURF 3', 1)


def test_rectangular_opening_on_a_lens_stop_vignettes_the_pupil(tmp_path):
    """SQAP on a stop that is a lens surface: the pupil keeps the size the system aperture
    gives it (ENPD 10; under FLOA the stop's DIAM, 8 mm, as OpticStudio floats it) and the
    rectangle clips it; the stop is the entrance pupil (nothing before it bends the rays), so
    exactly the pattern points with |x| <= 3.1 and |y| <= 4.1 mm pass."""
    from deeplens.analysis.spot import spot_diagram
    from deeplens.optics.sampling import pupil_pattern
    from deeplens.optics.surfaces.base import clear_rect_of

    for aperture, radius in (("ENPD 10", 5.0), ("FLOA", 8.0)):
        text = _stop_on_the_lens(aperture=aperture)
        assert text.count("STOP") == 1 and "SQAP 3.1 4.1 0" in text
        lens = read_zmx(write(tmp_path, text))
        assert clear_rect_of(lens.surfaces[lens.stop_index]) == (3.1, 4.1)
        assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(2 * radius,
                                                                              rel=1e-12)
        s = spot_diagram(lens, 0.0, 550.0, "hexapolar:10", pupil="paraxial")
        xy = pupil_pattern("hexapolar:10") * radius
        inside = (xy[:, 0].abs() <= 3.1) & (xy[:, 1].abs() <= 4.1)
        assert s.n_rays == int(inside.sum()) < s.n_launched, aperture


def test_decentred_opening_on_a_flat_mirror(tmp_path):
    """SQAP with OBDC on a flat fold mirror (a dove or roof prism's face): the flat surface
    carries the rectangle moved by the decenter; a ray through the opening's centre passes,
    one just outside its edge on either side is blocked; written back with its SQAP and OBDC."""
    from deeplens.optics.surfaces.base import clear_rect_of

    mirror = ["SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ -20", "  GLAS MIRROR",
              '  DIAM 20 1 0 0 1 ""', "  SQAP 2 3 0", "  OBDC 0 5", "SURF 5"]
    text = singlet(bfl=30.0).replace("SURF 4\n", "\n".join(mirror) + "\n", 1)
    lens = read_zmx(write(tmp_path, text))
    m = lens.surfaces[-1]
    assert clear_rect_of(m) == (2.0, 3.0) and [float(v) for v in m.clear_decenter] == [0, 5]
    xy = torch.tensor([[0.0, 5.0], [0.0, 1.9], [0.0, 8.1], [2.1, 5.0]], dtype=torch.float64)
    assert m.opening.contains(xy[:, 0], xy[:, 1]).tolist() == [True, False, False, False]
    write_zmx(lens, tmp_path / "back.zmx")
    back = (tmp_path / "back.zmx").read_text()
    assert "  SQAP 2.0 3.0 0\n  OBDC 0.0 5.0\n" in back
    assert lens_to_dict(read_zmx(tmp_path / "back.zmx")) == lens_to_dict(lens)


def test_afocal_system_with_a_finite_object_takes_object_heights_and_an_na(tmp_path):
    """A plane-parallel plate (no power: an infinite focal length) with the object 100 mm before
    the stop: object heights (FTYP 1) and an object-space NA (OBNA) need only the entrance
    pupil (the stop, nothing before it), so they load: EPD = 2 * 100 * tan(asin 0.1), the 5 mm
    field under atan(5 / 100); image heights (FTYP 2) need a focal length: refused at FTYP."""
    plate = dict(curv1=0.0, curv2=0.0, s1_type="STANDARD", s1_extra=(), k=0.0, obj="100",
                 aperture="OBNA 0.1 0")
    lens = read_zmx(write(tmp_path, singlet(ftyp="FTYP 1 0 2 2 0 0 0", **plate)))
    assert math.isinf(float(paraxial(lens).efl))
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(
        200.0 * math.tan(math.asin(0.1)), rel=1e-12)
    assert [abs(f) for f in lens.spec.fields_deg] == pytest.approx(
        [0.0, math.degrees(math.atan(0.05))], rel=1e-12)
    text = singlet(ftyp="FTYP 2 0 2 2 0 0 0", **plate)
    with pytest.raises(ZemaxFileError, match=f":{line_of(text, 'FTYP')}: the system is afocal"):
        read_zmx(write(tmp_path, text, "img.zmx"))
