"""The ``perfect`` variant's lens: an aberration-free camera with the experiment's first order.

The ceiling of an experiment (issue 36: how much can a better lens still give at the image
edge?) is what the same restorer, budget, sensor, noise and renderer reach with a *perfect*
lens.  :func:`write_perfect_lens` writes a lens file of an aperture stop and, in the same plane,
an :class:`~deeplens.optics.surfaces.IdealLens` (a plane that maps ray tangents exactly as a
paraxial lens: no aberration at any field or aperture, no dispersion, no distortion,
``κ tan θ`` on the sensor), with

* the focal length and F-number of the experiment's lens: the search's ``lens.search.spec``
  (``efl_mm``, ``fno``) with ``lens.start=search``, else the paraxial EFL and F/# of the file's
  lens (``lens.path``, at its primary wavelength);
* the sensor in exact focus for the scene's depth (``scene.depths_mm``: one depth, since a
  perfect lens is sharp at one depth only; a depth range is refused), at ``v = f s / (s - f)``
  from the lens (``s`` the depth from the stop, mm).

The scene fills the ideal camera's field of view whatever its focal length, so the framing,
and with it the image content per pixel, is that of every other variant.

The Monte Carlo renderer traces it like any lens, so its sensor image is the scene sampled at
the ideal image points over each pixel with the same samples per pixel, plus the sensor's
noise: a geometric delta PSF.  Diffraction is left out (``render.psf_model=geometric`` for this
variant, as ``auto`` chooses for the doublet's other variants): at F/4 the Airy pattern's first
dark ring has radius ``1.22 λ N`` = 3.2 µm at 656 nm, 0.04 of the doublet's 80.4 µm pixel, and a
point spread uniformly over a pixel sends 4.8 % of its light to the neighbouring pixels
(computed in the tests against the closed-form encircled energy), so the variant is the
ceiling of the geometric simulation every variant uses, within that share.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from omegaconf import DictConfig

from ..optics.errors import ConfigError
from ..optics.paraxial import paraxial
from ..render.sensor import RGB_WAVELENGTHS_NM
from ..training.checkpoint import write_text_atomic

__all__ = ["PERFECT_LENS", "perfect_first_order", "perfect_lens_dict", "write_perfect_lens"]

#: the perfect lens's file name in the variant's folder
PERFECT_LENS = "perfect_lens.json"


def perfect_first_order(cfg: DictConfig) -> tuple[float, float]:
    """``(efl_mm, fno)`` of the experiment's lens (module docstring)."""
    if cfg.lens.get("start") == "search":
        spec = (cfg.lens.get("search") or {}).get("spec") or {}
        try:
            return float(spec["efl_mm"]), float(spec["fno"])
        except (KeyError, TypeError, ValueError):
            raise ConfigError("lens.search.spec", "efl_mm and fno (numbers) for the perfect "
                              "variant", dict(spec) if spec else spec) from None
    from ..training.lens_setup import build_lens   # the file's lens, as its runs build it
    lens = build_lens(cfg.lens.path, dtype="float64",
                      table_options=dict(cfg.lens.table_options or {}))
    p = paraxial(lens)
    return float(p.efl), float(p.fno)


def perfect_lens_dict(efl_mm: float, fno: float, depth_mm: float, sensor_semi_mm: float,
                      wavelengths_nm) -> dict:
    """The perfect lens as a lens-file mapping (:mod:`deeplens.optics.io.lensfile`).

    Args:
        efl_mm: focal length (mm, > 0).
        fno: F-number (> 0): the stop's semi-diameter is ``efl_mm / (2 fno)``.
        depth_mm: the in-focus object distance from the stop (mm, > ``efl_mm``, or ``inf``).
        sensor_semi_mm: the sensor's semi-diagonal (mm).
        wavelengths_nm: the wavelengths (nm) recorded in the file (the first is the primary).
    """
    f, N, s = float(efl_mm), float(fno), float(depth_mm)
    if not (math.isfinite(f) and f > 0 and math.isfinite(N) and N > 0):
        raise ValueError(f"perfect lens: efl_mm and fno must be finite and > 0, got {f}, {N}")
    if not s > f:
        raise ValueError(f"perfect lens: the object distance {s} mm must exceed the focal "
                         f"length {f} mm (a real image)")
    v = f if math.isinf(s) else f * s / (s - f)
    a = f / (2 * N)
    w = [float(x) for x in wavelengths_nm]
    return {
        "format": "deeplens-lens", "version": 1,
        "name": f"perfect lens (ideal thin lens, f {f:g} mm, F/{N:g}), in focus at {s:g} mm",
        "units": {"length": "mm", "wavelength": "nm"},
        "object": {"distance_mm": "inf", "medium": "AIR"},
        "aperture": {"type": "stop"},
        "fields_deg": [0.0],
        "wavelengths_nm": w, "primary_wavelength_nm": w[0],
        "stop": 0,
        "surfaces": [
            {"type": "aperture", "semi_diameter_mm": a, "distance_mm": 0.0, "material": "AIR"},
            # a hair wider than the stop: the stop, not the lens's rim, clips the beam
            {"type": "ideal_lens", "focal_length_mm": f, "semi_diameter_mm": a * 1.001,
             "distance_mm": 0.0, "material": "AIR"}],
        "sensor": {"distance_mm": v, "semi_diameter_mm": float(sensor_semi_mm)},
    }


def write_perfect_lens(cfg: DictConfig, folder) -> Path:
    """Write the perfect lens of ``cfg``'s experiment to ``<folder>/perfect_lens.json``
    (atomically; the same content for the same settings) and return its path.

    Raises:
        ConfigError: a phase plate (``lens.plate_surface``) or more than one scene depth.
    """
    if cfg.lens.get("plate_surface") is not None:
        raise ConfigError("eval.variants", "perfect only for a lens without a phase plate "
                          "(a perfect lens is sharp at one depth)", "perfect")
    depths = sorted({float(d) for d in cfg.scene.depths_mm})
    if len(depths) != 1:
        raise ConfigError("scene.depths_mm", "one depth for the perfect variant (a perfect "
                          "lens is sharp at one depth only)", list(depths))
    efl, fno = perfect_first_order(cfg)
    sc = cfg.sensor
    h, w = (float(x) * float(sc.pixel_size_mm) for x in sc.resolution)
    waves = sorted({float(x) for ch in (sc.channels or [[w] for w in RGB_WAVELENGTHS_NM])
                    for x in ch})
    d = perfect_lens_dict(efl, fno, depths[0], 0.5 * math.hypot(h, w), waves)
    path = Path(folder) / PERFECT_LENS
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(d, indent=1)
    if not (path.is_file() and path.read_text() == text):
        write_text_atomic(path, text)
    return path
