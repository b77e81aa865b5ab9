"""Bitwise before/after record of the tracer's values and gradients (issue 24's refactor).

A refactor of the optics layer must leave every value and every gradient bit for bit as it was,
on the eager path and on the compiled one.  This script traces a fixed set of lenses (spheres,
even aspheres, XY polynomials, a B-spline, a cylinder, an ideal lens, mirror systems with and
without coordinate breaks, misaligned elements, a rectangular stop), forward to the sensor and
backward from it, computes geometric PSFs and a diffraction PSF, and takes the gradients of a
fixed random functional of each result with respect to *every* lens parameter; it stores each
tensor's raw bytes.

Modes per trace: eager; the fused (compiled) path's logic with the plain Python kernels in place
of their ``torch.compile``d wrappers (``surface``, ``lens``, ``auto``, with and without
``checkpoint``) on every lens; and, with ``--compiled``, the real inductor kernels (``auto``
with gradients, ``lens`` without, float64, plus a float32 ``lens`` run) on a subset, since each
lens structure costs 10-60 s of compilation.

Usage (from the repository root, one thread)::

    OMP_NUM_THREADS=1 python benchmarks/refactor_bitwise.py record before.pt --compiled
    OMP_NUM_THREADS=1 python benchmarks/refactor_bitwise.py record after.pt --compiled
    python benchmarks/refactor_bitwise.py compare before.pt after.pt

``compare`` prints the entries that differ (by bytes, dtype or shape), the ones missing on
either side, and exits non-zero unless everything is identical.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import math
import sys
import warnings
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from deeplens.optics import compiled as C  # noqa: E402
from deeplens.optics.options import TraceOptions  # noqa: E402
from deeplens.optics.io import load_lens  # noqa: E402
from deeplens.optics.lens import Lens  # noqa: E402
from deeplens.optics.materials import Air, get_material  # noqa: E402
from deeplens.optics.paraxial import paraxial  # noqa: E402
from deeplens.optics.rays import Rays  # noqa: E402
from deeplens.optics.sampling import field_rays  # noqa: E402
from deeplens.optics.surfaces import (Aperture, Asphere, BSpline, CoordinateBreak,  # noqa: E402
                                      Cylinder, IdealLens, Plane, XYPolynomial)

F64 = torch.float64
WL = 587.5618
LENSES = REPO / "data" / "lenses"
KERNELS = ("compiled_surface_run", "compiled_newton_start", "compiled_newton_more",
           "compiled_newton_last_check", "compiled_newton_refract")


# ------------------------------------------------------------------------------------ lenses
def _glass():
    return get_material("N-BK7")


def _singlet(front, back, stop_first=True, d_sensor=40.0):
    air = Air()
    if stop_first:
        return Lens([Aperture(6.0), front, back], [air, air, _glass(), air], [0.0, 2.0, 4.0],
                    d_sensor, 0)
    return Lens([front, back], [air, _glass(), air], [0.0, 4.0], d_sensor, 0)


def _misaligned_dg():
    lens = load_lens(LENSES / "double_gauss.json")
    with torch.no_grad():
        lens.misalignments[3].dx.fill_(0.02)
        m = lens.misalignments[1]
        for name in ("tilt_x", "tilt_y", "ty", "dy"):
            if hasattr(m, name):
                getattr(m, name).fill_(0.003)
    return lens


def _rect_dg():
    lens = load_lens(LENSES / "double_gauss.json")
    stop = lens.surfaces[lens.stop_index]
    lens.surfaces[lens.stop_index] = Aperture(None, "rect", float(stop.semi_diameter),
                                              0.6 * float(stop.semi_diameter))
    return lens


def _xy(b):
    coeffs = [0.0, 0.001, -0.002, 0.012, 0.0005, 0.010, 1e-4, -2e-4, 3e-4, 1e-4]
    return _singlet(XYPolynomial(7.0, coeffs, b=b), Asphere(-0.02, 7.0))


def _bspline():
    g = torch.Generator().manual_seed(3)
    coeffs = 0.02 * torch.rand(8, 8, generator=g, dtype=F64) - 0.01
    return _singlet(Asphere(0.05, 7.0), BSpline(7.0, coeffs))


def _cylinder():
    return _singlet(Cylinder(0.04, 7.0, conic=-0.5, coefficients=[1e-5]), Asphere(-0.01, 7.0))


def _ideal():
    air = Air()
    return Lens([Aperture(5.0), IdealLens(50.0, 8.0)], [air, air, air], [0.0, 3.0], 50.0, 0)


def _telescope():
    air = Air()
    R, sd = -1000.0, 60.0
    return Lens([Aperture(sd), Asphere(1.0 / R, sd, conic=-1.0)], [air, air, air],
                [0.0, 10.0], R / 2, 0, mirrors=[1])


def _newtonian(f=500.0, a=100.0):
    air = Air()
    t = math.radians(45.0)
    surfaces = [Aperture(60.0), Asphere(-1.0 / (2 * f), 60.0, conic=-1.0),
                CoordinateBreak(tilt_x=t), Plane(30.0), CoordinateBreak(tilt_x=t)]
    return Lens(surfaces, [air] * 6, [0.0, 10.0, -(f - a), 0.0, 0.0], a, 0, mirrors=[1, 3])


def _cassegrain():
    air = Air()
    return Lens([Asphere(1 / -2000.0, 100.0, conic=-1.0), Asphere(1 / -800.0, 30.0, conic=-2.7)],
                [air] * 3, [0.0, -700.0], 1200.0, 0, mirrors=[0, 1])


CASES = {
    "double_gauss": lambda: load_lens(LENSES / "double_gauss.json"),   # spheres, asphere, stop
    "cooke": lambda: load_lens(LENSES / "cooke_triplet.json"),         # spheres only
    "acl5040u": lambda: load_lens(LENSES / "thorlabs_acl5040u.json"),  # even asphere (Newton)
    "wide_doublet": lambda: load_lens(LENSES / "wide_doublet.json"),   # aspheres + stop
    "edof": lambda: load_lens(LENSES / "edof_achromat.json"),          # XY polynomial plate
    "xy_b0": lambda: _xy(0.0),
    "xy_b": lambda: _xy(0.004),
    "bspline": _bspline,
    "cylinder": _cylinder,
    "ideal": _ideal,
    "telescope": _telescope,
    "newtonian": _newtonian,
    "cassegrain": _cassegrain,
    "misaligned_dg": _misaligned_dg,
    "rect_dg": _rect_dg,
}

#: lenses traced through the real compiled kernels with ``--compiled``
COMPILED_CASES = ("double_gauss", "edof", "misaligned_dg")


def _f32(lens, aligned):
    """A float32 copy of ``lens`` and its parameters (the float64 original is untouched)."""
    l32 = copy.deepcopy(lens).to(torch.float32)
    return l32, _params(l32, aligned)


def _params(lens, aligned=False):
    """Make every lens parameter trainable and return them by name; ``aligned``: all but the
    misalignments that are zero (a trainable misalignment makes its element run eager, so only
    this set exercises the fused and compiled kernels)."""
    ps = []
    for n, p in lens.named_parameters():
        train = not (aligned and n.startswith("misalignments.") and float(p) == 0.0)
        p.requires_grad_(train)
        if train:
            ps.append((n, p))
    return ps


# ------------------------------------------------------------------------------------ rays
def _rays(lens, reverse, n=160, dtype=F64):
    g = torch.Generator().manual_seed(2)
    if reverse:
        r = 0.2 * float(lens.sensor_semi_diameter or 4.0) + 0.5
        xy = (torch.rand(n, 2, generator=g, dtype=F64) * 2 - 1) * r
        z0 = float(lens.z_sensor().detach())
        o = torch.cat([xy, torch.full((n, 1), z0, dtype=F64)], -1)
        sign = 1.0 if lens.directions()[-1] > 0 else -1.0
        d = torch.tensor([0.05, -0.03, -sign], dtype=F64).expand(n, 3)
        return Rays(o, d, WL).to(dtype)
    with torch.no_grad():
        try:
            p = paraxial(lens)
            z_ep, r_ep = float(p.entrance_pupil_z), 0.5 * float(p.entrance_pupil_diameter)
        except Exception:  # noqa: BLE001 - a lens paraxial analysis does not cover
            z_ep, r_ep = 0.0, float(lens.surfaces[0].semi_diameter)
        if not (math.isfinite(z_ep) and math.isfinite(r_ep) and r_ep > 0):
            z_ep, r_ep = 0.0, float(lens.surfaces[0].semi_diameter)
    rr = 1.2 * r_ep * torch.sqrt(torch.rand(n, generator=g, dtype=F64))
    phi = 2 * math.pi * torch.rand(n, generator=g, dtype=F64)
    xy = torch.stack([rr * torch.cos(phi), rr * torch.sin(phi)], -1)
    field = float(lens.spec.fields_deg[-1]) * 0.7 if len(lens.spec.fields_deg) > 1 else 2.0
    return field_rays(lens, field, WL, xy, z_ep).to(dtype)


def _functional(out, seed=4):
    g = torch.Generator().manual_seed(seed)
    w = torch.randn(out.o.shape, generator=g, dtype=F64).to(out.o)
    v = out.valid
    return ((torch.where(v[..., None], out.o, torch.zeros_like(out.o)) * w).sum()
            + out.opl[v].sum() + (out.d[v] * w[v]).sum())


# ------------------------------------------------------------------------------------ modes
@contextlib.contextmanager
def _plain_kernels():
    """The fused path with the plain functions instead of their compiled wrappers."""
    saved = {k: getattr(C, k) for k in KERNELS}
    plain = {"compiled_surface_run": C.surface_run, "compiled_newton_start": C.newton_start,
             "compiled_newton_more": C.newton_more,
             "compiled_newton_last_check": C.newton_last_check,
             "compiled_newton_refract": C.newton_refract}
    for k, v in plain.items():
        setattr(C, k, v)
    try:
        yield
    finally:
        for k, v in saved.items():
            setattr(C, k, v)


def _record(store, key, fn):
    """``store[key + ...] = tensors`` of ``fn()`` (a dict of name -> tensor), or the error."""
    calls = [0]
    real_call = C.call

    def counting_call(*args):
        calls[0] += 1
        return real_call(*args)

    C.call = counting_call
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = fn()
    except Exception as e:  # noqa: BLE001 - the error is part of the behaviour recorded
        store[key + "/error"] = f"{type(e).__name__}: {e}"
        return
    finally:
        C.call = real_call
    store[key + "/kernel_calls"] = calls[0]  # > 0: the fused/compiled path ran
    for k, v in res.items():
        store[f"{key}/{k}"] = v.detach().clone() if isinstance(v, torch.Tensor) else v


def _trace_entry(lens, params, reverse, opt, dtype=F64, grad=True):
    def fn():
        rays = _rays(lens, reverse, dtype=dtype)
        ctx = contextlib.nullcontext() if grad else torch.no_grad()
        with ctx:
            out = (lens.trace(rays, reverse=True, options=opt) if reverse
                   else lens.trace_to_sensor(rays, options=opt))
        res = {"o": out.o, "d": out.d, "opl": out.opl, "valid": out.valid}
        if grad:
            loss = _functional(out)
            gs = torch.autograd.grad(loss, [p for _, p in params], allow_unused=True)
            for (n, _), g in zip(params, gs):
                res[f"grad:{n}"] = g if g is not None else "None"
        return res
    return fn


def _kernels_and_grads(kers, params, name, seed):
    """The kernels and the gradients of a seeded random functional of them."""
    res = {f"{name}{j}": k for j, k in enumerate(kers)}
    g = torch.Generator().manual_seed(seed)
    loss = sum((k * torch.rand(k.shape, generator=g, dtype=F64).to(k)).sum() for k in kers)
    gs = torch.autograd.grad(loss, [p for _, p in params], allow_unused=True)
    for (n, _), gr in zip(params, gs):
        res[f"grad:{n}"] = gr if gr is not None else "None"
    return res


def _psf_entry(lens, params, opt):
    from deeplens.render.psf import psf_many
    from deeplens.render.sensor import Sensor

    def fn():
        sensor = Sensor((32, 32), 0.005, channels=[[WL]])
        jobs = [((0.0, 0.0), math.inf, WL), ((0.0, 0.05), math.inf, WL)]
        kers = psf_many(lens, sensor, jobs, n_rays=512, kernel_size=15, options=opt)
        return _kernels_and_grads(kers, params, "psf", 5)
    return fn


def _diffraction_entry(lens, params, opt):
    from deeplens.render.diffraction import DiffractionSampling, diffraction_psf_many
    from deeplens.render.sensor import Sensor

    def fn():
        sensor = Sensor((32, 32), 0.0069, channels=[[WL]])
        jobs = [((0.0, 0.0), 6000.0, WL), ((0.3, 0.2), 6000.0, 486.1327)]
        kers = diffraction_psf_many(lens, sensor, jobs, DiffractionSampling(24, 15, 2),
                                    options=opt)
        return _kernels_and_grads(kers, params, "dpsf", 6)
    return fn


FUSED = {"surface": TraceOptions(compile="surface"), "lens": TraceOptions(compile="lens"),
         "auto": TraceOptions(compile="auto"),
         "surface_ckpt": TraceOptions(compile="surface", checkpoint=True)}


def record(compiled: bool, only=None, compiled_cases=COMPILED_CASES) -> dict:
    torch.manual_seed(0)
    store: dict = {}
    eager_opts = {"eager": TraceOptions(), "eager_ckpt": TraceOptions(checkpoint=True),
                  "generic": TraceOptions(tol=1e-13, closed_form=False)}
    for name, build in CASES.items():
        if only and name not in only:
            continue
        for aligned in (False, True):
            _record_lens(store, name, build(), aligned, compiled and name in compiled_cases,
                         eager_opts)
        print(f"  {name}: {sum(1 for k in store if k.startswith(name + '/'))} entries",
              flush=True)
    return store


def _record_lens(store, name, lens, aligned, compiled, eager_opts):
    params = _params(lens, aligned)
    if aligned:
        name = name + "/aligned"
    for reverse in (False, True):
        tag = f"{name}/{'rev' if reverse else 'fwd'}"
        for mode, opt in eager_opts.items():
            _record(store, f"{tag}/{mode}", _trace_entry(lens, params, reverse, opt))
        with _plain_kernels():
            for mode, opt in FUSED.items():
                _record(store, f"{tag}/fused_{mode}", _trace_entry(lens, params, reverse, opt))
            _record(store, f"{tag}/fused_lens_nograd",
                    _trace_entry(lens, params, reverse, FUSED["lens"], grad=False))
            l32, p32 = _f32(lens, aligned)
            _record(store, f"{tag}/fused_f32", _trace_entry(
                l32, p32, reverse, FUSED["lens"], torch.float32, False))
        l32, p32 = _f32(lens, aligned)
        _record(store, f"{tag}/eager_f32", _trace_entry(l32, p32, reverse, None,
                                                        torch.float32, True))
        base = name.split("/")[0]
        if base in ("double_gauss", "acl5040u", "misaligned_dg", "cooke"):
            _record(store, f"{name}/psf/eager", _psf_entry(lens, params, None))
            with _plain_kernels():
                _record(store, f"{name}/psf/fused_auto", _psf_entry(lens, params, FUSED["auto"]))
        if base == "edof":
            _record(store, f"{name}/dpsf/eager", _diffraction_entry(lens, params, None))
            with _plain_kernels():
                _record(store, f"{name}/dpsf/fused_auto",
                        _diffraction_entry(lens, params, FUSED["auto"]))
        if compiled and aligned:
            for reverse in (False, True):
                tag = f"{name}/{'rev' if reverse else 'fwd'}"
                _record(store, f"{tag}/compiled_auto",
                        _trace_entry(lens, params, reverse, FUSED["auto"]))
                _record(store, f"{tag}/compiled_lens_nograd",
                        _trace_entry(lens, params, reverse, FUSED["lens"], grad=False))
            if base == "double_gauss":
                l32, p32 = _f32(lens, aligned)
                _record(store, f"{name}/fwd/compiled_lens_f32", _trace_entry(
                    l32, p32, False, FUSED["lens"], torch.float32, False))
                _record(store, f"{name}/psf/compiled_auto", _psf_entry(lens, params, FUSED["auto"]))


def _bytes(v):
    if isinstance(v, torch.Tensor):
        t = v.detach().cpu().contiguous()
        return (str(t.dtype), tuple(t.shape), t.reshape(-1).view(torch.uint8).numpy().tobytes()
                if t.numel() else b"")
    return ("obj", (), repr(v).encode())


def compare(a: dict, b: dict) -> int:
    bad = 0
    for k in sorted(set(a) | set(b)):
        if k not in a or k not in b:
            print(f"MISSING in {'before' if k not in a else 'after'}: {k}")
            bad += 1
            continue
        if _bytes(a[k]) != _bytes(b[k]):
            bad += 1
            msg = ""
            if isinstance(a[k], torch.Tensor) and isinstance(b[k], torch.Tensor) and \
                    a[k].shape == b[k].shape and a[k].dtype == b[k].dtype and \
                    a[k].is_floating_point():
                diff = (a[k].double() - b[k].double()).abs()
                msg = f" (max |diff| {float(diff.nan_to_num(0).max()):.3g})"
            elif not isinstance(a[k], torch.Tensor):
                msg = f" ({a[k]!r} vs {b[k]!r})"[:300]
            print(f"DIFFERS: {k}{msg}")
    errors = sum(1 for k in a if k.endswith("/error"))
    n_t = sum(1 for v in a.values() if isinstance(v, torch.Tensor))
    print(f"{len(a)} entries before ({n_t} tensors, {errors} recorded errors), {len(b)} after: "
          f"{'ALL BITWISE IDENTICAL' if not bad else f'{bad} DIFFER'}")
    return 1 if bad else 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--compiled", action="store_true", help="also the real inductor kernels")
    r.add_argument("--only", nargs="*", help="case names (default: all)")
    r.add_argument("--compiled-cases", nargs="*", default=list(COMPILED_CASES),
                   help=f"lenses through the real compiled kernels (default: {COMPILED_CASES})")
    c = sub.add_parser("compare")
    c.add_argument("before")
    c.add_argument("after")
    args = ap.parse_args(argv)
    if args.cmd == "record":
        store = record(args.compiled, args.only, tuple(args.compiled_cases))
        torch.save(store, args.out)
        print(f"wrote {len(store)} entries to {args.out}")
        return 0
    return compare(torch.load(args.before, weights_only=False),
                   torch.load(args.after, weights_only=False))


if __name__ == "__main__":
    sys.exit(main())
