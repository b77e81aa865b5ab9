"""Elliptical apertures and obscurations: the :class:`~deeplens.optics.openings.Ellipse`
opening, Zemax's ``ELAP``/``ELOB`` and CODE V's ``ELX``/``ELY`` (with ``OBDC`` / ``ADX``,
``ADY``), read, traced and written back.

Rays parallel to the axis meet a surface (or cross a stop plane) at their own ``(x, y)``, so
which pass is known by hand: a point at angle ``θ`` on the ellipse of half-axes ``a`` (along
x), ``b`` (along y) lies at radius ``r(θ) = 1 / sqrt(cos²θ / a² + sin²θ / b²)`` from its
centre; rays ``EPS`` inside it pass, rays ``EPS`` outside are blocked.  ``EPS`` = 1e-6 mm
changes ``(x/a)² + (y/b)²`` by about ``2 EPS / r`` ~ 1e-6, far above float64's rounding of a
hit point (~1e-15 relative), so the outcome cannot depend on the CPU's instruction set.
"""

from __future__ import annotations

import itertools
import math
import warnings

import helpers as H
import pytest
import torch
from test_zmx import singlet, write

from deeplens.optics.errors import LensFileError, ZemaxFileError
from deeplens.optics.io import lens_to_dict, read_zmx, write_zmx
from deeplens.optics.io.codev import read_seq, write_seq
from deeplens.optics.io.lensfile import lens_from_dict
from deeplens.optics.openings import Circle, Ellipse, in_ellipse
from deeplens.optics.options import TraceOptions
from deeplens.optics.surfaces import Aperture, Asphere
from deeplens.optics.surfaces.base import (clear_ellipse_of, obscuration_ellipse_of,
                                           set_clear_ellipse)

EPS = 1e-6
ANGLES = [0.0, 0.3, math.pi / 4, 1.2, math.pi / 2, 2.5, math.pi, 4.0, 5.5]


def _rim(a, b, centre=(0.0, 0.0), eps=0.0):
    """Points at radius ``r(θ) + eps`` from ``centre`` on the ellipse's rays ``θ`` (ANGLES)."""
    out = []
    for t in ANGLES:
        r = 1.0 / math.sqrt(math.cos(t) ** 2 / a ** 2 + math.sin(t) ** 2 / b ** 2) + eps
        out.append((centre[0] + r * math.cos(t), centre[1] + r * math.sin(t)))
    return out


def _passes(lens, points, options=None, z0=None):
    xy = torch.tensor(points, dtype=torch.float64)
    z0 = float(lens.z_vertices()[0]) - 1.0 if z0 is None else z0
    rays = H.collimated(xy, (0.0, 0.0, 1.0), z0, float(lens.spec.primary_wavelength_nm))
    with torch.no_grad():
        return lens.trace_to_sensor(rays, options=options).valid.tolist()


def _check_rim(lens, a, b, centre=(0.0, 0.0), obscuration=False, options=None, z0=None):
    inside, outside = _rim(a, b, centre, -EPS), _rim(a, b, centre, EPS)
    n = len(ANGLES)
    got = _passes(lens, inside + outside, options, z0)
    want = [not obscuration] * n + [obscuration] * n
    assert got == want


# --------------------------------------------------------------------------- the opening
def test_ellipse_is_the_circle_when_its_half_axes_are_equal():
    """``Ellipse((r, r))`` against ``Circle(r)`` at points 1e-6 mm either side of the rim at
    nine angles and on a grid: the same verdicts, ``contains`` and ``outside`` alike."""
    r = 2.5
    grid = list(itertools.product([-3.0, -1.0, 0.0, 1.7, 2.49], repeat=2))
    pts = _rim(r, r, eps=-EPS) + _rim(r, r, eps=EPS) + grid
    x = torch.tensor([p[0] for p in pts], dtype=torch.float64)
    y = torch.tensor([p[1] for p in pts], dtype=torch.float64)
    e, c = Ellipse(torch.tensor([r, r])), Circle(torch.tensor(r))
    assert e.contains(x, y).tolist() == c.contains(x, y).tolist()
    assert e.outside(x, y).tolist() == c.outside(x, y).tolist()
    n_grid = sum(gx * gx + gy * gy <= r * r for gx, gy in grid)   # 11 of 25
    assert e.contains(x, y).tolist() == [True] * len(ANGLES) + [False] * len(ANGLES) + [
        gx * gx + gy * gy <= r * r for gx, gy in grid] and n_grid == 11


