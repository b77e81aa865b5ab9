"""A virtual image plane (``Lens(virtual_image=True)``, issue 22): the image plane lies before
the last surface (a negative lens's virtual focus, as an OpticStudio file may put it) and the move
to it extends the rays backwards along their lines.  Analysis only: cameras with a sensor, PSFs
and renderers refuse such a lens.  Without the flag a plane behind the rays is never reached.

The corpus file that needs it (``krakenos_zmax_84383.zmx``) is checked against optiland in
``tests/optics/io/test_zmx_corpus.py`` (first-order data, on-axis RMS, the optical path)."""

from __future__ import annotations

import math

import pytest
import torch

from deeplens.optics.errors import LensError
from deeplens.optics.io import lens_from_dict, lens_to_dict
from deeplens.optics.lens import Lens, LensSpec
from deeplens.optics.materials import get_material
from deeplens.optics.rays import Rays
from deeplens.optics.surfaces import IdealLens

F = -20.0     # the thin negative lens's focal length (mm): its virtual focus lies 20 mm before it
TAN = 0.05    # the field's direction tangent


def _thin_negative(d_sensor=F, virtual=True, f=F):
    air = get_material("AIR")
    spec = LensSpec(object_distance_mm=math.inf, aperture_type="epd", aperture_value=6.0,
                    fields_deg=[0.0, math.degrees(math.atan(TAN))])
    return Lens([IdealLens(f, 5.0)], [air, air], [0.0], d_sensor, 0, spec=spec,
                virtual_image=virtual, name="thin negative")


def _collimated(tan=TAN, n=9):
    """Rays of direction ``(0, tan, 1)`` crossing ``z = -5`` at heights ``-2.5..2.5`` mm (y) and
    ``x = 0.7`` (a skew ray set), ``(n,)``."""
    h = torch.linspace(-2.5, 2.5, n, dtype=torch.float64)
    o = torch.stack([torch.full_like(h, 0.7), h - 5.0 * tan, torch.full_like(h, -5.0)], -1)
    d = torch.tensor([0.0, tan, 1.0], dtype=torch.float64).expand(n, 3)
    return Rays(o, d, torch.full((n,), 587.6, dtype=torch.float64))


def test_rays_meet_at_the_virtual_focus():
    """A perfect thin lens of focal length f < 0: every ray of direction tangent (0, u) leaves
    with tangent (-x/f, u - y/f) from its hit (x, y), so its line meets the plane z = f at
    (0, f u) whatever (x, y): the virtual image point, 20 mm *before* the lens."""
    lens = _thin_negative()
    out = lens.trace_to_sensor(_collimated())
    assert bool(out.valid.all())
    assert torch.allclose(out.o[:, 2], torch.full_like(out.o[:, 2], F), rtol=0, atol=1e-12)
    assert torch.allclose(out.o[:, 0], torch.zeros_like(out.o[:, 0]), rtol=0, atol=1e-12)
    assert torch.allclose(out.o[:, 1], torch.full_like(out.o[:, 1], F * TAN), rtol=0, atol=1e-12)
    # the same plane without the flag (a lens with a real sensor, z_image given) is behind
    # every ray: no ray reaches it
    real = _thin_negative(d_sensor=5.0, virtual=False)
    assert not bool(real.trace_to_sensor(_collimated(), z_image=F).valid.any())


def test_the_optical_path_decreases_along_the_backward_move():
    """OpticStudio's convention for a virtual image (checked against optiland on the corpus
    file): the move to the plane is a negative distance t along the ray, the optical path
    gains n t < 0."""
    lens = _thin_negative()
    rays = _collimated()
    after = lens.trace(rays)
    out = lens.trace_to_sensor(rays)
    back = torch.linalg.vector_norm(out.o - after.o, dim=-1)
    assert float(back.min()) > 19.0
    assert torch.allclose(out.opl - after.opl, -back, rtol=0, atol=1e-12)


