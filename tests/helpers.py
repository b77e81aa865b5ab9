"""Shared test helpers: small lenses built in Python, ray bundles, a float64 central finite
difference, and a relative-error measure.  Imported by test modules as ``import helpers``
(``tests/`` is on ``sys.path`` through ``pythonpath`` in ``pyproject.toml``)."""

from __future__ import annotations

import math
from pathlib import Path

import torch

from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens
from deeplens.optics.materials import Air, ModelGlass, get_material
from deeplens.optics.paraxial import paraxial
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import Asphere, Plane
from deeplens.optics.tracer import fused_kind

REPO = Path(__file__).resolve().parents[1]
LENS_DIR = REPO / "data" / "lenses"
TABLE_DIR = REPO / "tests" / "data" / "lenses"  # the paper authors' tables (copies)
WAVELENGTH_D = 587.5618


def rel_err(a, b) -> float:
    """``|a - b| / max(|a|, |b|)`` for scalars or tensors (max over elements); 0 for 0 vs 0."""
    a = torch.as_tensor(a, dtype=torch.float64)
    b = torch.as_tensor(b, dtype=torch.float64)
    den = torch.maximum(a.abs().max(), b.abs().max())
    if float(den) == 0.0:
        return 0.0
    return float((a - b).abs().max() / den)


def central_fd(fn, param: torch.Tensor, h: float, index=None) -> float:
    """Fourth-order central difference of the scalar ``fn()`` with respect to ``param`` (or to
    its entry ``index``), changing the value in place and restoring it afterwards::

        (8 (f(p + h) - f(p - h)) - (f(p + 2h) - f(p - 2h))) / 12h      (error O(h^4))
    """
    idx = () if index is None else index
    with torch.no_grad():
        p0 = param[idx].clone()
        f = {}
        for k in (-2, -1, 1, 2):
            param[idx] = p0 + k * h
            f[k] = float(fn())
        param[idx] = p0
    return (8.0 * (f[1] - f[-1]) - (f[2] - f[-2])) / (12.0 * h)


def fd_with_error(fn, param: torch.Tensor, h: float, index=None) -> tuple[float, float]:
    """:func:`central_fd` at ``h`` and an estimate of its error, so that a gradient test's
    tolerance comes from the computation at hand rather than from one machine's outcome:

    - truncation (and noise): ``|D(h) - D(2h)|``; the O(h^4) term is 16x larger in ``D(2h)``,
      so this bounds ``D(h)``'s truncation error with room to spare;
    - rounding: ``fn``'s noise ``s`` (the largest deviation from a straight line of ``fn`` over
      seven values of ``param`` a few ulps apart, where the true change is linear), which the
      stencil's weights ``(8 + 8 + 1 + 1) / 12h`` amplify to ``1.5 s / h``; counted 4x.

    Which rounding a trace gets depends on the CPU's vector unit (AVX-512, AVX2, the scalar
    default path), so a tolerance below this estimate passes on one machine and fails on
    another.  Returns ``(derivative, error)``.
    """
    idx = () if index is None else index
    d1 = central_fd(fn, param, h, index)
    d2 = central_fd(fn, param, 2 * h, index)
    with torch.no_grad():
        p0 = param[idx].clone()
        step = max(64 * torch.finfo(torch.float64).eps * float(p0.abs()), 1e-6 * h)
        ks = torch.arange(-3, 4, dtype=torch.float64)
        vals = []
        for k in ks.tolist():
            param[idx] = p0 + k * step
            vals.append(float(fn()))
        param[idx] = p0
    v = torch.tensor(vals, dtype=torch.float64)
    A = torch.stack([torch.ones_like(ks), ks], -1)
    fit = A @ torch.linalg.lstsq(A, v[:, None]).solution
    noise = float((v - fit[:, 0]).abs().max())
    return d1, abs(d1 - d2) + 4 * 1.5 * noise / h


def singlet(front, back, *, thickness: float = 4.0, glass: str = "N-BK7",
            d_sensor: float = 40.0, stop_index: int = 0, **kw) -> Lens:
    """A one-element lens ``front | glass | back`` in air, first vertex at z = 0."""
    return Lens([front, back], [get_material("AIR"), get_material(glass), get_material("AIR")],
                [0.0, thickness], d_sensor, stop_index, **kw)


def disk_points(n: int, radius: float, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    """``n`` seeded uniform points ``(n, 2)`` in a disk of ``radius`` mm."""
    g = torch.Generator().manual_seed(seed)
    r = radius * torch.sqrt(torch.rand(n, generator=g, dtype=torch.float64))
    phi = 2 * math.pi * torch.rand(n, generator=g, dtype=torch.float64)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi)], -1).to(dtype)


