"""``XOSPHERE``, OpticStudio's Extended Odd Asphere: ``z = STANDARD + Σ A_i (r / R_n)^i``, every
power of the normalised radius from ρ¹ on, the coefficients in lens units (``XDAT 1`` the maximum
term number, ``XDAT 2`` the normalisation radius, ``XDAT i + 2`` the coefficient on ``ρ^i``:
:mod:`deeplens.optics.io.zmx_xosphere`).

The sag of a hand-written file is worked out here from that formula (mm and inches); the file is
written back and read again bit for bit; two independent readings: rayoptics reads the
``XOSPHERE`` file itself (``R_n`` = 1, which is all its reader takes) and gives the same
first-order numbers and real rays to 1e-9; optiland reads the same surface written as an
``ODDASPHE`` with ``a_i = A_i / R_n^i`` (``R_n`` = 2.5) and gives the same EFL, BFL and real
rays to 1e-9.  What the reader refuses is refused on its line.
"""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest
import torch
from test_zmx import assert_refused_on_line, singlet, write
from test_zmx_corpus import _first_order, _oracle

from deeplens.optics.io import lens_to_dict, read_zmx, write_zmx
from deeplens.optics.options import TraceOptions
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Asphere, ExtendedOddAsphere
from helpers import read_zmx_quiet

C, K, RN = 0.02, -0.5, 2.5
#: A_i on ρ^i (lens units): no ρ¹ (refused) nor ρ² (both oracles' paraxial models take CURV alone)
TERMS = {3: 4e-3, 4: -2e-3, 5: 3e-4, 6: 1e-4, 8: -4e-6}


def xosphere(terms=TERMS, rn=RN, unit="MM", n=None):
    """The test singlet (:func:`test_zmx.singlet`) with an ``XOSPHERE`` front (its numbers in
    ``unit``), every term ``XDAT 3 .. n + 2`` written, zeros too, as OpticStudio writes them
    (rayoptics' reader counts the XDAT lines, not their numbers)."""
    n = max(terms) if n is None else n
    rec = (f"XDAT 1 {n}", f"XDAT 2 {rn!r}",
           *[f"XDAT {i + 2} {float(terms.get(i, 0.0))!r}" for i in range(1, n + 1)])
    return singlet(s1_type="XOSPHERE", s1_extra=rec, curv1=C, k=K, unit=unit)


def hand_sag(r, terms=TERMS, rn=RN, c=C, k=K, scale=1.0):
    """The Extended Odd Asphere's sag (mm) at radius ``r`` (mm), worked out by hand from the
    file's numbers in a unit of ``scale`` mm."""
    c, rn = c / scale, rn * scale
    z = c * r * r / (1 + math.sqrt(1 - (1 + k) * c * c * r * r))
    return z + sum(v * scale * (r / rn) ** i for i, v in terms.items())


@pytest.mark.parametrize("unit,s", [("MM", 1.0), ("IN", 25.4)])
def test_sag_is_the_extended_odd_asphere_formula(tmp_path, unit, s):
    """Each XDAT i + 2 on ρ^i, R_n and A_i scaled to mm: the sag at five radii is the formula's
    (1e-13 mm); the surface is an ExtendedOddAsphere keeping the normalised coefficients."""
    lens = read_zmx_quiet(write(tmp_path, xosphere(unit=unit)))
    surf = lens.surfaces[1]
    assert type(surf) is ExtendedOddAsphere
    assert float(surf.norm_radius) == pytest.approx(RN * s, rel=1e-15)
    want = [TERMS.get(i, 0.0) * s for i in range(1, max(TERMS) + 1)]
    assert [float(v) for v in surf.a] == pytest.approx(want, rel=1e-15, abs=0)
    for r in (0.0, 0.7, 1.9, 3.3, 4.1):   # in file units; the same points in mm
        x = torch.tensor(r * 0.6 * s, dtype=torch.float64)
        y = torch.tensor(r * 0.8 * s, dtype=torch.float64)
        assert float(surf.sag(x, y)) == pytest.approx(hand_sag(r * s, scale=s), abs=1e-13 * s)


def test_written_back_and_read_again(tmp_path):
    """write_zmx writes XOSPHERE (XDAT 1 N, XDAT 2 R_n, the terms); read back, the same lens bit
    for bit, from an inch file too."""
    for unit in ("MM", "IN"):
        lens = read_zmx_quiet(write(tmp_path, xosphere(unit=unit), f"in_{unit}.zmx"))
        out = tmp_path / f"out_{unit}.zmx"
        write_zmx(lens, out)
        text = out.read_text()
        assert "TYPE XOSPHERE" in text and "XDAT 1 8" in text
        back = read_zmx_quiet(out)
        a, b = lens_to_dict(lens), lens_to_dict(back)
        a.pop("name", None), b.pop("name", None)
        assert a == b
        assert float(paraxial(back).efl) == float(paraxial(lens).efl)


