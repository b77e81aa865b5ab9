"""Global placement of a folded lens's local frames (coordinate breaks composed).

The tracer works in local frames: each :class:`~.surfaces.CoordinateBreak` re-expresses the
rays in the frame of the following surfaces (its module docstring gives the map).  Frame ``k``
maps to the global frame (the object-space frame) by ``x_global = A_k x + b_k``; a break at
vertex ``z_b`` with decenter ``δ`` and rotation ``R`` gives

    A_{k+1} = A_k R,        b_{k+1} = b_k + A_k (z_b e_z + δ - R z_b e_z)

A lens without breaks has one frame, ``A = I``, ``b = 0``.  Used by layouts through a fold and
to place a folded system's image in space.
"""

from __future__ import annotations

import torch


__all__ = ["local_frames", "to_global"]


def local_frames(lens) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """``[(A (3, 3), b (3,)), ...]``: the frame of each of the ``N`` surfaces and, last, of the
    sensor (``N + 1`` entries), in the lens's dtype; differentiable in the breaks' values and
    the distances.  A break's own vertex is in the frame before it."""
    z = lens.z_vertices()
    like = z   # the lens's dtype and device
    A = torch.eye(3, dtype=lens.dtype, device=lens.device)
    b = torch.zeros(3, dtype=lens.dtype, device=lens.device)
    out = []
    for i, s in enumerate(lens.surfaces):
        out.append((A, b))
        if s.interaction.changes_frame:   # a coordinate break
            R = s.rotation(like)
            zero = torch.zeros_like(z[i])
            zc = torch.stack([zero, zero, z[i]])
            b = b + A @ (zc + s.offset(like) - R @ zc)
            A = A @ R
    out.append((A, b))
    return out


def to_global(frame, x: torch.Tensor) -> torch.Tensor:
    """Points ``(*B, 3)`` of a local frame ``(A, b)`` in global coordinates (for directions,
    pass ``b = 0``)."""
    A, b = frame
    return x @ A.T.to(x) + b.to(x)
