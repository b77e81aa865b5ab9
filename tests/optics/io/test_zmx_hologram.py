"""``TYPE HOLOGRM1`` / ``HOLOGRM2`` in ``.zmx`` files: read into
:class:`~deeplens.optics.surfaces.Hologram` with the file's units (``PARM 1-3`` and ``4-6`` the
construction points, lengths; ``PARM 7`` the construction wavelength, µm in every unit;
``PARM 8`` the order), in transmission and on a mirror; the paraxial focus against the thin-lens
closed form; real rays from construction point 1 through point 2; written back and read again;
a ``HOLOGRM1`` warned about at its line; odd data refused with its line.  The files here are
written for the tests (OpticStudio's own hologram samples carry no licence)."""

from __future__ import annotations

import warnings

import pytest
import torch
from test_zmx import line_of, write

from deeplens.optics.io import lens_to_dict
from deeplens.optics.io.zmx import ZemaxFileError, ZemaxWarning, read_zmx, write_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Hologram
from helpers import read_zmx_quiet

F64 = torch.float64
WLC_UM = 0.55


def hologram_file(kind=2, unit="MM", s=1.0, z1=-200.0, z2=100.0, image=100.0, mirror=False,
                  body=None):
    """An object 200 mm before a flat hologram (the stop, EPD 50 mm) with construction points
    ``(0, 0, z1)``, ``(0, 0, z2)`` (mm), 0.55 µm, order 1, the image plane ``image`` mm after it
    (negative after a mirror); lengths written in ``unit`` (``s`` mm per unit).  ``body``
    replaces the PARM lines."""
    if body is None:
        body = ["PARM 1 0", "PARM 2 0", f"PARM 3 {z1 / s!r}", "PARM 4 0", "PARM 5 0",
                f"PARM 6 {z2 / s!r}", f"PARM 7 {WLC_UM}", "PARM 8 1"]
    lines = ["VERS 130724 0 23203", "MODE SEQ", "NAME holo", f"UNIT {unit} X W X CM MR CPMM",
             f"ENPD {50 / s!r}", "FTYP 1 0 2 1 0 0 0", "XFLN 0 0", f"YFLN 0 {10 / s!r}",
             f"WAVM 1 {WLC_UM} 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", f"  DISZ {200 / s!r}",
             f"  DIAM {10 / s!r} 0 0 0 1 \"\"",
             "SURF 1", "  STOP", f"  TYPE HOLOGRM{kind}", "  CURV 0.0",
             *[f"  {x}" for x in body], f"  DISZ {image / s!r}",
             *(["  GLAS MIRROR 0 0 0 0 0 0 0 0 0 0"] if mirror else []),
             f"  DIAM {25 / s!r} 0 0 0 1 \"\"",
             "SURF 2", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", f"  DIAM {6 / s!r} 0 0 0 1 \"\""]
    return "\n".join(lines) + "\n"


def _from_object(lens, n=32):
    """Rays from the on-axis object point (200 mm before the hologram) over the pupil."""
    g = torch.Generator().manual_seed(0)
    aim = torch.empty(n, 3, dtype=F64).uniform_(-17.0, 17.0, generator=g)
    aim[:, 2] = 0.0
    o = torch.tensor([0.0, 0.0, -200.0], dtype=F64).expand(n, 3).clone()
    d = aim - o
    return Rays(o, d / torch.linalg.vector_norm(d, dim=-1, keepdim=True), 550.0)


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_transmission_hologram2_reads_with_the_units(tmp_path, unit, s):
    """PARM 1-6 are lengths (scaled), PARM 7 µm (not scaled); the paraxial image of the object
    at P1 is at P2 (thin lens 1/200 + 1/100: EFL 66.67 mm), and every real ray from P1 meets
    the image plane on the axis (1e-11 mm)."""
    lens = read_zmx_quiet(write(tmp_path, hologram_file(unit=unit, s=s)))
    h = lens.surfaces[0]
    assert isinstance(h, Hologram) and h.kind == 2 and h.order == 1
    assert [float(v) for v in h.p1] == pytest.approx([0, 0, -200.0], rel=1e-14)
    assert [float(v) for v in h.p2] == pytest.approx([0, 0, 100.0], rel=1e-14)
    assert float(h.wl_c) == pytest.approx(550.0, rel=1e-14)
    p = paraxial(lens)
    assert float(p.efl) == pytest.approx(200.0 / 3.0, rel=1e-13)
    assert float(p.image_distance) == pytest.approx(100.0, rel=1e-12)
    out = lens.trace_to_sensor(_from_object(lens))
    assert out.valid.all() and out.o[:, :2].abs().max() <= 1e-11


def test_reflection_hologram2_images_point2_on_point1(tmp_path):
    """GLAS MIRROR, P1 (0, 0, -100), P2 (0, 0, -200), the object at P2 and the image plane
    100 mm back: the paraxial image is there and every real ray meets it on the axis."""
    lens = read_zmx_quiet(write(tmp_path, hologram_file(z1=-100.0, z2=-200.0, image=-100.0,
                                                        mirror=True)))
    assert list(lens.mirrors) == [0]
    p = paraxial(lens)
    assert float(p.image_distance) == pytest.approx(-100.0, rel=1e-12)
    out = lens.trace_to_sensor(_from_object(lens))
    assert out.valid.all() and (out.d[:, 2] < 0).all() and out.o[:, :2].abs().max() <= 1e-11


