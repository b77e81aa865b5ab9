"""Procedural, seeded training textures (no downloads): dead leaves, fractal noise, gratings, ...

Every generator has the signature ``fn(size, generator, **params) -> (3, H, W)`` float32 tensor
with values in ``[0, 1]``, read as *linear* RGB (scene radiance up to a scale, not sRGB codes):

* ``size``: ``int`` (a square ``H = W``) or ``(H, W)``, in pixels.
* ``generator``: a :class:`torch.Generator` (its state is advanced) or an ``int`` seed (a fresh
  CPU generator).  The same seed gives a pixel-identical texture; every random choice,
  parameters included, is drawn from it.  Textures are made on the generator's device; the
  CPU is the intended (and tested) path: data-loader workers generate on the CPU.
* keyword parameters left at ``None`` are drawn at random per image from documented ranges.

Pixel ``(i, j)`` (row ``i`` from the top, column ``j`` from the left) has its centre at
``x = j + 0.5``, ``y = i + 0.5`` (pixel units); lengths and frequencies below are in pixels and
cycles per pixel.

Colours ("RGB with random colour statistics"): each image draws a :class:`RandomPalette`, a random
mean colour (grey level plus a colour cast), contrast and saturation, and takes all its colours
from it, so the training set spans dim/bright, flat/contrasty and grey/vivid images.

:data:`TEXTURES` maps kind names to generators (read-only); :func:`random_texture` picks one
uniformly.  Nothing here keeps module-level mutable state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Callable, Iterable, Mapping, Sequence, Union

import torch

__all__ = [
    "RandomPalette",
    "dead_leaves",
    "power_law_radii",
    "fractal_noise",
    "checkerboard",
    "grating",
    "voronoi",
    "strokes",
    "TEXTURES",
    "TEXTURE_KINDS",
    "random_texture",
    "parse_size",
    "as_generator",
    "check_kinds",
]

Size = Union[int, Sequence[int]]
GeneratorLike = Union[torch.Generator, int]


# ---------------------------------------------------------------------------------------------
# Arguments
# ---------------------------------------------------------------------------------------------

def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def parse_size(size: Size, name: str = "size") -> tuple[int, int]:
    """``int`` or ``(H, W)`` -> ``(H, W)`` positive ints; else ``ValueError`` naming ``name``."""
    if _is_int(size):
        h = w = size
    elif isinstance(size, (tuple, list, torch.Size)) and len(size) == 2 and all(
            _is_int(s) for s in size):
        h, w = size
    else:
        raise ValueError(f"{name} must be a positive int or a pair of positive ints (H, W), "
                         f"got {size!r}")
    if h <= 0 or w <= 0:
        raise ValueError(f"{name} must be a positive int or a pair of positive ints (H, W), "
                         f"got {size!r}")
    return int(h), int(w)


def as_generator(generator: GeneratorLike) -> torch.Generator:
    """A :class:`torch.Generator` as is, or an ``int`` seed -> a freshly seeded CPU generator."""
    if isinstance(generator, torch.Generator):
        return generator
    if _is_int(generator):
        return torch.Generator().manual_seed(generator)
    raise TypeError(f"generator must be a torch.Generator or an int seed, got "
                    f"{type(generator).__name__}")


def _uniform(gen: torch.Generator, lo: float, hi: float, n: int | None = None):
    """Uniform in ``[lo, hi)``: a float (``n`` None) or an ``(n,)`` tensor on ``gen``'s device."""
    u = torch.rand(1 if n is None else n, generator=gen, device=gen.device)
    u = lo + (hi - lo) * u
    return float(u) if n is None else u


def _log_uniform(gen: torch.Generator, lo: float, hi: float, n: int | None = None):
    """Log-uniform in ``[lo, hi)`` (``0 < lo <= hi``): a float or an ``(n,)`` tensor."""
    u = _uniform(gen, math.log(lo), math.log(hi), n)
    return math.exp(u) if n is None else torch.exp(u)


def _randint(gen: torch.Generator, lo: int, hi: int) -> int:
    """Uniform integer in ``[lo, hi]`` (inclusive)."""
    return int(torch.randint(lo, hi + 1, (1,), generator=gen, device=gen.device))


