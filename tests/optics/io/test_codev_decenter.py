"""CODE V decenters and tilts (:mod:`deeplens.optics.io.codev_decenter`): closed forms (a 45°
fold mirror, a decentred lens's image shift, DAR and REV frames, RET), rayoptics' own trace of
its decenter test files and of a compound-tilt file (test-only oracle), round trips through
``write_seq`` and located refusals.

Rays are traced in float64 through at most a dozen surfaces over a few hundred mm: rounding
leaves landing points within ~1e-13 mm of the exact value, so the closed forms and the oracle are
held to 1e-10 mm (1e-9 where a paraxial limit is taken, see there)."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import pytest
import torch

from deeplens.optics.errors import LensFileError
from deeplens.optics.frames import local_frames, to_global
from deeplens.optics.io.codev import read_seq, write_seq
from deeplens.optics.options import TraceOptions
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import CoordinateBreak

ROOT = Path(__file__).resolve().parents[3]
RAYOPTICS = ROOT / "tests" / "data" / "codev" / "rayoptics"
FILES = ["dar_test", "dec_rev_tilt_test", "dec_test", "dec_tilt_test", "folded_lenses",
         "tilt_test"]
TOL = 1e-10
HEAD = "RDM Y\nDIM M\nWL 587.56\nEPD 4\nYAN 0\n"


def _seq(tmp_path, body, name="t", so="SO 0 1e20\n", head=HEAD):
    p = tmp_path / f"{name}.seq"
    p.write_text(head + so + body)
    return p


def _read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_seq(path).double()


def _trace(lens, o, d):
    """Rays from points ``o`` along ``d`` (``(M, 3)``, object-space frame, mm) to the sensor at
    the lens's primary wavelength, apertures ignored: ``(local landing points, local directions,
    valid)``."""
    o = torch.as_tensor(o, dtype=torch.float64)
    d = torch.as_tensor(d, dtype=torch.float64)
    with torch.no_grad():
        r = lens.trace_to_sensor(Rays(o, d, float(lens.spec.primary_wavelength_nm)), options=TraceOptions(clip_aperture=False))
    return r.o, r.d, r.valid


def _global(lens, x, direction=False):
    A, b = local_frames(lens)[-1]
    return to_global((A, torch.zeros_like(b) if direction else b), x)


# --------------------------------------------------------------------------- closed forms
@pytest.mark.parametrize("ade,sign", [(45.0, -1.0), (-45.0, 1.0)])
def test_a_flat_fold_mirror_with_ben_turns_the_beam_by_90_degrees(tmp_path, ade, sign):
    """``S 0 -30 REFL; ADE 45; BEN`` 20 mm after the stop: the mirror plane is
    ``y_g + (z_g - 20) = 0`` (its normal ``(0, 1, 1)/sqrt 2``: CODE V's alpha is left-handed),
    so a ray parallel to the axis at ``(x, y)`` reflects at ``z_g = 20 - y`` into ``-y_g`` and
    lands on the image plane, which BEN turns onto the reflected axis 30 mm away, at
    ``(x, -30, 20 - y)``; with ``ADE -45`` everything mirrored in y."""
    lens = _read(_seq(tmp_path, f"S 0 20\n  STO\nS 0 -30 REFL\n  ADE {ade}\n  BEN\n  CIR 10\n"
                                "SI 0 0\n"))
    assert sum(isinstance(s, CoordinateBreak) for s in lens.surfaces) == 2
    xy = [(0.0, 0.0), (1.5, 0.0), (0.0, 2.0), (-1.0, -1.5)]
    o = [(x, y, -5.0) for x, y in xy]
    p, d, ok = _trace(lens, o, [(0.0, 0.0, 1.0)] * len(xy))
    assert bool(ok.all())
    g = _global(lens, p)
    gd = _global(lens, d, direction=True)
    for (x, y), gi, di in zip(xy, g.tolist(), gd.tolist()):
        assert gi == pytest.approx([x, sign * 30.0, 20.0 + sign * y], abs=TOL)
        assert di == pytest.approx([0.0, sign * 1.0, 0.0], abs=TOL)   # leaves at 90 degrees
    # the chief ray lands on the image vertex, travelling along the bent axis (-z there)
    assert p[0].tolist()[:2] == pytest.approx([0.0, 0.0], abs=TOL)
    assert d[0].tolist() == pytest.approx([0.0, 0.0, -1.0], abs=TOL)


def _image_distance(r1, r2, t, n, s):
    """Paraxial image distance after the lens's second vertex and the magnification ``m`` of a
    thick lens (radii ``r1``, ``r2``, thickness ``t``, index ``n``) for an object ``s`` before
    its first vertex: 2x2 ray transfer matrices, independent of deeplens' paraxial code."""
    def mul(a, b):
        return [[a[0][0] * b[0][0] + a[0][1] * b[1][0], a[0][0] * b[0][1] + a[0][1] * b[1][1]],
                [a[1][0] * b[0][0] + a[1][1] * b[1][0], a[1][0] * b[0][1] + a[1][1] * b[1][1]]]

    def gap(d, n_):          # (y, n u) convention: reduced thickness
        return [[1.0, d / n_], [0.0, 1.0]]

    def refr(c, n1, n2):
        return [[1.0, 0.0], [-(n2 - n1) * c, 1.0]]

    M = mul(refr(1 / r2, n, 1.0), mul(gap(t, n), mul(refr(1 / r1, 1.0, n), gap(s, 1.0))))
    # image where y no longer depends on the object ray's angle: B + D s' = 0
    (A, B), (C, D) = M
    s_img = -B / D
    return s_img, A + C * s_img


def _decentred_lens(tmp_path, d, s, y_obj=0.0, name="t"):
    """A biconvex lens (R 60, -60, 4 mm of n_d 1.517) decentred by ``d`` (``YDE d; DAR`` on both
    surfaces), an object ``s`` before it, the image plane at the centred lens's paraxial image
    (:func:`_image_distance`); ``(lens, m)``."""
    s_img, m = _image_distance(60.0, -60.0, 4.0, 1.517, s)
    dec = "".join(f"  {c}\n" for c in (f"YDE {d}", "DAR")) if d else ""
    body = (f"S 0 0\n  STO\n  CIR 8\nS 60 4 517000.642000\n{dec}  CIR 8\n"
            f"S -60 {s_img!r}\n{dec}  CIR 8\nSI 0 0\n")
    return _read(_seq(tmp_path, body, name, so=f"SO 0 {s}\n",
                      head=HEAD.replace("WL 587.56", "WL 587.5618"))), m


def test_a_decentred_lens_shifts_the_image_by_d_times_one_minus_m(tmp_path):
    """A lens decentred by ``d``, 200 mm from an on-axis object point: the object lies ``-d``
    from the lens's axis, is imaged ``-d m`` from it, and the axis is at ``d``: the image lies at
    ``y = d (1 - m)`` on the centred lens's paraxial image plane (m from 2x2 ray transfer
    matrices; at the d line the fictitious glass is n_d = 1.517).  With d = 1e-3 mm the ray
    through the lens's vertex is paraxial: O(u^3) distortion is far below 1e-9 mm.  For a large
    decenter (1.5 mm) the equivalence behind the closed form is exact: every ray from the object
    point lands, through the decentred lens, where the same ray moved by ``-d`` lands through the
    centred lens, moved by ``+d``."""
    s = 200.0
    for d in (1e-3, -1e-3):
        lens, m = _decentred_lens(tmp_path, d, s)
        u0 = d / s   # the ray from the object point to the lens's vertex
        p, _, ok = _trace(lens, [(0.0, 0.0, -s)], [(0.0, u0, 1.0)])
        assert bool(ok.all())
        assert m == pytest.approx(-0.4115, abs=1e-4)   # (a visible 1.41 d shift)
        assert float(p[0, 1]) == pytest.approx(d * (1 - m), abs=1e-9)
        assert float(p[0, 0]) == pytest.approx(0.0, abs=1e-15)
    d = 1.5
    dec, _ = _decentred_lens(tmp_path, d, s, name="dec")
    cen, _ = _decentred_lens(tmp_path, 0.0, s, name="cen")
    dirs = [(0.0, d / s + e, 1.0) for e in (-0.02, 0.0, 0.015)] + [(0.01, d / s, 1.0)]
    pa, da, oka = _trace(dec, [(0.0, 0.0, -s)] * 4, dirs)
    pb, db, okb = _trace(cen, [(0.0, -d, -s)] * 4, dirs)
    assert bool(oka.all()) and bool(okb.all())
    assert torch.allclose(pa[:, 1], pb[:, 1] + d, atol=TOL, rtol=0)
    assert torch.allclose(pa[:, 0], pb[:, 0], atol=TOL, rtol=0)
    assert torch.allclose(da, db, atol=TOL, rtol=0)


def test_dar_leaves_the_later_surfaces_on_the_axis(tmp_path):
    """A flat air surface decentred and tilted with ``DAR`` (and ``ZDE``) before a lens: every
    ray lands where it lands without that decenter, and the surfaces after it are back on the
    undecentred axis (identity orientation, vertices on the axis at the same positions)."""
    lens_body = "S 40 5 517000.642000\n  CIR 8\nS -40 30\nSI 0 0\n"
    dec = _read(_seq(tmp_path, "S 0 10\n  STO\nS 0 20\n  YDE 3\n  ZDE 2\n  ADE 10\n  BDE -4\n"
                               "  CDE 7\n  DAR\n  CIR 6\n" + lens_body, "dec"))
    ref = _read(_seq(tmp_path, "S 0 10\n  STO\nS 0 20\n  CIR 6\n" + lens_body, "ref"))
    o = [(0.0, 0.0, -5.0), (0.0, 1.5, -5.0), (1.0, -1.0, -5.0)]
    d = [(0.0, 0.0, 1.0), (0.0, -0.02, 1.0), (0.01, 0.02, 1.0)]
    pa, da, oka = _trace(dec, o, d)
    pb, db, okb = _trace(ref, o, d)
    assert bool(oka.all()) and bool(okb.all())
    assert torch.allclose(pa[:, :2], pb[:, :2], atol=TOL, rtol=0)
    assert torch.allclose(da, db, atol=TOL, rtol=0)
    (A, b), = local_frames(dec)[-1:]
    assert torch.allclose(A, torch.eye(3, dtype=A.dtype), atol=1e-14)
    assert b.tolist()[:2] == pytest.approx([0.0, 0.0], abs=1e-12)


def test_rev_undoes_a_basic_decenter_in_the_reverse_order(tmp_path):
    """A basic decenter ``YDE 2; ADE 5`` with ``T`` = 7 mm after it, then ``REV`` with the same
    values: the frame after the REV surface is the original orientation with its origin at
    ``R (0, 0, T)`` (the REV surface sits at ``δ + R (0, 0, T)`` and the inverse takes ``δ`` back
    along the restored axes: translation after the rotation).  An inverse in the forward order
    would put it at ``R (0, 0, T) + δ - R δ`` instead."""
    lens = _read(_seq(tmp_path, "S 0 1\n  STO\nS 0 7\n  YDE 2\n  ADE 5\nS 0 9\n  REV\n  YDE 2\n"
                                "  ADE 5\nSI 0 0\n"))
    a = -math.radians(5.0)   # CODE V's ADE is deeplens' -tilt_x
    R_ez = [0.0, -math.sin(a), math.cos(a)]
    A, b = local_frames(lens)[-1]
    assert torch.allclose(A, torch.eye(3, dtype=A.dtype), atol=1e-14)
    want = [7.0 * c for c in R_ez]
    want[2] += 1.0 + 9.0    # the stop's thickness before, the REV surface's after
    z_sensor = float(lens.z_vertices()[-1] + lens.d_sensor)
    assert (b + torch.tensor([0.0, 0.0, z_sensor], dtype=b.dtype)).tolist() == \
        pytest.approx(want, abs=1e-12)


def test_ret_returns_to_a_surfaces_frame(tmp_path):
    """Two basic decenters (with tilts about x and y), then ``RET S1``: the next surface lies in
    the stop's frame at the stop's vertex, so the lens after it traces exactly as the same lens
    4 mm after the stop without the decenters."""
    lens_body = "S 40 5 517000.642000\n  CIR 8\nS -40 30\nSI 0 0\n"
    dec = _read(_seq(tmp_path, "S 0 5\n  STO\nS 0 10\n  YDE 3\n  ADE 20\nS 0 7\n  XDE 1\n"
                               "  BDE 5\n  CDE 30\nS 0 4\n  RET S1\n" + lens_body, "dec"))
    ref = _read(_seq(tmp_path, "S 0 4\n  STO\n" + lens_body, "ref"))
    o = [(0.0, 0.0, -5.0), (0.0, 1.5, -5.0), (1.0, -1.0, -5.0)]
    d = [(0.0, 0.0, 1.0), (0.0, -0.02, 1.0), (0.01, 0.02, 1.0)]
    pa, da, oka = _trace(dec, o, d)
    pb, db, okb = _trace(ref, o, d)
    assert bool(oka.all()) and bool(okb.all())
    assert torch.allclose(pa[:, :2], pb[:, :2], atol=TOL, rtol=0)   # (local z: deeplens' own)
    assert torch.allclose(da, db, atol=TOL, rtol=0)


# --------------------------------------------------------------------------- rayoptics
def _rayoptics_trace(path, monkeypatch, tmp_path, rays, gap0, wl):
    """rayoptics' reading and trace of ``path`` (test-only oracle): for each ``(point, dir)`` on
    its object plane ``gap0`` mm before S1, the landing point and direction on the image
    surface, in the image's local frame."""
    monkeypatch.chdir(tmp_path)   # rayoptics' reader writes a log file where it runs
    cmdproc = pytest.importorskip("rayoptics.codev.cmdproc")
    from rayoptics.raytr.trace import trace

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opm, (_, not_found) = cmdproc.read_lens(Path(path))
        assert not not_found
        sm = opm["seq_model"]
        sm.gaps[0].thi = gap0
        opm.update_model()
        out = []
        for o, d in rays:
            ray = trace(sm, o, d, wl)[0]
            out.append((list(ray[-1][0]), list(ray[-1][1])))
    return out


def _oracle_rays():
    out = []
    for x, y in ((0.0, 0.0), (0.25, -0.3), (0.0, 0.2)):
        for a in (0.0, 0.03):
            out.append(([x, y, 0.0], [0.0, math.sin(a), math.cos(a)]))
    return out


def _check_against_rayoptics(path, monkeypatch, tmp_path, s1_z=0.0):
    """Each ray starts 10 mm before S1 (at ``s1_z`` in deeplens' frame) in both readers."""
    import numpy as np

    rays = _oracle_rays()
    lens = _read(path)
    wl = float(lens.spec.primary_wavelength_nm)
    want = _rayoptics_trace(path, monkeypatch, tmp_path,
                            [(np.array(o), np.array(d)) for o, d in rays], 10.0, wl)
    o = [[x, y, s1_z - 10.0] for (x, y, _), _ in rays]
    p, d, ok = _trace(lens, o, [dd for _, dd in rays])
    assert bool(ok.all())
    for (wp, wd), pi, di in zip(want, p.tolist(), d.tolist()):
        assert all(math.isfinite(v) for v in wp + wd)
        assert pi[:2] == pytest.approx(wp[:2], abs=TOL)
        assert di == pytest.approx(wd, abs=TOL)


@pytest.mark.parametrize("name", FILES)
def test_rayoptics_files_land_where_rayoptics_traces_them(name, monkeypatch, tmp_path):
    """rayoptics' own decenter test files (DAR, REV, BEN folds, basic decenters, ADE tilts,
    glass lenses between BEN folds; STO added on S1, where it does not change a ray given by
    position and direction): the landing points and directions on the image surface of rays
    given in object space equal rayoptics' trace of the same file (observed: 5e-14)."""
    _check_against_rayoptics(RAYOPTICS / f"{name}.seq", monkeypatch, tmp_path)


COMPOUND = """RDM Y
DIM M
WL 587.56
EPD 4
YAN 0
SO 0 1e11
S 0 20
  STO
S -200 -50 REFL
  XDE 1.5
  YDE -2
  ZDE 0.7
  ADE 3
  BDE -4
  CDE 10
S 150 40 REFL
  YDE 1
  ADE -2
  BDE 1.5
  CDE -7
  DAR
S 0 10
  REV
  XDE 0.5
  ADE 1
  BDE 2
SI 0 0
  XDE 0.2
  BDE 3
"""


def test_compound_decenters_land_where_rayoptics_traces_them(monkeypatch, tmp_path):
    """Tilts about all three axes with XDE, YDE and ZDE, on two curved mirrors (basic and DAR),
    a REV and a tilted image: the signs of BDE and CDE and ZDE's place before the tilts, which
    rayoptics' test files (ADE and YDE only) leave open, against rayoptics' trace."""
    p = tmp_path / "compound.seq"
    p.write_text(COMPOUND)
    _check_against_rayoptics(p, monkeypatch, tmp_path)


# --------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("name", FILES + ["compound"])
def test_write_seq_writes_the_breaks_back(name, tmp_path):
    """``.seq`` -> lens -> ``.seq`` -> lens: the same surfaces (breaks' decenters and tilts bit
    for bit), distances and mirrors."""
    if name == "compound":
        src = tmp_path / "compound.seq"
        src.write_text(COMPOUND)
    else:
        src = RAYOPTICS / f"{name}.seq"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = read_seq(src)
        write_seq(a, tmp_path / "out.seq")
        b = read_seq(tmp_path / "out.seq")
    assert [s.to_dict() for s in a.surfaces] == [s.to_dict() for s in b.surfaces]
    assert [float(x) for x in a.distances] == [float(x) for x in b.distances]
    assert float(a.d_sensor) == float(b.d_sensor) and a.mirrors == b.mirrors
    assert any(isinstance(s, CoordinateBreak) and s.order == 1 for s in a.surfaces) == \
        ("REV" in (tmp_path / "out.seq").read_text())


def test_a_break_inside_glass_is_not_written(tmp_path):
    lens = _read(_seq(tmp_path, "S 0 2\n  STO\nS 40 3 517000.642000\n  CIR 8\nS 0 3 "
                                "517000.642000\n  ADE 2\n  CIR 8\nS -40 30\nSI 0 0\n"))
    with pytest.raises(LensFileError, match="coordinate break inside"):
        write_seq(lens, tmp_path / "out.seq")


# --------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("body,line,match", [
    ("S 0 5\n  STO\nS 0 5\n  ADE 3\n  BDE 2\n  BEN\nSI 0 0\n", 12, "BEN with both ADE and BDE"),
    ("S 0 5\n  STO\nS 0 5\n  YDE 1\n  RET S1\nSI 0 0\n", 10, "RET with XDE"),
    ("S 0 5\n  STO\nS 0 5\n  RET S2\nSI 0 0\n", 10, r"RET S2: expected a surface before"),
    ("S 0 5\n  STO\nS 0 5\n  RET 1\nSI 0 0\n", 10, "expected 'RET Sk'"),
    ("S 0 5\n  STO\nS 0 5\n  DAR\n  BEN\nSI 0 0\n", 11, "already has the decenter type DAR"),
    ("S 0 5\n  STO\nS 0 5\n  DAR 1\nSI 0 0\n", 10, "DAR: expected no value"),
    ("S 0 5\n  STO\nS 0 5\n  ADE\nSI 0 0\n", 10, "ADE: expected 1 number"),
    ("S 0 5\n  STO\nS 0 5\n  ADE S2 3\nSI 0 0\n", 10, "ADE S2: surface qualifiers"),
])
def test_refusals_name_file_and_line(tmp_path, body, line, match):
    p = _seq(tmp_path, body)
    with pytest.raises(LensFileError, match=match) as e:
        read_seq(p)
    assert e.value.source == str(p) and e.value.line == line


