"""``TYPE PARAX_XY`` (OpticStudio's Paraxial XY) in ``.zmx`` files: ``PARM 1``, ``PARM 2`` the x
and y powers in 1/lens units.  A file built like OpticStudio's own diode-source sample (an object
0.5362 mm before a ``PARAX_XY`` with x power 0 and y power 7.971, the next surface 0.1638 mm
behind it, where that y power images the object: ``1/v = 7.971 − 1/0.5362``, so the PARMs are
powers, not focal lengths); in mm and inches; ``.zmx -> Lens -> .zmx -> Lens``; refusals on their
line."""

from __future__ import annotations

import warnings

import pytest
import torch
from test_zmx import line_of, write

from deeplens.optics.io import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.io.zmx import ZemaxWarning
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import IdealLensXY


def _file(px="0", py="7.971", unit="MM", extra=(), glass=None):
    s = 25.4 if unit == "IN" else 1.0
    lines = ["VERS 130724 8 23203", "MODE SEQ", "NAME diode", f"UNIT {unit} X W X CM MR CPMM",
             "OBNA 1.74E-1 0", "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0", "WAVM 1 0.55 1",
             "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {0.5362 / s!r}",
             "SURF 1", "  STOP", "  TYPE PARAX_XY", "  CURV 0.0",
             f"  PARM 1 {float(px) * s!r}", f"  PARM 2 {float(py) * s!r}", *extra,
             f"  DISZ {0.1638 / s!r}", *([f"  GLAS {glass}"] if glass else []),
             f"  DIAM {0.0947 / s!r} 0 0 0 1 \"\"",
             "SURF 2", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 0.01 0 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path).double()


@pytest.mark.parametrize("unit", ["MM", "IN"])
def test_the_powers_are_read_and_the_y_power_images_the_object_where_the_file_says(tmp_path, unit):
    text = _file(unit=unit)
    p = write(tmp_path, text, f"{unit}.zmx")
    with pytest.warns(ZemaxWarning, match=r"PARAX_XY with x power 0 /mm and y power 7\.971 /mm"):
        read_zmx(p)
    lens = _read(p)
    s = lens.surfaces[0]
    assert isinstance(s, IdealLensXY)
    assert float(s.power_x) == 0.0 and float(s.power_y) == pytest.approx(7.971, rel=1e-14)
    v = 1.0 / (7.971 - 1.0 / 0.5362)
    assert v == pytest.approx(0.1638, rel=2e-4)     # the file's own thickness after the lens
    assert float(paraxial(lens).efl) == pytest.approx(1 / 7.971, rel=1e-14)
    # real rays from the object point in the y-z plane meet on the axis at v
    t = torch.linspace(-0.15, 0.15, 7, dtype=torch.float64)
    d = torch.stack([torch.zeros_like(t), t, torch.ones_like(t)], -1)
    z_lens = float(lens.z_vertices()[0])
    o = torch.zeros(7, 3, dtype=torch.float64)
    o[:, 2] = z_lens - 0.5362                       # the object point
    rays = Rays(o, d / d.norm(dim=-1, keepdim=True), 550.0)
    with torch.no_grad():
        hits = lens.trace(rays)
    assert hits.valid.all()
    assert torch.allclose(hits.o[:, 2], torch.full_like(t, z_lens), rtol=0, atol=1e-15)
    y_at_v = hits.o[:, 1] + hits.d[:, 1] / hits.d[:, 2] * v
    assert float(y_at_v.abs().max()) < 1e-12


def test_zmx_round_trip(tmp_path):
    a = _read(write(tmp_path, _file(px="2.5"), "a.zmx"))
    write_zmx(a, tmp_path / "b.zmx")
    assert "TYPE PARAX_XY" in (tmp_path / "b.zmx").read_text()
    b = _read(tmp_path / "b.zmx")
    sa, sb = a.surfaces[0], b.surfaces[0]
    assert (float(sb.power_x), float(sb.power_y)) == (float(sa.power_x), float(sa.power_y))


@pytest.mark.parametrize("kw, needle, match", [
    ({"extra": ("  PARM 3 1",)}, "PARM 3", r"PARAX_XY PARM 3 = 1 is not read"),
    ({"px": "0", "py": "0"}, "TYPE PARAX_XY", r"needs a non-zero x or y power"),
    ({"glass": "___BLANK 1 0 1.5 60 0 0 0 0 0 0"}, "GLAS", r"PARAX_XY surface between glasses"),
])
def test_refusals_are_located(tmp_path, kw, needle, match):
    text = _file(**kw)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, needle)
