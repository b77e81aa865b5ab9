"""``TYPE IRREGULA`` (OpticStudio's Irregular surface) in ``.zmx`` files: the records as the User
Guide's parameter table gives them (``PARM 1-2`` decenter, ``3-4`` tilts in degrees, ``5-7`` Zs,
Za, Zc at the semi-diameter, ``8`` the angle), on a file built like OpticStudio's own sample
``Irregular surface.zmx`` (a stop, a conic lens, the irregular back face; the sample itself is
not redistributable); in mm and inches; ``.zmx -> Lens -> .zmx -> Lens``; with every PARM zero
the file reads as the same file with ``STANDARD``; refusals on their line."""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import line_of, write

from deeplens.optics.io import ZemaxFileError, lens_to_dict, read_zmx, write_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Irregular

# the sample's irregular surface: decenter (-4, 0.5), tilt x 0.1 deg, Zs, Za, Zc, angle 0
SAMPLE_PARMS = (-4.0, 0.5, 0.1, 0.0, -0.0666666666667, -0.3, 0.1, 0.0)


def _file(parms=SAMPLE_PARMS, unit="MM", typ="IRREGULA", diam="24", extra=()):
    s = 25.4 if unit == "IN" else 1.0
    lines = ["VERS 130724 0 23203", "MODE SEQ", "NAME irregular", f"UNIT {unit} X W X CM MR CPMM",
             f"ENPD {40 / s!r}", "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0", "WAVM 1 0.55 1",
             "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {5 / s!r}",
             f"  DIAM {20 / s!r} 0 0 0 1 \"\"",
             "SURF 2", "  TYPE STANDARD", f"  CURV {0.0260593072589999 * s!r}", f"  DISZ {12 / s!r}",
             "  GLAS ___BLANK 1 0 1.5168 64.17 0 0 0 0 0 0", "  CONI -0.43367133876",
             f"  DIAM {24 / s!r} 1 0 0 1 \"\"",
             "SURF 3", f"  TYPE {typ}", f"  CURV {0.00988900109250000 * s!r}"]
    lengths = {1, 2, 5, 6, 7}
    lines += [f"  PARM {i} {(v / s if i in lengths else v)!r}"
              for i, v in enumerate(parms, start=1)]
    lines += [*extra, f"  DISZ {100 / s!r}", f"  DIAM {float(diam) / s!r} 1 0 0 1 \"\"",
              "SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 2.48 0 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path).double()


def test_the_records_are_read_as_the_user_guide_lists_them(tmp_path):
    for unit in ("MM", "IN"):
        lens = _read(write(tmp_path, _file(unit=unit), f"{unit}.zmx"))
        s = lens.surfaces[-1]
        assert isinstance(s, Irregular)
        assert float(s.dx) == pytest.approx(-4.0, rel=1e-15)
        assert float(s.dy) == pytest.approx(0.5, rel=1e-15)
        assert float(s.tilt_x) == pytest.approx(math.radians(0.1), rel=1e-15)
        assert float(s.tilt_y) == 0.0
        assert (float(s.zs), float(s.za), float(s.zc)) == pytest.approx(
            (-0.0666666666667, -0.3, 0.1), rel=1e-14)
        assert float(s.r_max) == pytest.approx(24.0, rel=1e-15)
        assert float(s.c) == pytest.approx(0.0098890010925, rel=1e-14)


def test_with_every_parm_zero_it_is_the_standard_surface(tmp_path):
    """The closed-form reduction: the file with ``IRREGULA`` and PARM 1-8 zero and the file with
    ``STANDARD`` have the same paraxial data (bit for bit) and the same real rays (to 1e-12 mm:
    the STANDARD conic is intersected in closed form, the irregular surface by Newton)."""
    zero = (0.0,) * 8
    a = _read(write(tmp_path, _file(parms=zero), "irr.zmx"))
    b = _read(write(tmp_path, _file(parms=(), typ="STANDARD"), "std.zmx"))
    pa, pb = paraxial(a), paraxial(b)
    assert float(pa.efl) == float(pb.efl) and float(pa.bfl) == float(pb.bfl)
    r = torch.linspace(-19.0, 19.0, 11, dtype=torch.float64)
    o = torch.stack([0.2 * r, r, torch.full_like(r, -1.0)], -1)
    d = torch.tensor([0.01, 0.03, 1.0], dtype=torch.float64)
    rays = Rays(o, (d / d.norm()).expand(11, 3), 550.0)
    with torch.no_grad():
        ra, rb = a.trace_to_sensor(rays), b.trace_to_sensor(rays)
    assert ra.valid.all() and torch.allclose(ra.o, rb.o, rtol=0, atol=1e-12)


def test_the_sample_like_file_paraxial_data_take_the_y_section(tmp_path):
    """The sample's lens: its EFL is the file's with ``STANDARD`` and ``CURV c + 2 Za / r_max²``
    (the paraxial convention; θ = 0), to 1e-12 relative."""
    a = _read(write(tmp_path, _file(), "irr.zmx"))
    c_eff = 0.00988900109250000 + 2 * -0.3 / 24.0 ** 2
    text = _file(parms=(), typ="STANDARD").replace("CURV 0.0098890010925", f"CURV {c_eff!r}")
    b = _read(write(tmp_path, text, "std.zmx"))
    assert float(paraxial(a).efl) == pytest.approx(float(paraxial(b).efl), rel=1e-12)


def test_zmx_round_trip(tmp_path):
    a = _read(write(tmp_path, _file(), "a.zmx"))
    write_zmx(a, tmp_path / "b.zmx")
    text = (tmp_path / "b.zmx").read_text()
    assert "TYPE IRREGULA" in text
    b = _read(tmp_path / "b.zmx")
    da, db = lens_to_dict(a), lens_to_dict(b)
    sa, sb = da["surfaces"][-1], db["surfaces"][-1]
    for key in Irregular.file_fields:
        assert sb[key] == pytest.approx(sa[key], rel=1e-15, abs=1e-300), key


def test_a_semi_diameter_other_than_r_max_is_written_with_the_terms_scaled(tmp_path):
    s = Irregular(0.01, 12.0, 24.0, z_spherical=0.2, z_astigmatism=-0.3, z_coma=0.1)
    lines = "\n".join(__import__("deeplens.optics.io.zmx_irregular", fromlist=["x"])
                      .IrregularFormat().write_zmx(s, 3))
    assert "PARM 5 0.0125" in lines and "PARM 6 -0.075" in lines and "PARM 7 0.0125" in lines
    assert "DIAM 12.0 1" in lines


@pytest.mark.parametrize("extra, parms, diam, needle, match", [
    ((), SAMPLE_PARMS, "0", "PARM 5", r"IRREGULA Z terms need the surface's semi-diameter"),
    (("  PARM 9 1.5",), SAMPLE_PARMS, "24", "PARM 9", r"IRREGULA PARM 9 = 1.5 is not read"),
    (("  XDAT 1 2",), SAMPLE_PARMS, "24", "XDAT 1", r"IRREGULA XDAT 1 = 2 is not read \(an irregular surface has "
                                                 r"no extra data\)"),
])
def test_refusals_are_located(tmp_path, extra, parms, diam, needle, match):
    text = _file(parms=parms, diam=diam, extra=extra)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, needle)
