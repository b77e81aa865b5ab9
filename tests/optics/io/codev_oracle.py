"""rayoptics' reading of a CODE V ``.seq`` file (a test-only oracle) and the first-order numbers
deeplens and rayoptics give for it; shared by tests/optics/io/test_codev_corpus.py and
benchmarks/seq_corpus.py.

rayoptics reads the file with its own CODE V reader (``rayoptics.codev.cmdproc.read_lens``) and
is then given deeplens' refractive index at the reference wavelength for every gap (an
``opticalglass`` ``ConstantIndex`` medium), so the comparison checks the reading of the
prescription (surfaces, spacings, stop, pupil, units, mirrors, defaults) independently of the
two libraries' glass data.  Each rayoptics surface is matched to deeplens' by its path
coordinate (the running sum of ``|thickness|``) and curvature: deeplens folds a flat surface in
air that is not the stop into the gap (CODE V's dummies), rayoptics keeps it.

Both sides are float64 paraxial traces of the same numbers, so they agree to round-off: about
1e-13 relative on these files; :func:`agrees` allows 1e-9 relative (round-off grown through a
few tens of surfaces and an object at 1e11 units; a thickness read off by one surface moves the
numbers by more than 1e-4).

A decentred or tilted lens (one with coordinate breaks) is confirmed by real rays instead
(:func:`ray_landings`): paraxial numbers along the local axes say nothing of where a tilted
surface sends the beam.  Each deeplens surface other than a break is matched to a rayoptics
surface by its place in space (vertex, orientation and curvature in the object-space frame:
``deeplens.optics.frames.local_frames`` and rayoptics' ``seq_model.gbl_tfrms``), rayoptics is
given deeplens' indices as above, and the same rays (per field: the chief ray and three rays at
0.7 of the entrance pupil's radius, given in object space) are traced by both; their landing
points and directions on the image surface, in its own frame, must agree to float64 round-off
(:func:`ray_agrees`).
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import torch

from deeplens.optics.paraxial import paraxial

_UNITS = {"M": 1.0, "MM": 1.0, "C": 10.0, "CM": 10.0, "I": 25.4, "IN": 25.4}
QUANTITIES = ("EFL", "EPD", "ENP", "BFP")
#: real-ray tolerances (:func:`ray_agrees`): per unit of path length for the landing points,
#: absolute for the direction cosines
RAY_POINT_REL = 1e-11
RAY_DIR_ABS = 1e-11


def unit_mm(path) -> float:
    """The file's length unit in mm (its ``DIM`` line; mm without one)."""
    for line in Path(path).read_text(errors="replace").splitlines():
        for cmd in line.split("!")[0].split(";"):
            toks = cmd.split()
            if len(toks) >= 2 and toks[0].upper() == "DIM":
                return _UNITS.get(toks[1].upper(), 1.0)
    return 1.0


def agrees(dl: float, ro: float) -> bool:
    """Equal to float64 round-off of a paraxial trace (module docstring)."""
    if math.isinf(dl) or math.isinf(ro):
        return math.isinf(dl) and math.isinf(ro)
    return abs(dl - ro) <= 1e-9 * max(1.0, abs(dl), abs(ro))


@contextlib.contextmanager
def _scratch_cwd():
    # rayoptics' reader opens a log file in the working folder and may write glass replacement
    # files beside the file it reads: both in a scratch folder
    old = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)
        try:
            yield Path(tmp)
        finally:
            os.chdir(old)


def _update(opm):
    opm["seq_model"].update_model()
    opm["optical_spec"].update_model()
    opm.update_optical_properties()
    return opm["analysis_results"]["parax_data"].fod


def _match(lens, sm, s_mm):
    """``(lead, after)``: the path coordinate (file units) of deeplens' first surface from the
    file's surface 1, and for each rayoptics gap the index of deeplens' medium in it."""
    p_dl, acc = [], 0.0
    for i, d in enumerate(lens.distances):
        acc += abs(float(d)) if i else 0.0
        p_dl.append(acc / s_mm)
    c_dl = [float(getattr(s, "c", 0.0)) * s_mm for s in lens.surfaces]
    q, acc = [], 0.0
    for k in range(1, len(sm.ifcs) - 1):
        q.append(acc)
        acc += abs(sm.gaps[k].thi)
    after, i, lead = [0], 0, None
    for k, qk in enumerate(q, start=1):
        cv = sm.ifcs[k].profile.cv
        if i < len(p_dl):
            base = p_dl[i] + (lead if lead is not None else qk)
            same_z = abs(base - qk) <= 1e-9 * max(1.0, abs(qk))
            same_c = abs(cv - c_dl[i]) <= 1e-12 * max(1.0, abs(cv))
            if same_z and same_c:
                lead = qk if lead is None else lead
                i += 1
        after.append(i)   # deeplens' medium i after this surface (materials[i])
    if i != len(p_dl):
        raise AssertionError(f"rayoptics' surfaces do not match deeplens' ({i} of {len(p_dl)} "
                             f"found): extend the oracle")
    return lead or 0.0, after


