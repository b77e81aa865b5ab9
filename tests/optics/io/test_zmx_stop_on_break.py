"""A stop on a coordinate break (docs/guide/zemax.md, "A sixth set"; OpticStudio's toroid
sample puts its ``STOP`` on a ``COORDBRK`` that turns the frame 45 degrees about z).

A break with no decenter and no tilt about x or y turns the frame about the z axis through its
vertex: the vertex plane is the same before and after it, and a circle centred on the vertex
is the same circle in both frames.  The reader reads such a stop as a flat ``Aperture`` at the
break's vertex (``zmx_coordbrk.stop_plane_of_break``), so the file must read exactly as the
same file with the stop on a plain plane at that vertex, just before the break.  A break that
decentres or tilts out of its plane moves the plane, so before and after are two stops: refused
at the break's line.
"""

from __future__ import annotations

import math
import warnings

import pytest
import torch
from test_zmx import write
from zmx_blocks import surf as _surf, zmx_file

from deeplens.optics.errors import ZemaxFileError
from deeplens.optics.io import lens_to_dict, read_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Aperture, CoordinateBreak

_GLASS = "___BLANK 1 0 1.5 0 0 0 0 0 0 0"
_TURN = 30.0   # degrees about z


def _file(stop_blocks):
    """A singlet, 10 mm of air, the stop (``stop_blocks``: the break that carries it, or a plain
    plane and the break), 10 mm of air, a toroidal singlet (the turn about z matters to it) and
    the image 50 mm behind."""
    blocks = ([_surf(disz="INFINITY"),
               _surf(curv=0.02, disz=3.0, glas=_GLASS, diam=8.0),
               _surf(disz=10.0, diam=8.0)]
              + stop_blocks
              + [_surf("TOROIDAL", curv=0.02, parms=[40.0], disz=4.0, glas=_GLASS, diam=8.0),
                 _surf(curv=-0.01, disz=50.0, diam=8.0), _surf()])
    return zmx_file(blocks, name="stop on a break", aperture="ENPD 8.0",
                    fields="FTYP 0 0 2 1 0 0 0\nYFLN 0 3.0")


def _break(parms, stop, disz=10.0):
    return _surf("COORDBRK", parms=list(parms) + [0.0], disz=disz, stop=stop)


def _read(p):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(p).double()


def _landings(lens):
    """Where a fan of real rays at 0 and 3 degrees lands on the sensor, and which pass: rays
    up to 1.5 times the pupil's radius, so the stop's size and place decide which pass."""
    out = []
    for deg in (0.0, 3.0):
        t = math.radians(deg)
        xy = torch.linspace(-6.0, 6.0, 9, dtype=torch.float64)
        gx, gy = torch.meshgrid(xy, xy, indexing="ij")
        o = torch.stack([gx.reshape(-1), gy.reshape(-1), torch.full((81,), -5.0,
                                                                   dtype=torch.float64)], -1)
        d = torch.tensor([0.0, math.sin(t), math.cos(t)], dtype=torch.float64).expand(81, 3)
        r = lens.trace_to_sensor(Rays(o, d, torch.full((81,), 587.5618, dtype=torch.float64)))
        out.append((r.o, r.valid))
    return out


def test_stop_on_a_turn_about_z_reads_as_a_plane_stop_at_its_vertex(tmp_path):
    on_break = _read(write(tmp_path, _file([_break((0, 0, 0, 0, _TURN), stop=True)]), "b.zmx"))
    on_plane = _read(write(tmp_path, _file([_surf(disz=0.0, stop=True),
                                            _break((0, 0, 0, 0, _TURN), stop=False)]), "p.zmx"))
    kinds = [type(s).__name__ for s in on_break.surfaces]
    assert isinstance(on_break.surfaces[on_break.stop_index], Aperture)
    assert isinstance(on_break.surfaces[on_break.stop_index + 1], CoordinateBreak)
    assert kinds == [type(s).__name__ for s in on_plane.surfaces]
    assert lens_to_dict(on_break) == lens_to_dict(on_plane)
    a, b = paraxial(on_break), paraxial(on_plane)
    assert float(a.efl) == float(b.efl) and float(a.entrance_pupil_diameter) == 8.0
    assert float(a.entrance_pupil_diameter) == float(b.entrance_pupil_diameter)
    assert float(a.entrance_pupil_position) == float(b.entrance_pupil_position)
    for (oa, va), (ob, vb) in zip(_landings(on_break), _landings(on_plane)):
        assert torch.equal(va, vb)
        assert 0 < int(va.sum()) < va.numel()      # the stop vignettes part of the fan
        assert torch.equal(oa[va], ob[vb])


@pytest.mark.parametrize("parms", [(0, 0, 5.0, 0, _TURN), (0, 0, 0, -2.0, 0),
                                   (0.5, 0, 0, 0, 0), (0, -0.1, 0, 0, _TURN)])
def test_stop_on_a_break_that_moves_its_plane_is_refused_at_its_line(tmp_path, parms):
    text = _file([_break(parms, stop=True)])
    line = text.splitlines().index("SURF 3") + 1
    with pytest.raises(ZemaxFileError, match="COORDBRK that decentres") as e:
        _read(write(tmp_path, text))
    assert e.value.line == line


@pytest.mark.parametrize("record", ["SQAP 2 3 0 0 0 0", "SPID 0.5 3 0"])
def test_stop_on_a_break_with_a_rectangular_aperture_is_refused(tmp_path, record):
    """A shape that turns with the frame on a stop that is a break (a rectangle, a spider)."""
    text = _file([_break((0, 0, 0, 0, _TURN), stop=True)])
    text = text.replace("SURF 4", f"  {record}\nSURF 4")
    line = text.splitlines().index(f"  {record}") + 1
    with pytest.raises(ZemaxFileError,
                       match=f"{record.split()[0]} on a STOP that is a COORDBRK") as e:
        _read(write(tmp_path, text))
    assert e.value.line == line
