"""Batched geometric rays.

A ray is ``x(t) = o + t d`` with ``|d| = 1``.  A :class:`Rays` bundle holds, for any
leading batch shape ``B``:

* ``o``          origin, ``(*B, 3)``, mm
* ``d``          unit direction, ``(*B, 3)``
* ``wavelength`` vacuum wavelength, ``(*B,)``, nm (the package's single wavelength unit)
* ``valid``      boolean mask, ``(*B,)``: ``False`` once a ray misses a surface, leaves its
  domain, fails to converge or is totally internally reflected
* ``opl``        accumulated optical path length, ``(*B,)``, mm

Rays are immutable in spirit: tracing never writes into a bundle; every operation returns a
new :class:`Rays` (see :meth:`Rays.replace`).  Invalid rays keep *finite* coordinates so that
no NaN can reach a gradient; use ``valid`` to ignore them.
"""

from __future__ import annotations

import torch

__all__ = ["Rays"]


class Rays:
    """A batch of rays; see the module docstring for fields, shapes and units.

    Args:
        o: origins ``(*B, 3)`` in mm.
        d: directions ``(*B, 3)``; normalised here.
        wavelength: nm, a float or a tensor broadcastable to ``B``.
        valid: optional boolean mask broadcastable to ``B`` (default all valid).
        opl: optional optical path length ``(*B,)`` in mm (default zero).

    Example:
        >>> r = Rays(torch.zeros(4, 3), torch.tensor([0., 0., 1.]).expand(4, 3), 587.6)
        >>> r.shape
        torch.Size([4])
    """

    __slots__ = ("o", "d", "wavelength", "valid", "opl")

    def __init__(self, o, d, wavelength, valid=None, opl=None, *, normalize: bool = True):
        o = torch.as_tensor(o)
        d = torch.as_tensor(d, dtype=o.dtype, device=o.device)
        if o.shape[-1] != 3 or d.shape[-1] != 3:
            raise ValueError(
                f"Rays: origin and direction need a last dimension of 3, got {tuple(o.shape)} "
                f"and {tuple(d.shape)}"
            )
        o, d = torch.broadcast_tensors(o, d)
        batch = o.shape[:-1]
        if normalize:
            d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True).clamp_min(1e-30)
        w = torch.as_tensor(wavelength, dtype=o.dtype, device=o.device)
        try:
            w = w.expand(batch)
        except RuntimeError as e:
            raise ValueError(
                f"Rays: wavelength of shape {tuple(w.shape)} does not broadcast to batch "
                f"shape {tuple(batch)}"
            ) from e
        if valid is None:
            valid = torch.ones(batch, dtype=torch.bool, device=o.device)
        else:
            valid = torch.as_tensor(valid, dtype=torch.bool, device=o.device).expand(batch)
        if opl is None:
            opl = torch.zeros(batch, dtype=o.dtype, device=o.device)
        self.o, self.d, self.wavelength, self.valid, self.opl = o, d, w, valid, opl

    # ------------------------------------------------------------------ helpers
    @property
    def shape(self) -> torch.Size:
        return self.o.shape[:-1]

    @property
    def dtype(self) -> torch.dtype:
        return self.o.dtype

    @property
    def device(self) -> torch.device:
        return self.o.device

    def replace(self, **changes) -> "Rays":
        """A new bundle with some fields replaced (no copy of the others, no normalisation)."""
        fields = {k: getattr(self, k) for k in self.__slots__}
        unknown = set(changes) - set(fields)
        if unknown:
            raise TypeError(f"Rays.replace: unknown fields {sorted(unknown)}")
        fields.update(changes)
        return Rays(**fields, normalize=False)

    def at(self, t: torch.Tensor) -> torch.Tensor:
        """Points ``o + t d`` for marching distances ``t`` of shape ``B``; returns ``(*B, 3)``."""
        return self.o + t.unsqueeze(-1) * self.d

    def __getitem__(self, idx) -> "Rays":
        return Rays(self.o[idx], self.d[idx], self.wavelength[idx], self.valid[idx],
                    self.opl[idx], normalize=False)

    def reshape(self, *shape) -> "Rays":
        return Rays(self.o.reshape(*shape, 3), self.d.reshape(*shape, 3),
                    self.wavelength.reshape(*shape), self.valid.reshape(*shape),
                    self.opl.reshape(*shape), normalize=False)

    def to(self, *args, **kwargs) -> "Rays":
        o = self.o.to(*args, **kwargs)
        return Rays(o, self.d.to(o), self.wavelength.to(o), self.valid.to(o.device),
                    self.opl.to(o), normalize=False)

    def __len__(self) -> int:
        return self.shape[0] if len(self.shape) else 1

    def __repr__(self) -> str:
        n_valid = int(self.valid.sum())
        return (f"Rays(shape={tuple(self.shape)}, valid={n_valid}, dtype={self.dtype}, "
                f"device={self.device})")


# ------------------------------------------------------------------ layouts
def compact_broadcast(w):
    """``w`` without its broadcast (stride-0) dimensions' repeats: size 1 there (a view)."""
    if not isinstance(w, torch.Tensor):
        return torch.as_tensor(w)
    for dim, (size, stride) in enumerate(zip(w.shape, w.stride())):
        if stride == 0 and size > 1:
            w = w.narrow(dim, 0, 1)
    return w


def to_soa(v: torch.Tensor) -> torch.Tensor:
    """``(*B, 3)`` -> component-major ``(3, *B)``, contiguous.  ``torch.stack`` of the
    components: the same values as ``v.movedim(-1, 0).contiguous()``, whose strided copy is
    about 4x slower on the CPU (5 vs 1.2 ms for 1e6 float32 rays)."""
    return torch.stack(v.unbind(-1))


def from_soa(v: torch.Tensor) -> torch.Tensor:
    """Component-major ``(3, *B)`` -> ``(*B, 3)``, contiguous (see :func:`to_soa`)."""
    return torch.stack(v.unbind(0), -1)