def has_rdm(path) -> bool:
    """Whether the file has an ``RDM`` command (radius or curvature mode)."""
    text = Path(path).read_text(errors="replace")
    return any(cmd.split()[:1] and cmd.split()[0].upper() == "RDM"
               for line in text.splitlines() for cmd in line.split("!")[0].split(";"))


def _read_opm(path: Path, radius_mode):
    """rayoptics' optical model of ``path`` (``cmdproc.read_lens``), read from a scratch copy in
    deeplens' radius/curvature mode: a file without ``RDM`` is read by deeplens in radius mode
    (or as ``radius_mode`` says) and by rayoptics in curvature mode (its own convention,
    cmdproc's ``spec_data``), so the copy gets an ``RDM`` line before its first line."""
    with _scratch_cwd() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from rayoptics.codev import cmdproc   # (its import opens the log file)

        src = tmp / path.name
        shutil.copyfile(path, src)
        if radius_mode is not None or not has_rdm(path):
            rdm = "RDM N" if radius_mode is False else "RDM Y"
            src.write_bytes(rdm.encode() + b"\n" + path.read_bytes())
        opm, _ = cmdproc.read_lens(src)
    return opm


def rayoptics_model(path, lens, radius_mode=None):
    """rayoptics' reading of ``path`` with deeplens' indices (lengths in the file's units), and
    the path coordinate of deeplens' first surface from the file's surface 1.

    A file without ``RDM`` is read by deeplens in radius mode (or as ``radius_mode`` says) and by
    rayoptics in curvature mode (its own convention, cmdproc's ``spec_data``): the oracle gets
    deeplens' reading, an ``RDM`` line put before the file's first line of a scratch copy."""
    from opticalglass.opticalmedium import ConstantIndex

    path = Path(path)
    opm = _read_opm(path, radius_mode)
    sm = opm["seq_model"]
    s_mm = unit_mm(path)
    lead, after = _match(lens, sm, s_mm)
    w = float(lens.spec.primary_wavelength_nm)
    with torch.no_grad():
        n = [float(m.n(w)) for m in lens.materials]
    for g, j in zip(sm.gaps, after):
        g.medium = ConstantIndex(n[j], f"n={n[j]!r}")
    with _scratch_cwd():
        _update(opm)
    return opm, lead


def numbers(path, lens, radius_mode=None) -> dict[str, tuple[float, float]]:
    """``{quantity: (deeplens, rayoptics)}`` in the file's length unit: the EFL (image-side; after
    an odd number of mirrors rayoptics' sign is the other one), the entrance pupil diameter, its
    position from the file's surface 1 (``ENP``) and the rear focal point from the image plane
    (``BFP``)."""
    from rayoptics.parax.firstorder import compute_principle_points

    s_mm = unit_mm(path)
    opm, lead = rayoptics_model(path, lens, radius_mode)
    sm = opm["seq_model"]
    with _scratch_cwd():
        fod = opm["analysis_results"]["parax_data"].fod
        wvl = opm["optical_spec"]["wvls"].central_wvl
        n_0 = sm.z_dir[0] * sm.central_rndx(0)
        n_k = sm.z_dir[-1] * sm.central_rndx(-1)
        p_ray, q_ray, _ = compute_principle_points(sm.path(wl=wvl), sm.overall_length(), n_0,
                                                   n_k)
        stop = sm.stop_surface if sm.stop_surface is not None else 1
        enp_ro = q_ray[stop][0] / (sm.gaps[0].medium.rindex(wvl) * p_ray[stop][0])
        efl_ro = fod.efl if fod.efl != 0.0 else math.inf
        # rayoptics keeps SI's thickness as a focus shift (deeplens adds it to the last gap)
        image = sm.gaps[-1].thi + opm["optical_spec"]["focus"].focus_shift
        bfp_ro = fod.bfl - image if fod.efl != 0.0 else math.inf
        epd_ro = 2.0 * fod.enp_radius
        t = sm.gaps[0].thi
        if abs(t) >= 1e10:   # CODE V's infinity: rayoptics keeps it finite; the EPD's 1/T term
            sm.gaps[0].thi = 2.0 * t   # removed by evaluating at T and 2T
            epd_ro = 2.0 * (2.0 * _update(opm).enp_radius) - epd_ro
            sm.gaps[0].thi = t
            _update(opm)
    with torch.no_grad():
        p = paraxial(lens)
        sign = (-1) ** len(lens.mirrors)
        efl_dl = sign * float(p.efl) / s_mm
        bfp_dl = (float(p.bfl) + float(lens.z_vertices()[-1]) - float(lens.z_sensor())) / s_mm
        enp_dl = float(p.entrance_pupil_position) / s_mm + lead
        epd_dl = float(p.entrance_pupil_diameter) / s_mm
    return {"EFL": (efl_dl, efl_ro), "EPD": (epd_dl, epd_ro), "ENP": (enp_dl, enp_ro),
            "BFP": (bfp_dl, bfp_ro)}