def test_ellipse_half_axes_follow_x_then_y_and_the_decenter():
    """``a`` lies along x and ``b`` along y, about the decenter: with ``a = 3``, ``b = 1`` the
    point 2.9 mm along x passes and 2.9 mm along y does not (and both on the swapped one);
    ``in_ellipse`` is the definition; the bounds circle is ``max(a, b)`` about the centre."""
    e = Ellipse(torch.tensor([3.0, 1.0]), decenter=(0.5, -1.0))
    x = torch.tensor([0.5 + 2.9, 0.5, 0.5 - 3.0 - EPS, 0.5], dtype=torch.float64)
    y = torch.tensor([-1.0, -1.0 + 2.9, -1.0, -1.0 + 1.0 - EPS], dtype=torch.float64)
    assert e.contains(x, y).tolist() == [True, False, False, True]
    assert (e.outside(x, y) == ~e.contains(x, y)).all()   # no point on the rim here
    assert in_ellipse(torch.tensor([2.9, 0.0]), torch.tensor([0.0, 2.9]),
                      torch.tensor([1.0, 3.0])).tolist() == [False, True]
    assert e.bounds() == ((0.5, -1.0), 3.0)
    assert e.kernel_clip is None
    with pytest.raises(ValueError, match="half-axes must be finite and > 0"):
        Ellipse(torch.tensor([1.0, 0.0]))


def test_ellipse_keeps_the_rays_differentiable(tmp_path):
    """Clipping by an ellipse is a mask: the gradient of passing rays' image heights with
    respect to the curvature is that of the same lens without the ellipse (the rays lie far
    inside it, so no rim is crossed), and not zero."""
    grads = []
    for name, extra in (("e.zmx", ("ELAP 3 1.5 0",)), ("p.zmx", ())):
        ln = read_zmx(write(tmp_path, singlet(s1_extra=("PARM 1 0", "PARM 2 1e-05", *extra)),
                            name)).double()
        c = ln.surfaces[1].c
        c.requires_grad_(True)
        xy = torch.tensor([[0.5, 0.2], [-1.0, 0.4]], dtype=torch.float64)
        rays = H.collimated(xy, (0.0, 0.0, 1.0), -1.0, float(ln.spec.primary_wavelength_nm))
        out = ln.trace_to_sensor(rays)
        assert out.valid.all()
        (g,) = torch.autograd.grad(out.o[:, 1].sum(), c)
        grads.append(float(g))
    assert grads[0] == grads[1] and grads[0] != 0.0


# --------------------------------------------------------------------------- Zemax
LENS_CASES = {
    "even asphere": ("EVENASPH", ("PARM 1 0", "PARM 2 1e-05"), 0.02, -0.5),
    "flat face": ("STANDARD", (), 0.0, 0.0),
    "odd asphere": ("ODDASPHE", ("PARM 3 1e-4",), 0.02, -0.5),
}


