"""The deeplens JSON lens format: exact round trips, EPD / F-number apertures, and a clear
error (file name, JSON path, what was expected) for every kind of bad input."""

import json
import math
import re
from pathlib import Path

import pytest
import torch

from deeplens.optics.paraxial import paraxial
from deeplens.optics.io import LensFileError, lens_from_dict, lens_to_dict, load_lens, save_lens
from deeplens.optics.surfaces import (Aperture, Asphere, BSpline, CoordinateBreak, Cylinder,
                                      IdealLens, Plane,
                                      XYPolynomial)

ROOT = Path(__file__).resolve().parents[3]
SHIPPED = sorted((ROOT / "data" / "lenses").glob("*.json"))


def all_types_dict(aperture=None, object_distance="inf"):
    """A lens with every surface type, awkward floats, misalignment, in canonical form (exactly
    what ``lens_to_dict`` writes), so that ``lens_to_dict(lens_from_dict(d)) == d``."""
    return {
        "format": "deeplens-lens", "version": 1, "name": "every surface type",
        "units": {"length": "mm", "wavelength": "nm"},
        "object": {"distance_mm": object_distance, "medium": "AIR"},
        "aperture": aperture or {"type": "stop"},
        "fields_deg": [0.0, 0.1 + 0.2, 5.0],
        "wavelengths_nm": [486.1327, 587.5618, 656.2725],
        "primary_wavelength_nm": 587.5618,
        "stop": 2,
        "surfaces": [
            {"type": "asphere", "semi_diameter_mm": 5.0, "curvature_per_mm": 1 / 47.3,
             "conic": -0.5 - 1e-17, "aspheric": [1e-5 / 3, -2.000000000000001e-7, 3e-9],
             "distance_mm": 0.0, "material": "N-BK7"},
            {"type": "plane", "semi_diameter_mm": 5.0, "distance_mm": 3.0000000000000004,
             "material": "AIR"},
            {"type": "aperture", "semi_diameter_mm": 3.0, "distance_mm": 2.0, "material": "AIR"},
            {"type": "xy_polynomial", "semi_diameter_mm": 4.0, "b": 0.001,
             "coefficients": [0.0, 1e-4, -2e-4, 0.003, 1e-4 / 7, 0.002],
             "distance_mm": 2.0, "material": "1.4917/57.44"},
            {"type": "bspline", "semi_diameter_mm": 4.0,
             "coefficients": [[0.01 * ((i * 7 + j * 3) % 5) / 3 for j in range(6)]
                              for i in range(5)],
             "distance_mm": 2.0, "material": "AIR"},
            {"type": "aperture", "semi_diameter_mm": 2.5, "shape": "rect",
             "half_width_x_mm": 2.0, "half_width_y_mm": 1.5, "distance_mm": 1.0,
             "material": "AIR"},
            {"type": "ideal_lens", "semi_diameter_mm": 4.0, "focal_length_mm": 50.0 / 3,
             "distance_mm": 1.0, "material": "AIR"},
            {"type": "cylinder", "semi_diameter_mm": 2.5, "curvature_per_mm": 1 / 40.0,
             "conic": -0.3, "coefficients": [1e-4 / 3], "half_width_x_mm": 2.0,
             "half_width_y_mm": 1.5, "distance_mm": 1.0, "material": "AIR"},
            {"type": "coordinate_break", "semi_diameter_mm": 1.0, "dx_mm": 0.0,
             "dy_mm": 0.01 / 3, "tilt_x_rad": 1e-3 / 7, "tilt_y_rad": 0.0, "tilt_z_rad": 0.0,
             "distance_mm": 1.0, "material": "AIR"},
        ],
        "sensor": {"distance_mm": 20.0, "semi_diameter_mm": 5.0},
        "elements": [[0, 1], [2, 2], [3, 4], [5, 5], [6, 6], [7, 7], [8, 8]],
        "misalignment": [
            {"dx_mm": 0.01, "dy_mm": 0.0, "tilt_x_rad": 1e-3 / 3, "tilt_y_rad": 0.0},
            {"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0},
            {"dx_mm": 0.0, "dy_mm": -0.02, "tilt_x_rad": 0.0, "tilt_y_rad": math.pi * 1e-3},
            {"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0},
            {"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0},
            {"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0},
            {"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0},
        ],
    }


def tensors(lens):
    """Every parameter and buffer as raw bytes (bitwise comparison; -0.0 != 0.0)."""
    out = {}
    for k, t in lens.state_dict().items():
        t = t.detach().cpu().contiguous()
        out[k] = (t.dtype, tuple(t.shape), t.numpy().tobytes())
    return out


def assert_roundtrip(path: Path, tmp_path: Path) -> dict:
    """load -> save -> load: equal dicts, bitwise-equal tensors, same media; returns the dict."""
    a = load_lens(path)
    out = tmp_path / ("rt_" + path.name)
    save_lens(a, out)
    written = json.loads(out.read_text())
    b = load_lens(out)
    assert written == lens_to_dict(a)
    assert lens_to_dict(b) == lens_to_dict(a)
    ta, tb = tensors(a), tensors(b)
    assert ta.keys() == tb.keys()
    for k in ta:
        assert ta[k] == tb[k], f"{path.name}: tensor {k} changed in the round trip"
    assert [m.to_spec() for m in a.materials] == [m.to_spec() for m in b.materials]
    assert [type(s) for s in a.surfaces] == [type(s) for s in b.surfaces]
    assert not list(tmp_path.glob("*.tmp")), "save_lens left its temporary file behind"
    return written


# ------------------------------------------------------------------ round trips
def test_shipped_lenses_exist():
    assert {p.stem for p in SHIPPED} >= {"double_gauss", "edof_achromat", "nikon_z35_f1.8_x10",
                                         "thorlabs_acl5040u", "thorlabs_la1131"}


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_shipped_lens_roundtrip_exact(path, tmp_path):
    written = assert_roundtrip(path, tmp_path)
    # save(load(f)) reproduces f
    assert written == json.loads(path.read_text())


@pytest.mark.parametrize("object_distance", ["inf", 512.3456789])
def test_all_surface_types_roundtrip_exact(object_distance, tmp_path):
    d = all_types_dict(object_distance=object_distance)
    src = tmp_path / "all.json"
    src.write_text(json.dumps(d))
    lens = load_lens(src)
    assert [type(s) for s in lens.surfaces] == [Asphere, Plane, Aperture, XYPolynomial, BSpline,
                                                Aperture, IdealLens, Cylinder, CoordinateBreak]
    assert lens.surfaces[5].shape == "rect"
    assert float(lens.misalignments[2].tilt_y) == math.pi * 1e-3
    assert float(lens.misalignments[0].tilt_x) == 1e-3 / 3
    assert float(lens.surfaces[0].a[0]) == 1e-5 / 3
    assert lens.spec.object_distance_mm == (math.inf if object_distance == "inf"
                                            else object_distance)
    assert lens_to_dict(lens) == d
    assert assert_roundtrip(src, tmp_path) == d


@pytest.mark.parametrize("aperture", [{"type": "epd", "value": 2.2}, {"type": "fno", "value": 9.5}],
                         ids=["epd", "fno"])
@pytest.mark.parametrize("object_distance", ["inf", 300.0])
def test_epd_fno_lens_roundtrip_exact(aperture, object_distance, tmp_path):
    d = all_types_dict(aperture, object_distance)
    src = tmp_path / "ap.json"
    src.write_text(json.dumps(d))
    first = lens_to_dict(load_lens(src))
    # only the stop's size changes (it is computed from the aperture spec) ...
    assert first["aperture"] == aperture
    assert first["surfaces"][2]["semi_diameter_mm"] != d["surfaces"][2]["semi_diameter_mm"]
    first["surfaces"][2]["semi_diameter_mm"] = d["surfaces"][2]["semi_diameter_mm"]
    assert first == d
    # ... and a saved file is a fixed point
    out = tmp_path / "saved.json"
    save_lens(load_lens(src), out)
    assert assert_roundtrip(out, tmp_path) == json.loads(out.read_text())


def test_save_writes_exact_floats(tmp_path):
    d = all_types_dict()
    lens = lens_from_dict(d)
    lens.distances[1].data.fill_(0.1 + 0.2)
    save_lens(lens, tmp_path / "x.json")
    text = (tmp_path / "x.json").read_text()
    assert "0.30000000000000004" in text
    assert float(load_lens(tmp_path / "x.json").distances[1]) == 0.1 + 0.2


# ------------------------------------------------------------------ EPD / F-number
@pytest.mark.parametrize("epd", [3.0, 5.0, 7.25])
def test_epd_aperture_sets_paraxial_entrance_pupil(epd):
    d = json.loads((ROOT / "data/lenses/double_gauss.json").read_text())
    native = float(paraxial(lens_from_dict(d)).entrance_pupil_diameter)
    d["aperture"] = {"type": "epd", "value": epd}
    lens = lens_from_dict(d)
    p = paraxial(lens)
    assert abs(native - epd) > 0.1  # the test would notice an ignored aperture spec
    assert float(p.entrance_pupil_diameter) == pytest.approx(epd, rel=1e-12)


@pytest.mark.parametrize("fno", [2.8, 4.0, 8.0])
def test_fno_aperture_sets_paraxial_f_number(fno):
    d = json.loads((ROOT / "data/lenses/double_gauss.json").read_text())
    native = float(paraxial(lens_from_dict(d)).fno)
    d["aperture"] = {"type": "fno", "value": fno}
    d["object"]["distance_mm"] = 1000.0
    p = paraxial(lens_from_dict(d))
    assert abs(native - fno) > 0.1
    assert float(p.fno) == pytest.approx(fno, rel=1e-12)
    assert float(p.efl / p.entrance_pupil_diameter) == pytest.approx(fno, rel=1e-12)


def test_epd_sizes_a_stop_on_a_lens_surface(tmp_path):
    d = json.loads((ROOT / "data/lenses/thorlabs_la1131.json").read_text())
    d["aperture"] = {"type": "epd", "value": 10.0}  # its stop is surface 0, a lens surface
    p = tmp_path / "la.json"
    p.write_text(json.dumps(d))
    lens = load_lens(p)
    assert not isinstance(lens.stop, Aperture)
    # the stop is the first surface: it is its own entrance pupil, radius EPD / 2
    assert float(lens.stop.semi_diameter) == pytest.approx(5.0, rel=1e-12)
    assert float(paraxial(lens).entrance_pupil_diameter) == pytest.approx(10.0, rel=1e-12)


def test_fno_of_a_negative_lens_sizes_the_pupil_by_its_magnitude(tmp_path):
    """An image-space F-number on a diverging lens: ``EPD = |EFL| / F#`` (as OpticStudio and
    optiland; the Zemax guide, Object set-ups).  A plano-concave N-BK7 lens (curved face first)
    has ``EFL = 1 / ((n - 1) c)``; the stop 2 mm behind its flat face is met by the ray parallel
    to the axis at ``y_s = 1 + (n - 1)(-c)(3 / n + 2)`` per unit height, so its semi-diameter is
    ``y_s EPD / 2``.  Before, this was refused as needing a positive focal length."""
    d = {"surfaces": [
        {"type": "asphere", "distance_mm": 0.0, "semi_diameter_mm": 5.0, "curvature_per_mm": -0.05,
         "material": "N-BK7"},
        {"type": "plane", "distance_mm": 3.0, "semi_diameter_mm": 5.0},
        {"type": "aperture", "distance_mm": 2.0, "semi_diameter_mm": 2.0}],
        "stop": 2, "sensor": {"distance_mm": 10.0}, "aperture": {"type": "fno", "value": 4.0}}
    p = tmp_path / "neg.json"
    p.write_text(json.dumps(d))
    lens = load_lens(p)
    n = float(lens.materials[1].n(torch.tensor(587.5618, dtype=torch.float64)))
    efl = 1.0 / ((n - 1.0) * -0.05)
    pd = paraxial(lens)
    assert float(pd.efl) == pytest.approx(efl, rel=1e-12)
    assert float(pd.entrance_pupil_diameter) == pytest.approx(-efl / 4.0, rel=1e-12)
    assert float(pd.fno) == pytest.approx(4.0, rel=1e-12)
    y_s = 1.0 + (n - 1.0) * 0.05 * (3.0 / n + 2.0)
    assert float(lens.stop.semi_diameter) == pytest.approx(y_s * -efl / 8.0, rel=1e-12)


# ------------------------------------------------------------------ bad JSON files
def _del(*path):
    def f(d):
        obj = d
        for k in path[:-1]:
            obj = obj[k]
        del obj[path[-1]]
    return f


def _set(value, *path):
    def f(d):
        obj = d
        for k in path[:-1]:
            obj = obj[k]
        obj[path[-1]] = value
    return f


BAD = [
    # (id, mutation, regex the message must contain after "<file>: ")
    ("missing curvature", _del("surfaces", 0, "curvature_per_mm"),
     r"surfaces\[0\]\.curvature_per_mm: missing required field"),
    ("missing semi-diameter", _del("surfaces", 3, "semi_diameter_mm"),
     r"surfaces\[3\]\.semi_diameter_mm: missing required field"),
    ("missing distance", _del("surfaces", 1, "distance_mm"),
     r"surfaces\[1\]\.distance_mm: missing required field"),
    ("missing surfaces", _del("surfaces"), r"surfaces: expected a non-empty list"),
    ("missing sensor", _del("sensor"), r"sensor: missing"),
    ("missing xy coefficients", _del("surfaces", 3, "coefficients"),
     r"surfaces\[3\]\.coefficients: missing required field"),
    ("missing rect half-width", _del("surfaces", 5, "half_width_y_mm"),
     r"surfaces\[5\]\.half_width_y_mm: missing required field"),
    ("curvature as a string", _set("0.02", "surfaces", 0, "curvature_per_mm"),
     r"surfaces\[0\]\.curvature_per_mm: expected a finite number, got '0\.02'"),
    ("curvature null", _set(None, "surfaces", 0, "curvature_per_mm"),
     r"surfaces\[0\]\.curvature_per_mm: expected a finite number, got None"),
    ("curvature bool", _set(True, "surfaces", 0, "curvature_per_mm"),
     r"surfaces\[0\]\.curvature_per_mm: expected a finite number, got True"),
    ("curvature 'inf'", _set("inf", "surfaces", 0, "curvature_per_mm"),
     r"surfaces\[0\]\.curvature_per_mm: expected a finite number"),
    ("aspheric item", _set([1e-6, "x"], "surfaces", 0, "aspheric"),
     r"surfaces\[0\]\.aspheric\[1\]: expected a finite number, got 'x'"),
    ("aspheric scalar", _set(1e-6, "surfaces", 0, "aspheric"),
     r"surfaces\[0\]\.aspheric: expected a list of numbers"),
    ("bspline ragged", _set([[0.0] * 5, [0.0] * 4, [0.0] * 5, [0.0] * 5], "surfaces", 4,
                            "coefficients"), r"surfaces\[4\]\.coefficients: rows"),
    ("bspline item", _set([[0.0] * 5] * 3 + [[0.0] * 4 + ["a"]], "surfaces", 4, "coefficients"),
     r"surfaces\[4\]\.coefficients\[3\]\[4\]: expected a finite number, got 'a'"),
    ("xy count", _set([0.0] * 4, "surfaces", 3, "coefficients"),
     r"surfaces\[3\]: .*\(J\+1\)\(J\+2\)/2.*got 4"),
    ("surface not an object", _set("asphere", "surfaces", 2),
     r"surfaces\[2\]: expected an object, got str"),
    ("unknown surface type", _set("sphr", "surfaces", 2, "type"),
     r"surfaces\[2\]\.type: unknown surface type 'sphr'; did you mean 'sphere'\? \(known: "
     r"aperture, asphere, biconic, binary1, binary2, bspline, conic, coordinate_break, cylinder, "
     r"extended_odd_asphere, extended_polynomial, fresnel, grating, "
     r"grid_sag, hologram, ideal_lens, ideal_lens_xy, irregular, lenslet_array, odd_asphere, plane, qtype, sphere, toroid, xy_polynomial, "
     r"zernike_fringe_phase, zernike_fringe_sag, "
     r"zernike_sag\)"),
    ("misspelt field", _set(-1.0, "surfaces", 0, "conic_constant"),
     r"surfaces\[0\]\.conic_constant: unknown field; did you mean 'conic'\?"),
    ("misspelt top-level field", _set([0.0], "field_deg"),
     r"field_deg: unknown field; did you mean 'fields_deg'\?"),
    ("roc and curvature", _set(50.0, "surfaces", 0, "roc_mm"),
     r"surfaces\[0\]\.roc_mm: give curvature_per_mm or roc_mm, not both"),
    ("negative semi-diameter", _set(-5.0, "surfaces", 1, "semi_diameter_mm"),
     r"surfaces\[1\]\.semi_diameter_mm: must be > 0 mm, got -5\.0"),
    ("aperture shape", _set("hexagon", "surfaces", 2, "shape"),
     r"surfaces\[2\]\.shape: expected 'circle', 'rect' or 'ellipse', got 'hexagon'"),
    ("unknown glass", _set("N-BK77", "surfaces", 0, "material"),
     r"surfaces\[0\]\.material: unknown glass 'N-BK77'; closest known: N-BK7"),
    ("material number", _set(1.5, "surfaces", 0, "material"),
     r"surfaces\[0\]\.material: expected a string, got 1\.5"),
    ("bad model glass", _set("1.5/-3", "surfaces", 0, "material"),
     r"surfaces\[0\]\.material: malformed material '1\.5/-3'"),
    ("unknown object medium", _set("WATER!", "object", "medium"),
     r"object\.medium: unknown glass 'WATER!'"),
    ("no stop", _del("stop"), r"stop: missing: the lens has no aperture stop"),
    ("stop null", _set(None, "stop"), r"stop: missing: the lens has no aperture stop"),
    ("stop float", _set(2.0, "stop"), r"stop: expected an integer, got 2\.0"),
    ("stop out of range", _set(9, "stop"), r"stop: 9 is not a surface index \(0\.\.8\)"),
    ("version 2", _set(2, "version"), r"version: unsupported lens-file version 2"),
    ("version 0", _set(0, "version"), r"version: unsupported lens-file version 0"),
    ("version string", _set("1", "version"), r"version: expected an integer, got '1'"),
    ("format", _set("zemax", "format"), r"format: expected 'deeplens-lens', got 'zemax'"),
    ("length in inches", _set("in", "units", "length"),
     r"units\.length: unsupported unit 'in'.*lengths in mm"),
    ("wavelength in micrometres unit", _set("um", "units", "wavelength"),
     r"units\.wavelength: unsupported unit 'um'.*wavelengths in nm"),
    ("units not an object", _set("mm", "units"), r"units: expected an object, got str"),
    ("wavelength in micrometres", _set([0.5876], "wavelengths_nm"),
     r"wavelengths_nm: deeplens takes wavelengths in nanometres; got 0\.5876 .*micrometres\? "
     r"use 587\.6"),
    ("primary wavelength in micrometres", _set(0.5876, "primary_wavelength_nm"),
     r"primary_wavelength_nm: deeplens takes wavelengths in nanometres; got 0\.5876"),
    ("wavelength outside glass data", _set([587.5618, 2600.0], "wavelengths_nm"),
     r"wavelengths_nm: wavelength 2600 nm is outside the valid range 300.2500 nm of material "
     r"'N-BK7' \(used at surfaces\[0\]\.material\)"),
    ("primary wavelength outside glass data", _set(250.0, "primary_wavelength_nm"),
     r"primary_wavelength_nm: wavelength 250 nm is outside the valid range 300.2500 nm of "
     r"material 'N-BK7'"),
    ("no wavelengths", _set([], "wavelengths_nm"), r"wavelengths_nm: expected at least one"),
    ("wavelength scalar", _set(587.6, "wavelengths_nm"),
     r"wavelengths_nm: expected a list of numbers, got 587\.6"),
    ("field over 90", _set([0.0, 95.0], "fields_deg"),
     r"fields_deg: field angles must be finite and within \(-90, 90\) degrees, got 95\.0"),
    ("no fields", _set([], "fields_deg"), r"fields_deg: at least one field angle"),
    ("aperture type", _set({"type": "na", "value": 0.1}, "aperture"),
     r"aperture\.type: expected 'stop', 'epd' .* or 'fno' .*, got 'na'"),
    ("aperture value missing", _set({"type": "epd"}, "aperture"),
     r"aperture\.value: missing required field"),
    ("aperture value negative", _set({"type": "fno", "value": -2.0}, "aperture"),
     r"aperture\.value: the fno must be > 0, got -2\.0"),
    ("object distance zero", _set(0.0, "object", "distance_mm"),
     r"object\.distance_mm: the object distance must be > 0 mm"),
    ("object distance string", _set("far", "object", "distance_mm"),
     r"object\.distance_mm: expected a finite number or \"inf\", got 'far'"),
    ("sensor distance", _set(-1.0, "sensor", "distance_mm"),
     r"sensor\.distance_mm: the sensor distance must be > 0 mm, got -1\.0"),
    ("sensor semi-diameter", _set(0.0, "sensor", "semi_diameter_mm"),
     r"sensor\.semi_diameter_mm: must be > 0 mm"),
    ("elements not a list", _set("all", "elements"),
     r"elements: expected a list of \[first, last\] surface-index pairs"),
    ("elements bad pair", _set([[0, 1], [2, "x"], [3, 4], [5, 5]], "elements"),
     r"elements\[1\]: expected \[first, last\] surface indices, got \[2, 'x'\]"),
    ("elements gap", _set([[0, 1], [3, 4], [5, 5]], "elements"),
     r"elements .* must cover surfaces 0\.\.8 exactly once"),
    ("misalignment count", _set([{"dx_mm": 0.1}], "misalignment"),
     r"misalignment: expected a list of 7 entries \(one per element\)"),
    ("misalignment value", _set("0.1", "misalignment", 0, "dx_mm"),
     r"misalignment\[0\]\.dx_mm: expected a finite number, got '0\.1'"),
    ("misalignment field", _set(0.1, "misalignment", 1, "tilt_z_rad"),
     r"misalignment\[1\]\.tilt_z_rad: unknown field"),
    ("name not a string", _set(5, "name"), r"name: expected a string, got 5"),
    # geometry checked by Lens (the message names the surfaces)
    ("surfaces cross", _set(0.2, "surfaces", 1, "distance_mm"),
     r"surfaces 0 and 1 cross: .*surface 1 lies .* before surface 0"),
    ("negative gap", _set(-1.0, "surfaces", 4, "distance_mm"),
     r"distance before surface 4 is negative \(-1 mm\)"),
    # beside a stop a negative distance is allowed (a stop inside a lens's sag), but the lens
    # surfaces around it keep their order
    ("negative gap across a stop", _set(-3.0, "surfaces", 3, "distance_mm"),
     r"distance from surface 1 to surface 3 \(across the stop between them\) is negative "
     r"\(-1 mm\)"),
    ("semi-diameter beyond the conic", _set(100.0, "surfaces", 0, "conic"),
     r"surface 0 \(Asphere\): semi-diameter 5 mm lies beyond the domain of the conic "
     r"\(R = 47\.3 mm, k = 100\): the sag is only defined for r < 4\.706"),
]


@pytest.mark.parametrize("mutate,expected", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_json_field_is_named(mutate, expected, tmp_path):
    d = all_types_dict()
    mutate(d)
    p = tmp_path / "bad_lens.json"
    p.write_text(json.dumps(d))
    with pytest.raises(LensFileError) as e:
        load_lens(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: "), msg
    assert re.search(expected, msg), f"{expected!r} not in {msg!r}"


def test_valid_base_dict_loads():
    # the mutations above start from a valid lens: each error is the mutation's
    lens_from_dict(all_types_dict())


def test_invalid_json_names_the_line(tmp_path):
    text = json.dumps(all_types_dict(), indent=1).splitlines()
    k = next(i for i, line in enumerate(text) if '"stop": 2,' in line)
    text[k] = text[k].rstrip(",")  # a missing comma: the error is on the next line
    p = tmp_path / "broken.json"
    p.write_text("\n".join(text))
    with pytest.raises(LensFileError, match=rf"broken\.json:{k + 2}:\d+: invalid JSON at line "
                                            rf"{k + 2}, column \d+: Expecting ',' delimiter"):
        load_lens(p)


@pytest.mark.parametrize("text,expected", [
    ("", r"empty\.json:1:1: invalid JSON at line 1"),
    ("[1, 2]", r"empty\.json: \(top level\): expected a JSON object, got list"),
    ('{"surfaces": [], "stop": 0}', r"empty\.json: surfaces: expected a non-empty list"),
    ('{"stop": 0, "surfaces": [{"type": "plane", "distance_mm": NaN, "semi_diameter_mm": 1}]}',
     r"empty\.json: surfaces\[0\]\.distance_mm: expected a finite number, got nan"),
])
def test_degenerate_json(text, expected, tmp_path):
    p = tmp_path / "empty.json"
    p.write_text(text)
    with pytest.raises(LensFileError, match=expected):
        load_lens(p)


def test_missing_and_unsupported_files(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"lens file not found: .*nope\.json"):
        load_lens(tmp_path / "nope.json")
    z = tmp_path / "lens.len"   # OSLO: not read (.zmx, .seq are: test_zmx.py, test_codev.py)
    z.write_bytes("VERS 1\n".encode("utf-16"))
    with pytest.raises(LensFileError, match=r"lens\.len: unsupported lens file type '\.len'"):
        load_lens(z)
    u = tmp_path / "utf16.json"
    u.write_bytes(json.dumps(all_types_dict()).encode("utf-16"))
    with pytest.raises(LensFileError, match=r"utf16\.json: not a UTF-8 text file"):
        load_lens(u)


def test_errors_are_value_errors_and_no_nan_reaches_the_lens(tmp_path):
    # LensFileError is a ValueError, so callers can catch either
    assert issubclass(LensFileError, ValueError)
    # a lens that loads has only finite parameters
    lens = lens_from_dict(all_types_dict())
    for k, t in lens.state_dict().items():
        assert torch.isfinite(t).all(), k


# ------------------------------------------------------------------ Lens / LensSpec validation
def test_lens_constructor_validation_behind_the_file_reader():
    from deeplens.optics.lens import Lens, LensSpec
    from deeplens.optics.materials import get_material

    def make(spec=None, sensor_sd=None):
        return Lens([Asphere(0.02, 5.0), Plane(5.0), Aperture(3.0)],
                    [get_material(m) for m in ("AIR", "N-SF5", "AIR", "AIR")],
                    [0.0, 3.0, 2.0], 20.0, 2, sensor_sd, spec)

    make(LensSpec(wavelengths_nm=[486.1327, 656.2725]), 4.0)
    with pytest.raises(ValueError, match=r"lens wavelengths: wavelength 350 nm is outside the "
                                         r"valid range 370.2500 nm of material 'N-SF5' \(the "
                                         r"medium after surface 0\)"):
        make(LensSpec(wavelengths_nm=[350.0, 587.6]))
    with pytest.raises(ValueError, match=r"lens wavelengths: .*nanometres; got 0\.5876"):
        make(LensSpec(wavelengths_nm=[0.5876]))
    with pytest.raises(ValueError, match=r"field angles must be finite and within \(-90, 90\)"):
        LensSpec(fields_deg=[0.0, 90.0])
    with pytest.raises(ValueError, match=r"at least one field angle"):
        LensSpec(fields_deg=[])
    with pytest.raises(ValueError, match=r"sensor semi-diameter must be a positive number of mm"):
        make(sensor_sd=-1.0)
    with pytest.raises(ValueError, match=r"the lens has no aperture stop"):
        Lens([Plane(5.0)], [get_material("AIR")] * 2, [0.0], 10.0, None)


# ---------------------------------------------------------------- issue 12, defect 6
def test_every_registered_surface_type_round_trips():
    """Regression (issue 12, defect 6): a lens with an ``IdealLens`` was written to JSON but
    could not be read back ("unknown surface type 'ideal_lens'"): the reader listed the types by
    hand.  Every type in the registry must appear in the all-types lens, which round-trips."""
    from deeplens.optics.surfaces import SURFACE_TYPES

    d = all_types_dict()
    # the toroid (the cylinder's profile turned about an axis: a Zemax TOROIDAL with a finite
    # radius of rotation), added here so that the other tests keep their indices
    d["surfaces"].append({"type": "toroid", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": -1 / 40.0, "conic": 0.2,
                          "coefficients": [1e-4 / 7], "radius_of_rotation_mm": -70.0 / 3,
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([9, 9])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a diffraction grating on a conic (OpticStudio's DGRATING), likewise
    d["surfaces"].append({"type": "grating", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 90.0, "conic": -0.5, "lines_per_um": 0.3,
                          "order": -1, "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([10, 10])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a Q-type (Forbes) asphere (OpticStudio's QED_TYPE), likewise
    d["surfaces"].append({"type": "qtype", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": -1 / 70.0, "conic": 0.0, "norm_radius_mm": 2.6,
                          "q_coefficients": [1e-3 / 3, -2e-4], "q_kind": "qcon",
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([11, 11])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # an odd asphere (OpticStudio's ODDASPHE, or an EVENASPH with an r² term), likewise
    d["surfaces"].append({"type": "odd_asphere", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 60.0, "conic": -0.3,
                          "radial_coefficients": [1e-3 / 3, 0.0, -2e-5, 1e-6 / 7],
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([12, 12])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a biconic (OpticStudio's BICONICX), likewise
    d["surfaces"].append({"type": "biconic", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 70.0, "conic": -0.4,
                          "curvature_x_per_mm": -1 / 30.0, "conic_x": 0.3,
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([13, 13])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a Binary 2 diffractive surface (OpticStudio's BINARY_2), likewise
    d["surfaces"].append({"type": "binary2", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": -1 / 80.0, "conic": 0.2, "aspheric": [1e-5 / 3],
                          "norm_radius_mm": 2.5, "phase_coefficients": [-150.0, 2.0 / 3],
                          "order": 1, "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([14, 14])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a Zernike standard sag (OpticStudio's SZERNSAG), likewise
    d["surfaces"].append({"type": "zernike_sag", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 90.0, "conic": -0.2,
                          "even_coefficients": [1e-4 / 3, 0.0, 1e-6],
                          "norm_radius_mm": 2.6, "zernike_coefficients": [0.0, 1e-4, 0.0, 2e-3 / 3],
                          "zernike_extrapolate": 1, "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([15, 15])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a Zernike Fringe sag (OpticStudio's FZERNSAG), likewise
    d["surfaces"].append({"type": "zernike_fringe_sag", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": -1 / 95.0, "conic": 0.1,
                          "even_coefficients": [1e-4 / 7],
                          "norm_radius_mm": 2.7, "zernike_coefficients": [0.0, 0.0, 0.0, 1e-3 / 3],
                          "zernike_extrapolate": 0, "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([16, 16])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a grid sag (OpticStudio's GRID_SAG), likewise: a 3 x 4 grid (rows of rising y)
    d["surfaces"].append({"type": "grid_sag", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 85.0, "conic": -0.1,
                          "even_coefficients": [1e-4 / 3], "grid_spacing_mm": [1.75, 2.6],
                          "grid_decenter_mm": [0.1, -1 / 3],
                          "grid_sag_mm": [[0.0, 1e-3, 2e-3 / 3], [0.0, -1e-3 / 7, 0.0],
                                          [1e-4, 0.0, 0.0], [0.0, 0.0, 5e-4]],
                          "grid_dz_dx": [[0.0, 1e-4, 0.0]] * 4, "grid_dz_dy": [[0.0] * 3] * 4,
                          "grid_d2z_dxdy_per_mm": [[0.0, 0.0, 1e-5 / 3]] * 4,
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([17, 17])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # OpticStudio's Irregular surface (IRREGULA), likewise
    d["surfaces"].append({"type": "irregular", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 80.0, "conic": -0.3, "r_max_mm": 2.6,
                          "decenter_x_mm": 0.1, "decenter_y_mm": -1 / 3, "tilt_x_rad": 1e-3 / 3,
                          "tilt_y_rad": -2e-4, "z_spherical_mm": 1e-4 / 3,
                          "z_astigmatism_mm": -2e-4, "z_coma_mm": 1e-4 / 7,
                          "angle_rad": 0.3, "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([18, 18])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # an anamorphic ideal lens (OpticStudio's PARAX_XY), likewise
    d["surfaces"].append({"type": "ideal_lens_xy", "semi_diameter_mm": 2.5,
                          "power_x_per_mm": 0.0, "power_y_per_mm": 1 / 70.0,
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([19, 19])
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a two-point hologram (OpticStudio's HOLOGRM1/HOLOGRM2), likewise
    d["surfaces"].append({"type": "hologram", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 75.0, "conic": -0.2,
                          "point1_mm": [0.1, -1 / 3, -150.0], "point2_mm": [0.0, 0.2, 90.0],
                          "construction_wavelength_nm": 532.0, "order": -1, "kind": 1,
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([len(d["surfaces"]) - 1] * 2)
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a Fresnel surface (OpticStudio's FRESNELS: a plane with an even asphere's facets), likewise
    d["surfaces"].append({"type": "fresnel", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 75.0, "conic": -0.4,
                          "fresnel_coefficients": [1e-4 / 3, 0.0, 1e-6],
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([len(d["surfaces"]) - 1] * 2)
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # OpticStudio's Extended Polynomial on a conic (XPOLYNOM with CURV != 0), likewise
    d["surfaces"].append({"type": "extended_polynomial", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 80.0, "conic": -0.3, "norm_radius_mm": 2.5,
                          "polynomial_coefficients": [0.0, 1e-3 / 3, 2e-3, 0.0, -1e-3],
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([len(d["surfaces"]) - 1] * 2)
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a Zernike Fringe phase (OpticStudio's FZERNPHA: waves on a conic base), likewise
    d["surfaces"].append({"type": "zernike_fringe_phase", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 65.0, "conic": -0.4, "norm_radius_mm": 2.6,
                          "zernike_waves": [0.0, 0.1, 0.0, -1 / 3], "order": 1,
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([len(d["surfaces"]) - 1] * 2)
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a Binary 1 phase (OpticStudio's BINARY_1: x-y polynomial radians on a conic), likewise
    d["surfaces"].append({"type": "binary1", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 70.0, "conic": -0.2, "norm_radius_mm": 2.4,
                          "phase_terms_rad": [0.0, 3.0, -10.0, 0.0, -10.0], "order": 1,
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([len(d["surfaces"]) - 1] * 2)
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # a lenslet array (OpticStudio's US_ARRAY.DLL: identical conic lenslets), likewise
    d["surfaces"].append({"type": "lenslet_array", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 60.0, "conic": -0.3,
                          "lenslet_counts": [5, 3], "lenslet_widths_mm": [1.1, 5 / 3],
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([len(d["surfaces"]) - 1] * 2)
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    # an Extended Odd Asphere (OpticStudio's XOSPHERE: Σ A_i (r / R_n)^i on a conic), likewise
    d["surfaces"].append({"type": "extended_odd_asphere", "semi_diameter_mm": 2.5,
                          "curvature_per_mm": 1 / 75.0, "conic": -0.3, "norm_radius_mm": 2.2,
                          "rho_coefficients_mm": [0.0, 1e-3 / 3, -2e-4, 1e-5 / 7],
                          "distance_mm": 1.0, "material": "AIR"})
    d["elements"].append([len(d["surfaces"]) - 1] * 2)
    d["misalignment"].append({"dx_mm": 0.0, "dy_mm": 0.0, "tilt_x_rad": 0.0, "tilt_y_rad": 0.0})
    written = {s["type"] for s in d["surfaces"]}
    canonical = {name for name, cls in SURFACE_TYPES.items() if cls.type_name == name}
    assert canonical <= written, f"add {sorted(canonical - written)} to all_types_dict"
    lens = lens_from_dict(d)
    assert lens_to_dict(lens) == d
    assert lens_to_dict(lens_from_dict(json.loads(json.dumps(lens_to_dict(lens))))) == d


def test_ideal_lens_checkpoint_export_loads(tmp_path):
    """The exported lens of a checkpoint (save_lens) with an ideal lens loads back, with the
    same focal length bit for bit."""
    from deeplens.optics.surfaces import IdealLens

    lens = lens_from_dict(all_types_dict())
    save_lens(lens, tmp_path / "ideal.json")
    back = load_lens(tmp_path / "ideal.json")
    assert isinstance(back.surfaces[6], IdealLens)
    assert float(back.surfaces[6].focal) == 50.0 / 3


def test_surface_field_errors_are_structured(tmp_path):
    """Errors carry where they are (file, JSON path, surface index) as attributes, so callers
    (the table reader, the training set-up) never parse the message."""
    d = all_types_dict()
    d["surfaces"][6]["focal_length_mm"] = "long"
    with pytest.raises(LensFileError) as e:
        lens_from_dict(d, source="x.json")
    err = e.value
    assert (err.source, err.key, err.surfaces) == ("x.json", "surfaces[6].focal_length_mm", (6,))
    assert str(err) == "x.json: surfaces[6].focal_length_mm: expected a finite number, got 'long'"
    d = all_types_dict()
    d["surfaces"][1]["distance_mm"] = 0.5  # the plane now cuts into the asphere before it
    d["surfaces"][0]["curvature_per_mm"] = 1 / 10.0
    with pytest.raises(LensFileError) as e:
        lens_from_dict(d, source="x.json")
    assert e.value.surfaces == (0, 1) and "surfaces 0 and 1 cross" in e.value.message
