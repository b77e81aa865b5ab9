"""A second independent reading of the real ``.zmx`` corpus (tests/data/zmx_real): rayoptics'
own ``.zmx`` reader (``rayoptics.zemax.zmxread``, a test-only oracle) against deeplens' first-order
numbers of the same file: EFL, entrance pupil diameter and position, back focal point.

As in test_zmx_corpus.py (optiland), the oracle gets deeplens' refractive index at the primary
wavelength for every gap (an ``opticalglass`` ``ConstantIndex`` medium at the same position along
the light's path), so the comparison checks the reading of the prescription (surfaces, spacings,
stop, pupil, units, mirrors) independently of the two libraries' glass data.  Both sides are
float64 paraxial traces of the same numbers: they agree to ~1e-13 relative; the tolerance below
(1e-9 relative) leaves room for round-off grown through 30 surfaces and nothing else (a thickness
read off by one surface moves the numbers by > 1e-4).

Where the oracle reads a file differently by a documented convention of its own, the oracle is
given deeplens' convention (with the source of each in the code below); what it cannot read at all
is in :data:`NOT_CONFIRMED` with the reason, and the test checks that the reason still holds.
"""

from __future__ import annotations

import math
import re
import shutil
import warnings

import pytest

from deeplens.optics.io.agf import decode_zemax_text
from deeplens.optics.paraxial import paraxial
from test_zmx_corpus import (CORPUS, FILES, REFUSED, _dl_path_coords, _even_r2_terms,
                             _file_path_coords, _floa_stop_radius, _load, _medium_after,
                             _plain_planes, _unit_mm, grid_sag_vertex_curvatures,
                             qtype_vertex_curvatures, xpolynom_vertex_curvatures)

#: file -> (the quantities rayoptics cannot confirm, the verified reason).  Every other loaded
#: file is confirmed on all four numbers.
NOT_CONFIRMED = {
    # (the three FLOA files, optiland_lens_floa, nerfzemax_Ray_generation_for_NeRF_data_demo and
    # deeplens_zemax_double_gaussian, are confirmed since rayoptics' own marginal ray is scaled to
    # the stop's size: _float_by_stop_size, test_floating_stop_pupil_is_rayoptics_own_ray)
    # an object space of index n0 = 0.999982 (the file's air at its temperature and pressure,
    # relative to the air at the reference conditions): rayoptics' entrance pupil distance is
    # deeplens' / n0² (to 1e-15: its compute_first_order divides by n_0 a principal-ray slope
    # that is already reduced; optiland's geometric reading agrees with deeplens), and the EPD
    # of its OBNA aperture, a slope times that distance, follows it; EFL and BFL agree to 1e-9
    # (test_object_space_index_in_rayoptics_pupil)
    "patent2zemax_US20030048547A1-3.zmx": ({"EPD", "EP position"},
                                           "rayoptics' EP distance is reduced by n0² (n0 != 1)"),
}

#: where deeplens puts the sensor behind an image plane on the last vertex (mm; Zemax guide)
IMAGE_ON_VERTEX_MM = 1e-9

#: the numbers compared, by name
QUANTITIES = ("EFL", "EPD", "EP position", "BFL")


def _media_per_gap(name, lens):
    """deeplens' refractive index (primary wavelength) after each ``SURF`` block of the file but
    the image (the file's gaps, object space first): each non-``COORDBRK`` surface is matched to
    deeplens' surfaces by its path coordinate (as the optiland oracle does); a ``COORDBRK`` does
    not change the medium."""
    s_mm = _unit_mm(name)
    w = float(lens.spec.primary_wavelength_nm)
    n_dl = [float(m.n(w)) for m in lens.materials]
    p_dl = _dl_path_coords(lens) / s_mm
    types, _, q_all = _file_path_coords(CORPUS / name)
    keep = [k for k, t in enumerate(types) if t != "COORDBRK"]
    q = [q_all[k] for k in keep]
    out = [None] * len(types)
    for k, j in zip(keep[:-1], _medium_after(lens, p_dl, q, _plain_planes(CORPUS / name))):
        out[k] = n_dl[j]
    for k, n in enumerate(out):
        if n is None:   # a COORDBRK: the medium before it
            out[k] = out[k - 1] if k else n_dl[0]
    return out[:-1]


