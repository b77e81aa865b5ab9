"""``TYPE USERSURF US_ARRAY.DLL`` (OpticStudio's sample lenslet-array surface) in ``.zmx`` files:
read into :class:`~deeplens.optics.surfaces.LensletArray` (``PARM 1``/``2`` the counts along
x/y, ``PARM 3``/``4`` the widths), checked against the automatic semi-diameters OpticStudio
itself traced and stored in two of its sample files (written afresh here: the ±y marginal and
chief rays' heights, to the 13 digits printed), written back, and what no source fixes refused
on its line (an even count, ``PARM 0``/``5..12``, ``CONI``) or named in a located warning
(unequal x/y pairs, an opening beyond the array)."""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import assert_refused_on_line, assert_written_back, write

from deeplens.optics.io.zmx import ZemaxFileError, read_zmx, write_zmx
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import LensletArray
from helpers import read_zmx_quiet

F64 = torch.float64


def array_block(k, curv, parms=None, extra=(), dll="US_ARRAY.DLL"):
    """A ``SURF k`` block of the DLL surface: ``parms`` the PARM 0..12 values (5 x 5 lenslets
    of 50 units by default), ``extra`` more records (DISZ, GLAS, DIAM, ...)."""
    if parms is None:
        parms = [0, 5, 5, 50, 50] + [0] * 8
    return [f"SURF {k}", f"  TYPE USERSURF {dll}", f"  CURV {curv!r}",
            *[f"  PARM {i} {v!r}" for i, v in enumerate(parms)], *[f"  {e}" for e in extra]]


#: OpticStudio's short-course sample "sc_uds1": a 5 x 5 array of 50 mm lenslets (R 100 mm, BK7)
#: as the stop, EPD 250 mm, 0.55 µm, a plane 10 mm behind (in the glass) and the image 186.27 mm
#: on: the automatic semi-diameters OpticStudio stored there, the ±y marginal rays' heights
UDS1_OS = (124.4027397083, 99.5236051065)