def test_gradient_of_the_landing_point_in_the_plane_distance():
    """d y / d d_sensor on the virtual plane (the ray's slope dy/dz) against central finite
    differences in float64."""
    lens = _thin_negative(d_sensor=F + 1.5)
    lens.d_sensor.requires_grad_(True)
    rays = _collimated(n=3)
    y = lens.trace_to_sensor(rays).o[:, 1].sum()
    (g,) = torch.autograd.grad(y, lens.d_sensor)
    h = 1e-6
    with torch.no_grad():
        lens.d_sensor += h
        yp = float(lens.trace_to_sensor(rays).o[:, 1].sum())
        lens.d_sensor -= 2 * h
        ym = float(lens.trace_to_sensor(rays).o[:, 1].sum())
        lens.d_sensor += h
    fd = (yp - ym) / (2 * h)
    assert float(g) == pytest.approx(fd, rel=1e-7)
    # and the closed form: y = f u + (d - f)(u - y_hit / f), summed over the three rays
    assert float(g) == pytest.approx(3 * TAN, rel=1e-12)   # the heights -2.5, 0, 2.5 sum to 0


def test_the_flag_is_required_and_checked():
    with pytest.raises(LensError, match="sensor distance must be > 0"):
        _thin_negative(virtual=False)
    with pytest.raises(LensError, match="virtual image plane .* must lie before"):
        _thin_negative(d_sensor=5.0, virtual=True)


def test_json_round_trip_and_errors():
    lens = _thin_negative()
    d = lens_to_dict(lens)
    assert d["sensor"] == {"distance_mm": F, "virtual_image": True}
    back = lens_from_dict(d)
    assert back.virtual_image and float(back.d_sensor) == F
    assert lens_to_dict(back) == d
    real = lens_to_dict(_thin_negative(d_sensor=5.0, virtual=False))
    assert "virtual_image" not in real["sensor"]       # files without the flag: unchanged
    assert not lens_from_dict(real).virtual_image
    bad = dict(d, sensor={"distance_mm": F})
    with pytest.raises(ValueError, match=r"sensor\.distance_mm.*virtual_image"):
        lens_from_dict(bad)
    bad = dict(d, sensor={"distance_mm": 5.0, "virtual_image": True})
    with pytest.raises(ValueError, match=r"sensor\.distance_mm.*must lie before"):
        lens_from_dict(bad)
    bad = dict(d, sensor={"distance_mm": F, "virtual_image": "yes"})
    with pytest.raises(ValueError, match=r"sensor\.virtual_image.*true or false"):
        lens_from_dict(bad)


def test_zmx_round_trip(tmp_path):
    from deeplens.optics.io import read_zmx, write_zmx

    lens = _thin_negative()
    write_zmx(lens, tmp_path / "v.zmx")
    with pytest.warns(Warning, match="virtual image plane"):
        back = read_zmx(tmp_path / "v.zmx")
    assert back.virtual_image and float(back.d_sensor) == F


def _refusals(lens):
    from deeplens.optics.camera import Camera
    from deeplens.render import IdealCamera, MonteCarloRenderer, Sensor
    from deeplens.render.image import render_image
    from deeplens.render.diffraction import diffraction_psf_many
    from deeplens.render.psf import psf

    sensor = Sensor((8, 8), 0.01)
    return {
        "Camera": lambda: Camera(lens, sensor),
        "MonteCarloRenderer": lambda: MonteCarloRenderer(lens, sensor),
        "psf_many": lambda: psf(lens, sensor, (0.0, 0.0), math.inf, 587.6),
        "IdealCamera": lambda: IdealCamera(lens, sensor),
        "diffraction_psf_many": lambda: diffraction_psf_many(
            lens, sensor, [((0.0, 0.0), math.inf, 587.6)]),
        "MonteCarloRenderer ": lambda: render_image(lens, torch.rand(3, 8, 8), 1000.0,
                                                    pixel_size_mm=0.01),
    }


@pytest.mark.parametrize("what", list(_refusals(None)))
def test_renderers_refuse_a_virtual_image(what):
    lens = _thin_negative()
    with pytest.raises(ValueError, match="cannot record a virtual image") as e:
        _refusals(lens)[what]()
    assert what.strip() in str(e.value)
    # the same with a real image is not refused for it (the refusal is the flag's, not the
    # call's): it runs, or (the diffraction PSF of this coarse 10 µm grid) fails for another
    # reason
    try:
        _refusals(_thin_negative(d_sensor=F * -1.0, virtual=False, f=-F))[what]()
    except ValueError as e:
        assert what == "diffraction_psf_many" and "virtual" not in str(e), str(e)