def collimated(xy: torch.Tensor, direction, z0: float, wavelength: float = WAVELENGTH_D) -> Rays:
    """Parallel rays through the points ``xy`` ``(M, 2)`` of the plane ``z = z0``, travelling
    along ``direction`` (3 numbers, normalised here)."""
    dtype = xy.dtype
    d = torch.as_tensor(direction, dtype=dtype)
    d = d / torch.linalg.vector_norm(d)
    o = torch.cat([xy, torch.full((xy.shape[0], 1), z0, dtype=dtype)], -1)
    return Rays(o, d.expand_as(o), wavelength)


def cat_rays(*bundles: Rays) -> Rays:
    """One bundle from several 1-D bundles."""
    return Rays(torch.cat([b.o for b in bundles]), torch.cat([b.d for b in bundles]),
                torch.cat([b.wavelength for b in bundles]),
                torch.cat([b.valid for b in bundles]), torch.cat([b.opl for b in bundles]),
                normalize=False)


def weighted_image_sum(out: Rays, weights: torch.Tensor) -> torch.Tensor:
    """``sum over valid rays of w · (x, y)`` at the rays' positions: a loss that moves with
    every image coordinate (``weights`` is ``(M, 2)``)."""
    xy = out.o[..., :2]
    terms = (weights.to(xy) * xy).sum(-1)
    return torch.where(out.valid, terms, torch.zeros_like(terms)).sum()


def optiland_optic(spec: dict, index_of, object_distance: float = math.inf):
    """An optiland ``Optic`` (the test-only oracle) with the surfaces of a lens-file dictionary:
    object surface, every surface (even aspheres with their conic and coefficients; planes and
    the aperture flat), an image surface 10 mm after the last, the aperture floating by the
    stop's diameter.  ``index_of(material_name) -> float`` gives each medium's index (our own,
    at the test's wavelength).  Fields, wavelengths and the image solve are the caller's."""
    import numpy as np
    from optiland.materials import IdealMaterial
    from optiland.optic import Optic
    from optiland.physical_apertures import RadialAperture

    surfaces, stop = spec["surfaces"], spec["stop"]
    op = Optic()
    op.surfaces.add(index=0, radius=np.inf, thickness=object_distance,
                    material=IdealMaterial(index_of(spec["object"]["medium"])))
    for i, s in enumerate(surfaces):
        # optiland's thickness follows a surface; ours (distance_mm) precedes it.
        thickness = surfaces[i + 1]["distance_mm"] if i + 1 < len(surfaces) else 10.0
        kw = dict(index=i + 1, thickness=thickness, material=IdealMaterial(index_of(s["material"])),
                  aperture=RadialAperture(r_max=s["semi_diameter_mm"]), is_stop=(i == stop))
        if s["type"] == "asphere":
            c = s["curvature_per_mm"]
            kw["radius"] = 1.0 / c if c != 0 else np.inf
            if s.get("aspheric"):
                kw.update(surface_type="even_asphere", conic=s.get("conic", 0.0),
                          coefficients=[0.0] + list(s["aspheric"]), tol=1e-13)
            else:
                kw["conic"] = s.get("conic", 0.0)
        else:
            assert s["type"] in ("plane", "aperture"), s["type"]
            kw["radius"] = np.inf
        op.surfaces.add(**kw)
    op.surfaces.add(index=len(surfaces) + 1)
    op.set_aperture(aperture_type="float_by_stop_size",
                    value=2.0 * surfaces[stop]["semi_diameter_mm"])
    return op


def run_cli(argv, capsys):
    """``(exit status, stdout, stderr)`` of ``deeplens ARGV`` in-process; argparse's own errors
    exit via SystemExit."""
    from deeplens.cli import main

    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def hexapolar_unit(rings: int):
    """The CLI's hexapolar pupil pattern in normalised coordinates, built independently of
    ``deeplens.optics.sampling`` (for the optiland oracles): the centre, then ring ``k`` of
    ``6k`` points at radius ``k / rings``, angle ``2πj / 6k`` from +y towards +x.  Returns
    ``(p_x, p_y)`` as numpy arrays."""
    import numpy as np

    px, py = [0.0], [0.0]
    for k in range(1, rings + 1):
        r = k / rings
        for j in range(6 * k):
            phi = 2.0 * math.pi * j / (6 * k)
            px.append(r * math.sin(phi))
            py.append(r * math.cos(phi))
    return np.array(px), np.array(py)


