"""Rendering physics against closed forms (every renderer, through the public API).

A perfect thin lens (:class:`~deeplens.optics.surfaces.IdealLens`) that is its own aperture stop
images without aberration and has its entrance and exit pupils at the lens, so two results hold
exactly and are computed here without the library:

* Relative illumination.  A uniform Lambertian scene of radiance ``L`` gives the sensor point
  ``s`` the irradiance ``E(s) = L ∫_pupil cos θ cos θ' / ρ² dA = L ∫ Δz² / (Δz² + |e - s|²)² dA``
  (``Δz`` the pupil-to-sensor distance, ``e`` the pupil point), which for a small pupil is the
  cos⁴ law ``E(θ) = E(0) cos⁴ θ`` with ``tan θ = |s| / f`` (focused at infinity).  The test
  compares each pixel with the pixel-averaged cos⁴ (an f/16 pupil: the pupil integral differs
  from cos⁴ of the chief ray by < 0.1 %).
* Where a point lands.  An object point ``(X, Y)`` at distance ``D`` is imaged at
  ``-(v / D) (X, Y)`` on the sensor (``1/v = 1/f - 1/D``); with the documented read-out (pixel
  ``(i, j)`` at ``x = -(j + 1/2 - W/2) p``, ``y = (i + 1/2 - H/2) p``) it appears upright: at
  fractional pixel ``(H/2 - m Y / p, W/2 + m X / p)`` with ``m = v / D`` (centre of pixel 0 at
  0.5), i.e. an object point right of and above the axis renders right of and above the image
  centre (texture row 0 is the top, column 0 the left).
"""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.lens import Lens
from deeplens.optics.materials import get_material
from deeplens.optics.surfaces import IdealLens
from deeplens.render import IdealCamera, MonteCarloRenderer, Scene, Sensor
from deeplens.render.splat import splat_bilinear, trace_to_sensor_pixels
from deeplens.render.psf_conv import PSFConvRenderer
from deeplens.render.splat import point_source_rays



def irradiance(lens, sensor, rays):
    """Forward-trace ``rays`` and splat them onto the whole sensor: ``(H, W)`` rays per pixel."""
    i, j, valid = trace_to_sensor_pixels(lens, sensor, rays.reshape(-1))
    return splat_bilinear(i, j, valid.to(i.dtype), sensor.resolution)

def thin_lens(f: float, semi_diameter: float, focus_mm: float = math.inf) -> Lens:
    """A perfect lens of focal length ``f`` (its own stop) focused at ``focus_mm``."""
    v = f if math.isinf(focus_mm) else 1.0 / (1.0 / f - 1.0 / focus_mm)
    air = get_material("AIR")
    return Lens([IdealLens(f, semi_diameter)], [air, air], [0.0], v, 0).double()


def pixel_average(fn, sensor: Sensor, sub: int = 16) -> torch.Tensor:
    """``(H, W)`` mean of ``fn(x, y)`` over each pixel's area (``sub x sub`` midpoint rule),
    pixel centres from the documented formula."""
    H, W = sensor.resolution
    p = sensor.pixel_size_mm
    i = torch.arange(H, dtype=torch.float64) + 0.5
    j = torch.arange(W, dtype=torch.float64) + 0.5
    u = ((torch.arange(sub, dtype=torch.float64) + 0.5) / sub - 0.5)
    y = ((i[:, None, None, None] + u[None, None, :, None]) - H / 2) * p  # (H, 1, sub, 1)
    x = -((j[None, :, None, None] + u[None, None, None, :]) - W / 2) * p  # (1, W, 1, sub)
    return fn(x, y).mean(dim=(-1, -2))