def _rayoptics(name, lens, monkeypatch, tmp_path):
    """rayoptics' reading of the file (lengths in the file's units) with deeplens' indices."""
    pytest.importorskip("rayoptics")
    # rayoptics' readers open a log file in the working folder: a scratch one
    monkeypatch.chdir(tmp_path)
    import rayoptics.elem.elements as ro_elements
    import rayoptics.elem.parttree as ro_parttree
    from opticalglass.opticalmedium import ConstantIndex
    from rayoptics.zemax import zmxread

    # the element model and part tree (drawing, element grouping) are no part of the paraxial
    # data; their sequence grammar fails on fold-mirror sequences (ParseError "Rule 'image'
    # didn't match" on optiland_simple_fold_mirror_up and _complicated_fold_mirrors_setup_v2)
    monkeypatch.setattr(ro_elements.ElementModel, "update_model", lambda self, **k: None)
    monkeypatch.setattr(ro_parttree.PartTree, "update_model", lambda self, **k: None)
    # read from a copy: for glasses it does not find, zmxread writes (and later reads back) a
    # ``<name>_tmpl.smx`` replacement file beside the file it reads
    src = tmp_path / name
    shutil.copyfile(CORPUS / name, src)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opm, _ = zmxread.read_lens_file(src)
    sm = opm["seq_model"]
    ns = _media_per_gap(name, lens)
    assert len(sm.gaps) == len(ns), "rayoptics' gaps are not the file's: extend the oracle"
    for g, n in zip(sm.gaps, ns):
        g.medium = ConstantIndex(n, f"n={n!r}")
    # OBNA: rayoptics takes an object-space NA as the paraxial marginal slope itself
    # (PupilSpec.derive_parax_params -> etendue.na2slp(na), n = 1: u = NA); deeplens (Zemax
    # guide) takes the real marginal ray's angle, NA = n sin θ, u = tan θ: the oracle gets the
    # value whose slope is that one (the object space of patent2zemax_US20030048547A1-3 has
    # n = 1.000018, seen at 1.7e-5 in its EPD)
    pupil = opm["optical_spec"]["pupil"]
    if tuple(pupil.key) == ("object", "NA"):
        pupil.value = math.tan(math.asin(pupil.value / ns[0]))
    # Zernike sag surfaces: zmxread reads CURV alone; deeplens' stated rule (the Zemax guide)
    # takes the vertex curvature of the rotationally symmetric part, worked out here from the file
    for k, cv in _zernike_vertex_curvatures(name).items():
        sm.ifcs[k].profile.cv = cv
    # Irregular surfaces: zmxread reads CURV alone; deeplens' stated rule takes the y section at
    # the surface's vertex, worked out here from the file
    for k, cv in _irregular_vertex_curvatures(name).items():
        sm.ifcs[k].profile.cv = cv
    # Q-type surfaces: zmxread reads CURV alone; a Qbfs departure has an r² term
    # (x(1 − x) Σ a_m Q_m(x), x = r²/ρ_n²), so the vertex curvature includes it, worked out
    # here from the file (test_zmx_corpus.qtype_vertex_curvatures)
    for k, cv in qtype_vertex_curvatures(name).items():
        sm.ifcs[k].profile.cv = cv
    # Extended Polynomial surfaces (XPOLYNOM): rayoptics 0.9.8 has no XY polynomial profile;
    # its paraxial model gets the vertex curvature worked out from the file's terms
    # (test_zmx_corpus.xpolynom_vertex_curvatures)
    for k, cv in xpolynom_vertex_curvatures(name).items():
        sm.ifcs[k].profile.cv = cv
    # Grid sag surfaces: zmxread reads a plane; deeplens' stated rule (the Zemax guide, Grid
    # sag) takes the interpolated surface's mean vertex curvature, worked out here from the
    # file's GDAT/GARR numbers (test_zmx_corpus.grid_sag_vertex_curvatures)
    for k, cv in grid_sag_vertex_curvatures(name).items():
        sm.ifcs[k].profile.cv = cv
    # Paraxial XY surfaces (anamorphic ideal lenses): zmxread reads a plane; deeplens' stated
    # rule takes the y section, given here as rayoptics' own ideal thin lens of the y power
    for k, phi in _parax_xy_powers(name).items():
        sm.ifcs[k] = _thin_lens(phi)
    # even aspheres with an r² term: zmxread's paraxial model takes CURV alone; deeplens' rule
    # (the vertex curvature, CURV + 2 PARM 1) is given to it as for the Zernike terms
    for k, a1 in _even_r2_terms(name).items():
        sm.ifcs[k].profile.cv += 2.0 * a1
    # Extended Odd Asphere (XOSPHERE): zmxread appends XDAT 3.. as its RadialPolynomial's
    # coefficients from r¹ on and ignores XDAT 2, the normalisation radius: they are given here
    # on r^i (A_i / R_n^i, file units); its paraxial model takes CURV alone, so it gets deeplens'
    # rule, the vertex curvature CURV + 2 A_2 / R_n² (the ρ² term), as the even aspheres above
    for k, _, rec in _surfaces_of_type(name, ("XOSPHERE",)):
        n, rn = int(rec("XDAT", 1)), rec("XDAT", 2, default=1.0)
        prof = sm.ifcs[k].profile
        prof.coefs = [rec("XDAT", i + 2) / rn ** i for i in range(1, n + 1)]
        prof.update()
        if n >= 2:
            prof.cv += 2.0 * prof.coefs[1]
    # Binary 2 surfaces: zmxread reads the base surface alone; the phase's r² term adds the
    # paraxial power of a thin diffractive lens, given to rayoptics as the curvature that
    # refracts the same (a surface's paraxial power is (n' - n) c)
    wl = float(lens.spec.primary_wavelength_nm) * 1e-6 / _unit_mm(name)   # file units
    for k, phi in _binary2_powers(name, wl).items():
        assert ns[k] != ns[k - 1], "a Binary 2 surface between equal media: extend the oracle"
        sm.ifcs[k].profile.cv += phi / (ns[k] - ns[k - 1])
    # Holograms (HOLOGRM1, HOLOGRM2): zmxread reads the substrate alone; the two construction
    # beams' phase is, to second order at the vertex, a thin lens (_hologram_powers, written out
    # from the records): on a mirror given as the curvature that reflects the same (a mirror's
    # paraxial power is -2 n c), between unequal media as the curvature that refracts the same,
    # between equal media (the substrate powerless) as rayoptics' own ideal thin lens
    wl_um = float(lens.spec.primary_wavelength_nm) * 1e-3
    for k, phi in _hologram_powers(name, wl_um).items():
        _give_power(sm, ns, k, phi)
    # Zernike Fringe Phase (FZERNPHA) and Binary 1 (BINARY_1): zmxread reads the base surface
    # alone; the phase's y-z section is, to second order at the vertex, a thin lens
    # (_fzernpha_powers, written out from the published Fringe polynomials; _binary1_powers,
    # from the Extended Polynomial's published term order), given as the hologram's above
    for powers in (_fzernpha_powers(name, wl), _binary1_powers(name, wl)):
        for k, phi in powers.items():
            if phi != 0.0:
                _give_power(sm, ns, k, phi)
    _update(opm)
    if re.search(r"^FLOA\b", decode_zemax_text(CORPUS / name), re.M):
        _float_by_stop_size(name, opm)
    return opm


