r"""CODE V private glass catalogues (``PRV``): glasses given as indices at listed wavelengths.

A ``.seq`` file may define its own glasses before the surfaces::

    PRV
      PWL 1600.0 1500.0 ... 404.7 400.0          ! the wavelengths, nm
      'E48' 1.5184 1.5188 ... 1.5476 1.5484      ! a glass: one index per PWL wavelength
    END

and then name them as a surface's glass (``S 9.93 3.7 'E48'``).  Between the listed wavelengths
deeplens interpolates the index with the cubic spline through the table (not-a-knot end
conditions), the interpolation rayoptics' CODE V reader uses (``InterpolatedMedium``:
``scipy.interpolate.interp1d(kind="cubic")``); the table's own values are returned at its
wavelengths.  The glass is defined only over the listed range: a lens wavelength outside it is
refused (``Material.n`` raises, and the reader names the glass and its range).  With fewer than
four wavelengths (no cubic spline) the table must hold the lens's wavelengths exactly.

The spline's coefficients are computed once in float64 (numpy); :meth:`PrivateGlass.n` evaluates
the piecewise cubic in torch, so the index is differentiable in the wavelength.
"""

from __future__ import annotations

import numpy as np
import torch

from ..materials import Material

__all__ = ["PrivateGlass", "not_a_knot_spline"]


def not_a_knot_spline(x, y) -> np.ndarray:
    """Coefficients ``(n - 1, 4)`` of the cubic spline through ``(x, y)`` (``x`` increasing,
    ``n >= 4``) with not-a-knot end conditions: on ``[x_i, x_{i+1}]``
    ``s(t) = c0 + c1 (t - x_i) + c2 (t - x_i)² + c3 (t - x_i)³``."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n = len(x)
    h = np.diff(x)
    d = np.diff(y) / h
    # unknowns: the second derivatives M_0 .. M_{n-1}
    a = np.zeros((n, n))
    b = np.zeros(n)
    for i in range(1, n - 1):
        a[i, i - 1], a[i, i], a[i, i + 1] = h[i - 1], 2.0 * (h[i - 1] + h[i]), h[i]
        b[i] = 6.0 * (d[i] - d[i - 1])
    # not-a-knot: the third derivative continuous at x_1 and x_{n-2}
    a[0, 0], a[0, 1], a[0, 2] = h[1], -(h[0] + h[1]), h[0]
    a[-1, -3], a[-1, -2], a[-1, -1] = h[-1], -(h[-2] + h[-1]), h[-2]
    m = np.linalg.solve(a, b)
    c1 = d - h * (2.0 * m[:-1] + m[1:]) / 6.0
    c2 = m[:-1] / 2.0
    c3 = (m[1:] - m[:-1]) / (6.0 * h)
    return np.stack([y[:-1], c1, c2, c3], axis=1)


class PrivateGlass(Material):
    """A glass of a CODE V private catalogue: indices at listed wavelengths (module docstring).

    Args:
        name: the glass's name in the file.
        wavelengths_nm: the ``PWL`` wavelengths, nm (any order, distinct).
        indices: one index per wavelength.
    """

    def __init__(self, name: str, wavelengths_nm, indices):
        w = [float(v) for v in wavelengths_nm]
        n = [float(v) for v in indices]
        if len(w) != len(n) or not w:
            raise ValueError(f"private glass {name!r}: {len(n)} indices for {len(w)} "
                             f"wavelengths; expected one index per PWL wavelength")
        order = np.argsort(w)
        w = [w[i] for i in order]
        n = [n[i] for i in order]
        if any(b <= a for a, b in zip(w, w[1:])) or w[0] <= 0:
            raise ValueError(f"private glass {name!r}: the PWL wavelengths must be distinct and "
                             f"> 0 nm, got {wavelengths_nm!r}")
        if not all(v > 0 and np.isfinite(v) for v in n):
            raise ValueError(f"private glass {name!r}: indices must be finite and > 0, got "
                             f"{indices!r}")
        super().__init__(name, (w[0], w[-1]))
        self.table_nm = tuple(w)
        self.table_n = tuple(n)
        self._coef = not_a_knot_spline(w, n) if len(w) >= 4 else None

    def to_spec(self) -> str:
        raise ValueError(f"private glass {self.name!r} (a CODE V PRV table) has no catalogue "
                         f"name: it is written only where the file format holds its table")

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        x = torch.tensor(self.table_nm, dtype=w.dtype, device=w.device)
        if self._coef is None:   # no spline: only the listed wavelengths
            hit = w.detach().unsqueeze(-1) == x
            if not bool(hit.any(-1).all()):
                raise ValueError(f"private glass {self.name!r}: {len(x)} wavelengths "
                                 f"{list(self.table_nm)} nm (too few for a spline): the lens's "
                                 f"wavelengths must be among them")
            k = hit.to(torch.int64).argmax(-1)
            return torch.tensor(self.table_n, dtype=w.dtype, device=w.device)[k] + 0.0 * w
        c = torch.tensor(self._coef, dtype=w.dtype, device=w.device)
        i = torch.clamp(torch.searchsorted(x, w.detach().contiguous(), right=True) - 1, 0,
                        len(x) - 2)
        t = w - x[i]
        ci = c[i]
        return ci[..., 0] + t * (ci[..., 1] + t * (ci[..., 2] + t * ci[..., 3]))