# ---------------------------------------------------------------- relative illumination
def test_uniform_scene_follows_the_cos4_law_with_vignetting_on():
    f = 50.0
    lens = thin_lens(f, semi_diameter=1.5)  # f/16.7
    sensor = Sensor((24, 24), 2.0)  # corner pixels at 32 mm: field angles up to 33 degrees
    camera = IdealCamera(lens, sensor)
    assert camera.field_angle_deg(32.0) == pytest.approx(math.degrees(math.atan(32 / f)))
    scene = Scene(torch.ones(1, 8, 8, dtype=torch.float64), 1e7, camera.fov_size_mm(1e7) * 2)
    # pupil_margin 1: the paraxial exit pupil is the stop itself, every sample passes, so the
    # estimate is nearly noise-free (only cos^4 varies over the samples)
    img = MonteCarloRenderer(lens, sensor, spp=64, vignetting=True, pupil_margin=1.0,
                             adjoint=False)(scene, seed=0)[0, 0]
    cos4 = pixel_average(lambda x, y: (f * f / (f * f + x * x + y * y)) ** 2, sensor)
    assert float(cos4.min()) < 0.5  # the law is tested over a wide range
    rel = img / cos4 - 1
    # Monte Carlo noise (pixel-position jitter under a sloped cos^4) is ~0.3 % per pixel: the
    # mean of the four pixels mirrored about both axes (same field angle) is held to 1 %, every
    # pixel to 2.5 % and the mean over the sensor (the on-axis normalisation) to 0.2 %
    sym = (rel + rel.flip(0) + rel.flip(1) + rel.flip(0, 1)) / 4
    assert float(sym.abs().max()) < 0.01, f"max deviation from cos^4: {float(sym.abs().max()):.4f}"
    assert float(rel.abs().max()) < 0.025
    assert abs(float(rel.mean())) < 0.002
    # the same image is far from the cos^2 (or cos^3) law a plausible bug would give
    cos2 = pixel_average(lambda x, y: f * f / (f * f + x * x + y * y), sensor)
    assert float((img / cos2 - 1).abs().max()) > 0.2


def test_uniform_scene_is_flat_with_vignetting_off():
    """Off: each pixel is normalised by its own rays, so the cos^4 fall-off disappears exactly."""
    lens = thin_lens(50.0, semi_diameter=1.5)
    sensor = Sensor((12, 12), 4.0)
    camera = IdealCamera(lens, sensor)
    scene = Scene(torch.ones(1, 8, 8, dtype=torch.float64), 1e7, camera.fov_size_mm(1e7) * 2)
    img = MonteCarloRenderer(lens, sensor, spp=4, vignetting=False, adjoint=False)(scene, seed=0)
    assert torch.allclose(img, torch.ones_like(img), rtol=0, atol=1e-12)


# ---------------------------------------------------------------- where a point lands
F, SD, DEPTH = 50.0, 2.0, 1000.0
V = 1.0 / (1.0 / F - 1.0 / DEPTH)
SENSOR = dict(resolution=(32, 40), pixel_size_mm=0.05)
# texture: 40 x 40 texels of 1 mm; a 3 x 3 bright patch, texel rows 8..10 and columns 26..28
TEX_SIZE_MM, TEX_N = 40.0, 40
ROWS, COLS = slice(8, 11), slice(26, 29)


def patch_scene() -> tuple[Scene, float, float]:
    """The scene and the patch centre ``(X, Y)`` in mm (texel ``(r, c)`` centre at
    ``X = (c + 1/2 - N/2) s``, ``Y = -(r + 1/2 - N/2) s``: row 0 on top, column 0 on the left)."""
    tex = torch.zeros(1, 1, TEX_N, TEX_N, dtype=torch.float64)
    tex[..., ROWS, COLS] = 1.0
    s = TEX_SIZE_MM / TEX_N
    X = (27 + 0.5 - TEX_N / 2) * s  # +7.5 mm: right of the axis
    Y = -(9 + 0.5 - TEX_N / 2) * s  # +10.5 mm: above the axis
    return Scene(tex, DEPTH, [[TEX_SIZE_MM, TEX_SIZE_MM]]), X, Y


def expected_pixel(sensor: Sensor, X: float, Y: float) -> tuple[float, float]:
    """Fractional ``(row, column)`` of the image of ``(X, Y)`` (module docstring)."""
    H, W = sensor.resolution
    m, p = V / DEPTH, sensor.pixel_size_mm
    return H / 2 - m * Y / p, W / 2 + m * X / p


def centroid(img: torch.Tensor) -> tuple[float, float]:
    """Intensity centroid ``(row, column)`` of an ``(H, W)`` image, pixel centres at k + 1/2."""
    img = img.to(torch.float64)
    H, W = img.shape
    i = torch.arange(H, dtype=torch.float64) + 0.5
    j = torch.arange(W, dtype=torch.float64) + 0.5
    total = img.sum()
    return float((img.sum(1) * i).sum() / total), float((img.sum(0) * j).sum() / total)


@pytest.fixture(scope="module")
def setup():
    lens = thin_lens(F, SD, focus_mm=DEPTH)
    sensor = Sensor(**SENSOR)
    scene, X, Y = patch_scene()
    i0, j0 = expected_pixel(sensor, X, Y)
    # the patch lands right of and above the centre, away from the diagonal (a transposed,
    # mirrored or flipped image lands many pixels away)
    H, W = sensor.resolution
    assert i0 < H / 2 - 5 and j0 > W / 2 + 5 and abs((H / 2 - i0) - (j0 - W / 2)) > 2
    return lens, sensor, scene, (i0, j0)