# --------------------------------------------------------------------------- real rays
def ray_agrees(dp: float, dd: float, length: float) -> bool:
    """Landing points ``dp`` apart (file units) and directions ``dd`` apart, for rays that
    travelled ``length`` (file units, from the launch plane to the image, summed over the
    gaps): float64 round-off.  Each intersection rounds the point to ~1e-16 of the coordinates
    involved and the error grows with the path (and a few tens of surfaces): 1e-11 per unit of
    path, 1e-11 in the direction cosines, is a thousand times that.  A wrong tilt of 1e-6 degree
    moves a landing point by ~2e-8 per unit of path after it, a thickness read off by 1e-6
    moves it by the ray's slope times 1e-6."""
    return dp <= RAY_POINT_REL * max(1.0, length) and dd <= RAY_DIR_ABS


def _frames_dl(lens, s_mm):
    """deeplens' surfaces other than breaks: ``[(index, vertex (3,), rotation (3, 3), c)]`` in
    the object-space frame, file units, origin at deeplens' first vertex; and the sensor's
    ``(vertex, rotation)``."""
    from deeplens.optics.frames import local_frames

    with torch.no_grad():
        fr = local_frames(lens)
        z = lens.z_vertices()
        out = []
        for i, s in enumerate(lens.surfaces):
            if s.interaction.changes_frame:
                continue
            A, b = fr[i]
            v = (A[:, 2] * z[i] + b) / s_mm
            out.append((i, v.tolist(), A.tolist(), float(getattr(s, "c", 0.0)) * s_mm))
        A, b = fr[-1]
        img = (((A[:, 2] * (z[-1] + lens.d_sensor) + b) / s_mm).tolist(), A.tolist())
    return out, img


def _close(a, b, tol) -> bool:
    import numpy as np

    return bool(np.all(np.abs(np.asarray(a, dtype=float) - np.asarray(b, dtype=float)) <= tol))


def match_frames(lens, sm, s_mm, focus_shift=0.0):
    """``(lead, after)`` for a lens with coordinate breaks: deeplens' surfaces other than breaks
    matched, in order, to rayoptics surfaces at the same place (vertex and rotation in the
    object-space frame, curvature), rayoptics' origin (its surface 1) being ``lead`` before
    deeplens' first vertex along the object-space axis (the leading dummies deeplens folds into
    the object distance); the image surface must match the sensor.  ``after``: for each
    rayoptics gap the index of deeplens' medium in it.  ``focus_shift``: rayoptics' (its reader
    keeps SI's thickness so): the sensor lies that far along the image surface's own axis.
    Raises ``AssertionError`` when no ``lead`` matches every surface."""
    dl, (img_v, img_A) = _frames_dl(lens, s_mm)
    ro = [(list(map(float, t)), [list(map(float, row)) for row in r]) for r, t in sm.gbl_tfrms]
    cv = [float(ifc.profile.cv) for ifc in sm.ifcs]
    n_ro = len(sm.ifcs)
    scale = max([1.0] + [abs(x) for v, _ in ro[1:] for x in v])
    tol = 1e-9 * scale

    def same(j, k, lead):
        _, v, A, c = dl[j]
        t, r = ro[k]
        return (_close([v[0], v[1], v[2] + lead], t, tol) and _close(A, r, 1e-12)
                and abs(c - cv[k]) <= 1e-12 * max(1.0, abs(c)))

    for k0 in range(1, n_ro - 1):
        lead = ro[k0][0][2] - dl[0][1][2]
        hit, k = [], k0
        for j in range(len(dl)):
            while k < n_ro - 1 and not same(j, k, lead):
                k += 1
            if k == n_ro - 1:
                break
            hit.append(k)
            k += 1
        else:
            t, r = ro[-1]
            t = [t[q] + focus_shift * r[q][2] for q in range(3)]
            if _close([img_v[0], img_v[1], img_v[2] + lead], t, tol) and _close(img_A, r, 1e-12):
                after, m = [], 0
                for g in range(len(sm.gaps)):
                    while m < len(hit) and hit[m] <= g:
                        m += 1
                    after.append(dl[m - 1][0] + 1 if m else 0)
                return lead, after
    raise AssertionError("rayoptics' surfaces do not lie where deeplens' do (vertices, "
                         "orientations, curvatures in the object-space frame)")


