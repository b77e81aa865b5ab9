"""Input checks shared by the analysis functions: wavelengths inside every medium's range and
fields the lens can image, each failing with a message that names the value and the limit."""

from __future__ import annotations

import math

import torch

from ..optics.materials import check_wavelength_nm

__all__ = ["check_wavelength", "check_field", "AnalysisError"]


class AnalysisError(ValueError):
    """An analysis that cannot be computed for the given lens, field or wavelength."""


def check_wavelength(lens, wavelength_nm, owner: str = "") -> None:
    """Raise :class:`AnalysisError` unless ``wavelength_nm`` (nm, number or list) lies in the
    range of every medium of ``lens``; the message names the medium (followed by ``owner``,
    e.g. ``" of lens.json"``)."""
    w = [float(v) for v in (wavelength_nm if isinstance(wavelength_nm, (list, tuple))
                            else [wavelength_nm])]
    try:
        check_wavelength_nm(w)
    except ValueError as e:
        raise AnalysisError(str(e)) from None
    for i, m in enumerate(lens.materials):
        medium = "object space" if i == 0 else f"the medium after surface {i - 1}"
        try:
            check_wavelength_nm(w, m)
        except ValueError as e:
            raise AnalysisError(f"{e} ({medium}{owner})") from None


def max_field_deg(lens) -> float:
    """The largest field angle of the lens spec (deg)."""
    return max(abs(float(f)) for f in lens.spec.fields_deg)


def check_field(lens, field_deg: float, wavelength_nm: float, z_pupil: float,
                r_pupil: float, options=None) -> None:
    """Raise :class:`AnalysisError` if ``field_deg`` is not a finite angle within (-90, 90) or
    if its ray through the centre of the (paraxial) entrance pupil does not reach the image:
    the field lies beyond what the lens can image.  ``options``: the trace's
    :class:`~deeplens.optics.options.TraceOptions` (``None``: the defaults)."""
    from ..optics.sampling import field_rays

    f = float(field_deg)
    if not (math.isfinite(f) and abs(f) < 90.0):
        raise AnalysisError(f"field angle must be finite and within (-90, 90) degrees, got "
                            f"{field_deg!r}")
    dtype = lens.dtype
    with torch.no_grad():
        xy = torch.zeros(1, 2, dtype=dtype, device=lens.device)
        out = lens.trace_to_sensor(field_rays(lens, f, wavelength_nm, xy, z_pupil),
                                   options=options)
    if not bool(out.valid[0]):
        raise AnalysisError(
            f"field {f:g} deg at {wavelength_nm:g} nm is beyond the lens's reach: its chief ray "
            f"(through the entrance-pupil centre) does not reach the image (the lens file's "
            f"fields go to {max_field_deg(lens):g} deg)")