def test_no_term_is_the_standard_surface(tmp_path):
    """Every coefficient zero (or N = 0): the Standard surface, read as STANDARD would be."""
    lens = read_zmx_quiet(write(tmp_path, xosphere(terms={3: 0.0}, n=3)))
    plain = read_zmx_quiet(write(tmp_path, singlet(s1_type="STANDARD", s1_extra=(), curv1=C,
                                                   k=K), "std.zmx"))
    assert type(lens.surfaces[1]) is Asphere
    assert lens_to_dict(lens)["surfaces"] == lens_to_dict(plain)["surfaces"]


def _rays_xy():
    """Ray starts (x, y) on a plane 10 mm before SURF 1 and their directions (y-z plane tilts)."""
    out = []
    for x, y in ((0.0, 0.0), (0.0, 3.0), (1.5, -2.5), (-2.0, 1.0), (0.0, 4.2)):
        for a in (0.0, 0.05):
            out.append(((x, y), (0.0, math.sin(a), math.cos(a))))
    return out


def _deeplens_landings(lens):
    z0 = float(lens.z_vertices()[0]) - 10.0
    o = torch.tensor([[x, y, z0] for (x, y), _ in _rays_xy()], dtype=torch.float64)
    d = torch.tensor([dd for _, dd in _rays_xy()], dtype=torch.float64)
    with torch.no_grad():
        out = lens.trace_to_sensor(Rays(o, d, float(lens.spec.primary_wavelength_nm)),
                                   options=TraceOptions(clip_aperture=False))
    assert bool(out.valid.all())
    return out.o[:, :2].tolist()


def test_first_order_and_real_rays_match_rayoptics_reading_of_the_file(monkeypatch, tmp_path):
    """rayoptics 0.9 reads XOSPHERE itself (its RadialPolynomial, XDAT 3.. from ρ¹ on; it takes
    no R_n, so R_n = 1 here): EFL, EPD, entrance pupil and back focal point to 1e-9
    (test_zmx_corpus_rayoptics' comparison), and ten real rays, skew ones too, land where its
    trace puts them to 1e-9 mm.  The terms matter: the bare conic's rays land > 1e-3 mm apart."""
    from test_zmx_corpus_rayoptics import _assert_agrees, _corpus_of_one, _rayoptics, _update

    pytest.importorskip("rayoptics")
    from rayoptics.raytr.trace import trace

    name = "xosphere_rn1.zmx"
    lens, scratch = _corpus_of_one(name, xosphere(rn=1.0, terms={3: 1e-4, 4: -2e-5, 5: 1e-6,
                                                                 7: -3e-9}),
                                   monkeypatch, tmp_path)
    opm = _rayoptics(name, lens, monkeypatch, scratch)
    _assert_agrees(name, lens, opm)
    sm = opm["seq_model"]
    sm.gaps[0].thi = 10.0
    _update(opm)
    wl = float(lens.spec.primary_wavelength_nm)
    want = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for (x, y), d in _rays_xy():
            ray = trace(sm, np.array([x, y, 0.0]), np.array(d), wl)[0]
            want.append(list(ray[-1][0][:2]))
    got = _deeplens_landings(lens)
    for g, w in zip(got, want):
        assert g == pytest.approx(w, abs=1e-9)
    bare = read_zmx_quiet(write(tmp_path, xosphere(rn=1.0, terms={3: 0.0}, n=3), "bare.zmx"))
    assert max(abs(a - b) for g, h in zip(got, _deeplens_landings(bare))
               for a, b in zip(g, h)) > 1e-3


def test_corpus_oracle_gives_rayoptics_the_normalisation_radius_and_the_rho2_term(monkeypatch,
                                                                                  tmp_path):
    """The corpus benchmark's rayoptics oracle (test_zmx_corpus_rayoptics._rayoptics) on a file
    with R_n = 2.5 and a ρ² term: zmxread ignores XDAT 2 and its paraxial model takes CURV alone,
    so the oracle gives it ``A_i / R_n^i`` on ``r^i`` and the vertex curvature ``CURV + 2 A_2 /
    R_n²``; then EFL, EPD, pupil and back focus agree to 1e-9, and from CURV alone they do
    not."""
    from test_zmx_corpus_rayoptics import (_agrees, _assert_agrees, _corpus_of_one, _numbers,
                                           _rayoptics, _update)

    pytest.importorskip("rayoptics")
    name = "xosphere_rn.zmx"
    lens, scratch = _corpus_of_one(name, xosphere(terms={2: 0.05, **TERMS}), monkeypatch,
                                   tmp_path)
    opm = _rayoptics(name, lens, monkeypatch, scratch)
    prof = opm["seq_model"].ifcs[2].profile
    assert prof.coefs[:4] == pytest.approx([0.0, 0.05 / RN ** 2, TERMS[3] / RN ** 3,
                                            TERMS[4] / RN ** 4], rel=1e-15)
    _assert_agrees(name, lens, opm)
    prof.cv = C
    _update(opm)
    assert not _agrees(*_numbers(name, lens, opm)["EFL"])