def _pixel_centres(h: int, w: int, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Flattened ``(H*W,)`` pixel-centre coordinates ``x = j + 0.5``, ``y = i + 0.5`` (float32)."""
    y = torch.arange(h, device=device, dtype=torch.float32) + 0.5
    x = torch.arange(w, device=device, dtype=torch.float32) + 0.5
    yy, xx = torch.meshgrid(y, x, indexing="ij")
    return xx.reshape(-1), yy.reshape(-1)


def _paint(index: torch.Tensor, colours: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """``(H*W,)`` colour indices + ``(N, 3)`` colours -> ``(3, H, W)`` float32 in ``[0, 1]``."""
    img = colours[index].T.reshape(3, h, w)
    return img.clamp(0.0, 1.0).to(torch.float32).contiguous()


# ---------------------------------------------------------------------------------------------
# Colours
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RandomPalette:
    """Per-image colour statistics, in linear RGB.

    A colour is ``clamp(mean + a (g + 0.5 saturation q), 0, 1)`` with a grey deviation ``g`` in
    ``[-1, 1]`` (shared by the three channels), a zero-mean chroma deviation
    ``q = u - mean(u)``, ``u ~ U(-1, 1)^3``, and the amplitude ``a = contrast min(m, 1 - m)``,
    ``m`` the mean's grey level: deviations use a fraction ``contrast`` of the headroom around
    the mean, so dark or bright images keep their texture instead of clipping to black/white
    (only strongly saturated extremes clip).

    Attributes:
        mean: ``(3,)`` mean colour ``m (1 + cast)``: grey level ``m ~ U(0.1, 0.7)``, colour cast
            ``~U(-0.2, 0.2)`` per channel (a white-balance error).
        contrast: ``~U(0.5, 1.0)``: fraction of the headroom ``min(m, 1 - m)`` spanned by ``g``.
        saturation: ``~U(0, 1)``: 0 gives greys, 1 vivid colours.
    """

    mean: torch.Tensor
    contrast: float
    saturation: float

    @classmethod
    def draw(cls, generator: GeneratorLike) -> "RandomPalette":
        """A palette with random mean, contrast and saturation (ranges in the class docstring)."""
        gen = as_generator(generator)
        grey = _uniform(gen, 0.1, 0.7)
        cast = _uniform(gen, -0.2, 0.2, 3)
        mean = (grey * (1 + cast)).clamp(0.02, 0.98)
        return cls(mean, _uniform(gen, 0.5, 1.0), _uniform(gen, 0.0, 1.0))

    @property
    def amplitude(self) -> float:
        """``a = contrast min(m, 1 - m)``, ``m`` the grey level of :attr:`mean`."""
        m = float(self.mean.mean())
        return self.contrast * min(m, 1.0 - m)

    def _colours(self, g: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        u = _uniform(gen, -1.0, 1.0, 3 * g.numel()).reshape(-1, 3)
        q = u - u.mean(dim=1, keepdim=True)
        dev = g.reshape(-1, 1) + 0.5 * self.saturation * q
        return (self.mean.to(dev.device) + self.amplitude * dev).clamp(0.0, 1.0)

    def sample(self, n: int, generator: GeneratorLike) -> torch.Tensor:
        """``(n, 3)`` independent colours, grey deviations ``g ~ U(-1, 1)``."""
        gen = as_generator(generator)
        return self._colours(_uniform(gen, -1.0, 1.0, n), gen)

    def contrasting(self, n: int, generator: GeneratorLike) -> torch.Tensor:
        """``(n, 3)`` colours (``n >= 2``) whose grey deviations are spread over ``[-1, 1]``.

        ``g_k = linspace(-1, 1, n)_k + U(-1, 1) / (2n)`` in random order, so the darkest and the
        brightest differ by at least ``a (2 - 1/n)`` in grey before clamping: the two colours of
        a checkerboard or grating never coincide.
        """
        gen = as_generator(generator)
        g = torch.linspace(-1.0, 1.0, n, device=gen.device)
        g = (g + _uniform(gen, -1.0, 1.0, n) / (2 * n)).clamp(-1.0, 1.0)
        g = g[torch.randperm(n, generator=gen, device=gen.device)]
        return self._colours(g, gen)

    def ramp(self, t: torch.Tensor, generator: GeneratorLike, stops: int | None = None
             ) -> torch.Tensor:
        """Colour a scalar field ``t`` in ``[0, 1]``, shape ``(H, W)``, -> ``(3, H, W)``.

        Piecewise-linear colour map through ``stops`` (default ``U{2..5}``) contrasting colours
        at positions ``0 = s_0 < s_1 < ... < s_{K-1} = 1`` (inner positions sorted uniforms).
        """
        gen = as_generator(generator)
        k = _randint(gen, 2, 5) if stops is None else int(stops)
        if k < 2:
            raise ValueError(f"ramp needs at least 2 stops, got {k}")
        cols = self.contrasting(k, gen)                                   # (K, 3)
        inner = torch.sort(_uniform(gen, 0.05, 0.95, k - 2)).values
        pos = torch.cat([torch.zeros(1, device=gen.device), inner,
                         torch.ones(1, device=gen.device)])
        t = t.clamp(0.0, 1.0)
        flat = t.reshape(-1)
        seg = torch.zeros(flat.shape, dtype=torch.long, device=flat.device)   # segment index
        for p in inner:                                   # K <= 5 stops: a few comparisons
            seg += (flat >= p).long()
        p0, p1 = pos[seg], pos[seg + 1]
        a = ((flat - p0) / (p1 - p0).clamp_min(1e-6)).clamp(0.0, 1.0).unsqueeze(1)
        out = cols[seg] * (1 - a) + cols[seg + 1] * a                     # (H*W, 3)
        return out.T.reshape(3, *t.shape).clamp(0.0, 1.0).to(torch.float32).contiguous()


# ---------------------------------------------------------------------------------------------
# Textures
# ---------------------------------------------------------------------------------------------

def power_law_radii(n: int, rmin: float, rmax: float, generator: GeneratorLike) -> torch.Tensor:
    """``(n,)`` radii with density ``p(r) = 2 r^-3 / (rmin^-2 - rmax^-2)`` on ``[rmin, rmax]``.

    Inverse-CDF sampling: ``r = (rmin^-2 - u (rmin^-2 - rmax^-2))^(-1/2)``, ``u ~ U(0, 1)``;
    survival ``P(r > x) = (x^-2 - rmax^-2) / (rmin^-2 - rmax^-2)``.  Units are the caller's
    (pixels in :func:`dead_leaves`).
    """
    gen = as_generator(generator)
    u = torch.rand(n, generator=gen, device=gen.device)
    return (rmin ** -2 - u * (rmin ** -2 - rmax ** -2)).rsqrt()


def dead_leaves(size: Size, generator: GeneratorLike, *, rmin: float = 2.0,
                rmax: float | None = None, max_discs: int = 2_000_000,
                palette: RandomPalette | None = None) -> torch.Tensor:
    """Dead-leaves texture: occluding random discs with a power-law ``r^-3`` size density.

    Model (Matheron; the scale-invariant chart of camera texture-loss evaluation): discs fall one
    after the other, each hiding what lies beneath.  Radii have density ``p(r) ∝ r^-3`` on
    ``[rmin, rmax]`` (pixels), drawn by inverting the CDF,
    ``r = (rmin^-2 - u (rmin^-2 - rmax^-2))^(-1/2)``, ``u ~ U(0, 1)``; centres are uniform over
    the image dilated by ``rmax`` on every side (so large discs enter from outside as they would
    in the infinite model); colours come from the image's :class:`RandomPalette`.

    Rendering is front to back, which is equivalent and lets it stop early: each pixel takes the
    colour of the first disc in the sequence whose disc covers its centre, ``|p - c| <= r``.
    Discs are drawn in batches (about as many as cover the dilated canvas once); each disc is
    tested only on the pixels of its bounding box and a per-pixel running minimum of the
    covering disc's sequence index is kept (scatter ``amin``), until every pixel is covered.
    Pixels still uncovered after ``max_discs`` discs (practically never with ``rmin >= 1``)
    take one background colour.

    Args:
        size: ``int`` or ``(H, W)`` pixels.
        generator: ``torch.Generator`` or ``int`` seed.
        rmin: smallest radius, pixels (> 0).
        rmax: largest radius, pixels (``>= rmin``); default half the shorter image side.
        max_discs: cap on the number of discs drawn.
        palette: colour statistics; default drawn from ``generator``.

    Returns:
        ``(3, H, W)`` float32 in ``[0, 1]``: flat discs with hard edges, a colour per disc.
    """
    h, w = parse_size(size)
    gen = as_generator(generator)
    dev = gen.device
    rmax = 0.5 * min(h, w) if rmax is None else float(rmax)
    rmin = float(rmin)
    if not (rmin > 0 and math.isfinite(rmin)):
        raise ValueError(f"dead_leaves: rmin must be a positive number of pixels, got {rmin}")
    if not (rmax >= rmin and math.isfinite(rmax)):
        raise ValueError(f"dead_leaves: rmax must be >= rmin = {rmin}, got {rmax}")
    if not _is_int(max_discs) or max_discs < 1:
        raise ValueError(f"dead_leaves: max_discs must be a positive int, got {max_discs!r}")
    pal = RandomPalette.draw(gen) if palette is None else palette

    n_pix = h * w
    sentinel = torch.iinfo(torch.long).max
    first = torch.full((n_pix,), sentinel, dtype=torch.long, device=dev)  # first covering disc
    colours = [pal.sample(1, gen)]                      # index 0: background, disc i: i + 1
    b = rmin ** -2 - rmax ** -2
    # discs per batch: about as many as cover the dilated canvas once, pi E[r^2] n = area
    mean_area = math.pi * (2 * math.log(rmax / rmin) / b if rmax > rmin else rmin ** 2)
    batch = int(min(max((w + 2 * rmax) * (h + 2 * rmax) / mean_area, 1024), 65536))
    drawn = 0
    uncovered = n_pix
    while uncovered > 0 and drawn < max_discs:
        n = min(batch, max_discs - drawn)
        r = power_law_radii(n, rmin, rmax, gen)
        cx = _uniform(gen, -rmax, w + rmax, n)
        cy = _uniform(gen, -rmax, h + rmax, n)
        colours.append(pal.sample(n, gen))
        idx = torch.nonzero(_touches_uncovered(first == sentinel, h, w, cx, cy, r)).squeeze(1)
        _first_cover(first, idx + drawn, cx[idx], cy[idx], r[idx], h, w)
        drawn += n
        uncovered = int((first == sentinel).sum())
    colour_index = torch.where(first == sentinel, 0, first + 1)
    return _paint(colour_index, torch.cat(colours), h, w)


def _touches_uncovered(uncovered: torch.Tensor, h: int, w: int, cx: torch.Tensor,
                       cy: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """``(n,)`` bool: does the pixel box around disc ``(cx, cy, r)`` hold an uncovered pixel?

    A disc can only set pixels whose centres lie in ``[c - r, c + r]``, i.e. columns
    ``floor(cx - r) .. floor(cx + r)`` (and rows alike); the uncovered pixels in that box are
    counted from a summed-area table of ``uncovered`` (``(H*W,)`` bool).  Discs off the image
    or over already covered pixels only cannot change the result and are skipped.
    """
    sat = torch.zeros(h + 1, w + 1, dtype=torch.int64, device=uncovered.device)
    sat[1:, 1:] = uncovered.reshape(h, w).long().cumsum(0).cumsum(1)
    j0 = torch.floor(cx - r).long().clamp(0, w)
    j1 = (torch.floor(cx + r).long() + 1).clamp(0, w)
    i0 = torch.floor(cy - r).long().clamp(0, h)
    i1 = (torch.floor(cy + r).long() + 1).clamp(0, h)
    count = sat[i1, j1] - sat[i0, j1] - sat[i1, j0] + sat[i0, j0]
    return count > 0


def _first_cover(first: torch.Tensor, index: torch.Tensor, cx: torch.Tensor, cy: torch.Tensor,
                 r: torch.Tensor, h: int, w: int) -> None:
    """In place: ``first[p] = min(first[p], index of each given disc covering pixel p)``.

    Each disc is tested on the pixels of a square box of half-width ``R >= r + 1`` about its
    centre (``R = ceil(r + 1)``, rounded up to a power of two above 8, so discs batch by box
    size); boxes at least as large as the image test every pixel instead.  The minimum over
    indices is order-independent, so the result does not depend on how discs are grouped.
    """
    if index.numel() == 0:
        return
    dev = first.device
    half = torch.ceil(r + 1).long()
    big = half > 8
    half[big] = torch.pow(2, torch.ceil(torch.log2(half[big].double()))).long()
    for R in torch.unique(half).tolist():
        sel = torch.nonzero(half == R).squeeze(1)
        side = 2 * R + 1
        if side * side >= h * w:             # dense: every pixel
            px, py = _pixel_centres(h, w, dev)
            pix_all = torch.arange(h * w, device=dev)
            step = max(1, (1 << 20) // (h * w))
            for s in range(0, sel.numel(), step):
                d = sel[s:s + step]
                inside = ((px[None] - cx[d, None]) ** 2 + (py[None] - cy[d, None]) ** 2
                          <= r[d, None] ** 2)
                disc = index[d, None].expand_as(inside)[inside]
                first.scatter_reduce_(0, pix_all.expand_as(inside)[inside], disc, reduce="amin")
            continue
        off = torch.arange(-R, R + 1, device=dev)
        step = max(1, (1 << 20) // (side * side))
        for s in range(0, sel.numel(), step):
            d = sel[s:s + step]
            j0, i0 = torch.floor(cx[d]).long(), torch.floor(cy[d]).long()
            j, i = j0[:, None] + off, i0[:, None] + off                        # (n, S)
            dx2 = (j.to(cx.dtype) + 0.5 - cx[d, None]) ** 2
            dy2 = (i.to(cy.dtype) + 0.5 - cy[d, None]) ** 2
            dx2 = dx2.masked_fill_((j < 0) | (j >= w), math.inf)             # off the image
            dy2 = dy2.masked_fill_((i < 0) | (i >= h), math.inf)
            inside = dy2[:, :, None] + dx2[:, None, :] <= (r[d] ** 2)[:, None, None]
            k, a, b = inside.nonzero(as_tuple=True)                          # disc, row, col
            pix = (i0[k] + a - R) * w + (j0[k] + b - R)
            disc = index[d][k]
            first.scatter_reduce_(0, pix, disc, reduce="amin")


def _gradient_noise(h: int, w: int, cells_y: int, cells_x: int, gen: torch.Generator
                    ) -> torch.Tensor:
    """One octave of Perlin gradient noise on a ``cells_y x cells_x`` lattice, ``(H, W)``.

    Random unit gradients ``g`` at the lattice nodes; at a point with cell coordinates
    ``(i + fy, j + fx)`` the noise is the smoothstep (``6t^5 - 15t^4 + 10t^3``) blend of the four
    corner dot products ``g_c . (f - c)``.  Zero at the nodes, values within about ``+-0.7``.
    """
    dev = gen.device
    ang = _uniform(gen, 0.0, 2 * math.pi, (cells_y + 1) * (cells_x + 1)).reshape(
        cells_y + 1, cells_x + 1)
    gx, gy = torch.cos(ang), torch.sin(ang)
    y = (torch.arange(h, device=dev, dtype=torch.float32) + 0.5) * (cells_y / h)
    x = (torch.arange(w, device=dev, dtype=torch.float32) + 0.5) * (cells_x / w)
    y0 = y.floor().long().clamp(max=cells_y - 1)
    x0 = x.floor().long().clamp(max=cells_x - 1)
    fy, fx = (y - y0)[:, None], (x - x0)[None, :]

    def corner(dy: int, dx: int) -> torch.Tensor:
        rows_x, rows_y = gx.index_select(0, y0 + dy), gy.index_select(0, y0 + dy)   # (H, cx+1)
        return (rows_x.index_select(1, x0 + dx) * (fx - dx)
                + rows_y.index_select(1, x0 + dx) * (fy - dy))

    def fade(t):
        return t * t * t * (t * (t * 6 - 15) + 10)

    sy, sx = fade(fy), fade(fx)
    top = corner(0, 0) * (1 - sx) + corner(0, 1) * sx
    bottom = corner(1, 0) * (1 - sx) + corner(1, 1) * sx
    return top * (1 - sy) + bottom * sy


def fractal_noise(size: Size, generator: GeneratorLike, *, octaves: int | None = None,
                  persistence: float | None = None, base_cells: int | None = None,
                  palette: RandomPalette | None = None) -> torch.Tensor:
    """Fractal (fBm) Perlin noise, coloured through a random palette ramp.

    ``f(p) = sum_k persistence^k N_k(p)``, ``N_k`` gradient noise (:func:`_gradient_noise`) on a
    lattice of ``base_cells * 2^k`` cells across the shorter side (proportionally more across
    the longer one); octaves whose cells would be smaller than 2 pixels are skipped (no
    aliasing).  ``f`` is min-max normalised to ``[0, 1]`` and mapped through
    :meth:`RandomPalette.ramp` (2-5 colour stops).

    Args:
        size, generator: as everywhere in this module.
        octaves: number of octaves, default ``U{3..7}``.
        persistence: amplitude ratio between octaves, default ``U(0.4, 0.75)`` (higher: rougher).
        base_cells: lattice cells of the coarsest octave across the shorter side, default
            ``U{1..4}``.
        palette: colour statistics; default drawn from ``generator``.

    Returns:
        ``(3, H, W)`` float32 in ``[0, 1]``, smooth multi-scale clouds.
    """
    h, w = parse_size(size)
    gen = as_generator(generator)
    pal = RandomPalette.draw(gen) if palette is None else palette
    octaves = _randint(gen, 3, 7) if octaves is None else octaves
    persistence = _uniform(gen, 0.4, 0.75) if persistence is None else float(persistence)
    base_cells = _randint(gen, 1, 4) if base_cells is None else base_cells
    if not _is_int(octaves) or octaves < 1:
        raise ValueError(f"fractal_noise: octaves must be a positive int, got {octaves!r}")
    if not _is_int(base_cells) or base_cells < 1:
        raise ValueError(f"fractal_noise: base_cells must be a positive int, got {base_cells!r}")
    if not persistence > 0:
        raise ValueError(f"fractal_noise: persistence must be > 0, got {persistence}")
    short = min(h, w)
    field = torch.zeros(h, w, device=gen.device)
    for k in range(octaves):
        cells = base_cells * 2 ** k
        if k > 0 and cells > short / 2:
            break
        cy = max(1, round(cells * h / short))
        cx = max(1, round(cells * w / short))
        field = field + persistence ** k * _gradient_noise(h, w, cy, cx, gen)
    lo, hi = field.min(), field.max()
    t = (field - lo) / (hi - lo).clamp_min(1e-12)
    return pal.ramp(t, gen)


def _rotated_coords(h: int, w: int, angle: float, gen: torch.Generator):
    """Pixel centres relative to a random origin, rotated by ``angle`` (rad): ``(u, v)``, (H, W)."""
    ox, oy = _uniform(gen, 0.0, w), _uniform(gen, 0.0, h)
    x, y = _pixel_centres(h, w, gen.device)
    x, y = (x - ox).reshape(h, w), (y - oy).reshape(h, w)
    c, s = math.cos(angle), math.sin(angle)
    return x * c + y * s, -x * s + y * c


def checkerboard(size: Size, generator: GeneratorLike, *, period: float | None = None,
                 angle: float | None = None, palette: RandomPalette | None = None
                 ) -> torch.Tensor:
    """Rotated two-colour checkerboard, hard edges.

    With ``(u, v)`` the pixel centre rotated by ``angle`` about a random origin, the colour is
    ``c_{(floor(u / period) + floor(v / period)) mod 2}``; the two colours are contrasting
    palette colours (:meth:`RandomPalette.contrasting`).

    Args:
        size, generator: as everywhere in this module.
        period: square side, pixels; default log-uniform in ``[3, max(4, short / 3)]``.
        angle: rotation, radians; default ``U(0, pi/2)``.
        palette: colour statistics; default drawn from ``generator``.

    Returns:
        ``(3, H, W)`` float32 in ``[0, 1]``.
    """
    h, w = parse_size(size)
    gen = as_generator(generator)
    pal = RandomPalette.draw(gen) if palette is None else palette
    period = _log_uniform(gen, 3.0, max(4.0, min(h, w) / 3)) if period is None else float(period)
    angle = _uniform(gen, 0.0, math.pi / 2) if angle is None else float(angle)
    if not period > 0:
        raise ValueError(f"checkerboard: period must be > 0 pixels, got {period}")
    u, v = _rotated_coords(h, w, angle, gen)
    parity = (torch.floor(u / period) + torch.floor(v / period)).remainder(2).long()
    return _paint(parity.reshape(-1), pal.contrasting(2, gen), h, w)


def grating(size: Size, generator: GeneratorLike, *, frequency: float | None = None,
            angle: float | None = None, phase: float | None = None,
            palette: RandomPalette | None = None) -> torch.Tensor:
    """Sinusoidal grating between two contrasting palette colours.

    ``t = (1 + sin(2 pi f u + phase)) / 2`` with ``u`` the pixel-centre coordinate along the
    direction ``angle``; colour ``c_0 (1 - t) + c_1 t``.

    Args:
        size, generator: as everywhere in this module.
        frequency: ``f`` in cycles per pixel, default log-uniform in ``[2 / short, 0.4]``
            (two periods across the image up to just below Nyquist, 0.5).
        angle: direction of ``u``, radians; default ``U(0, pi)``.
        phase: radians, default ``U(0, 2 pi)``.
        palette: colour statistics; default drawn from ``generator``.

    Returns:
        ``(3, H, W)`` float32 in ``[0, 1]``.
    """
    h, w = parse_size(size)
    gen = as_generator(generator)
    pal = RandomPalette.draw(gen) if palette is None else palette
    lo = min(2.0 / min(h, w), 0.2)
    frequency = _log_uniform(gen, lo, 0.4) if frequency is None else float(frequency)
    angle = _uniform(gen, 0.0, math.pi) if angle is None else float(angle)
    phase = _uniform(gen, 0.0, 2 * math.pi) if phase is None else float(phase)
    if not frequency > 0:
        raise ValueError(f"grating: frequency must be > 0 cycles/pixel, got {frequency}")
    u, _ = _rotated_coords(h, w, angle, gen)
    t = 0.5 * (1 + torch.sin(2 * math.pi * frequency * u + phase))
    return pal.ramp(t, gen, stops=2)


def voronoi(size: Size, generator: GeneratorLike, *, n_cells: int | None = None,
            palette: RandomPalette | None = None) -> torch.Tensor:
    """Voronoi cells: each pixel takes the colour of its nearest random site (Euclidean).

    Sites are uniform over the image; ties (measure zero) go to the lower site index.

    Args:
        size, generator: as everywhere in this module.
        n_cells: number of sites, default log-uniform in ``[8, 256]``.
        palette: colour statistics; default drawn from ``generator``.

    Returns:
        ``(3, H, W)`` float32 in ``[0, 1]``, flat polygonal cells with hard edges.
    """
    h, w = parse_size(size)
    gen = as_generator(generator)
    pal = RandomPalette.draw(gen) if palette is None else palette
    n = int(round(_log_uniform(gen, 8, 256))) if n_cells is None else n_cells
    if not _is_int(n) or n < 1:
        raise ValueError(f"voronoi: n_cells must be a positive int, got {n!r}")
    sx, sy = _uniform(gen, 0.0, w, n), _uniform(gen, 0.0, h, n)
    colours = pal.sample(n, gen)
    px, py = _pixel_centres(h, w, gen.device)
    nearest = torch.empty(h * w, dtype=torch.long, device=gen.device)
    step = max(1, (1 << 18) // n)
    for s in range(0, h * w, step):
        dx = px[s:s + step, None] - sx[None]                            # (m, n)
        dy = py[s:s + step, None] - sy[None]
        nearest[s:s + step] = dx.mul_(dx).addcmul_(dy, dy).argmin(dim=1)
    return _paint(nearest, colours, h, w)


def strokes(size: Size, generator: GeneratorLike, *, n_shapes: int | None = None,
            palette: RandomPalette | None = None) -> torch.Tensor:
    """Random strokes and edges: thick line segments, filled polygons and half-planes.

    Shapes are painted in sequence over a background (later ones on top), hard edges, no
    anti-aliasing; the ``n + 1`` colours are :meth:`RandomPalette.contrasting` (grey levels
    spread over the palette's range, so strokes stand out).  Each shape is one of
    (probabilities 0.45 / 0.45 / 0.1):

    * a stroke: the pixels within ``width / 2`` of a segment ``ab`` (distance to the segment,
      ``|p - a - clamp(t, 0, 1)(b - a)|``, ``t = (p - a).(b - a) / |b - a|^2``); width
      log-uniform in ``[1, short / 12]`` px, length up to the image diagonal;
    * a polygon: 3-8 vertices at sorted random angles and radii ``R U(0.4, 1)`` about a random
      centre (sorted by angle about it, hence simple), ``R`` log-uniform in
      ``[short / 32, short / 3]``,
      filled by the even-odd crossing rule;
    * a half-plane ``(p - c).n >= 0``: a long straight (slanted) edge; half-planes are painted
      first, splitting the background, so they never wipe out the shapes drawn before them.

    Args:
        size, generator: as everywhere in this module.
        n_shapes: number of shapes, default ``U{8..48}``.
        palette: colour statistics; default drawn from ``generator``.

    Returns:
        ``(3, H, W)`` float32 in ``[0, 1]``.
    """
    h, w = parse_size(size)
    gen = as_generator(generator)
    dev = gen.device
    pal = RandomPalette.draw(gen) if palette is None else palette
    n = _randint(gen, 8, 48) if n_shapes is None else n_shapes
    if not _is_int(n) or n < 1:
        raise ValueError(f"strokes: n_shapes must be a positive int, got {n!r}")
    short, diag = min(h, w), math.hypot(h, w)
    vmax = 8

    kind = torch.bucketize(torch.rand(n, generator=gen, device=dev),
                           torch.tensor([0.45, 0.9], device=dev), right=True)  # 0, 1, 2
    # strokes: start, direction, length, width
    ax, ay = _uniform(gen, 0.0, w, n), _uniform(gen, 0.0, h, n)
    theta = _uniform(gen, 0.0, 2 * math.pi, n)
    length = _uniform(gen, 0.02, 1.0, n) * diag
    bx, by = ax + length * torch.cos(theta), ay + length * torch.sin(theta)
    width = _log_uniform(gen, 1.0, max(1.5, short / 12), n)
    # polygons: centre (ax, ay), radius, vertex count, angles, radii
    radius = _log_uniform(gen, max(1.0, short / 32), max(2.0, short / 3), n)
    nv = torch.randint(3, vmax + 1, (n,), generator=gen, device=dev)
    ang = torch.sort(_uniform(gen, 0.0, 2 * math.pi, n * vmax).reshape(n, vmax), dim=1).values
    rad = radius[:, None] * _uniform(gen, 0.4, 1.0, n * vmax).reshape(n, vmax)
    slot = torch.arange(vmax, device=dev)[None]
    last = (nv - 1)[:, None]
    src = torch.minimum(slot.expand(n, vmax), last)      # pad by repeating the last vertex
    ang, rad = ang.gather(1, src), rad.gather(1, src)
    vx, vy = ax[:, None] + rad * torch.cos(ang), ay[:, None] + rad * torch.sin(ang)
    wx, wy = vx.roll(-1, dims=1), vy.roll(-1, dims=1)    # edge ends (closing edge wraps)
    # half-planes: point (ax, ay), normal theta
    nx, ny = torch.cos(theta), torch.sin(theta)
    colours = pal.contrasting(n + 1, gen)                # 0: background, r: r-th painted

    px, py = _pixel_centres(h, w, dev)
    index = torch.zeros(h * w, dtype=torch.long, device=dev)   # paint rank of the top shape
    # paint order (1 = bottom): half-planes first, then the rest in sequence
    paint = torch.sort((kind != 2).to(torch.int32), stable=True).indices
    order = torch.empty(n, device=dev, dtype=torch.int32)
    order[paint] = torch.arange(1, n + 1, device=dev, dtype=torch.int32)
    seg_i, poly_i, half_i = (torch.nonzero(kind == k).squeeze(1) for k in range(3))
    # strokes: segment a -> b, within width / 2; row extent for culling
    sax, say = ax[seg_i, None], ay[seg_i, None]
    sdx, sdy = (bx - ax)[seg_i, None], (by - ay)[seg_i, None]
    slen2 = (sdx * sdx + sdy * sdy).clamp_min(1e-12)
    sr2 = (0.5 * width[seg_i, None]) ** 2
    s_lo = torch.minimum(ay, by)[seg_i] - 0.5 * width[seg_i]
    s_hi = torch.maximum(ay, by)[seg_i] + 0.5 * width[seg_i]
    # half-planes: point a, normal n
    hax, hay, hnx, hny = ax[half_i, None], ay[half_i, None], nx[half_i, None], ny[half_i, None]
    # polygons: edges (x0, y0) -> (x1, y1), (n_poly, V, 1); y1 is y0 rolled by -1
    x0, y0, x1, y1 = (t[poly_i, :, None] for t in (vx, vy, wx, wy))
    slope = (x1 - x0) / torch.where(y1 == y0, torch.ones_like(y1), y1 - y0)
    p_lo, p_hi = vy[poly_i].amin(dim=1), vy[poly_i].amax(dim=1)
    rows = max(1, (1 << 18) // max(1, w * poly_i.numel() * vmax, w * n))
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        sl = slice(r0 * w, r1 * w)
        qx, qy = px[None, sl], py[None, sl]                             # (1, m)
        top = index[sl]
        # shapes whose row extent meets rows r0..r1-1 (centres r0 + 0.5 .. r1 - 0.5)
        k = torch.nonzero((s_hi >= r0) & (s_lo <= r1)).squeeze(1)
        if k.numel():
            rx, ry = qx - sax[k], qy - say[k]
            t = ((rx * sdx[k] + ry * sdy[k]) / slen2[k]).clamp_(0.0, 1.0)
            ex, ey = rx - t * sdx[k], ry - t * sdy[k]
            hit = ex * ex + ey * ey <= sr2[k]
            top = torch.maximum(top, (hit * order[seg_i[k], None]).amax(dim=0))
        if half_i.numel():
            hit = (qx - hax) * hnx + (qy - hay) * hny >= 0
            top = torch.maximum(top, (hit * order[half_i, None]).amax(dim=0))
        k = torch.nonzero((p_hi >= r0) & (p_lo <= r1)).squeeze(1)
        if k.numel():
            qy3 = qy[:, None]                                           # (1, 1, m)
            above = y0[k] > qy3                                         # (n_poly, V, m)
            straddle = above != above.roll(-1, dims=1)                  # edge: y0_v vs y0_v+1
            crossings = (straddle & (qx[:, None] < x0[k] + slope[k] * (qy3 - y0[k]))).sum(1)
            hit = crossings.remainder(2) == 1                           # even-odd rule
            top = torch.maximum(top, (hit * order[poly_i[k], None]).amax(dim=0))
        index[sl] = top
    return _paint(index, colours, h, w)


# ---------------------------------------------------------------------------------------------
# Registry
# ---------------------------------------------------------------------------------------------

TEXTURES: Mapping[str, Callable[..., torch.Tensor]] = MappingProxyType({
    "dead_leaves": dead_leaves,
    "fractal_noise": fractal_noise,
    "checkerboard": checkerboard,
    "grating": grating,
    "voronoi": voronoi,
    "strokes": strokes,
})
"""Read-only map kind name -> generator ``fn(size, generator) -> (3, H, W)``."""

TEXTURE_KINDS: tuple[str, ...] = tuple(TEXTURES)
"""All kind names, in registry order (the order :func:`random_texture` indexes)."""


def check_kinds(kinds: str | Iterable[str] | None) -> tuple[str, ...]:
    """Validate texture kind names: ``None`` -> all kinds; a single name -> a 1-tuple."""
    if kinds is None:
        return TEXTURE_KINDS
    if isinstance(kinds, str):
        kinds = (kinds,)
    try:
        kinds = tuple(kinds)
    except TypeError:
        raise TypeError(f"kinds must be a texture name, a sequence of names or None, got "
                        f"{type(kinds).__name__}") from None
    if not kinds:
        raise ValueError(f"kinds must name at least one texture; available: "
                         f"{', '.join(TEXTURE_KINDS)}")
    unknown = [k for k in kinds if k not in TEXTURES]
    if unknown:
        raise ValueError(f"unknown texture kind(s) {unknown}; available: "
                         f"{', '.join(TEXTURE_KINDS)}")
    return kinds


def random_texture(size: Size, generator: GeneratorLike,
                   kinds: str | Iterable[str] | None = None) -> tuple[torch.Tensor, str]:
    """A texture of a kind drawn uniformly from ``kinds`` (default: all of :data:`TEXTURES`).

    The kind is drawn from ``generator`` first, then the texture from the same generator, so a
    seed fixes both.

    Returns:
        ``(texture, kind)``: ``(3, H, W)`` float32 in ``[0, 1]`` and the kind's name.
    """
    kinds = check_kinds(kinds)
    h, w = parse_size(size)
    gen = as_generator(generator)
    name = kinds[_randint(gen, 0, len(kinds) - 1)]
    return TEXTURES[name]((h, w), gen), name
