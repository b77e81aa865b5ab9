"""Procedural textures: shapes, ranges, determinism, content, dead-leaves statistics, bad input."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.data import textures as T
from deeplens.data.textures import (
    TEXTURE_KINDS,
    TEXTURES,
    RandomPalette,
    dead_leaves,
    power_law_radii,
    random_texture,
)

KINDS = list(TEXTURE_KINDS)


def test_registry_is_complete_and_read_only():
    assert set(KINDS) == {"dead_leaves", "fractal_noise", "checkerboard", "grating", "voronoi",
                          "strokes"}
    with pytest.raises(TypeError):
        TEXTURES["mine"] = dead_leaves  # type: ignore[index]


@pytest.mark.parametrize("kind", KINDS)
def test_shape_dtype_range(kind):
    x = TEXTURES[kind]((40, 56), 3)
    assert x.shape == (3, 40, 56)
    assert x.dtype == torch.float32
    assert bool(torch.isfinite(x).all())
    assert float(x.min()) >= 0.0 and float(x.max()) <= 1.0
    assert TEXTURES[kind](17, 3).shape == (3, 17, 17)


@pytest.mark.parametrize("kind", KINDS)
def test_deterministic_per_seed(kind):
    fn = TEXTURES[kind]
    a, b = fn(48, 11), fn(48, 11)
    assert torch.equal(a, b)                                    # pixel-identical
    assert torch.equal(a, fn(48, torch.Generator().manual_seed(11)))   # int seed == generator
    assert not torch.equal(a, fn(48, 12))
    # a generator is advanced: two draws from one generator differ
    g = torch.Generator().manual_seed(11)
    assert not torch.equal(fn(48, g), fn(48, g))


@pytest.mark.parametrize("kind", KINDS)
def test_nontrivial_content(kind):
    stds = []
    for seed in range(6):
        x = TEXTURES[kind](64, seed)
        stds.append(float(x.std()))
        assert stds[-1] > 0.01, f"{kind} seed {seed} is nearly flat"
        # spatial structure: neighbouring pixels differ somewhere, in both directions
        assert float((x[:, 1:] - x[:, :-1]).abs().max()) > 0.02
        assert float((x[:, :, 1:] - x[:, :, :-1]).abs().max()) > 0.02
    assert sorted(stds)[len(stds) // 2] > 0.05, f"{kind}: median std {sorted(stds)} too low"


def test_kinds_look_different():
    """Flat-region kinds have few colours, smooth kinds many, gratings are periodic."""
    def n_colours(x):
        return x.reshape(3, -1).unique(dim=1).shape[1]

    assert n_colours(T.checkerboard(64, 0)) == 2
    assert n_colours(T.voronoi(64, 0, n_cells=10)) <= 10
    assert n_colours(T.fractal_noise(64, 0)) > 500
    g = T.grating(64, 0, frequency=0.125, angle=0.0, phase=0.0)   # u along x: 8-px period
    assert torch.allclose(g[:, :, 8:], g[:, :, :-8], atol=1e-5)
    assert torch.allclose(g[:, 1:], g[:, :-1])                     # constant along y


def test_palette_statistics():
    p = RandomPalette.draw(5)
    assert p.mean.shape == (3,) and 0.4 <= p.contrast <= 1 and 0 <= p.saturation <= 1
    c = p.sample(100, 0)
    assert c.shape == (100, 3) and float(c.min()) >= 0 and float(c.max()) <= 1
    pair = p.contrasting(2, 1)
    grey = pair.mean(dim=1)
    assert abs(float(grey[0] - grey[1])) > 0.5 * p.amplitude
    # palettes vary between images: means and contrasts spread
    means = torch.stack([RandomPalette.draw(s).mean for s in range(50)])
    assert float(means.mean(dim=1).std()) > 0.1
    # zero saturation -> colours are the mean's colour cast shifted equally in each channel
    grey_pal = RandomPalette(torch.tensor([0.3, 0.3, 0.3]), 0.8, 0.0)
    g = grey_pal.sample(20, 0)
    assert torch.allclose(g[:, 0], g[:, 1]) and torch.allclose(g[:, 1], g[:, 2])


def test_power_law_radii_follow_r_minus_3():
    rmin, rmax, n = 2.0, 100.0, 200_000
    r = power_law_radii(n, rmin, rmax, 0)
    assert float(r.min()) >= rmin and float(r.max()) <= rmax
    for x in (3.0, 5.0, 10.0, 30.0):
        expected = (x ** -2 - rmax ** -2) / (rmin ** -2 - rmax ** -2)
        observed = float((r > x).double().mean())
        assert observed == pytest.approx(expected, rel=0.05, abs=1e-3)
    # log-log slope of the density ~ -3
    edges = torch.logspace(math.log10(3), math.log10(30), 6, dtype=torch.float64)
    counts = torch.histc(r.double().log(), bins=5, min=math.log(3), max=math.log(30))
    density = counts / (edges[1:] - edges[:-1])
    centres = (edges[1:] * edges[:-1]).sqrt()
    slope = torch.diff(density.log()) / torch.diff(centres.log())
    assert float(slope.mean()) == pytest.approx(-3.0, abs=0.25)


def test_first_cover_matches_brute_force():
    """The box-limited scatter rasteriser agrees with testing every disc on every pixel."""
    h, w = 37, 53
    g = torch.Generator().manual_seed(0)
    n = 300
    r = torch.cat([power_law_radii(n - 4, 0.7, 20.0, g), torch.tensor([40.0, 60.0, 9.5, 0.3])])
    cx = torch.rand(n, generator=g) * (w + 40) - 20
    cy = torch.rand(n, generator=g) * (h + 40) - 20
    index = torch.randperm(n, generator=g) * 3 + 1           # arbitrary distinct sequence ids
    sentinel = torch.iinfo(torch.long).max
    first = torch.full((h * w,), sentinel, dtype=torch.long)
    T._first_cover(first, index, cx, cy, r, h, w)
    yy, xx = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(w) + 0.5, indexing="ij")
    cover = ((xx.reshape(1, -1) - cx[:, None]) ** 2 + (yy.reshape(1, -1) - cy[:, None]) ** 2
             <= r[:, None] ** 2)
    ref = torch.where(cover, index[:, None], sentinel).amin(dim=0)
    assert torch.equal(first, ref)


def test_dead_leaves_statistics():
    x = dead_leaves(128, 0)
    colours = x.reshape(3, -1).unique(dim=1).shape[1]
    assert colours > 50                                  # many occluding discs
    # hard edges between flat discs: a fair fraction of neighbour pairs change colour
    change = (x[:, :, 1:] != x[:, :, :-1]).any(dim=0).float().mean()
    # flat regions: most pixels equal their right neighbour exactly
    assert 0.05 < float(change) < 0.5
    # scale: smaller discs -> more edges
    fine = dead_leaves(128, 0, rmin=1.0, rmax=8.0)
    coarse = dead_leaves(128, 0, rmin=8.0, rmax=64.0)

    def edge_density(img):
        return float((img[:, :, 1:] != img[:, :, :-1]).any(dim=0).float().mean())

    assert edge_density(fine) > 2 * edge_density(coarse)


class _MarkedBackground(RandomPalette):
    """Grey disc colours; the first colour drawn (dead_leaves' background) is pure magenta."""

    def sample(self, n, generator):
        if not getattr(self, "_used", False):
            object.__setattr__(self, "_used", True)
            return torch.tensor([[1.0, 0.0, 1.0]])
        return super().sample(n, generator)


def _background_fraction(img):
    magenta = torch.tensor([1.0, 0.0, 1.0])[:, None, None]
    return float((img == magenta).all(dim=0).float().mean())


def test_dead_leaves_covers_every_pixel():
    """By default every pixel is covered by a disc; only a tiny disc budget leaves background."""
    def palette():
        return _MarkedBackground(torch.tensor([0.4, 0.4, 0.4]), 0.8, 0.0)   # discs are grey

    assert _background_fraction(dead_leaves(96, 1, palette=palette())) == 0.0
    assert _background_fraction(dead_leaves((40, 70), 2, rmin=0.8, palette=palette())) == 0.0
    assert _background_fraction(dead_leaves(64, 1, rmin=1.0, rmax=2.0, max_discs=5,
                                            palette=palette())) > 0.9


def test_random_texture_kinds():
    seen = set()
    for seed in range(60):
        x, kind = random_texture(24, seed)
        assert kind in TEXTURES and x.shape == (3, 24, 24)
        seen.add(kind)
    assert seen == set(KINDS)                             # uniform choice reaches every kind
    x, kind = random_texture((20, 30), 4, kinds=["grating", "voronoi"])
    assert kind in ("grating", "voronoi") and x.shape == (3, 20, 30)
    assert random_texture(16, 2, kinds="checkerboard")[1] == "checkerboard"
    a, ka = random_texture(32, 9)
    b, kb = random_texture(32, 9)
    assert ka == kb and torch.equal(a, b)


def test_bad_arguments():
    with pytest.raises(ValueError, match="got -3"):
        dead_leaves(-3, 0)
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        T.voronoi((10, 0), 0)
    with pytest.raises(ValueError):
        T.grating(True, 0)
    with pytest.raises(TypeError, match="generator"):
        T.checkerboard(16, "seed")
    with pytest.raises(ValueError, match="rmin"):
        dead_leaves(16, 0, rmin=0.0)
    with pytest.raises(ValueError, match="rmax"):
        dead_leaves(16, 0, rmin=4.0, rmax=2.0)
    with pytest.raises(ValueError, match="unknown texture kind"):
        random_texture(16, 0, kinds=["dead_leaves", "clouds"])
    with pytest.raises(ValueError, match="at least one"):
        random_texture(16, 0, kinds=[])
    with pytest.raises(ValueError, match="octaves"):
        T.fractal_noise(16, 0, octaves=0)
