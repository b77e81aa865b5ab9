"""Sensitivity (paper Eq. 10): the Jacobian of per-field merits w.r.t. tolerance parameters.

For a per-field merit ``ε_f`` (the RMS spot of field ``f``, polychromatic as
``sqrt(mean_λ RMS_fλ^2)``) and tolerance parameters ``θ`` (element decenters ``dx, dy`` in mm,
tilts ``tilt_x, tilt_y`` in rad, spacings ``distances.i`` in mm, curvatures ``surfaces.i.c`` in
1/mm) the first-order change of the merit under a perturbation ``Δθ`` is

    Δε = J_ε Δθ,        J_ε = ∂ε/∂θ  (F x P),

built column by column with forward-mode AD (one Jacobian-vector product per parameter) and
checked against central differences (:func:`finite_difference_matrix`).

The RMS spot of a centred, rotationally symmetric lens is *stationary* in decenters and tilts
at fields in their plane of symmetry (``ε(δ) = ε(-δ)``), so ``J_ε`` alone says nothing about
them.  The RSS tolerance estimate therefore uses the residual vector ``r`` of the spot (ray
deviations, ``ε_f^2 = |r_f|^2``) and its Jacobian ``J_r``: for independent zero-mean
perturbations of standard deviation ``σ_j``,

    E[ε_f^2] ≈ |r_f|^2 + sum_j σ_j^2 |J_r,f[:, j]|^2          (Gauss-Newton, second order)

and the RSS estimate is ``sqrt`` of it; the increase ``sqrt(E[ε^2]) - ε`` is what
:mod:`.tolerance`'s Monte Carlo measures.  A uniform tolerance ``±t`` has ``σ = t / sqrt 3``.
"""

from __future__ import annotations

import math
import warnings

import torch

from ..optics.camera import Camera, unpack
from ..optics.materials import Air
from ..optics.surfaces import Aperture
from .merit import SpotMerit
from .optimizers import jacobian
from .variables import Variables, on_camera

__all__ = ["tolerance_parameters", "field_merits", "sensitivity_matrix",
           "finite_difference_matrix", "rss_estimate", "KINDS"]

KINDS = ("decenter", "tilt", "spacing", "curvature")


def tolerance_parameters(lens, kinds=KINDS) -> list[str]:
    """Parameter names of the given kinds: decenter/tilt of every glass element (not the stop),
    every spacing ``distances.1..N-1`` and the curvature of every curved surface."""
    for k in kinds:
        if k not in KINDS:
            raise ValueError(f"tolerance kind must be one of {KINDS}, got {k!r}")
    out = []
    for e, (a, b) in enumerate(lens.elements):
        glass = any(not isinstance(lens.materials[i + 1], Air) for i in range(a, b + 1))
        if not glass or all(isinstance(lens.surfaces[i], Aperture) for i in range(a, b + 1)):
            continue
        if "decenter" in kinds:
            out += [f"misalignments.{e}.dx", f"misalignments.{e}.dy"]
        if "tilt" in kinds:
            out += [f"misalignments.{e}.tilt_x", f"misalignments.{e}.tilt_y"]
    if "spacing" in kinds:
        out += [f"distances.{i}" for i in range(1, len(lens.surfaces))]
    if "curvature" in kinds:
        out += [f"surfaces.{i}.c" for i, s in enumerate(lens.surfaces)
                if hasattr(s, "c") and float(s.c) != 0.0]
    return out


def field_merits(merit: SpotMerit, lens) -> torch.Tensor:
    """``ε_f = sqrt(mean_λ RMS_fλ^2)`` ``(F,)`` in mm; ``lens``: a Lens or a Camera (its
    options are used)."""
    rms = merit.rms(lens)
    return torch.sqrt((rms * rms).mean(-1))


def _split(lens, where):
    """``(camera or None, lens)`` of a Lens or a :class:`~deeplens.optics.camera.Camera`."""
    return (lens if isinstance(lens, Camera) else None), unpack(lens, where=where)[0]


def _unscaled(lens, names):
    # tolerance parameters work in their own units (mm, rad, 1/mm): unit scales
    return Variables(lens, names, scales={n: 1.0 for n in names}, what="tolerance parameters")


