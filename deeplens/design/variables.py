"""Design variables: lens parameters chosen by name or glob, scaled to millimetres of sag.

A variable is an entry of a lens parameter named as in ``lens.named_parameters()``:
``surfaces.3.c`` (a curvature), ``surfaces.16.a.0`` (the a4 coefficient), ``surfaces.*.k``,
``distances.5``, ``d_sensor``, ``misalignments.2.tilt_x``.  The optimiser works on the scaled
vector

    x_j = s_j p_j,        s_j = mm of sag at the rim per unit of p_j   (:func:`parameter_scale`)

so that a step of 1 in any ``x_j`` changes its surface by about 1 mm at the rim: a curvature
scales by ``R^2 / 2``, an even asphere ``a_2k`` by ``R^2k``, an XY coefficient of ``x^i y^j``
by ``R^(i+j)``, a conic ``k`` by ``∂z/∂k = c^3 R^4 / (2 q (1 + q)^2)`` (``q = sqrt(1 - (1+k)
c^2 R^2)``), a tilt by the largest semi-diameter (mm of rim displacement per rad); distances,
decenters and B-spline heights are already mm.  ``R`` is the surface's semi-diameter.

Evaluation never writes into the lens: :meth:`Variables.call` substitutes the values for the
parameters (``torch.func.functional_call``) so that ``x`` may carry autograd or forward-mode
tangents, and :meth:`Variables.assign` writes a final ``x`` back.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..optics.camera import Camera
from ..optics.parameters import parameter_scale, resolve_names

__all__ = ["parameter_scale", "Variables", "resolve_names", "on_camera"]


def on_camera(camera: Camera | None, lens):
    """``lens`` as a merit should see it: ``lens`` itself when ``camera`` is ``None``, else
    ``camera`` when it holds this lens (inside :meth:`Variables.call` the lens is the camera's,
    with substituted values), else a :class:`~deeplens.optics.camera.Camera` of ``lens`` with
    ``camera``'s sensor and options, so that the camera's options reach every trace."""
    if camera is None:
        return lens
    if lens is camera.lens:
        return camera
    return Camera(lens, camera.sensor, camera.options)


class _Call(nn.Module):
    """Holds the lens so that ``functional_call`` can substitute its parameters."""

    def __init__(self, lens):
        super().__init__()
        self.lens = lens

    def forward(self, fn):
        return fn(self.lens)


class Variables:
    """The design variables of ``lens`` (names or globs) and their scales.

    Args:
        lens: the :class:`~deeplens.optics.lens.Lens` (its parameters are not modified until
            :meth:`assign`).
        patterns: names/globs, a list or a comma-separated string.
        scales: optional ``{name: mm per unit}`` overrides of :func:`parameter_scale`.

    Attributes:
        names: parameter names (in the order of ``patterns``); ``sizes``: entries per parameter;
        ``scale``: ``(n,)`` float64 scales; ``labels``: one label per entry.

    Example:
        >>> from deeplens.optics import load_lens
        >>> lens = load_lens("double_gauss")
        >>> v = Variables(lens, "surfaces.0.c,surfaces.0.k")
        >>> c = v.call(lambda L: L.surfaces[0].c, v.x0())   # any merit of the lens
        >>> bool(c == lens.surfaces[0].c)
        True
    """

    def __init__(self, lens, patterns, scales: dict | None = None, what: str = "--vary"):
        if isinstance(lens, Camera):  # the variables of the camera's lens
            lens = lens.lens
        self.lens = lens
        self.names = resolve_names(lens, patterns, what)
        params = dict(lens.named_parameters())
        self.shapes = [tuple(params[n].shape) for n in self.names]
        self.sizes = [max(1, params[n].numel()) for n in self.names]
        sc = []
        self.labels = []
        for n, k in zip(self.names, self.sizes):
            s = float((scales or {}).get(n, parameter_scale(lens, n)))
            if not (s > 0 and math.isfinite(s)):
                raise ValueError(f"variable {n}: scale must be a positive number, got {s!r}")
            sc += [s] * k
            self.labels += [n] if k == 1 else [f"{n}[{i}]" for i in range(k)]
        self.scale = torch.tensor(sc, dtype=torch.float64)
        self._call = _Call(lens)

    def __len__(self) -> int:
        return int(self.scale.numel())

    def __repr__(self) -> str:
        return f"Variables({', '.join(self.labels)})"

    def current(self) -> torch.Tensor:
        """The lens's current parameter values, flattened ``(n,)`` (float64, unscaled)."""
        params = dict(self.lens.named_parameters())
        return torch.cat([params[n].detach().reshape(-1).double().cpu() for n in self.names])

    def x0(self) -> torch.Tensor:
        """The scaled vector ``x = s p`` at the lens's current values ``(n,)``."""
        return self.current() * self.scale

    def values(self, x: torch.Tensor) -> dict:
        """``{name: tensor}`` parameter values for the scaled vector ``x`` (differentiable)."""
        if x.shape != (len(self),):
            raise ValueError(f"expected {len(self)} variables ({', '.join(self.labels)}), got "
                             f"a tensor of shape {tuple(x.shape)}")
        params = dict(self.lens.named_parameters())
        p = x / self.scale.to(x)
        out, i = {}, 0
        for n, shape, k in zip(self.names, self.shapes, self.sizes):
            ref = params[n]
            out[n] = p[i:i + k].reshape(shape).to(dtype=ref.dtype, device=ref.device)
            i += k
        return out

    def call(self, fn, x: torch.Tensor):
        """``fn(lens)`` evaluated with the variables set to ``x`` (the lens is not modified);
        gradients and forward-mode tangents of ``x`` flow into the result."""
        vals = {f"lens.{n}": v for n, v in self.values(x).items()}
        return torch.func.functional_call(self._call, vals, (fn,), strict=False)

    def assign(self, x: torch.Tensor) -> None:
        """Write the scaled vector ``x`` into the lens parameters (in place, no graph)."""
        params = dict(self.lens.named_parameters())
        with torch.no_grad():
            for n, v in self.values(x.detach()).items():
                params[n].copy_(v)

    def as_dict(self, x: torch.Tensor | None = None) -> dict:
        """``{label: value}`` in the parameters' own units (for reports)."""
        p = (self.current() if x is None else x.detach().double().cpu() / self.scale)
        return {lab: float(v) for lab, v in zip(self.labels, p)}