def test_hologram1_loads_with_one_located_warning(tmp_path):
    """HOLOGRM1 (P1 (0, 0, -200), P2 (0, 0, -100): a virtual image at P2); the warning names
    its line, the reading and how to flip it; the paraxial image is at P2."""
    text = hologram_file(kind=1, z2=-100.0, image=50.0)
    p = write(tmp_path, text)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(p)
    ours = [x for x in w if issubclass(x.category, ZemaxWarning) and "HOLOGRM1" in str(x.message)]
    assert len(ours) == 1
    assert ours[0].message.line == line_of(text, "TYPE HOLOGRM1")
    assert "negate PARM 8" in str(ours[0].message)
    assert lens.surfaces[0].kind == 1
    assert float(paraxial(lens).image_distance) == pytest.approx(-100.0, rel=1e-12)


@pytest.mark.parametrize("kind,mirror", [(2, False), (1, False), (2, True)])
def test_write_and_read_back(tmp_path, kind, mirror):
    text = hologram_file(kind=kind, z1=-100.0 if mirror else -200.0,
                         z2=-200.0 if mirror else 100.0, image=-100.0 if mirror else 100.0,
                         mirror=mirror)
    lens = read_zmx_quiet(write(tmp_path, text))
    write_zmx(lens, tmp_path / "out.zmx")
    out = (tmp_path / "out.zmx").read_text()
    assert f"TYPE HOLOGRM{kind}" in out and "PARM 7 0.55" in out and "PARM 8 1" in out
    back = read_zmx_quiet(tmp_path / "out.zmx")
    a, b = lens_to_dict(lens), lens_to_dict(back)
    a.pop("name", None), b.pop("name", None)
    assert a == b


BASE = ["PARM 1 0", "PARM 2 0", "PARM 3 -200", "PARM 4 0", "PARM 5 0", "PARM 6 100"]


@pytest.mark.parametrize("body,needle,match", [
    (BASE + ["PARM 7 -0.55", "PARM 8 1"], "PARM 7 -0.55",
     r"HOLOGRM2 PARM 7 \(the construction wavelength, µm\) must be > 0.*recorded in transmission"),
    (BASE + ["PARM 8 1"], "TYPE HOLOGRM2", r"HOLOGRM2 PARM 7 \(the construction wavelength"),
    (BASE + ["PARM 7 0.55", "PARM 8 1.5"], "PARM 8 1.5",
     r"diffraction order \(HOLOGRM2 PARM 8\) must be an integer"),
    (BASE + ["PARM 7 0.55", "PARM 8 1", "PARM 9 1"], "PARM 9", r"HOLOGRM2 PARM 9 = 1 is not read"),
    (BASE + ["PARM 7 0.55", "PARM 8 1", "XDAT 1 2"], "XDAT 1", r"HOLOGRM2 XDAT 1 = 2 is not read"),
    (["PARM 3 0", "PARM 6 100", "PARM 7 0.55", "PARM 8 1"], "TYPE HOLOGRM2",
     r"HOLOGRM2 construction point 1 \(PARM 1-3\) is at the surface's vertex"),
])
def test_odd_data_is_refused_with_its_line(tmp_path, body, needle, match):
    text = hologram_file(body=body)
    p = write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(p)
    assert e.value.line == line_of(text, needle)
    assert str(p) in str(e.value)


def test_a_clear_aperture_on_a_hologram_is_written_back(tmp_path):
    """A clear circle and an obscuration on a hologram (behind a stop) are written as CLAP and
    OBSC and read back as the same surface; a decentred one is refused by the writer (the
    reader refuses OBDC on a hologram)."""
    from deeplens.optics.lens import Lens
    from deeplens.optics.materials import Air
    from deeplens.optics.surfaces import Aperture

    def h_dict(x):
        s = x.surfaces[1] if hasattr(x, "surfaces") else x
        return s.to_dict()

    def lens_with(decenter):
        h = Hologram(1 / 90.0, 14.0, (0.0, 0.0, -200.0), (0.0, 0.0, 100.0), 550.0, 1, 2,
                     clear_radius=12.0, clear_decenter=decenter, obscuration=2.0)
        return Lens([Aperture(10.0), h], [Air(), Air(), Air()], [0.0, 5.0], 100.0, 0)

    lens = lens_with((0.0, 0.0))
    write_zmx(lens, tmp_path / "out.zmx")
    out = (tmp_path / "out.zmx").read_text()
    assert "CLAP 0 12.0 0" in out and "OBSC 0 2.0 0" in out
    back = read_zmx_quiet(tmp_path / "out.zmx").surfaces[1]
    # the reader takes a CLAP as the surface's semi-diameter (the Zemax guide): the same opening
    assert float(back.semi_diameter) == 12.0 and float(back.obscuration) == 2.0
    a = {k: v for k, v in h_dict(lens).items() if k not in ("semi_diameter_mm", "clear_radius_mm")}
    b = {k: v for k, v in h_dict(back).items() if k not in ("semi_diameter_mm", "clear_radius_mm")}
    assert a == b and isinstance(back, Hologram)
    with pytest.raises(ZemaxFileError, match="a decentred opening on a hologram is not written"):
        write_zmx(lens_with((1.0, -0.5)), tmp_path / "dec.zmx")