def test_a_decentred_object_is_refused(tmp_path):
    p = _seq(tmp_path, "S 0 5\n  STO\nSI 0 0\n", so="SO 0 100\n  YDE 1\n")
    with pytest.raises(LensFileError, match="decentred or tilted object") as e:
        read_seq(p)
    assert e.value.line == 7


# --------------------------------------------------------------------------- semi-diameters
@pytest.mark.parametrize("name", ["dec_test", "dec_tilt_test", "folded_lenses"])
def test_automatic_semi_diameters_of_a_decentred_lens_do_not_vignette(name):
    """Surfaces without CIR in a decentred lens get the largest height of real rays over the
    pupil (the ``.zmx`` reader's automatic semi-diameters; CODE V's come from real rays too): the
    spot of every field equals the spot of the same lens whose surfaces other than the stop are
    made 1 m wide (1e-12 mm).  The paraxial estimate about the local axes clipped part of these
    beams."""
    import copy

    from deeplens.analysis.spot import spot_diagram

    lens = _read(RAYOPTICS / f"{name}.seq")
    wide = copy.deepcopy(lens)
    with torch.no_grad():
        for i, s in enumerate(wide.surfaces):
            if i != wide.stop_index:
                s.semi_diameter.fill_(1000.0)
    w = float(lens.spec.primary_wavelength_nm)
    for f in lens.spec.fields_deg:
        a = spot_diagram(lens, float(f), w, sampling="hexapolar:6")
        b = spot_diagram(wide, float(f), w, sampling="hexapolar:6")
        assert a.n_rays == b.n_rays == a.n_launched
        assert float(a.rms_radius) == pytest.approx(float(b.rms_radius), abs=1e-12)


