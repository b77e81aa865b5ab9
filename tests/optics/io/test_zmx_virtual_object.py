"""A virtual object (``DISZ`` of ``SURF 0`` < 0, as in a relay fed by a converging beam): the
object point lies ``|s|`` behind the first vertex and object-space rays are aimed at it.

Checked against the Gaussian imaging equation surface by surface (``n'/l' - n/l = (n' - n) c``,
distances from each vertex, a virtual object at ``l > 0``), worked out here without deeplens'
paraxial code, and by real rays: every launched ray's line passes through the object point, the
rays start before the first surface, and near-axis real rays cross the axis at that image.
"""

from __future__ import annotations

import math

import pytest
import torch
from test_zmx import singlet, write

from deeplens.optics.paraxial import paraxial
from deeplens.optics.io import lens_to_dict, read_zmx, write_zmx
from deeplens.optics.io.lensfile import lens_from_dict
from deeplens.optics.sampling import field_rays

S_OBJ = -40.0   # the object 40 mm behind the stop plane (the first vertex)
C1, C2, T = 0.02, -0.005, 5.0


def relay(tmp_path, obj=S_OBJ, aperture="ENPD 10", yfln="YFLN 0 5"):
    text = singlet(obj=repr(obj), aperture=aperture, yfln=yfln, s1_extra=(), k=0.0, curv1=C1,
                   curv2=C2, t=T, bfl=10.0)
    return read_zmx(write(tmp_path, text, "relay.zmx"))


def gaussian_image_distance(lens) -> float:
    """The image distance from the last vertex (mm): Gaussian equation at each surface."""
    w = torch.tensor(float(lens.spec.primary_wavelength_nm), dtype=torch.float64)
    n = float(lens.materials[2].n(w))
    l1 = -S_OBJ - 2.0                   # the object seen from the lens's front vertex (> 0)
    l1p = n / (1.0 / l1 + (n - 1.0) * C1)
    l2 = l1p - T
    return 1.0 / (n / l2 + (1.0 - n) * C2)


def test_the_object_is_virtual_and_the_paraxial_image_is_gaussian(tmp_path):
    lens = relay(tmp_path)
    assert lens.spec.object_distance_mm == S_OBJ
    img = float(paraxial(lens).image_distance)
    assert img == pytest.approx(gaussian_image_distance(lens), rel=1e-12)
    # a real object at the same distance images elsewhere (the sign matters)
    real = relay(tmp_path, obj=-S_OBJ)
    assert abs(float(paraxial(real).image_distance) - img) > 1.0


@pytest.mark.parametrize("field", [0.0, 5.0])
def test_rays_are_aimed_at_the_virtual_object_point(tmp_path, field):
    lens = relay(tmp_path)
    par = paraxial(lens)
    z0, z_ep = float(lens.z_vertices()[0]), float(par.entrance_pupil_z)
    xy = torch.tensor([[0.0, 0.0], [0.0, 4.0], [3.0, -2.0], [-4.0, 1.0]], dtype=torch.float64)
    rays = field_rays(lens, field, 587.5618, xy, z_ep)
    z_obj = z0 - S_OBJ
    q_y = -math.tan(math.radians(field)) * (z_ep - z_obj)
    assert bool((rays.o[:, 2] < z0).all())           # launched before the first surface
    assert bool((rays.d[:, 2] > 0).all())            # travelling towards the lens
    t = (z_obj - rays.o[:, 2]) / rays.d[:, 2]
    at = rays.o + t[:, None] * rays.d                # the lines at the object plane
    assert at[:, 0].abs().max().item() < 1e-12
    assert (at[:, 1] - q_y).abs().max().item() < 1e-12
    # the ray through the pupil centre has the field's slope
    assert float(rays.d[0, 1] / rays.d[0, 2]) == pytest.approx(math.tan(math.radians(field)),
                                                              abs=1e-15)


def test_near_axis_real_rays_focus_at_the_gaussian_image(tmp_path):
    lens = relay(tmp_path)
    z_ep = float(paraxial(lens).entrance_pupil_z)
    h = 1e-3
    rays = field_rays(lens, 0.0, float(lens.spec.primary_wavelength_nm),
                      torch.tensor([[0.0, h]], dtype=torch.float64), z_ep)
    z_img = float(lens.z_vertices()[-1]) + gaussian_image_distance(lens)
    out = lens.trace_to_sensor(rays, z_image=z_img)
    assert bool(out.valid.all())
    # spherical aberration at 1 um pupil height: the height there is O(h^3), far below h
    assert abs(float(out.o[0, 1])) < 1e-6 * h


def test_a_virtual_object_survives_both_file_formats(tmp_path):
    lens = relay(tmp_path)
    back = lens_from_dict(lens_to_dict(lens))
    assert back.spec.object_distance_mm == S_OBJ
    write_zmx(lens, tmp_path / "out.zmx")
    again = read_zmx(tmp_path / "out.zmx")
    assert again.spec.object_distance_mm == pytest.approx(S_OBJ, abs=1e-12)
    assert float(paraxial(again).image_distance) == pytest.approx(
        float(paraxial(lens).image_distance), rel=1e-12)


def test_the_wavefront_of_a_virtual_object_is_measured_from_it(tmp_path):
    """Optical paths from a virtual object point are negative (the rays reach it after the
    start plane): on axis at the paraxial image, the OPD is the lens's spherical aberration
    alone, growing as the fourth power of the pupil (W040 y⁴); a reference on the wrong side
    would leave a defocus growing as y²."""
    from deeplens.analysis.wavefront import wavefront

    rms = [float(wavefront(relay(tmp_path, aperture=f"ENPD {d}"), 0.0, n=16,
                           image_plane="paraxial").rms) for d in (1.0, 2.0)]
    assert rms[0] < 1e-3
    assert rms[1] / rms[0] == pytest.approx(16.0, rel=0.02)


@pytest.mark.parametrize("aim", ["paraxial", "stop"])
def test_normalized_rays_of_a_virtual_object_start_before_the_lens(tmp_path, aim):
    """normalized_rays (normalised field and pupil) launches the same way: before the first
    surface, along lines through the virtual object point of its field."""
    from deeplens.optics.normalized import normalized_rays

    lens = relay(tmp_path)
    z0 = float(lens.z_vertices()[0])
    z_obj = z0 - S_OBJ
    rays = normalized_rays(lens, (0.0, 1.0), [(0.0, 0.0), (0.0, 0.7), (0.5, -0.5)], aim=aim)
    assert bool(rays.valid.all()) and bool((rays.o[:, 2] < z0).all())
    t = (z_obj - rays.o[:, 2]) / rays.d[:, 2]
    at = rays.o + t[:, None] * rays.d
    assert at[:, 0].abs().max().item() < 1e-12          # one object point: x = 0 ...
    assert (at[:, 1] - at[0, 1]).abs().max().item() < 1e-12   # ... and one height
