"""The file-format registry (:mod:`deeplens.optics.io.surface_formats`): a new surface type is
read and written through the public ``read_zmx``/``write_zmx`` by one handler registered in the
test alone (no edit to the package), the registration ends with its ``with`` block, and a name
or class registered twice is refused."""

from __future__ import annotations

import re

import pytest
import torch
from test_zmx import write

from deeplens.optics.io.surface_formats import (FormatRegistry, SurfaceFormat,
                                                registered_format)
from deeplens.optics.io.surface_handlers import FORMATS, AsphereFormat
from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.surfaces import Asphere
from helpers import read_zmx_quiet

#: the toy surface's curvature (1/mm) and conic
C, K = 0.02, -0.5


class ToyConic(Asphere):
    """A toy surface type: a conic whose file record carries the conic as ``PARM 1``."""


class ToyConicFormat(SurfaceFormat):
    """Its handler: Zemax ``TYPE TOYCONIC`` (a made-up name), ``CURV`` the curvature, ``PARM 1``
    the conic (in place of ``CONI``)."""

    classes = (ToyConic,)
    zmx_types = ("TOYCONIC",)

    def read_zmx(self, s, ctx):
        conic = s.parm.get(1, (0.0, 0))[0]
        return ToyConic(ctx.c, ctx.sd_build, conic=conic)

    def write_zmx(self, surface, i):
        return ["TYPE TOYCONIC", f"CURV {float(surface.c)!r}", f"PARM 1 {float(surface.k)!r}",
                f"DIAM {float(surface.semi_diameter)!r} 1 0 0 1 \"\""]


def singlet(front: list[str]) -> str:
    """A singlet in mm (a flat stop, EPD 10 mm; the front surface's records ``front``; a
    spherical back)."""
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME toy", "UNIT MM X W X CM MR CPMM",
             "ENPD 10.0", "GCAT SCHOTT", "FTYP 0 0 2 1 0 0 0", "XFLN 0 0", "YFLN 0 3",
             "WAVM 1 0.5875618 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 2.0",
             "  DIAM 5.0 1 0 0 1 \"\"",
             "SURF 2", *[f"  {x}" for x in front], "  DISZ 5.0",
             "  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0", "  DIAM 6.0 1 0 0 1 \"\"",
             "SURF 3", "  TYPE STANDARD", "  CURV -0.005", "  DISZ 46.0",
             "  DIAM 6.0 1 0 0 1 \"\"",
             "SURF 4", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 6.0 1 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


TOY = singlet(["TYPE TOYCONIC", f"CURV {C!r}", f"PARM 1 {K!r}"])
STANDARD = singlet(["TYPE STANDARD", f"CURV {C!r}", f"CONI {K!r}"])


@pytest.fixture
def toy_format():
    """The toy handler, registered for the test only (removed on teardown, also on failure)."""
    before = (FORMATS.zmx_types(), FORMATS.codev_types())
    with registered_format(ToyConicFormat()) as handler:
        yield handler
    assert (FORMATS.zmx_types(), FORMATS.codev_types()) == before


def test_a_toy_type_registered_in_a_test_is_read_and_written(tmp_path, toy_format):
    """``TYPE TOYCONIC`` reads into a ``ToyConic`` with the file's curvature and conic (its
    ``PARM 1``); ``write_zmx`` writes it with its own records, and they read back to the same
    surface bit for bit; the lens is the conic singlet a ``STANDARD`` front with ``CONI`` gives
    (the same paraxial focal length to float64 rounding)."""
    lens = read_zmx_quiet(write(tmp_path, TOY, "toy.zmx"))
    toy = lens.surfaces[1]
    assert type(toy) is ToyConic
    assert (float(toy.c), float(toy.k), float(toy.semi_diameter)) == (C, K, 6.0)
    out = tmp_path / "out.zmx"
    write_zmx(lens, out)
    text = out.read_text()
    assert re.search(r"^\s+TYPE TOYCONIC\n\s+CURV 0\.02\n\s+PARM 1 -0\.5\n", text, re.M)
    again = read_zmx_quiet(out).surfaces[1]
    assert type(again) is ToyConic
    for name, v in toy.state_dict().items():
        assert torch.equal(again.state_dict()[name], v), name
    plain = read_zmx_quiet(write(tmp_path, STANDARD, "std.zmx"))
    assert type(plain.surfaces[1]) is Asphere and float(plain.surfaces[1].k) == K
    with torch.no_grad():
        assert float(paraxial(lens).efl) == pytest.approx(float(paraxial(plain).efl), rel=1e-13)