@pytest.mark.parametrize("ext", ["zmx", "json"])
@pytest.mark.parametrize("name", ["folded_lenses", "dec_test", "compound"])
def test_a_decentred_seq_lens_keeps_its_rays_through_zmx_and_json(name, ext, tmp_path):
    """``.seq`` -> lens -> ``.zmx`` (breaks as ``COORDBRK``) or JSON -> lens: every ray lands at
    the same point of the image surface, in the same direction (1e-10 mm)."""
    from deeplens.optics.io import load_lens, save_lens

    if name == "compound":
        src = tmp_path / "compound.seq"
        src.write_text(COMPOUND)
    else:
        src = RAYOPTICS / f"{name}.seq"
    a = _read(src)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        save_lens(a, tmp_path / f"out.{ext}")
        b = load_lens(tmp_path / f"out.{ext}").double()
    rays = _oracle_rays()
    o = [[x, y, -10.0] for (x, y, _), _ in rays]
    pa, da, oka = _trace(a, o, [d for _, d in rays])
    pb, db, okb = _trace(b, o, [d for _, d in rays])
    assert bool(oka.all()) and bool(okb.all())
    assert torch.allclose(pa[:, :2], pb[:, :2], atol=TOL, rtol=0)
    assert torch.allclose(da, db, atol=TOL, rtol=0)