def render_ideal_camera(lens, sensor, scene):
    return IdealCamera(lens, sensor).render(scene, supersample=4)[0, 0]


def render_monte_carlo(lens, sensor, scene):
    return MonteCarloRenderer(lens, sensor, spp=16, vignetting=False)(scene, seed=0)[0, 0]


def render_psf_convolution(lens, sensor, scene):
    return PSFConvRenderer(lens, sensor, n_rays=256, supersample=4)(scene)[0, 0]


@pytest.mark.parametrize("render", [render_ideal_camera, render_monte_carlo,
                                    render_psf_convolution])
def test_bright_patch_lands_where_the_thin_lens_equation_says(setup, render):
    lens, sensor, scene, (i0, j0) = setup
    img = render(lens, sensor, scene)
    assert img.shape == sensor.resolution
    assert float(img.max()) > 0.5  # the patch is in the image, in focus
    i, j = centroid(img)
    assert i == pytest.approx(i0, abs=0.25) and j == pytest.approx(j0, abs=0.25), \
        f"patch centroid (row, col) = ({i:.2f}, {j:.2f}), expected ({i0:.2f}, {j0:.2f})"


def test_forward_splatted_point_lands_where_the_thin_lens_equation_says(setup):
    lens, sensor, _, _ = setup
    for X, Y in [(7.5, 10.5), (-12.0, 4.0), (3.0, -9.0)]:
        rays = point_source_rays(lens, (X, Y), DEPTH, 550.0, n_rays=500, seed=1)
        img = irradiance(lens, sensor, rays)
        # the rays the stop passes (the pupil is sampled 10 % wide) all reach the sensor
        n_valid = int(lens.trace_to_sensor(rays).valid.sum())
        assert n_valid > 300 and float(img.sum()) == pytest.approx(n_valid, rel=1e-12)
        i, j = centroid(img)
        i0, j0 = expected_pixel(sensor, X, Y)
        # a perfect lens sends every ray to one point; bilinear splatting keeps its centroid
        assert (i, j) == pytest.approx((i0, j0), abs=1e-6)


def test_point_at_infinity_lands_at_f_tan_theta():
    """A parallel beam travelling along ``(tx, ty, 1)`` (``point_source_rays``' tangents for a
    point at infinity) comes from the object direction ``-(tx, ty)`` and focuses at
    ``+f (tx, ty)`` on the sensor: upright in the read-out, left of and below the centre for
    ``tx, ty > 0`` (as a finite point at ``X = -tx D``, ``Y = -ty D`` would)."""
    lens = thin_lens(F, SD)
    sensor = Sensor(**SENSOR)
    H, W = sensor.resolution
    p = sensor.pixel_size_mm
    for tx, ty in [(0.01, 0.004), (-0.006, -0.012)]:
        rays = point_source_rays(lens, (tx, ty), math.inf, 550.0, n_rays=200, seed=2)
        i, j = centroid(irradiance(lens, sensor, rays))
        assert (i, j) == pytest.approx((H / 2 + F * ty / p, W / 2 - F * tx / p), abs=1e-6)


def test_psf_convolution_keeps_an_asymmetric_psf_the_right_way_round():
    """A decentred stop and a defocused sensor make the PSF lopsided (its centroid sits off the
    ideal image in both axes).  The PSF-convolution render of a point scene must put the light
    where forward tracing puts it; a kernel applied as a correlation (not flipped) mirrors the
    offset."""
    from deeplens.optics.surfaces import Aperture

    air = get_material("AIR")
    lens = Lens([Aperture(1.5), IdealLens(F, 10.0)], [air, air, air], [0.0, 2.0], V - 0.5,
                0).double()
    with torch.no_grad():
        lens.misalignments[0].dx.fill_(1.0)
        lens.misalignments[0].dy.fill_(-0.4)
    sensor = Sensor((32, 40), 0.01)
    tex = torch.zeros(1, 1, 41, 41, dtype=torch.float64)
    tex[..., 20, 20] = 1.0  # a point on the axis (the centre texel of a 4.1 mm texture)
    img = PSFConvRenderer(lens, sensor, n_rays=4000, supersample=4)(
        Scene(tex, DEPTH, [[4.1, 4.1]]))[0, 0]
    rays = point_source_rays(lens, (0.0, 0.0), DEPTH, 550.0, n_rays=4000, seed=0)
    i_ref, j_ref = centroid(irradiance(lens, sensor, rays))
    H, W = sensor.resolution
    assert abs(i_ref - H / 2) > 0.15 and abs(j_ref - W / 2) > 0.15  # lopsided in both axes
    assert centroid(img) == pytest.approx((i_ref, j_ref), abs=1e-6)