def _thin_lens(phi):
    """rayoptics' own ideal thin lens of power ``phi`` (file units⁻¹)."""
    import rayoptics.oprops.thinlens as ro_thinlens

    thin = ro_thinlens.ThinLens(power=phi)
    thin.z_type = "PARAXIAL"
    return thin


def _give_power(sm, ns, k, phi):
    """rayoptics' surface ``k`` (of the sequential model ``sm``, media ``ns`` per gap) given the
    thin-lens power ``phi`` of a phase: on a mirror as the curvature that reflects the same (a
    mirror's paraxial power is -2 n c), between unequal media as the curvature that refracts
    the same, between equal media (the substrate powerless) as rayoptics' own ideal thin
    lens."""
    if sm.ifcs[k].interact_mode == "reflect":
        sm.ifcs[k].profile.cv += phi / (-2.0 * ns[k - 1])
    elif ns[k] != ns[k - 1]:
        sm.ifcs[k].profile.cv += phi / (ns[k] - ns[k - 1])
    else:
        sm.ifcs[k] = _thin_lens(phi)


def _surf_blocks(name):
    """The file's ``SURF`` blocks, ``SURF 0`` first (block ``k`` is rayoptics' ``ifcs[k]``)."""
    return re.split(r"^SURF\s+\d+.*$", decode_zemax_text(CORPUS / name), flags=re.M)[1:]


def _surfaces_of_type(name, types):
    """``(k, type, rec)`` for each ``SURF k`` block of the file whose ``TYPE`` is in ``types``;
    ``rec(key, i=None, default=0.0)`` reads the first number of the block's record ``key i``
    (``key`` alone without ``i``), ``default`` where there is none."""
    for k, b in enumerate(_surf_blocks(name)):
        t = re.search(r"^\s+TYPE\s+(\S+)", b, re.M)
        if t is None or t.group(1) not in types:
            continue

        def rec(key, i=None, default=0.0, b=b):
            pat = rf"^\s+{key}\s+{i}\s+(\S+)" if i is not None else rf"^\s+{key}\s+(\S+)"
            m = re.search(pat, b, re.M)
            return float(m.group(1)) if m else default

        yield k, t.group(1), rec


def _float_by_stop_size(name, opm):
    """FLOA (the pupil floats on the stop's semi-diameter ``DIAM``): rayoptics 0.9.8 lists FLOA
    among the commands it does not support and keeps its default pupil (EPD 1).  The pupil the
    file means is the one whose axial marginal ray meets the stop's rim: rayoptics' own axial
    paraxial ray, scaled (a paraxial ray is linear in the pupil size), ``value *= r / |y_stop|``
    with ``r`` the stop's ``DIAM`` (its ``CLAP``'s radius where it has one: deeplens' stated rule,
    :func:`test_zmx_corpus._floa_stop_radius`); then every first-order number is rayoptics' own,
    and the EPD depends on the file's stop size, not on deeplens' reading of it."""
    sm = opm["seq_model"]
    blocks = _surf_blocks(name)
    stop = next(k for k, b in enumerate(blocks) if re.search(r"^\s+STOP\b", b, re.M))
    # rayoptics keeps no stop index for a stop on SURF 1 (None: its first surface)
    assert (sm.stop_surface if sm.stop_surface is not None else 1) == stop, \
        "rayoptics' stop is not the file's: extend the oracle"
    radius = _floa_stop_radius(blocks[stop])
    pupil = opm["optical_spec"]["pupil"]
    assert tuple(pupil.key) == ("object", "epd"), pupil.key
    y_stop = abs(opm["analysis_results"]["parax_data"].ax_ray[stop][0])
    pupil.value *= radius / y_stop
    _update(opm)