def test_analysis_works_on_a_virtual_image():
    """Spot (the point image at the virtual focus: RMS 0 on axis and at the field, whose
    centroid lies at f u), paraxial data, the report and the layout plot."""
    from deeplens.analysis.plot import layout_figure
    from deeplens.analysis.report import format_report, lens_report
    from deeplens.analysis.spot import spot_diagram
    from deeplens.optics.camera import Camera
    from deeplens.optics.paraxial import paraxial

    lens = _thin_negative()
    p = paraxial(lens)
    assert float(p.efl) == pytest.approx(F, rel=1e-12)
    assert float(p.bfl) == pytest.approx(F, rel=1e-12)
    field = math.degrees(math.atan(TAN))
    for cam in (lens, Camera(lens)):   # a camera without a sensor is analysis
        s = spot_diagram(cam, field, 587.6, "hexapolar:6", pupil="paraxial")
        assert s.n_rays == s.n_launched
        assert float(s.rms_radius) < 1e-12
        assert float(s.centroid[1]) == pytest.approx(F * TAN, abs=1e-12)
    rep = lens_report(lens, [0.0, field], None, "hexapolar:3", "paraxial")
    assert rep["image_plane"]["virtual"] is True
    assert "sensor, virtual" in format_report(rep)
    assert all(r["rms_spot_um"] < 1e-9 for r in rep["fields"])
    fig = layout_figure(lens, n_rays=3)
    dashed = [ln for ln in fig.axes[0].lines if ln.get_linestyle() == "--"]
    assert len(dashed) == 6   # two fields x three rays extended backwards
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_a_convex_mirrors_virtual_image_behind_it_closed_form():
    """After a mirror the flag works as before one (a convex mirror of radius R = 100 mm: its
    virtual focus lies R / 2 behind it, a positive distance after the mirror where light
    travels towards -z): every ray parallel to the axis, reflected at its exact hit point on
    the sphere, reaches the plane z = 50 along its line extended backwards (1e-12 mm); without
    the flag the plane behind the rays is never reached."""
    from deeplens.optics.surfaces import Asphere

    air = get_material("AIR")
    R, z_img = 100.0, 50.0
    lens = Lens([Asphere(1.0 / R, 5.0)], [air, air], [0.0], z_img, 0, mirrors=[0],
                virtual_image=True)
    h = torch.tensor([0.01, 0.5, 2.0, 4.5], dtype=torch.float64)
    o = torch.stack([torch.zeros_like(h), h, torch.full_like(h, -5.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(4, 3)
    out = lens.trace_to_sensor(Rays(o, d, torch.full((4,), 587.5618, dtype=torch.float64)))
    assert bool(out.valid.all())
    # closed form: hit at sag z_s; unit normal towards the centre (0, 0, R); reflect; extend
    zs = R - torch.sqrt(R * R - h * h)
    n = torch.stack([torch.zeros_like(h), -h, R - zs], -1) / R
    dr = d - 2 * (d * n).sum(-1, keepdim=True) * n
    t = (z_img - zs) / dr[:, 2]
    assert bool((t < 0).all())   # behind the rays: a virtual image
    want_y = h + t * dr[:, 1]
    assert torch.allclose(out.o[:, 1], want_y, atol=1e-12, rtol=0)
    assert torch.allclose(out.o[:, 2], torch.full_like(h, z_img), atol=1e-12, rtol=0)
    assert float(want_y[0]) == pytest.approx(0.0, abs=1e-9)   # the paraxial virtual focus
    real = Lens([Asphere(1.0 / R, 5.0)], [air, air], [0.0], -z_img, 0, mirrors=[0])
    assert not bool(real.propagate_to_z(real.trace(Rays(o, d, out.wavelength)),
                                        torch.tensor(z_img, dtype=torch.float64)).valid.any())