def spy_trace_options(monkeypatch) -> list:
    """Replace the tracer's entry point by a spy that records the ``options`` of every trace
    (and then traces as before); returns the list it appends to."""
    from deeplens.optics import tracer

    seen = []
    real = tracer.trace

    def spy(lens, rays, **kw):
        seen.append(kw.get("options"))
        return real(lens, rays, **kw)

    monkeypatch.setattr(tracer, "trace", spy)
    return seen


def disk_xy(n: int = 200, rmax: float = 6.0, seed: int = 0):
    """``n`` points (numpy ``(n,)`` x and y, mm) uniform over the disk of radius ``rmax``
    (numpy generator ``seed``): where surface sags and slopes are compared."""
    import numpy as np

    rng = np.random.default_rng(seed)
    r = rmax * np.sqrt(rng.random(n))
    t = 2 * np.pi * rng.random(n)
    return r * np.cos(t), r * np.sin(t)


def read_zmx_quiet(path):
    """``read_zmx(path)`` with the reader's warnings silenced (synthetic files that exercise
    one feature; the warnings themselves are tested where they matter)."""
    import warnings

    from deeplens.optics.io.zmx import read_zmx

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_zmx(path)


def assert_compiled_run_equals_eager(lens, params, mode) -> None:
    """A 10 deg field of the (double Gauss based) ``lens`` traced eager and with
    ``compile=mode``: the same valid rays, positions, directions and paths to 1e-12 mm, and the
    same (non-zero) gradient of ``sum |o|^2 + sum opl`` in each of ``params`` to 1e-10; for a
    surface type that the fused kernels run eager between compiled runs."""
    import pytest

    from deeplens.optics.options import TraceOptions
    from deeplens.optics.sampling import field_rays

    rays = field_rays(lens, 10.0, WAVELENGTH_D, disk_points(120, 2.6, seed=2), 6.0)

    def run(opt):
        out = lens.trace_to_sensor(rays, options=opt)
        v = out.valid
        loss = (out.o[v] ** 2).sum() + out.opl[v].sum()
        return out, torch.autograd.grad(loss, params)

    a, ga = run(TraceOptions(compile=False))
    b, gb = run(TraceOptions(compile=mode))
    assert torch.equal(a.valid, b.valid) and 0.3 * len(a.valid) < int(a.valid.sum())
    v = a.valid
    for x, y in ((a.o, b.o), (a.d, b.d), (a.opl, b.opl)):
        assert float((x - y)[v].detach().abs().max()) < 1e-12
    for x, y in zip(ga, gb):
        assert float(x) != 0.0 and float(y) == pytest.approx(float(x), rel=1e-10)


def assert_value_and_efl_grads_match_fd(q, x0, steps, powerless=(), rel: float = 1e-6) -> None:
    """``q(*x, grad=True)`` returns ``(value, efl, params)``: a traced quantity, the paraxial
    EFL (mm) and the ``len(x0)`` parameter tensors set from ``x`` with gradients on; ``q(*x)``
    the same without.  Each autograd derivative of ``value`` and ``efl`` in ``params[j]``
    equals the central difference with step ``steps[j]`` (relative ``rel``; the difference of
    ``value`` not below 1e-6, so the check can fail); for ``j`` in ``powerless`` the parameter
    has no paraxial power: the EFL's difference is exactly 0 and its derivative 0 or unused."""
    import pytest

    val, efl, params = q(*x0, grad=True)
    grads = torch.autograd.grad(val, params, retain_graph=True)
    egrads = torch.autograd.grad(efl, params, allow_unused=True)
    for j, h in enumerate(steps):
        xp, xm = list(x0), list(x0)
        xp[j] += h
        xm[j] -= h
        vp, ep, _ = q(*xp)
        vm, em, _ = q(*xm)
        fd = float(vp - vm) / (2 * h)
        assert abs(fd) > 1e-6, j
        assert float(grads[j]) == pytest.approx(fd, rel=rel), j
        efd = float(ep - em) / (2 * h)
        if j in powerless:
            assert efd == 0.0 and (egrads[j] is None or float(egrads[j]) == 0.0), j
        else:
            assert float(egrads[j]) == pytest.approx(efd, rel=rel), j


# ---- phase surfaces on a conic base (Binary1, ZernikeFringePhase) ----------------------------
def single_in_air(surface, dist: float = 100.0) -> Lens:
    """``surface`` alone in air, the sensor ``dist`` mm behind it."""
    return Lens([surface], [Air(), Air()], [0.0], dist, 0)