def uds1_file(parms=None, curv=0.01, dll="US_ARRAY.DLL", extra=()):
    lines = ["VERS 80915 14 20100", "MODE SEQ", "NAME lenslet array", "UNIT MM X W X CM MR CPMM",
             "ENPD 250", "GCAT SCHOTT", "FTYP 0 0 1 1 0 0 0", "XFLD 0", "YFLD 0", "WAVL 0.55",
             "PWAV 1",
             "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
             *array_block(1, curv, parms, ["STOP", "DISZ 10", *extra,
                                           "GLAS BK7 0 0 1.5 40 0 0 0 0 0 0",
                                           "DIAM 125 0 0 0 1"], dll),
             "SURF 2", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 186.2703547242",
             "  DIAM 124.4027397083 0 0 0 1",
             "SURF 3", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 99.5236051065 0 0 0 1"]
    return "\n".join(lines) + "\n"


def _heights(lens, o, d, wavelength):
    """``(hits, image)``: the rays' radial heights (mm) at every surface and on the image."""
    rays = Rays(o, d, wavelength)
    _, hits = lens.trace(rays, record=True)
    img = lens.trace_to_sensor(rays)
    assert img.valid.all()
    return ([torch.hypot(h[:, 0], h[:, 1]) for h in hits],
            torch.hypot(img.o[:, 0], img.o[:, 1]))


@pytest.mark.parametrize("dll", ["US_ARRAY.DLL", "US_Array.dll"])
def test_uds1_marginal_rays_meet_opticstudios_semi_diameters(tmp_path, dll):
    """PARM 3 the width and a lenslet on the vertex: the ±y marginal rays (y = ±125 mm, the
    array's edge) meet the lenslets centred at ±100 mm and cross the plane and the image at the
    heights OpticStudio stored, to 1e-10 mm (13 printed digits; a corner on the vertex puts them
    at 125.0014 and 127.57 mm).  The DLL's name is read in either case."""
    lens = read_zmx_quiet(write(tmp_path, uds1_file(dll=dll)))
    s = lens.surfaces[0]
    assert isinstance(s, LensletArray) and s.counts == (5, 5)
    assert [float(w) for w in s.lenslet_widths] == [50.0, 50.0] and float(s.c) == 0.01
    with torch.no_grad():
        for t in lens.surfaces:
            t.semi_diameter.fill_(200.0)
    o = torch.tensor([[0.0, 125.0, -1.0], [0.0, -125.0, -1.0]], dtype=F64)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(2, 3)
    hits, img = _heights(lens, o, d, 550.0)
    assert hits[1].tolist() == pytest.approx([UDS1_OS[0]] * 2, abs=1e-10)
    assert img.tolist() == pytest.approx([UDS1_OS[1]] * 2, abs=1e-10)
    # the paraxial data are the on-axis lenslet's: f = R / (n - 1) in the glass's units
    n = float(lens.materials[1].n(550.0))
    assert float(paraxial(lens).efl) == pytest.approx(100.0 / (n - 1.0), rel=1e-12)


#: OpticStudio's sample "sc_array1": an object 60 mm before a paraboloid mirror (R 120 mm, the
#: stop, EPD 75 mm) and, folded back, two 9 x 9 arrays of 8.33 mm lenslets (R -25 and +25 mm,
#: B270) and two B270 lenses, object heights 0 and ±2.5 mm, the F, d and C lines: the automatic
#: semi-diameters OpticStudio stored on the mirror, the nine surfaces after it and the image
ARR1_OS = (34.59164175216, 36.49825956956, 36.43448973223, 34.87418867073, 34.80680307492,
           33.30730456091, 30.95476115424, 26.03454116152, 19.87461794874, 14.69836514619)


def arr1_file():
    parms = [0, 9, 9, 8.33, 8.33] + [0] * 8
    b270 = "GLAS B270 0 0 1.5 40 0 0 0 0 0 0"

    def std(k, curv, disz, glas=None):
        return [f"SURF {k}", "  TYPE STANDARD", f"  CURV {curv!r}", f"  DISZ {disz!r}",
                *([f"  {glas}"] if glas else [])]

    lines = ["VERS 80915 52 20100", "MODE SEQ", "NAME lenslet arrays", "UNIT MM X W X CM MR CPMM",
             "ENPD 75", "GCAT SCHOTT MISC", "FTYP 1 0 3 3 0 0 0", "XFLD 0 0 0", "YFLD 0 -2.5 2.5",
             "WAVL 0.4861327 0.5875618 0.6562725", "PWAV 2",
             *std(0, 0.0, 60.0),
             "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV -0.008333333333333", "  CONI -1",
             "  DISZ -75", "  GLAS MIRROR 0 0 1.5 40 0 0 0 0 0 0",
             *array_block(2, -0.04, parms, ["DISZ -3", b270]),
             *std(3, 0.0, -45.0), *std(4, 0.0, -3.0, b270),
             *array_block(5, 0.04, parms, ["DISZ -10"]),
             *std(6, -0.02, -20.0, b270), *std(7, 0.0, -10.0), *std(8, 0.0, -20.0, b270),
             *std(9, -0.02, -35.0), *std(10, 0.0, 0.0)]
    return "\n".join(lines) + "\n"


def test_arr1_rays_meet_opticstudios_ten_semi_diameters(tmp_path):
    """Two arrays, a mirror, three object heights and three wavelengths: the largest height of
    the ±y marginal and chief rays (aimed at the paraxial pupil, the mirror's vertex plane) on
    the mirror, each surface after it and the image equals the ten semi-diameters OpticStudio
    stored, to 1e-10 mm (the off-axis marginal rays cross the arrays in their eighth and ninth
    lenslets; a corner on the vertex misses by up to 9 mm).  Traced through the semi-diameters
    deeplens gives the file (automatic: the arrays' are not capped at one lenslet's sphere)."""
    lens = read_zmx_quiet(write(tmp_path, arr1_file()))
    arrays = [s for s in lens.surfaces if isinstance(s, LensletArray)]
    assert len(arrays) == 2 and [float(s.c) for s in arrays] == [-0.04, 0.04]
    # their automatic semi-diameters (no DIAM) reach past one lenslet's sphere (|R| = 25 mm):
    # the array's extent caps them, not the conic's, and every ray below passes them
    assert all(36.0 < float(s.semi_diameter) <= s.domain_radius() for s in arrays)
    z_obj = float(lens.z_vertices()[0]) - 60.0
    top = torch.zeros(len(ARR1_OS), dtype=F64)
    for w in lens.spec.wavelengths_nm:
        for yf in (0.0, -2.5, 2.5):
            o = torch.tensor([[0.0, yf, z_obj]], dtype=F64).expand(3, 3)
            aim = torch.tensor([[0.0, 37.5, 60.0], [0.0, -37.5, 60.0], [0.0, 0.0, 60.0]],
                               dtype=F64) + torch.tensor([0.0, 0.0, z_obj])
            d = aim - o
            hits, img = _heights(lens, o, d / d.norm(dim=-1, keepdim=True), float(w))
            h = torch.stack([*[x.max() for x in hits], img.max()])
            top = torch.maximum(top, h)
    assert top.tolist() == pytest.approx(list(ARR1_OS), abs=1e-10)


def test_write_and_read_back(tmp_path):
    lens = read_zmx_quiet(write(tmp_path, uds1_file()))
    assert_written_back(tmp_path, lens, ["TYPE USERSURF US_ARRAY.DLL", "PARM 1 5", "PARM 2 5",
                                         "PARM 3 50.0", "PARM 4 50.0", "PARM 12 0"])


def test_even_counts_and_a_conic_are_not_written(tmp_path):
    lens = read_zmx_quiet(write(tmp_path, uds1_file()))
    lens.surfaces[0] = LensletArray(0.01, 125.0, (4, 5), (50.0, 50.0))
    with pytest.raises(ZemaxFileError, match=r"an even lenslet count \(4 x 5\) is not written"):
        write_zmx(lens, tmp_path / "out.zmx")
    lens.surfaces[0] = LensletArray(0.01, 125.0, (5, 5), (50.0, 50.0), conic=-1.0)
    with pytest.raises(ZemaxFileError, match=r"a conic on the lenslets \(k = -1\) is not "
                                             r"written"):
        write_zmx(lens, tmp_path / "out.zmx")


@pytest.mark.parametrize("parms,needle,match", [
    ([0, 4, 5, 50, 50] + [0] * 8, "PARM 1 4",
     r"US_ARRAY PARM 1 = 4: an even lenslet count is not read: whether OpticStudio's sample DLL "
     r"puts a lenslet or a corner on the vertex then is in no source at hand"),
    ([0, 5, 2, 50, 50] + [0] * 8, "PARM 2 2", r"US_ARRAY PARM 2 = 2: an even lenslet count"),
    ([0, 5, 5, 50, 50, 0.5] + [0] * 7, "PARM 5 0.5",
     r"US_ARRAY PARM 5 = 0.5 is not read \(what it means is in no source at hand"),
    ([1, 5, 5, 50, 50] + [0] * 8, "PARM 0 1", r"US_ARRAY PARM 0 = 1 is not read"),
    ([0, 5, 5, 50, 0] + [0] * 8, "PARM 4 0",
     r"US_ARRAY PARM 4 = 0: the lenslet width along y must be > 0"),
    ([0, 5.5, 5, 50, 50] + [0] * 8, "PARM 1 5.5",
     r"PARM 1 = 5.5: the number of lenslets along x must be a whole number >= 1"),
    ([0, 5, 5], "TYPE USERSURF", r"SURF 1: US_ARRAY without PARM 3 \(the lenslet width along "
                                 r"x\)"),
])
def test_what_no_source_fixes_is_refused_on_its_line(tmp_path, parms, needle, match):
    assert_refused_on_line(tmp_path, uds1_file(parms), needle, match)


def test_a_conic_on_the_lenslets_is_refused(tmp_path):
    assert_refused_on_line(tmp_path, uds1_file(extra=["CONI -0.5"]), "TYPE USERSURF",
                           r"US_ARRAY with CONI -0.5: a conic on the lenslets is not read")


def test_another_dll_is_still_refused_naming_it(tmp_path):
    text = uds1_file().replace("US_ARRAY.DLL", "US_HEXARRAY.DLL")
    assert_refused_on_line(tmp_path, text, "TYPE USERSURF",
                           r"surface type 'USERSURF' \(SURF 1\) is not supported: its shape is "
                           r"computed by OpticStudio's compiled plug-in US_HEXARRAY.DLL")


def test_unequal_pairs_load_with_a_warning_naming_the_order(tmp_path):
    """7 x 3 lenslets of 30 x 80 mm: read with PARM 1/3 along x and PARM 2/4 along y (one
    located warning saying so: every file confirming the layout has equal pairs)."""
    text = uds1_file([0, 7, 3, 30, 80] + [0] * 8)
    with pytest.warns(UserWarning, match=r"SURF 1: US_ARRAY: 7 x 3 lenslets of 30 x 80 read with "
                                         r"PARM 1 and PARM 3 along x, PARM 2 and PARM 4 along y"):
        lens = read_zmx(write(tmp_path, text))
    s = lens.surfaces[0]
    assert s.counts == (7, 3) and [float(w) for w in s.lenslet_widths] == [30.0, 80.0]


def test_an_opening_beyond_the_array_warns_that_rays_there_are_blocked(tmp_path):
    """A 3 x 3 array of 50 mm (75 mm from the vertex) under a 125 mm DIAM: one located warning
    at the DIAM line; rays beyond 75 mm miss the surface."""
    text = uds1_file([0, 3, 3, 50, 50] + [0] * 8)
    with pytest.warns(UserWarning, match=r"the opening \(DIAM 125 x 125\) reaches beyond the 3 x "
                                         r"3 array \(75 x 75 from the vertex\): rays landing "
                                         r"outside it are blocked"):
        lens = read_zmx(write(tmp_path, text))
    o = torch.tensor([[0.0, 74.0, -1.0], [0.0, 76.0, -1.0]], dtype=F64)
    out = lens.trace(Rays(o, torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(2, 3), 550.0))
    assert out.valid.tolist() == [True, False]
    assert math.isfinite(float(paraxial(lens).efl))