def sensitivity_matrix(lens, merit: SpotMerit, names, mode: str = "forward") -> torch.Tensor:
    """``J_ε`` ``(F, P)``: ``∂ε_f / ∂θ_j`` by forward-mode AD (mm per parameter unit).

    ``merit`` must be prepared on the nominal ``lens`` (its pupil regions are held fixed).
    ``mode="reverse"`` builds the same matrix from ``F`` vector-Jacobian products instead (one
    trace and ``F`` backward passes: cheaper when there are fewer fields than parameters).
    ``lens``: a Lens or a :class:`~deeplens.optics.camera.Camera` (its options reach every
    trace of the merit)."""
    cam, lens = _split(lens, "sensitivity_matrix")
    v = _unscaled(lens, names)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad")
        _, J = jacobian(lambda x: v.call(lambda L: field_merits(merit, on_camera(cam, L)), x),
                        v.x0(), mode)
    return J


def finite_difference_matrix(lens, merit: SpotMerit, names, steps=None) -> torch.Tensor:
    """Central differences ``(ε(θ + h) - ε(θ - h)) / 2h`` ``(F, P)``; default steps ``h``:
    1e-5 mm (decenters, spacings), 1e-6 rad (tilts), 1e-6 |c| (curvatures).  ``lens``: a Lens
    or a Camera (its options are used)."""
    cam, lens = _split(lens, "finite_difference_matrix")
    v = _unscaled(lens, names)
    x0 = v.x0()
    cols = []
    with torch.no_grad():
        for j, n in enumerate(names):
            if steps is not None:
                h = float(steps[j])
            elif n.endswith(".c"):
                h = 1e-6 * max(abs(float(x0[j])), 1e-3)
            elif "tilt" in n:
                h = 1e-6
            else:
                h = 1e-5
            e = torch.zeros_like(x0)
            e[j] = h
            fp = v.call(lambda L: field_merits(merit, on_camera(cam, L)), x0 + e)
            fm = v.call(lambda L: field_merits(merit, on_camera(cam, L)), x0 - e)
            cols.append((fp - fm) / (2 * h))
    return torch.stack(cols, -1)


def rss_estimate(lens, merit: SpotMerit, names, sigmas) -> dict:
    """The second-order RSS estimate of the module docstring.

    Args:
        lens: a Lens or a :class:`~deeplens.optics.camera.Camera` (its options are used).
        sigmas: ``(P,)`` standard deviations of the parameters (their units).

    Returns:
        ``{"nominal_um": (F,), "rss_um": (F,), "contrib_um2": (F, P)}`` lists:
        ``contrib[f][j] = σ_j^2 |J_r,f[:, j]|^2`` in µm².
    """
    sig = torch.as_tensor(sigmas, dtype=torch.float64)
    if sig.shape != (len(names),):
        raise ValueError(f"need {len(names)} sigmas, got shape {tuple(sig.shape)}")
    cam, lens = _split(lens, "rss_estimate")
    v = _unscaled(lens, names)
    F, W = len(merit.fields), len(merit.waves)
    nominal, contrib = [], []
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad")
        for i, f in enumerate(merit.fields):
            eps2, c = 0.0, torch.zeros(len(names), dtype=torch.float64)
            for wl in merit.waves:
                def res(x, f=f, wl=wl):
                    def on(L):
                        dev, ok, n, _ = merit._block(on_camera(cam, L), f, wl)
                        return (dev / torch.sqrt(n.to(dev))).reshape(-1)
                    return v.call(on, x)
                r, J = jacobian(res, v.x0(), "forward")
                eps2 += float((r * r).sum()) / W
                c += (J * J).sum(0) * sig ** 2 / W
            nominal.append(math.sqrt(eps2))
            contrib.append(c)
    contrib = torch.stack(contrib)
    rss = torch.sqrt(torch.tensor(nominal) ** 2 + contrib.sum(-1))
    return {"nominal_um": [x * 1e3 for x in nominal], "rss_um": (rss * 1e3).tolist(),
            "contrib_um2": (contrib * 1e6).tolist(), "fields_deg": list(merit.fields),
            "F": F}