def test_first_order_and_real_rays_match_optilands_odd_asphere(tmp_path):
    """optiland reads the same surface written as ODDASPHE, ``PARM i = A_i / R_n^i`` (R_n =
    2.5, worked out here): its EFL, BFL, EPD and entrance pupil agree to 1e-9 relative with
    deeplens' reading of the XOSPHERE file, and its real rays of the 5° field (skew ones too)
    land where deeplens' do to 1e-9 mm."""
    from deeplens.optics.sampling import field_rays

    p = write(tmp_path, xosphere(), "x.zmx")
    parms = tuple(f"PARM {i} {TERMS.get(i, 0.0) / RN ** i!r}" for i in range(1, 9))
    q = write(tmp_path, singlet(s1_type="ODDASPHE", s1_extra=parms, curv1=C, k=K), "odd.zmx")
    lens = read_zmx_quiet(p)
    optic, s_mm = _oracle(str(q), lens)
    for what, (a, b) in _first_order(lens, optic, s_mm, str(q)).items():
        assert a == pytest.approx(b, rel=1e-9, abs=1e-9), what
    w = float(lens.spec.primary_wavelength_nm)
    par = paraxial(lens)
    r, z = 0.5 * float(par.entrance_pupil_diameter), float(par.entrance_pupil_z)
    pupil = [(0.0, 0.0), (0.0, 0.9), (0.0, -0.9), (0.8, 0.0), (0.5, 0.5), (-0.6, 0.3)]
    with torch.no_grad():
        xy = torch.tensor(pupil, dtype=lens.dtype) * r
        out = lens.trace_to_sensor(field_rays(lens, 5.0, w, xy, z),
                                   options=TraceOptions(clip_aperture=False))
    assert bool(out.valid.all())
    sign = None
    for (px, py), o in zip(pupil, out.o):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            optic.trace_generic(0.0, 1.0, px, py, w / 1000.0)
        sg = optic.surface_group
        x, y = (float(torch.as_tensor(c)[-1].reshape(-1)[0]) for c in (sg.x, sg.y))
        # deeplens' field angle points the other way in y: the sign from the chief ray
        sign = sign or (1.0 if abs(float(o[1]) - y) < abs(float(o[1]) + y) else -1.0)
        assert [float(o[0]), float(o[1])] == pytest.approx([x, sign * y], abs=1e-9), (px, py)
    assert abs(float(out.o[0, 1])) > 1.0   # a real field height, not the axis


@pytest.mark.parametrize("edit,needle,match", [
    (lambda t: t.replace("XDAT 1 8", "XDAT 1 8\n  PARM 2 0.1"), "PARM 2 0.1",
     r"SURF 2: XOSPHERE PARM 2 = 0.1 is not read"),
    (lambda t: t.replace("XDAT 1 8", "XDAT 1 8.5"), "XDAT 1 8.5",
     r"XOSPHERE XDAT 1 \(the maximum term number\) must be an integer 0\.\.240, got 8\.5"),
    (lambda t: t.replace("XDAT 1 8", "XDAT 1 241"), "XDAT 1 241",
     r"XOSPHERE XDAT 1 \(the maximum term number\) must be an integer 0\.\.240"),
    (lambda t: t.replace("XDAT 1 8", "XDAT 1 7"), "XDAT 10 ",
     r"XOSPHERE XDAT 10 lies beyond the 7 terms XDAT 1 declares"),
    (lambda t: t.replace("XDAT 2 2.5", "XDAT 2 0"), "XDAT 2 0",
     r"XOSPHERE XDAT 2 \(the normalisation radius\) must be > 0, got 0\.0"),
    (lambda t: t.replace("XDAT 3 0.0", "XDAT 3 0.01"), "XDAT 3 0.01",
     r"XOSPHERE XDAT 3 \(the ρ¹ term, a cone tip on the axis\) = 0\.01 is refused: no source "
     r"at hand says how OpticStudio's paraxial data treat it"),
])
def test_refused_on_its_line(tmp_path, edit, needle, match):
    assert_refused_on_line(tmp_path, edit(xosphere()), needle, match)


def test_a_fixed_diam_in_air_does_not_clip(tmp_path):
    """XOSPHERE is a shape alone (its format's ``shape_only``): between air on both sides a
    fixed DIAM does not clip (the note at its line), as for every shape-only type."""
    text = xosphere().replace("  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0\n", "")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_zmx(write(tmp_path, text))
    # both faces lie in air: one warning for the cause, naming each surface
    assert any(re.search(r"SURF 2\b.*a fixed DIAM of a curved surface in one medium \(no "
                         r"refractive power\).* does not clip", str(w.message)) for w in caught)


def test_counts_as_rotationally_symmetric_for_tilt_conversions():
    """A pair of breaks tilting an Extended Odd Asphere about x and y becomes the element's
    misalignment (as for the odd asphere): the surface is a function of r alone."""
    from deeplens.optics.io.zmx_system import rotationally_symmetric

    assert rotationally_symmetric(ExtendedOddAsphere(C, 5.0, RN, [0.0, 0.0, 1e-3]))