def ray_landings(path, lens, radius_mode=None):
    """deeplens' and rayoptics' landings of the same real rays on the image surface of a lens
    with coordinate breaks (module docstring), in the file's units.

    Returns:
        ``{"rays": n, "dp": max point distance, "dd": max direction difference, "length": max
        path from the launch plane, "failed": [...]}``; ``failed`` lists rays one side traced
        and the other did not (deeplens ``valid`` False, or a rayoptics ``TraceError``), which
        is a disagreement.  Rays neither side traces are left out.
    """
    import numpy as np
    from opticalglass.opticalmedium import ConstantIndex

    from deeplens.optics.options import TraceOptions
    from deeplens.optics.rays import Rays

    path = Path(path)
    s_mm = unit_mm(path)
    opm = _read_opm(path, radius_mode)
    from rayoptics.raytr.traceerror import TraceError

    sm = opm["seq_model"]
    foc = float(opm["optical_spec"]["focus"].focus_shift)
    lead, after = match_frames(lens, sm, s_mm, foc)
    w = float(lens.spec.primary_wavelength_nm)
    with torch.no_grad():
        n = [float(m.n(w)) for m in lens.materials]
        p = paraxial(lens)
        z_ep = float(p.entrance_pupil_position) / s_mm
        r_ep = float(p.entrance_pupil_diameter) / s_mm / 2
        z0 = float(lens.z_vertices()[0]) / s_mm
    for g, j in zip(sm.gaps, after):
        g.medium = ConstantIndex(n[j], f"n={n[j]!r}")
    obj = float(lens.spec.object_distance_mm)
    finite = math.isfinite(obj)
    gap0 = obj / s_mm - lead if finite else max(10.0, 2.0 * r_ep)   # object plane before S1
    sm.gaps[0].thi = gap0
    with _scratch_cwd(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sm.update_model()
    starts = []   # (point on the launch plane, direction), rayoptics' global frame
    for f in lens.spec.fields_deg:
        t = math.radians(float(f))
        for ex, ey in ((0.0, 0.0), (0.0, 0.7 * r_ep), (0.0, -0.7 * r_ep), (0.7 * r_ep, 0.0)):
            e = np.array([ex, ey, z0 + z_ep + lead])
            if finite:
                o = np.array([0.0, -(gap0 + e[2]) * math.tan(t), -gap0])
                d = (e - o) / np.linalg.norm(e - o)
            else:
                d = np.array([0.0, math.sin(t), math.cos(t)])
                o = e - d * (e[2] + gap0) / d[2]
            starts.append((o, d))
    out = {"rays": 0, "dp": 0.0, "dd": 0.0, "length": 0.0, "failed": []}
    o_dl = torch.tensor(np.array([o - [0.0, 0.0, lead] for o, _ in starts]) * s_mm,
                        dtype=torch.float64)
    d_dl = torch.tensor(np.array([d for _, d in starts]), dtype=torch.float64)
    with torch.no_grad():
        r = lens.double().trace_to_sensor(Rays(o_dl, d_dl, w),
                                          options=TraceOptions(clip_aperture=False))
    with _scratch_cwd(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for j, (o, d) in enumerate(starts):
            try:
                ray = sm.trace(np.array([o[0], o[1], 0.0]), d, w)[0]
            except TraceError:
                ray = None
            ok = bool(r.valid[j])
            if ray is None or not ok:
                if ok != (ray is None):
                    out["failed"].append((j, "deeplens" if ok else "rayoptics"))
                continue
            pt, dr = np.asarray(ray[-1][0]), np.asarray(ray[-1][1])
            pt = pt + dr * (foc - pt[2]) / dr[2]   # to the focus-shifted plane (its own z)
            mine = r.o[j].numpy() / s_mm
            out["rays"] += 1
            out["dp"] = max(out["dp"], float(np.hypot(*(mine[:2] - pt[:2]))))
            out["dd"] = max(out["dd"], float(np.abs(r.d[j].numpy() - dr).max()))
            out["length"] = max(out["length"], float(sum(abs(seg[2]) for seg in ray[:-1])))
    return out
