"""The real chief ray, and the plane heights are measured on.

The chief ray of a field passes through the centre of the aperture stop.  :func:`chief_ray`
aims it there by secant iterations on its height in the paraxial entrance-pupil plane (real
ray aiming: pupil aberration included), tracing to the stop without clipping apertures (the
chief ray of an object-space telecentric lens, ``lens.object_telecentric``, is parallel to the
axis in object space by definition and is not aimed), and returns where it lands on the image plane (:func:`image_plane_z`: the sensor, the paraxial
image or a given ``z``).  Used by spot and aberration analysis, the design merit functions and
the Zemax reader (image heights of ``FTYP 3`` fields), so it lives with the tracer.
"""

from __future__ import annotations

import math

import torch

from .camera import unpack
from .options import TraceOptions
from .paraxial import paraxial
from .sampling import field_rays

__all__ = ["aiming_options", "chief_ray", "image_plane_z"]


def image_plane_z(lens, image_plane="sensor"):
    """Axial position of the evaluation plane: ``"sensor"``, ``"paraxial"`` or a number (mm)."""
    if image_plane == "sensor":
        return lens.z_sensor()
    if image_plane == "paraxial":
        return paraxial(lens).image_z
    if isinstance(image_plane, (int, float)):
        return torch.as_tensor(float(image_plane), dtype=lens.dtype)
    raise ValueError(f"image plane must be 'sensor', 'paraxial' or a z position in mm, got "
                     f"{image_plane!r}")


def aiming_options(options: TraceOptions | None) -> TraceOptions:
    """The options of an aiming trace: ``options`` (``None``: the defaults) without clear
    apertures, so a camera's tolerance and iterations reach its aiming traces too."""
    return (options or TraceOptions()).replace(clip_aperture=False)


def chief_ray(lens, field_deg: float, wavelength_nm: float, image_plane="sensor",
              iterations: int = 30, options: TraceOptions | None = None):
    """The real chief ray (aimed by secant iterations at the stop centre).

    Args:
        lens: a :class:`~.lens.Lens` (traced with ``options``) or a
            :class:`~.camera.Camera` (its options are used).
        options: the :class:`~.options.TraceOptions` of the traces (``None``: the defaults);
            the aiming traces run at these without clear apertures (:func:`aiming_options`).

    Returns ``(y_image_mm, y_pupil_mm)``: its height on the image plane and where it crosses the
    entrance-pupil plane.  Heights are signed: a positive field angle (rays rising towards
    ``+y``) images to ``+y`` through an imaging lens.
    """
    lens, _, options = unpack(lens, None, options, "chief_ray")
    dtype = lens.dtype
    with torch.no_grad():
        p = paraxial(lens)
        z_ep = float(p.entrance_pupil_z)

        aim = aiming_options(options)
        z = lens.z_vertices()
        n = lens.indices(torch.tensor(wavelength_nm, dtype=dtype))

        def stop_y(yp: float) -> float:
            xy = torch.tensor([[0.0, yp]], dtype=dtype)
            rays = field_rays(lens, field_deg, wavelength_nm, xy, z_ep)
            for i in range(lens.stop_index + 1):
                rays = lens.trace_surface(i, rays, n[i], n[i + 1], z, aim,
                                          refract_=i < lens.stop_index)
            return float(rays.o[0, 1])

        y0, y1 = 0.0, 1e-3 * max(float(p.entrance_pupil_diameter), 1e-3)
        if getattr(lens, "object_telecentric", False):
            # the entrance pupil at infinity: the chief ray is parallel to the axis by definition
            y1, iterations = 0.0, 0
        else:
            f0, f1 = stop_y(y0), stop_y(y1)
        for _ in range(iterations):
            if abs(f1) < 1e-12 or f1 == f0:
                break
            y0, y1, f0 = y1, y1 - f1 * (y1 - y0) / (f1 - f0), f1
            f1 = stop_y(y1)
    xy = torch.tensor([[0.0, y1]], dtype=dtype)
    rays = field_rays(lens, field_deg, wavelength_nm, xy, z_ep)
    out = lens.trace_to_sensor(rays, z_image=image_plane_z(lens, image_plane), options=options)
    y_img = out.o[0, 1] if bool(out.valid[0]) else torch.tensor(math.nan, dtype=dtype)
    return y_img, y1