@pytest.mark.parametrize("case", sorted(LENS_CASES))
def test_elap_on_a_lens_surface_clips_by_hand_geometry(tmp_path, case):
    """``ELAP 3 1.5`` on the singlet's first surface (three sag types): rays 1e-6 mm inside the
    ellipse at nine angles pass, 1e-6 mm outside are blocked, on the closed-form and Newton
    paths; the .zmx and JSON round trips keep the ellipse (and so the verdicts)."""
    typ, extra, curv, k = LENS_CASES[case]
    lens = read_zmx(write(tmp_path, singlet(s1_type=typ, s1_extra=(*extra, "ELAP 3 1.5 0"),
                                            curv1=curv, k=k)))
    s = lens.surfaces[1]
    assert clear_ellipse_of(s) == (3.0, 1.5) and float(s.semi_diameter) == 3.0
    for options in (None, TraceOptions(closed_form=False)):
        _check_rim(lens, 3.0, 1.5, options=options)
    write_zmx(lens, tmp_path / "out.zmx")
    text = (tmp_path / "out.zmx").read_text()
    assert text.count("ELAP 3.0 1.5 0") == 1
    again = read_zmx(tmp_path / "out.zmx")
    assert lens_to_dict(again) == lens_to_dict(lens)
    _check_rim(again, 3.0, 1.5)
    d = lens_to_dict(lens)
    assert d["surfaces"][1]["clear_ellipse_mm"] == [3.0, 1.5]
    back = lens_from_dict(d)
    assert lens_to_dict(back) == d
    _check_rim(back, 3.0, 1.5)


def test_without_the_ellipse_the_outside_rays_pass(tmp_path):
    """The control: the rays the ellipse blocks above pass the same lens without it."""
    lens = read_zmx(write(tmp_path, singlet()))
    assert _passes(lens, _rim(3.0, 1.5, eps=EPS)) == [True] * len(ANGLES)


def test_decentred_elap_on_a_lens_surface(tmp_path):
    """``ELAP 2 1`` with ``OBDC 0.5 -1``: the ellipse moved to (0.5, -1); the semi-diameter
    encloses it (|d| + max(a, b)); written back as ELAP + OBDC."""
    lens = read_zmx(write(tmp_path, singlet(s1_extra=("PARM 1 0", "PARM 2 1e-05", "ELAP 2 1 0",
                                                      "OBDC 0.5 -1"))))
    s = lens.surfaces[1]
    assert [float(v) for v in s.clear_decenter] == [0.5, -1.0]
    assert float(s.semi_diameter) == pytest.approx(math.hypot(0.5, 1.0) + 2.0, rel=1e-15)
    _check_rim(lens, 2.0, 1.0, centre=(0.5, -1.0))
    write_zmx(lens, tmp_path / "out.zmx")
    assert "  ELAP 2.0 1.0 0\n  OBDC 0.5 -1.0\n" in (tmp_path / "out.zmx").read_text()
    assert lens_to_dict(read_zmx(tmp_path / "out.zmx")) == lens_to_dict(lens)
    assert lens_to_dict(lens_from_dict(lens_to_dict(lens))) == lens_to_dict(lens)


def _flat_stop(tmp_path, stop_lines, aperture="FLOA"):
    text = singlet(aperture=aperture).replace('  DIAM 5 1 0 0 1 ""\nSURF 2',
                                              '  DIAM 5 1 0 0 1 ""\n' + "".join(
                                                  f"  {x}\n" for x in stop_lines) + "SURF 2", 1)
    return write(tmp_path, text)


def test_elap_on_a_flat_stop_is_an_elliptical_aperture(tmp_path):
    """``ELAP 2 1`` on the flat stop in air: an :class:`Aperture` of shape ``"ellipse"``
    (crossed, not landed on); rays parallel to the axis cross it at their own (x, y): inside
    the ellipse they pass, outside they are blocked; .zmx and JSON keep it (a .seq file has an
    EPD or F-number, which needs a circular or rectangular stop)."""
    lens = read_zmx(_flat_stop(tmp_path, ["ELAP 2 1 0"]))
    ap = lens.surfaces[lens.stop_index]
    assert isinstance(ap, Aperture) and ap.shape == "ellipse"
    assert [float(v) for v in ap.half_widths] == [2.0, 1.0]
    _check_rim(lens, 2.0, 1.0, z0=-1.0)
    write_zmx(lens, tmp_path / "out.zmx")
    assert "ELAP 2.0 1.0 0" in (tmp_path / "out.zmx").read_text()
    assert lens_to_dict(read_zmx(tmp_path / "out.zmx")) == lens_to_dict(lens)
    d = lens_to_dict(lens)
    assert d["surfaces"][0]["shape"] == "ellipse"
    assert lens_to_dict(lens_from_dict(d)) == d
    _check_rim(lens_from_dict(d), 2.0, 1.0, z0=-1.0)