#: the rotationally symmetric Zernike terms (m = 0, n >= 2) by index: Fringe order (University
#: of Arizona): Z4, Z9, Z16, Z25, Z36 (n = 2, 4, .., 10: j = (n/2 + 1)²) and Z37 (n = 12), no
#: normalisation; Noll's order (OpticStudio's Standard): the first term of each even row n,
#: j = n (n + 1) / 2 + 1 (Z4, Z11, Z22, Z37, ...), normalised by sqrt(n + 1)
_M0_TERMS = {
    "FZERNSAG": {**{(n // 2 + 1) ** 2: (n, 1.0) for n in range(2, 11, 2)}, 37: (12, 1.0)},
    "SZERNSAG": {n * (n + 1) // 2 + 1: (n, math.sqrt(n + 1)) for n in range(2, 21, 2)},
}


def _zernike_vertex_curvatures(name):
    """``{SURF k: vertex curvature}`` (file units) of the file's Zernike sag surfaces under the rule
    deeplens states (Zemax guide, What is read): ``CURV + 2 PARM 1 + 2 Σ N_n A_j r_n / R_n²`` over
    the rotationally symmetric terms, ``r_n = (-1)^(n/2 - 1) (n/2)(n/2 + 1)`` the ρ² coefficient of
    the radial polynomial ``R_n^0``, ``A_j`` = ``XDAT j + 2``, ``R_n`` = ``XDAT 2``: written out
    here from the polynomials' definitions, not taken from deeplens."""
    out = {}
    for k, kind, rec in _surfaces_of_type(name, _M0_TERMS):
        cv = rec("CURV") + 2.0 * rec("PARM", 1)
        n_terms, r_n = int(rec("XDAT", 1)), rec("XDAT", 2)
        for j, (n, norm) in _M0_TERMS[kind].items():
            if j <= n_terms:
                h = n // 2
                cv += 2.0 * norm * (-1) ** (h - 1) * h * (h + 1) * rec("XDAT", j + 2) / r_n ** 2
        out[k] = cv
    return out


def _irregular_vertex_curvatures(name):
    """``{SURF k: vertex curvature}`` (file units) of the file's ``IRREGULA`` surfaces under the
    rule deeplens states (Zemax guide, What is read): the y section of ``c r² / (1 + ...) + Zs ρ⁴
    + Za w² + Zc ρ² w`` at the vertex, ``w = (y cos θ + x sin θ) / r_max``: ``CURV + 2 Za cos²θ /
    r_max²`` (``Za`` = ``PARM 6``, θ = ``PARM 8`` in degrees, ``r_max`` the ``DIAM``), written out
    here from the sag, not taken from deeplens."""
    out = {}
    for k, _, rec in _surfaces_of_type(name, ("IRREGULA",)):
        za, theta, r_max = rec("PARM", 6), math.radians(rec("PARM", 8)), rec("DIAM")
        out[k] = rec("CURV") + (2.0 * za * math.cos(theta) ** 2 / r_max ** 2 if za else 0.0)
    return out


def _parax_xy_powers(name):
    """``{SURF k: y power}`` (file units⁻¹) of the file's ``PARAX_XY`` surfaces: ``PARM 2``."""
    return {k: rec("PARM", 2) for k, _, rec in _surfaces_of_type(name, ("PARAX_XY",))}


def _binary2_powers(name, wl):
    """``{SURF k: paraxial power}`` (file units⁻¹) of the file's ``BINARY_2`` surfaces at the
    wavelength ``wl`` (file units): OpticStudio's Binary 2 phase ``Φ = M Σ A_i ρ^(2i)`` (radians,
    ``ρ = r / R_n``; ``M`` = ``PARM 0``, ``R_n`` = ``XDAT 2``, ``A_1`` = ``XDAT 3``) bends a ray by
    ``(λ / 2π) dΦ/dr``, so its ``r²`` term is a thin lens of power ``-M A_1 λ / (π R_n²)``
    (written out here from the phase's definition, not taken from deeplens)."""
    out = {}
    for k, _, rec in _surfaces_of_type(name, ("BINARY_2",)):
        m_order, r_n = rec("PARM", 0, 1.0), rec("XDAT", 2)
        a1 = rec("XDAT", 3) if rec("XDAT", 1) >= 1 else 0.0
        out[k] = -m_order * a1 * wl / (math.pi * r_n ** 2)
    return out


#: the ρ² coefficient, along the y axis (x = 0, φ = 90°), of the Fringe polynomials that have
#: one, as published (University of Arizona / OpticStudio Fringe table): Z4 = 2ρ² − 1, Z9 = 6ρ⁴ −
#: 6ρ² + 1, Z16 = 20ρ⁶ − 30ρ⁴ + 12ρ² − 1, Z25 = 70ρ⁸ − 140ρ⁶ + 90ρ⁴ − 20ρ² + 1, Z36 = 252ρ¹⁰ − ...
#: + 30ρ² − 1, Z37 = 924ρ¹² − ... − 42ρ² + 1, and the cos 2φ terms (−1 along y) Z5 = ρ² cos 2φ,
#: Z12 = (4ρ² − 3)ρ² cos 2φ, Z21 = (15ρ⁴ − 20ρ² + 6)ρ² cos 2φ, Z32 = (56ρ⁶ − 105ρ⁴ + 60ρ² − 10)ρ²
#: cos 2φ (the sin 2φ terms vanish along y)
_FRINGE_Y_RHO2 = {4: 2.0, 9: -6.0, 16: 12.0, 25: -20.0, 36: 30.0, 37: -42.0,
                  5: -1.0, 12: 3.0, 21: -6.0, 32: 10.0}


def _fzernpha_powers(name, wl):
    """``{SURF k: paraxial y power}`` (file units⁻¹) of the file's ``FZERNPHA`` surfaces at the
    wavelength ``wl`` (file units): the phase ``2π M Σ A_j Z_j`` (``A_j`` = ``XDAT j + 2`` in
    waves, ``R_n`` = ``XDAT 2``, ``M`` = ``PARM 0``) bends a ray by ``(λ/2π) ∂Φ/∂y``; along y
    it is ``2π M (Σ a_j A_j) y² / R_n²`` to second order (``a_j``: :data:`_FRINGE_Y_RHO2`), a
    thin lens of power ``−2 M λ Σ a_j A_j / R_n²`` (written out here from the polynomials, not
    taken from deeplens)."""
    out = {}
    for k, _, rec in _surfaces_of_type(name, ("FZERNPHA",)):
        n_terms, r_n = int(rec("XDAT", 1)), rec("XDAT", 2)
        acc = sum(a * rec("XDAT", j + 2) for j, a in _FRINGE_Y_RHO2.items() if j <= n_terms)
        out[k] = -2.0 * rec("PARM", 0, 1.0) * wl * acc / r_n ** 2 if acc else 0.0
    return out


#: OpticStudio's Extended Polynomial terms 1..5 as its User Guide lists them ("the first term is
#: x, then y, then x*x, x*y, y*y"): (power of x, power of y); along y only the y² term (5, in
#: XDAT 7) curves the phase at the vertex
_XPOLY_FIRST_TERMS = ((1, 0), (0, 1), (2, 0), (1, 1), (0, 2))


def _binary1_powers(name, wl):
    """``{SURF k: paraxial y power}`` (file units⁻¹) of the file's ``BINARY_1`` surfaces at the
    wavelength ``wl`` (file units): the phase ``M Σ A_t x̂^i ŷ^j`` (radians, ``A_t`` = ``XDAT
    t + 2``, ``x̂ = x / R_n``, ``R_n`` = ``XDAT 2``, ``M`` = ``PARM 0``) bends a ray by
    ``(λ/2π) ∂Φ/∂y``; along y it is ``M A_y² y² / R_n²`` to second order, a thin lens of power
    ``−M λ A_y² / (π R_n²)`` (written out here from the term order, not taken from deeplens)."""
    out = {}
    t_y2 = _XPOLY_FIRST_TERMS.index((0, 2)) + 1
    for k, _, rec in _surfaces_of_type(name, ("BINARY_1",)):
        n_terms, r_n = int(rec("XDAT", 1)), rec("XDAT", 2)
        a = rec("XDAT", t_y2 + 2) if n_terms >= t_y2 else 0.0
        out[k] = -rec("PARM", 0, 1.0) * wl * a / (math.pi * r_n ** 2) if a else 0.0
    return out


def _hologram_powers(name, wl_um):
    """``{SURF k: paraxial power}`` (file units⁻¹) of the file's ``HOLOGRM1``/``HOLOGRM2``
    surfaces at the wavelength ``wl_um`` (µm), written out here from the records, not taken
    from deeplens: the hologram adds the optical path ``m (λ/λ_c) W`` with ``W = -(r_1 + r_2)``
    (type 2) or ``r_2 - r_1`` (type 1), ``r_i`` the distance from the surface point to
    construction point ``i`` (``PARM 1-3``, ``4-6``; ``λ_c`` = ``PARM 7`` µm, ``m`` = ``PARM 8``;
    the Zemax guide, Holograms); along the substrate's y section (curvature ``c`` = ``CURV``)
    ``d²r_i/dy² = (1 - c z_i)/L_i - y_i²/L_i³`` at the vertex (``L_i = |P_i|``), and a path
    ``W(y) ≈ W'' y²/2`` is a thin lens of power ``-W''``."""
    out = {}
    for k, kind, rec in _surfaces_of_type(name, ("HOLOGRM1", "HOLOGRM2")):
        c = rec("CURV")
        second = []
        for first in (1, 4):
            x, y, z = (rec("PARM", first + j) for j in range(3))
            L = math.sqrt(x * x + y * y + z * z)
            second.append((1.0 - c * z) / L - y * y / L ** 3)
        w2 = -(second[0] + second[1]) if kind == "HOLOGRM2" else second[1] - second[0]
        out[k] = -rec("PARM", 8, 0.0) * (wl_um / rec("PARM", 7)) * w2
    return out


def _update(opm):
    """rayoptics' paraxial model and first-order data after a change (its element model and part
    tree, patched out above, stay as they are)."""
    opm["seq_model"].update_model()
    opm["optical_spec"].update_model()
    opm.update_optical_properties()
    return opm["analysis_results"]["parax_data"].fod


def _enp(opm):
    """The entrance pupil diameter and its distance from SURF 1, as rayoptics computes them.

    An object at infinity is put at ``T = 1e10`` file units by zmxread, a finite conjugate: the
    EPD then differs from the infinite one by a term in ``1/T`` (``(T + l_EP) / (T c + d)``,
    c, d from its principal rays: up to 5e-7 relative on this corpus), removed here by evaluating
    at ``T`` and ``2T`` (``2 v(2T) - v(T)``, leaving ``O((f/T)^2)`` < 1e-13); and ``fod.enp_dist``
    subtracts ``T`` from ``T + l_EP`` (the chief ray's height at SURF 1: ~1e-6 absolute lost to
    round-off), so the distance is taken from rayoptics' own object-independent formula in
    ``compute_first_order``, ``l_EP = b_s / (n_0 a_s)`` with its principal rays' heights at the
    stop (the first surface when the file has no STOP, as rayoptics)."""
    from rayoptics.parax.firstorder import compute_principle_points

    sm = opm["seq_model"]
    fod = opm["analysis_results"]["parax_data"].fod
    wvl = opm["optical_spec"]["wvls"].central_wvl
    n_0 = sm.z_dir[0] * sm.central_rndx(0)
    n_k = sm.z_dir[-1] * sm.central_rndx(-1)
    p_ray, q_ray, _ = compute_principle_points(sm.path(wl=wvl), sm.overall_length(), n_0, n_k)
    stop = sm.stop_surface if sm.stop_surface is not None else 1
    enp_dist = q_ray[stop][0] / (sm.gaps[0].medium.rindex(wvl) * p_ray[stop][0])
    epd = 2.0 * fod.enp_radius
    t = sm.gaps[0].thi
    if t == 1e10:   # zmxread's infinity
        sm.gaps[0].thi = 2.0 * t
        epd = 2.0 * (2.0 * _update(opm).enp_radius) - epd
        sm.gaps[0].thi = t
        _update(opm)
    return epd, enp_dist


def _numbers(name, lens, opm):
    """``{quantity: (deeplens, rayoptics)}`` in the file's length unit.  The entrance pupil is
    placed relative to the file's first surface (SURF 1: rayoptics' ``enp_dist``), the rear focal
    point relative to the image plane along the last local axis (rayoptics' ``bfl`` is from the
    last surface before the image, whose gap to the image is ``gaps[-1].thi``)."""
    fod = opm["analysis_results"]["parax_data"].fod
    sm = opm["seq_model"]
    s_mm = _unit_mm(name)
    p = paraxial(lens)
    _, _, q = _file_path_coords(CORPUS / name)
    first = float(_dl_path_coords(lens)[0]) - q[1] * s_mm   # deeplens surface 0 after SURF 1
    if q[-2] == 0.0 and abs(float(lens.d_sensor)) == IMAGE_ON_VERTEX_MM:
        # an image plane on the last vertex: deeplens puts the sensor 1e-9 mm behind it (Zemax
        # guide, a located warning), which moves every path coordinate from the sensor by that
        first += IMAGE_ON_VERTEX_MM
    ep_dl = (float(p.entrance_pupil_z) - float(lens.z_vertices()[0]) + first) / s_mm
    sign = (-1) ** len(lens.mirrors)   # rayoptics' image-space index sign (the mirror parity)
    bfl_dl = (float(p.bfl) + float(lens.z_vertices()[-1]) - float(lens.z_sensor())) / s_mm
    # both EFLs are image-side focal lengths, |n'|/φ (an image in glass: cots_COTS-0002-*'s
    # n' = 1.328); deeplens' is positive for a converging beam whichever way it leaves, so after
    # an odd number of mirrors rayoptics' sign is the other one (as optiland's f2)
    efl_dl = sign * float(p.efl) / s_mm
    efl_ro = fod.efl if fod.efl != 0.0 else math.inf
    bfl_ro = fod.bfl - sm.gaps[-1].thi if fod.efl != 0.0 else math.inf
    epd_ro, enp_ro = _enp(opm)
    return {"EFL": (efl_dl, efl_ro),
            "EPD": (float(p.entrance_pupil_diameter) / s_mm, epd_ro),
            "EP position": (ep_dl, enp_ro),
            "BFL": (bfl_dl, bfl_ro)}


def _agrees(dl, ro):
    if math.isinf(ro) or math.isinf(dl):   # afocal (flat folds): no focal length either way
        return math.isinf(ro) and math.isinf(dl)
    return abs(dl - ro) <= 1e-9 * max(1.0, abs(dl), abs(ro))


LOADED = [f for f in FILES if f not in REFUSED]


def _assert_agrees(name, lens, opm):
    """Every first-order number of :func:`_numbers` agrees (:func:`_agrees`)."""
    for what, (dl, ro) in _numbers(name, lens, opm).items():
        assert _agrees(dl, ro), f"{what}: deeplens {dl!r} vs rayoptics {ro!r}"


def _efl_with_a_plane(name, lens, opm, k):
    """``(deeplens' EFL, rayoptics' EFL)`` with rayoptics' surface ``k`` replaced by a plane (a
    phase left out)."""
    import rayoptics.elem.surface as ro_surface

    opm["seq_model"].ifcs[k] = ro_surface.Surface()
    _update(opm)
    return _numbers(name, lens, opm)["EFL"]


def test_every_listed_file_is_in_the_corpus():
    assert set(NOT_CONFIRMED) <= set(LOADED)
    assert all(set(q) <= set(QUANTITIES) and why for q, why in NOT_CONFIRMED.values())


@pytest.mark.parametrize("name", LOADED)
def test_rayoptics_confirms_first_order_numbers(name, monkeypatch, tmp_path):
    lens = _load(name)
    opm = _rayoptics(name, lens, monkeypatch, tmp_path)
    skip = NOT_CONFIRMED.get(name, (set(), ""))[0]
    for what, (dl, ro) in _numbers(name, lens, opm).items():
        if what in skip:
            assert not _agrees(dl, ro), f"{what}: rayoptics now agrees; drop it from the list"
            continue
        assert _agrees(dl, ro), f"{what}: deeplens {dl!r} vs rayoptics {ro!r}"


@pytest.mark.parametrize("name", ["optiland_lens_floa.zmx",
                                  "nerfzemax_Ray_generation_for_NeRF_data_demo.zmx",
                                  "deeplens_zemax_double_gaussian.zmx"])
def test_floating_stop_pupil_is_rayoptics_own_ray(name, monkeypatch, tmp_path):
    """FLOA (the pupil floats on the stop's semi-diameter DIAM), which rayoptics 0.9.8 does not
    read (its default pupil, EPD 1, stays): the oracle scales rayoptics' own axial paraxial ray
    to reach the stop's rim.  That ray meets the stop at DIAM (1e-12), the default was not the
    pupil (the adaptation is needed), and the EPD it gives is deeplens' (1e-9)."""
    lens = _load(name)
    opm = _rayoptics(name, lens, monkeypatch, tmp_path)
    pd = opm["analysis_results"]["parax_data"]
    blocks = _surf_blocks(name)
    stop = next(k for k, b in enumerate(blocks) if re.search(r"^\s+STOP\b", b, re.M))
    diam = float(re.search(r"^\s+DIAM\s+(\S+)", blocks[stop], re.M).group(1))
    assert abs(pd.ax_ray[stop][0]) == pytest.approx(diam, rel=1e-12)
    assert opm["optical_spec"]["pupil"].value != pytest.approx(1.0, rel=1e-3)
    epd_dl = float(paraxial(lens).entrance_pupil_diameter) / _unit_mm(name)
    assert _agrees(epd_dl, _enp(opm)[0]), (epd_dl, _enp(opm)[0])


def test_object_space_index_in_rayoptics_pupil(monkeypatch, tmp_path):
    """The reason patent2zemax_US20030048547A1-3's pupil is not confirmed holds: rayoptics'
    entrance pupil distance is deeplens' divided by n0² (n0 the object-space index), to 1e-12."""
    name = "patent2zemax_US20030048547A1-3.zmx"
    lens = _load(name)
    opm = _rayoptics(name, lens, monkeypatch, tmp_path)
    n0 = _media_per_gap(name, lens)[0]
    assert abs(n0 - 1.0) > 1e-5
    dl, ro = _numbers(name, lens, opm)["EP position"]
    assert ro * n0 ** 2 == pytest.approx(dl, rel=1e-12)


SINGLET = CORPUS.parent / "zmx_opticstudio" / "zernike_sag_singlet.zmx"


def _corpus_of_one(name, text, monkeypatch, tmp_path):
    """``text`` written as ``tmp_path / name``, the one file of the corpus this module and
    test_zmx_corpus read (both ``CORPUS`` patched), and deeplens' reading of it, warnings
    silenced: ``(lens, scratch)``, ``scratch`` an empty folder for rayoptics' copy."""
    import sys

    import test_zmx_corpus as tc
    from helpers import read_zmx_quiet

    (tmp_path / name).write_text(text)
    monkeypatch.setattr(tc, "CORPUS", tmp_path)
    monkeypatch.setattr(sys.modules[__name__], "CORPUS", tmp_path)
    lens = read_zmx_quiet(tmp_path / name)
    scratch = tmp_path / "ro"
    scratch.mkdir()
    return lens, scratch


@pytest.mark.parametrize("kind", ["SZERNSAG", "FZERNSAG"])
def test_zernike_sag_vertex_curvature_rule_through_rayoptics(kind, monkeypatch, tmp_path):
    """A Zernike sag singlet (Standard, and the same records read as Fringe terms): deeplens'
    EFL, EPD, pupil position and back focus equal rayoptics' once rayoptics, which reads CURV
    alone, is given the vertex curvature of the rule deeplens states, worked out by the oracle
    from the file (``CURV + 2 PARM 1 + 2 Σ N_n A_j r_n / R_n²``: Noll Z4 and Z11, Fringe Z4 only,
    since Fringe Z11 is a trefoil); the rule matters: from CURV alone the EFL is > 1 % apart."""
    text = SINGLET.read_text().replace("TYPE SZERNSAG", f"TYPE {kind}")
    lens, scratch = _corpus_of_one("z.zmx", text, monkeypatch, tmp_path)
    cv = _zernike_vertex_curvatures("z.zmx")
    m0 = 2.0 * (2.0 * 0.01 * (math.sqrt(3) if kind == "SZERNSAG" else 1.0)
                + (6.0 * math.sqrt(5) * 0.002 if kind == "SZERNSAG" else 0.0)) / 25.0
    assert cv == {2: pytest.approx(0.025 + 2 * 0.001 + m0, rel=1e-14)}
    opm = _rayoptics("z.zmx", lens, monkeypatch, scratch)
    _assert_agrees("z.zmx", lens, opm)
    opm["seq_model"].ifcs[2].profile.cv = 0.025   # CURV alone
    _update(opm)
    dl, ro = _numbers("z.zmx", lens, opm)["EFL"]
    assert abs(dl - ro) > 0.01 * abs(dl)


def test_binary2_power_through_rayoptics(monkeypatch, tmp_path):
    """The hybrid singlet of test_zmx_binary2 (a Binary 2 back face: M 1, R_n 5 mm, A_1 -1500):
    deeplens' EFL, EPD, pupil position and back focus equal rayoptics' once rayoptics, which
    reads the base surface alone, is given the phase's thin-lens power ``-M A_1 λ / (π R_n²)``
    as curvature; without it the EFL is > 1 % apart."""
    from test_zmx_binary2 import binary2_file

    lens, scratch = _corpus_of_one("b.zmx", binary2_file(), monkeypatch, tmp_path)
    wl = 587.5618e-6
    phi = _binary2_powers("b.zmx", wl)
    assert list(phi) == [3] and phi[3] == pytest.approx(1500.0 * wl / (math.pi * 25.0),
                                                        rel=1e-14)
    opm = _rayoptics("b.zmx", lens, monkeypatch, scratch)
    _assert_agrees("b.zmx", lens, opm)
    n_glass = _media_per_gap("b.zmx", lens)[2]
    opm["seq_model"].ifcs[3].profile.cv -= phi[3] / (1.0 - n_glass)   # the base surface alone
    _update(opm)
    dl, ro = _numbers("b.zmx", lens, opm)["EFL"]
    assert abs(dl - ro) > 0.01 * abs(dl)


def test_fzernpha_power_through_rayoptics(monkeypatch, tmp_path):
    """The Zernike Fringe phase file of test_zmx_zernike_phase with an astigmatic phase
    (A_1 = A_4 = 0.735, A_5 = -1.47 waves: 2.94 y² / R_n², OpticStudio's Test_Astigmatism) and a
    primary spherical term: deeplens' EFL, EPD, pupil position and back focus equal rayoptics'
    once rayoptics, which reads a plane, is given the y-section power written out from the
    published polynomials; without it the EFL is > 1 % apart."""
    from test_zmx_zernike_phase import phase_file

    body = ["PARM 0 1", "XDAT 1 9", "XDAT 2 4", "XDAT 3 0.735", "XDAT 6 0.735", "XDAT 7 -1.47",
            "XDAT 11 0.2"]
    lens, scratch = _corpus_of_one("f.zmx", phase_file(body), monkeypatch, tmp_path)
    wl = 550e-6
    phi = _fzernpha_powers("f.zmx", wl)
    # Z4: 2 × 0.735, Z5 along y: -1 × -1.47, Z9: -6 × 0.2 (per R_n² = 16)
    assert list(phi) == [1] and phi[1] == pytest.approx(
        -2.0 * wl * (2 * 0.735 + 1.47 - 6 * 0.2) / 16.0, rel=1e-14)
    opm = _rayoptics("f.zmx", lens, monkeypatch, scratch)
    _assert_agrees("f.zmx", lens, opm)
    dl, ro = _efl_with_a_plane("f.zmx", lens, opm, 1)   # the phase left out
    assert abs(dl - ro) > 0.01 * abs(dl)


def test_binary1_power_through_rayoptics(monkeypatch, tmp_path):
    """The Binary 1 file of test_zmx_binary1 (OpticStudio's diffract3: tilts, x², xy, y² and
    higher terms, a flat phase in air): deeplens' EFL, EPD, pupil position and back focus equal
    rayoptics' once rayoptics, which reads a plane, is given the y-section power written out from
    the published term order; without it rayoptics has no power at all."""
    from test_zmx_binary1 import DIFFRACT3_XDAT, binary1_file

    lens, scratch = _corpus_of_one("b1.zmx", binary1_file(), monkeypatch, tmp_path)
    wl = 550e-6
    phi = _binary1_powers("b1.zmx", wl)
    assert list(phi) == [1] and phi[1] == pytest.approx(
        -wl * DIFFRACT3_XDAT[4] / (math.pi * 100.0), rel=1e-14)
    opm = _rayoptics("b1.zmx", lens, monkeypatch, scratch)
    _assert_agrees("b1.zmx", lens, opm)
    dl, ro = _efl_with_a_plane("b1.zmx", lens, opm, 1)   # the phase left out
    assert not abs(dl - ro) <= 0.01 * abs(dl)


@pytest.mark.parametrize("case", ["transmission", "reflection", "hologram1"])
def test_hologram_power_through_rayoptics(monkeypatch, tmp_path, case):
    """The holograms of test_zmx_hologram (an object 200 mm before a flat HOLOGRM2 with points
    (0, 0, -200), (0, 0, 100); on a mirror with (0, 0, -100), (0, 0, -200); a HOLOGRM1 with
    (0, 0, -200), (0, 0, -100)): deeplens' EFL, EPD, pupil position and back focus equal
    rayoptics' once rayoptics, which reads the bare substrate, is given the thin-lens power
    written out from the records (_hologram_powers: 1/200 + 1/100, 1/100 + 1/200, 1/200 - 1/100
    per mm); given half of it, rayoptics' EFL differs."""
    import sys

    from test_zmx_hologram import hologram_file

    text = {"transmission": hologram_file(),
            "reflection": hologram_file(z1=-100.0, z2=-200.0, image=-100.0, mirror=True),
            "hologram1": hologram_file(kind=1, z2=-100.0, image=50.0)}[case]
    lens, scratch = _corpus_of_one("h.zmx", text, monkeypatch, tmp_path)
    phi = _hologram_powers("h.zmx", 0.55)
    expect = {"transmission": 0.015, "reflection": 0.015, "hologram1": -0.005}[case]
    assert list(phi) == [1] and phi[1] == pytest.approx(expect, rel=1e-14)
    opm = _rayoptics("h.zmx", lens, monkeypatch, scratch)
    _assert_agrees("h.zmx", lens, opm)
    # the power is what confirms: with half of it rayoptics' EFL is twice deeplens'
    monkeypatch.setattr(sys.modules[__name__], "_hologram_powers",
                        lambda name, wl: {k: v / 2 for k, v in phi.items()})
    opm = _rayoptics("h.zmx", lens, monkeypatch, tmp_path / "ro")
    dl, ro = _numbers("h.zmx", lens, opm)["EFL"]
    assert not _agrees(dl, ro)