# --------------------------------------------------------------------------- the oracle
@pytest.mark.parametrize("name", ["dar_test", "folded_lenses"])
def test_the_corpus_oracle_confirms_decentred_files_by_real_rays(name):
    """The benchmark's oracle for decentred files (codev_oracle.ray_landings): the surfaces lie
    where rayoptics puts them, and 4 rays per field (dar_test: a finite object, rays from the
    object plane; folded_lenses: glasses between BEN folds, rayoptics given deeplens' indices)
    land at the same points in the same directions, to the oracle's round-off bound."""
    pytest.importorskip("rayoptics")
    from codev_oracle import ray_agrees, ray_landings

    lens = _read(RAYOPTICS / f"{name}.seq")
    r = ray_landings(RAYOPTICS / f"{name}.seq", lens)
    assert r["rays"] == 4 * len(lens.spec.fields_deg) and not r["failed"]
    assert ray_agrees(r["dp"], r["dd"], r["length"])


def test_the_corpus_oracle_rejects_a_misread_decentred_lens():
    """The oracle can fail: a conic of -1e-3 on a lens surface of folded_lenses (which leaves
    every vertex, orientation and curvature in place) moves the landings beyond the bound; a
    tilt off by 1e-9 rad puts a surface where rayoptics' is not."""
    pytest.importorskip("rayoptics")
    from codev_oracle import ray_agrees, ray_landings

    path = RAYOPTICS / "folded_lenses.seq"
    lens = _read(path)
    i = next(i for i, s in enumerate(lens.surfaces) if float(getattr(s, "c", 0.0)) != 0)
    with torch.no_grad():
        lens.surfaces[i].k.fill_(-1e-3)
    r = ray_landings(path, lens)
    assert r["rays"] == 4 and not ray_agrees(r["dp"], r["dd"], r["length"])
    lens = _read(path)
    cb = next(s for s in lens.surfaces if isinstance(s, CoordinateBreak) and float(s.tilt_x))
    with torch.no_grad():
        cb.tilt_x.add_(1e-9)
    with pytest.raises(AssertionError, match="do not lie where"):
        ray_landings(path, lens)
