"""COORDBRK surfaces in .zmx files (deeplens/optics/io/zmx_coordbrk.py): which become an
element's misalignment and which a CoordinateBreak surface, and that both readings agree where
both apply (two independent implementations of OpticStudio's coordinate-break geometry:
``Misalignment`` with the tilt conversion of ``element_tilts``, and ``CoordinateBreak`` with
its order flags)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
import torch

from deeplens.optics.io import load_lens, read_zmx, write_zmx
from deeplens.optics.io.zmx_coordbrk import degrees_read_back_exactly
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import CoordinateBreak

REPO = Path(__file__).resolve().parents[3]
JSON = REPO / "data" / "lenses" / "double_gauss.json"


def _bracketed(tmp_path, tilts, decenter=(0.0, 0.03)):
    """The table lens with element 1 between a COORDBRK (decenter, tilts about x, y, z, order
    flag 0) and the break that undoes it (values negated, order flag 1), as tolerancing files
    write it; the text of the file."""
    lens = load_lens(JSON).double()
    with torch.no_grad():
        lens.misalignments[1].tilt_x.fill_(0.01)   # a bracket to edit
    p = tmp_path / "bracket.zmx"
    write_zmx(lens, p)
    text = p.read_text()
    blocks = re.split(r"(?=^SURF \d+$)", text, flags=re.M)
    cbs = [i for i, b in enumerate(blocks) if "TYPE COORDBRK" in b]
    assert len(cbs) == 2
    vals = (*decenter, *tilts)
    for i, sign in zip(cbs, (1.0, -1.0)):
        for k, v in enumerate(vals, start=1):
            blocks[i] = re.sub(rf"^  PARM {k} .*$", f"  PARM {k} {sign * v!r}", blocks[i],
                               flags=re.M)
    return blocks, cbs


def _renumbered(blocks):
    out, k = [], 0
    for b in blocks:
        if b.startswith("SURF "):
            b = re.sub(r"^SURF \d+", f"SURF {k}", b)
            k += 1
        out.append(b)
    return "".join(out)


def _image(lens, field_deg):
    """Image points of a fan of rays (float64), in the sensor's frame."""
    t = math.radians(field_deg)
    y = torch.linspace(-3.0, 3.0, 13, dtype=torch.float64)
    o = torch.stack([0.4 * torch.ones_like(y), y, torch.full_like(y, -5.0)], -1)
    d = torch.tensor([0.0, math.sin(t), math.cos(t)], dtype=torch.float64).expand(13, 3)
    out = lens.trace_to_sensor(Rays(o, d, torch.full((13,), 587.5618, dtype=torch.float64)))
    return out.o, out.valid


@pytest.mark.parametrize("tilts", [(0.6, 0.9, 0.0), (-0.5, 0.4, 30.0), (0.0, 0.7, -15.0)])
def test_split_bracket_as_coordinate_breaks_traces_like_the_misalignment(tmp_path, tilts):
    """The opening break split in two (decenter and tilt about x; then tilts about y and z):
    the same geometry in OpticStudio (R_x R_y R_z applied in turn), but no longer a pair that
    undoes itself, so it is read as three CoordinateBreak surfaces.  It must image exactly as
    the element's Misalignment read from the unsplit file."""
    blocks, (a, b) = _bracketed(tmp_path, tilts)
    p = tmp_path / "whole.zmx"
    p.write_text(_renumbered(blocks))
    whole = read_zmx(p).double()
    assert not any(isinstance(s, CoordinateBreak) for s in whole.surfaces)
    assert not whole.misalignments[1].is_identity()
    first = re.sub(r"^  PARM [45] .*$", "  PARM 4 0", blocks[a], flags=re.M)
    first = re.sub(r"^  PARM 4 0$", "  PARM 4 0\n  PARM 5 0", first, count=1, flags=re.M)
    second = blocks[a]
    for k in (1, 2, 3):
        second = re.sub(rf"^  PARM {k} .*$", f"  PARM {k} 0", second, flags=re.M)
    split = blocks[:a] + [first, second] + blocks[a + 1:]
    p = tmp_path / "split.zmx"
    p.write_text(_renumbered(split))
    cbs = read_zmx(p).double()
    assert sum(isinstance(s, CoordinateBreak) for s in cbs.surfaces) == 3
    assert all(m.is_identity() for m in cbs.misalignments)
    for field in (0.0, 7.0):
        pa, va = _image(whole, field)
        pb, vb = _image(cbs, field)
        assert torch.equal(va, vb) and int(va.sum()) >= 8
        torch.testing.assert_close(pb[vb], pa[va], rtol=0, atol=1e-12)
    # and the tilt is seen: the aligned lens images elsewhere
    pc, vc = _image(load_lens(JSON).double(), 7.0)
    assert (pc[vc & va] - pa[vc & va]).abs().max() > 1e-3


def test_written_tilts_read_back_bit_for_bit():
    """A tilt that came from a file (radians of some degrees) is written as degrees that read
    back to the same radians exactly; any other tilt to within one unit in the last place
    (``radians`` does not reach every float)."""
    g = torch.Generator().manual_seed(3)
    for deg in (torch.rand(300, generator=g, dtype=torch.float64) * 400 - 200).tolist():
        rad = math.radians(deg)
        assert math.radians(degrees_read_back_exactly(rad)) == rad
        other = math.nextafter(rad, math.inf)
        back = math.radians(degrees_read_back_exactly(other))
        assert abs(back - other) <= math.ulp(other)
