"""The law of reflection in vector form.

With unit normal ``n`` (either orientation) and incident unit direction ``d``:

    d_r = d - 2 (d · n) n

``d_r`` is a unit vector in the plane of ``d`` and ``n``, the angle of reflection equals the
angle of incidence (``d_r · n = -d · n``) and the tangential component is kept
(``d_r - (d_r · n) n = d - (d · n) n``).  The expression is even in ``n``, so the normal's
orientation does not matter.  A ray that grazes the mirror (``d · n = 0``) is returned
unchanged; it has already been marked invalid by the intersection (``d · ∇f`` vanishes).
"""

from __future__ import annotations

import torch

__all__ = ["reflect"]


def reflect(d: torch.Tensor, n: torch.Tensor, valid: torch.Tensor):
    """Reflect unit directions ``d`` at unit normals ``n``.

    Args:
        d: ``(*B, 3)`` incident unit directions.
        n: ``(*B, 3)`` unit surface normals (either orientation).
        valid: ``(*B,)`` incoming mask (returned unchanged: reflection never fails).

    Returns:
        ``(d_r, valid)``; invalid rays keep ``d``.

    Example::

        >>> d = torch.tensor([[0.6, 0.0, 0.8]]); n = torch.tensor([[0.0, 0.0, -1.0]])
        >>> reflect(d, n, torch.tensor([True]))[0]
        tensor([[ 0.6000,  0.0000, -0.8000]])
    """
    cos_i = (d * n).sum(-1, keepdim=True)
    d_r = d - 2.0 * cos_i * n
    return torch.where(valid.unsqueeze(-1), d_r, d), valid