def test_an_epd_needs_a_circular_or_rectangular_stop(tmp_path):
    """An elliptical stop under ENPD: refused at the ENPD line (deeplens sizes a stop from an
    EPD by its radius; a rectangle keeps its outline and vignettes, an ellipse is not done)."""
    path = _flat_stop(tmp_path, ["ELAP 2 1 0"], aperture="ENPD 10")
    with pytest.raises(ZemaxFileError, match="needs a circular or rectangular stop .this "
                                             "Aperture is elliptical.") as e:
        read_zmx(path)
    assert f"{path}:{_line(path.read_text(), 'ENPD')}:" in str(e.value)


def _mirror(tmp_path, extra=(), name="m.zmx"):
    """A concave mirror (R 200) behind a flat stop, the image at its focus: rays parallel to
    the axis meet the mirror at their own (x, y) (the stop is a plane in air)."""
    lines = ["VERS 170912 299 123456", "MODE SEQ", "NAME mirror", "UNIT MM X W X CM MR CPMM",
             "FLOA", "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0", "WAVM 1 0.55 1", "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 10",
             '  DIAM 10 1 0 0 1 ""',
             "SURF 2", "  TYPE STANDARD", "  CURV -0.005", "  DISZ -100", "  GLAS MIRROR",
             '  DIAM 10 1 0 0 1 ""', *[f"  {x}" for x in extra],
             "SURF 3", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", '  DIAM 1 1 0 0 1 ""']
    return write(tmp_path, "\n".join(lines) + "\n", name)


def test_elob_on_a_mirror_blocks_exactly_the_inner_rays(tmp_path):
    """``ELOB 3 1.5`` on a concave mirror: rays 1e-6 mm inside the ellipse at nine angles are
    blocked, 1e-6 mm outside pass (and reach the focus); the other half of the disc passes; the
    control mirror without it passes all; .zmx and JSON round trips keep it."""
    lens = read_zmx(_mirror(tmp_path, ["ELOB 3 1.5 0"]))
    m = lens.surfaces[1]
    assert isinstance(m, Asphere) and obscuration_ellipse_of(m) == (3.0, 1.5)
    _check_rim(lens, 3.0, 1.5, obscuration=True, z0=-1.0)
    for options in (None, TraceOptions(closed_form=False)):
        _check_rim(lens, 3.0, 1.5, obscuration=True, options=options, z0=-1.0)
    plain = read_zmx(_mirror(tmp_path, name="plain.zmx"))
    assert _passes(plain, _rim(3.0, 1.5, eps=-EPS), z0=-1.0) == [True] * len(ANGLES)
    write_zmx(lens, tmp_path / "out.zmx")
    assert "ELOB 3.0 1.5 0" in (tmp_path / "out.zmx").read_text()
    again = read_zmx(tmp_path / "out.zmx")
    assert lens_to_dict(again) == lens_to_dict(lens)
    _check_rim(again, 3.0, 1.5, obscuration=True, z0=-1.0)
    d = lens_to_dict(lens)
    assert d["surfaces"][1]["obscuration_ellipse_mm"] == [3.0, 1.5]
    back = lens_from_dict(d)
    assert lens_to_dict(back) == d
    _check_rim(back, 3.0, 1.5, obscuration=True, z0=-1.0)
    with pytest.raises(LensFileError, match="elliptical obscuration has no CODE V record"):
        write_seq(lens, tmp_path / "out.seq")


def _line(text, needle):
    return next(i for i, ln in enumerate(text.splitlines(), 1) if needle in ln)


@pytest.mark.parametrize("extra, needle, match", [
    (("ELAP 3 1.5 0", "CLAP 0 4 0"), "ELAP", "ELAP on SURF 2: an elliptical aperture together "
                                             "with CLAP"),
    (("ELAP 3 1.5 0", "OBSC 0 1 0"), "ELAP", "together with OBSC"),
    (("SQAP 3 1.5 0", "ELAP 3 1.5 0"), "ELAP", "together with SQAP"),
    (("ELOB 1 0.5 0", "OBDC 0 1"), "OBDC", "a decentred elliptical obscuration"),
    (("ELAP 3 0 0",), "ELAP", "expected two half-axes > 0"),
    (("SQOB 1 1 0",), "SQOB", "a rectangular obscuration is not supported"),
])
def test_zemax_refusals_name_the_line(tmp_path, extra, needle, match):
    """What the rectangles refuse is refused for ellipses, each with its file and line."""
    text = singlet(s1_extra=("PARM 1 0", "PARM 2 1e-05", *extra))
    path = write(tmp_path, text)
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(path)
    assert f"{path}:{_line(text, needle)}:" in str(e.value)


def test_a_decentred_elliptical_stop_is_refused(tmp_path):
    """OBDC on the stop (deeplens' entrance pupil is centred on the axis): refused at its
    line, as for a rectangle."""
    path = _flat_stop(tmp_path, ["ELAP 2 1 0", "OBDC 0.5 0"])
    with pytest.raises(ZemaxFileError, match="decentred aperture stop") as e:
        read_zmx(path)
    assert f":{_line(path.read_text(), 'OBDC')}:" in str(e.value)


def _dummy_before_stop(tmp_path, lines, name="d.zmx"):
    """The singlet with a flat surface in air 1 mm before its stop carrying ``lines``."""
    text = singlet(aperture="FLOA").replace(
        "SURF 1\n  STOP", "SURF 1\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 1\n"
        + "".join(f"  {x}\n" for x in lines) + "SURF 2\n  STOP", 1)
    n = 0   # renumber the SURF lines that follow
    out = []
    for ln in text.splitlines():
        if ln.startswith("SURF "):
            ln = f"SURF {n}"
            n += 1
        out.append(ln)
    return write(tmp_path, "\n".join(out) + "\n", name)


def test_elob_on_a_flat_surface_in_air_blocks_exactly_the_inner_rays(tmp_path):
    """``ELOB 1.5 0.8`` on a flat surface in air before the stop (a secondary's shadow on a
    dummy plane): an :class:`Aperture` whose opening is a circle less the ellipse; rays
    1e-6 mm inside the ellipse at nine angles are blocked, 1e-6 mm outside pass.  The JSON
    round trip is exact; the .zmx one writes ELOB alone (OpticStudio gives a surface one
    aperture type, so no CLAP beside it: the fixed DIAM is read back as an automatic
    semi-diameter, with a note) and keeps every verdict."""
    with pytest.warns(UserWarning, match="beside an ELOB"):
        lens = read_zmx(_dummy_before_stop(tmp_path, ["ELOB 1.5 0.8 0", 'DIAM 4 1 0 0 1 ""']))
    ap = lens.surfaces[0]
    assert isinstance(ap, Aperture) and obscuration_ellipse_of(ap) == (1.5, 0.8)
    _check_rim(lens, 1.5, 0.8, obscuration=True, z0=-0.5)
    d = lens_to_dict(lens)
    assert d["surfaces"][0]["obscuration_ellipse_mm"] == [1.5, 0.8]
    assert lens_to_dict(lens_from_dict(d)) == d
    write_zmx(lens, tmp_path / "out.zmx")
    text = (tmp_path / "out.zmx").read_text()
    block = text[text.index("SURF 1"):text.index("SURF 2")]
    assert "ELOB 1.5 0.8 0" in block and "CLAP" not in block
    with pytest.warns(UserWarning, match="beside an ELOB"):
        again = read_zmx(tmp_path / "out.zmx")
    assert obscuration_ellipse_of(again.surfaces[0]) == (1.5, 0.8)
    _check_rim(again, 1.5, 0.8, obscuration=True, z0=-0.5)
    with pytest.raises(LensFileError, match="elliptical obscuration has no CODE V record"):
        write_seq(lens, tmp_path / "out.seq")


def test_set_clear_ellipse_refuses_beside_a_rectangle_and_on_a_stop():
    s = Asphere(0.01, 5.0, clear_rect=(2.0, 1.0))
    with pytest.raises(ValueError, match="beside a rectangular one"):
        set_clear_ellipse(s, (2.0, 1.0))
    with pytest.raises(TypeError, match="shape='ellipse'"):
        set_clear_ellipse(Aperture(5.0), (2.0, 1.0))


# --------------------------------------------------------------------------- CODE V
HEAD = "RDM Y\nDIM M\nWL 587.56\nEPD 12\nYAN 0\nSO 0 1e20\n"


def _seq(tmp_path, body, name="t"):
    p = tmp_path / f"{name}.seq"
    p.write_text(HEAD + body)
    return p


def _read_seq(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_seq(path).double()


def test_elx_ely_on_a_lens_surface_with_adx_ady(tmp_path):
    """``ELX 3; ELY 2; ADX 0.5; ADY -1`` on a lens's first surface (R 50): rays parallel to
    the axis inside the ellipse about (0.5, -1) pass, outside are blocked (the 6 mm stop and
    the rear surface do not limit them); ``write_seq`` writes it back, the re-read lens is the
    same, and the .zmx and JSON formats keep it too."""
    path = _seq(tmp_path, "S 0 5\n  STO\n  CIR 6\nS 50 4 517000.642000\n  ELX 3; ELY 2\n"
                          "  ADX 0.5; ADY -1\nS 0 30\n  CIR 8\nSI 0 0\n")
    lens = _read_seq(path)
    s = lens.surfaces[1]
    assert isinstance(s, Asphere) and clear_ellipse_of(s) == (3.0, 2.0)
    assert [float(v) for v in s.clear_decenter] == [0.5, -1.0]
    _check_rim(lens, 3.0, 2.0, centre=(0.5, -1.0), z0=-1.0)
    write_seq(lens, tmp_path / "out.seq")
    out = (tmp_path / "out.seq").read_text()
    assert "ELX 3.0" in out and "ELY 2.0" in out and "ADX 0.5" in out and "ADY -1.0" in out
    again = _read_seq(tmp_path / "out.seq")
    assert lens_to_dict(again) == lens_to_dict(lens)
    write_zmx(lens, tmp_path / "out.zmx")
    assert lens_to_dict(read_zmx(tmp_path / "out.zmx")) == lens_to_dict(lens)


def test_rayoptics_reads_elx_as_the_x_half_width(tmp_path):
    """The oracle for the argument order: rayoptics' CODE V reader (``cmdproc.aperture_data``)
    reads the file ``write_seq`` wrote for an ellipse of half-axes (3, 2) about (0.5, -1) as an
    ``Elliptical`` with ``x_half_width`` 3, ``y_half_width`` 2 and offsets (0.5, -1)."""
    pytest.importorskip("rayoptics")
    from rayoptics.elem.surface import Elliptical
    from rayoptics.environment import open_model

    lens = _read_seq(_seq(tmp_path, "S 0 5\n  STO\n  CIR 6\nS 50 4 517000.642000\n  ELX 3\n"
                                    "  ELY 2; ADX 0.5; ADY -1\nS 0 30\n  CIR 8\nSI 0 0\n"))
    write_seq(lens, tmp_path / "out.seq")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opm = open_model(str(tmp_path / "out.seq"))
    cas = [ca for ifc in opm["seq_model"].ifcs for ca in ifc.clear_apertures
           if isinstance(ca, Elliptical)]
    assert len(cas) == 1
    ca = cas[0]
    assert (ca.x_half_width, ca.y_half_width, ca.x_offset, ca.y_offset) == (3.0, 2.0, 0.5, -1.0)


def test_elx_on_a_flat_surface_in_air_is_an_elliptical_aperture(tmp_path):
    """``ELX 1.5; ELY 1; ADY 0.5`` on a flat surface in air (not the stop): an
    :class:`Aperture` of shape ``"ellipse"`` about (0, 0.5), which would otherwise be a
    dummy."""
    lens = _read_seq(_seq(tmp_path, "S 0 2\n  ELX 1.5\n  ELY 1\n  ADY 0.5\nS 0 5\n  STO\n"
                                    "  CIR 6\nS 50 4 517000.642000\n  CIR 8\nS 0 30\n  CIR 8\n"
                                    "SI 0 0\n"))
    ap = lens.surfaces[0]
    assert isinstance(ap, Aperture) and ap.shape == "ellipse"
    _check_rim(lens, 1.5, 1.0, centre=(0.0, 0.5), z0=-0.5)
    write_seq(lens, tmp_path / "out.seq")
    assert lens_to_dict(_read_seq(tmp_path / "out.seq")) == lens_to_dict(lens)


@pytest.mark.parametrize("block, needle, match", [
    ("  ELX 3\n", "ELX", "needs both ELX and ELY"),
    ("  ELX 3; ELY 2; REX 1; REY 1\n", "REY", "REX/REY and ELX/ELY on one surface"),
    ("  CIR 4\n  ELX 3; ELY 2\n", "CIR 4", "CIR and ELX/ELY on one surface"),
    ("  ELX OBS 1\n", "ELX", "obscuration or hole is not supported"),
    ("  ELX 3; ELY 2; ARO 10\n", "ARO", "a rotated aperture is not supported"),
    ("  ELX 0\n", "ELX", "expected a half-width > 0"),
])
def test_codev_refusals_name_the_line(tmp_path, block, needle, match):
    body = f"S 0 5\n  STO\n  CIR 6\nS 50 4 517000.642000\n{block}S 0 30\n  CIR 8\nSI 0 0\n"
    path = _seq(tmp_path, body)
    with pytest.raises(LensFileError, match=match) as e:
        _read_seq(path)
    assert f":{_line(HEAD + body, needle)}" in str(e.value)


def test_an_elliptical_codev_stop_is_refused_at_the_epd_line(tmp_path):
    """A .seq file gives EPD or FNO, which deeplens applies to a circular or rectangular stop
    (a rectangle keeps its outline and vignettes the pupil, branch set6): an elliptical flat stop
    is refused at the EPD line, naming its shape."""
    body = "S 0 5\n  STO\n  ELX 2; ELY 1\nS 50 4 517000.642000\n  CIR 8\nS 0 30\n  CIR 8\nSI 0 0\n"
    path = _seq(tmp_path, body)
    with pytest.raises(LensFileError,
                       match="needs a circular or rectangular stop .this Aperture is elliptical"
                       ) as e:
        _read_seq(path)
    assert e.value.line == _line(HEAD + body, "EPD")


def test_a_rectangular_codev_stop_under_an_epd_keeps_its_rectangle(tmp_path):
    """``REX 2; REY 1`` on a flat stop under ``EPD``: the lens loads, the stop keeps half-widths
    (2, 1) mm, and its nominal semi-diameter is the pupil's (the stop is in front of the lens,
    so it is the EPD's radius, 6 mm)."""
    body = "S 0 5\n  STO\n  REX 2; REY 1\nS 50 4 517000.642000\n  CIR 8\nS 0 30\n  CIR 8\nSI 0 0\n"
    lens = _read_seq(_seq(tmp_path, body))
    stop = lens.stop
    assert stop.opening.outer.kind == "rect"
    assert [float(v) for v in stop.opening.outer.half_widths] == pytest.approx([2.0, 1.0],
                                                                               rel=1e-12)
    assert float(stop.semi_diameter) == pytest.approx(6.0, rel=1e-9)