def parallel_rays(x, y, wavelength) -> Rays:
    """Rays along +z from ``(x, y, −1)`` (mm; ``x``, ``y`` ``(B,)``), wavelength in nm."""
    x = torch.as_tensor(x, dtype=torch.float64)
    y = torch.as_tensor(y, dtype=torch.float64)
    o = torch.stack([x, y, torch.full_like(x, -1.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(o)
    return Rays(o, d, wavelength)


def assert_directions_match_rayoptics_doe(surface, value, scale: float, g, tol: float,
                                          ref_nm: float = 550.0) -> None:
    """Skew rays (10, drawn from the generator ``g``) through the flat phase ``surface`` alone
    in air at 486.1 and 656.3 nm: deeplens' directions equal rayoptics' DiffractiveElement's (a
    test-only oracle: its own grating law, ``d' = d + M (λ/λ_ref) ∇W + Q N``, order 1) to
    ``tol``, given the phase as the optical path ``W = scale · value(x, y)`` (mm; ``value`` the
    test's own table, ``scale`` its unit at ``ref_nm``) and its slopes as central differences
    with ``h`` = 1e-6 mm.  Skipped without rayoptics."""
    import pytest

    pytest.importorskip("rayoptics")
    from rayoptics.oprops.doe import DiffractiveElement

    def phase_fct(pt, coefficients):
        x, y, _ = pt
        h = 1e-6
        w = scale * value(x, y)
        wx = scale * (value(x + h, y) - value(x - h, y)) / (2 * h)
        wy = scale * (value(x, y + h) - value(x, y - h)) / (2 * h)
        return w, wx, wy

    doe = DiffractiveElement(coefficients=[], ref_wl=ref_nm, order=1, phase_fct=phase_fct)
    lens = single_in_air(surface)
    n = 10
    o = torch.empty(n, 3, dtype=torch.float64).uniform_(-2.5, 2.5, generator=g)
    o[:, 2] = -1.0
    d = torch.empty(n, 3, dtype=torch.float64).uniform_(-0.15, 0.15, generator=g)
    d[:, 2] = 1.0
    d = d / d.norm(dim=-1, keepdim=True)
    for wl in (486.1, 656.3):
        out = lens.trace(Rays(o, d, wl))
        assert out.valid.all()
        for i in range(n):
            pt = (o[i] - d[i] * o[i, 2] / d[i, 2]).tolist()   # the hit on z = 0
            ro, _ = doe.phase(pt, d[i].numpy().copy(), [0.0, 0.0, 1.0],
                              (1, wl, 1.0, 1.0, "transmit"))
            err = float((out.d[i] - torch.as_tensor(ro, dtype=torch.float64)).abs().max())
            assert err <= tol, (wl, i, err)


def phase_on_singlet_quantities(surface, params, grad: bool):
    """``(value, efl, params)`` for :func:`assert_value_and_efl_grads_match_fd`: a glass
    singlet (front ``1/30`` mm⁻¹, n 1.6, 3 mm) whose rear is the phase ``surface``, the
    ``params`` (tensors of ``surface``) given gradients when ``grad``; ``value`` sums squared
    image heights, ``x y`` products and 0.1 × the optical paths of 12 tilted rays at 587 nm;
    ``efl`` the paraxial EFL (mm)."""
    lens = Lens([Asphere(1 / 30.0, 6.0), surface], [Air(), ModelGlass(1.6, 40.0), Air()],
                [0.0, 3.0], 30.0, 0)
    if grad:
        for p in params:
            p.requires_grad_(True)
    g = torch.Generator().manual_seed(5)
    o = torch.empty(12, 3, dtype=torch.float64).uniform_(-1.5, 1.5, generator=g)
    o[:, 2] = -2.0
    d = torch.tensor([0.02, -0.03, 1.0], dtype=torch.float64).expand_as(o)
    out = lens.trace_to_sensor(Rays(o, d / d.norm(dim=-1, keepdim=True), 587.0))
    assert out.valid.all()
    val = (out.o[:, 1] ** 2 + out.o[:, 0] * out.o[:, 1]).sum() + 0.1 * out.opl.sum()
    return val, paraxial(lens).efl, params


def assert_phase_round_trips(surface, type_name: str, field: str, values) -> None:
    """A lens (a flat glass front, n 1.6, then ``surface``, order −1, R_n 4 mm) traces the phase
    eagerly, writes ``type_name`` with ``field`` = ``values``, reads back the same and is not
    axisymmetric."""
    lens = Lens([Plane(8.0), surface], [Air(), ModelGlass(1.6, 40.0), Air()], [0.0, 4.0], 20.0, 0)
    assert fused_kind(lens, 1) is None
    d = lens_to_dict(lens)
    s = d["surfaces"][1]
    assert s["type"] == type_name and s["order"] == -1
    assert s[field] == values and s["norm_radius_mm"] == 4.0
    assert lens_to_dict(lens_from_dict(d)) == d
    assert not lens.surfaces[1].axisymmetric