def test_the_toy_type_is_unknown_outside_its_registration(tmp_path):
    """Without the handler ``TYPE TOYCONIC`` is refused on its line with today's message (the
    built-in types listed), and a ``ToyConic`` surface is written by its base class's handler
    (an ``Asphere``'s records): nothing of the toy registration outlives its block."""
    path = write(tmp_path, TOY, "toy.zmx")
    with pytest.raises(ZemaxFileError, match=r"surface type 'TOYCONIC' \(SURF 2, a surface type "
                                             r"deeplens does not know\) is not supported; "
                                             r"deeplens reads STANDARD, .* GRID_SAG, IRREGULA, HOLOGRM1, HOLOGRM2, GRINSUR1, FRESNELS, USERSURF US_ARRAY.DLL and XOSPHERE$") as e:
        read_zmx(path)
    assert e.value.line == TOY.splitlines().index("  TYPE TOYCONIC") + 1
    assert "TOYCONIC" not in FORMATS.zmx_types()
    assert isinstance(FORMATS.for_surface(ToyConic(C, 6.0, conic=K)), AsphereFormat)


def test_registration_ends_with_its_block_when_the_block_raises():
    with pytest.raises(RuntimeError, match="inside"):
        with registered_format(ToyConicFormat()):
            assert FORMATS.for_zmx_type("TOYCONIC") is not None
            raise RuntimeError("inside")
    assert FORMATS.for_zmx_type("TOYCONIC") is None
    assert isinstance(FORMATS.for_surface(ToyConic(C, 6.0)), AsphereFormat)


def test_a_name_or_class_registered_twice_is_refused_and_nothing_registered():
    """A handler claiming a built-in Zemax type name, or a class another handler writes, is
    refused whole: none of its other names is registered."""

    class Clash(SurfaceFormat):
        zmx_types = ("TOYCONIC", "STANDARD")

    with pytest.raises(ValueError, match="Zemax type 'STANDARD' already has a file handler "
                                         r"\(AsphereFormat\)"):
        FORMATS.add(Clash())
    assert FORMATS.for_zmx_type("TOYCONIC") is None
    assert isinstance(FORMATS.for_zmx_type("STANDARD"), AsphereFormat)

    class ClassClash(SurfaceFormat):
        classes = (ToyConic,)

    reg = FormatRegistry()   # a registry of its own: FORMATS is not touched
    reg.add(ToyConicFormat())
    with pytest.raises(ValueError, match="surface class 'ToyConic' already has a file handler"):
        reg.add(ClassClash())
    reg.remove(ToyConicFormat())   # another instance: not the registered one, nothing removed
    assert isinstance(reg.for_zmx_type("TOYCONIC"), ToyConicFormat)


def test_every_builtin_type_has_a_handler_that_reads_it():
    """Each Zemax type name the parser accepts has a handler that builds surfaces (``read_zmx``
    overridden), except ``COORDBRK``, which the reader's sequence reads; each handler's classes
    are found by their own lookup."""
    for name in FORMATS.zmx_types():
        h = FORMATS.for_zmx_type(name)
        overridden = type(h).read_zmx is not SurfaceFormat.read_zmx
        assert overridden == (name != "COORDBRK"), name
        for cls in h.classes:
            assert FORMATS._classes[cls] is h
