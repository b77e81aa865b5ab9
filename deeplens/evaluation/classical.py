"""The ``classical`` evaluation variant: the optics designed first by the design engine
(:mod:`deeplens.design`), then frozen while a restorer is trained on them, the baseline that
end-to-end design has to beat.

* A lens with a phase plate (EDOF): the plate's trainable coefficients (``lens.trainable``)
  minimise the change of the on-axis PSF over the scene's depth range at the blur size of the
  start plate (:class:`~deeplens.design.depth_invariance.DepthInvarianceMerit`), starting from
  the cubic plate of ``eval.classical.start_alpha_mm``.
* Any other lens (e.g. the doublet): the same variables (``lens.trainable``) minimise the RMS
  spot (:class:`~deeplens.design.merit.SpotMerit`, centroid reference, on the sensor) over the
  scene's PSF fields (``scene.psf_fields_deg``) and the sensor's wavelengths; the lens's own
  geometry checks are the constraints, as in end-to-end training.

``eval.classical.max_sag_mm`` (default ``null``: no bound) bounds each designed surface's
departure from its starting sag as end-to-end training's ``model.max_sag_mm`` does (the same
grid, :class:`~deeplens.training.constraints.SagDepartureConstraint`), as a hard constraint of the design
(the largest departure over the grid ``<= max_sag_mm``): ``eval.classical.max_sag_mm=model``
takes the end-to-end run's own bound, so that both designs are held to the same constraints.

Damped least squares with a float64 central-difference Jacobian.  The designed lens is written
to ``classical_lens.json`` (with ``classical_design.json``: the settings, merit before/after,
variables, seconds) in the variant's folder, and reused when its settings and the content of its
inputs (the lens file, and the ``.agf`` catalogues a ``.zmx`` loads: :mod:`deeplens.training.input_digest`) are
unchanged.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from ..design.constraints import Constraint
from ..design.depth_invariance import DepthInvarianceMerit
from ..design.lensopt import optimize_lens
from ..design.merit import SpotMerit
from ..design.variables import Variables
from ..optics.errors import ConfigError
from ..optics.io import save_lens
from ..render.sensor import Sensor
from ..training.checkpoint import write_text_atomic
from ..training.constraints import SagDepartureConstraint
from ..training.input_digest import input_digests
from ..training.lens_setup import build_lens

__all__ = ["check_classical_config", "design_classical", "DEFAULTS"]

#: ``eval.classical`` defaults (a partial mapping in the config is completed with these)
DEFAULTS = {"steps": 15, "sampling": "grid:32", "n_freq": 6, "blur_weight": 1.0,
            "start_alpha_mm": None, "blur_px": None, "fields_deg": None,
            "spot_sampling": "hexapolar:6", "max_sag_mm": None}


def _settings(cfg: DictConfig) -> dict:
    c = cfg.eval.get("classical")
    given = {} if c is None else OmegaConf.to_container(c, resolve=True)
    if not isinstance(given, dict):
        raise ConfigError("eval.classical", "null or a mapping of the classical design's "
                          "settings", given)
    unknown = set(given) - set(DEFAULTS)
    if unknown:
        raise ConfigError.unknown("eval.classical", unknown, sorted(DEFAULTS))
    s = {**DEFAULTS, **given}
    if not (isinstance(s["steps"], int) and not isinstance(s["steps"], bool)
            and s["steps"] >= 1):
        raise ConfigError("eval.classical.steps", "an integer >= 1", s["steps"])
    m = s["max_sag_mm"]
    if m == "model":
        m = s["max_sag_mm"] = cfg.model.get("max_sag_mm")
    if m is not None and not (isinstance(m, (int, float)) and not isinstance(m, bool)
                              and math.isfinite(m) and m > 0):
        raise ConfigError("eval.classical.max_sag_mm", "null, 'model' or a bound > 0 (mm)", m)
    return s


def check_classical_config(cfg: DictConfig) -> None:
    """Start-up check of ``eval.classical`` (known keys, ``steps``, ``max_sag_mm``); raises
    :class:`~deeplens.optics.errors.ConfigError` naming the key."""
    _settings(cfg)


def sag_departure_constraints(lens, max_sag_mm: float) -> list:
    """One design constraint per surface with trainable parameters: the largest departure of
    its sag from the current one over :class:`~deeplens.training.constraints.SagDepartureConstraint`'s grid is
    at most ``max_sag_mm`` (mm)."""
    bound = SagDepartureConstraint(lens, max_sag_mm)
    out = []
    for i in bound.surfaces:
        def fn(L, i=i):
            X, Y = bound._points(L.surfaces[i], L.dtype, L.device)
            sag0 = getattr(bound, f"sag0_{i}").to(X)
            return (L.surfaces[i].sag(X, Y) - sag0).abs().max()

        out.append(Constraint(f"max_sag_departure.{i}", "max", float(max_sag_mm), fn))
    return out


def _start_alpha(cfg: DictConfig, s: dict) -> float:
    """The cubic plate the design starts from: ``eval.classical.start_alpha_mm``, else the
    learned plate's start, else the largest α of the cubic sweep."""
    if s["start_alpha_mm"] is not None:
        return float(s["start_alpha_mm"])
    if cfg.lens.get("learned_start_alpha_mm") is not None:
        return float(cfg.lens.learned_start_alpha_mm)
    a = cfg.eval.cubic_alpha_mm
    return float(max(a) if OmegaConf.is_list(a) else a)


def design_classical(cfg: DictConfig, out_dir) -> Path:
    """Design the lens of the ``classical`` variant for ``cfg`` (module docstring); returns the
    path of the designed lens file in ``out_dir`` (reused when designed with the same
    settings)."""
    s = _settings(cfg)
    lc, sc = cfg.lens, cfg.sensor
    if not list(lc.trainable):
        raise ConfigError("lens.trainable", "the variables the classical variant designs "
                          "(eval.variants has classical or refined), not an empty list", [])
    plate = lc.plate_surface is not None
    if plate:
        s["start_alpha_mm"] = _start_alpha(cfg, s)
    key = {"lens": OmegaConf.to_container(lc, resolve=True),
           "sensor": OmegaConf.to_container(sc, resolve=True),
           "depths_mm": list(cfg.scene.depths_mm), "fields_deg": list(cfg.scene.psf_fields_deg),
           # max_sag_mm only when set: designs made before the option existed stay valid
           "settings": {k: v for k, v in s.items() if k != "max_sag_mm" or v is not None}}
    # the content of the lens file (and of the .agf catalogues a .zmx loads), not only its path:
    # a lens edited in place is designed again (and the variant's runs, keyed on the designed
    # lens's content, trained again)
    key["inputs"] = input_digests(key, outputs=[out_dir])
    out = Path(out_dir)
    lens_path, rec_path = out / "classical_lens.json", out / "classical_design.json"
    if lens_path.is_file() and rec_path.is_file():
        try:
            if json.loads(rec_path.read_text()).get("key") == json.loads(json.dumps(key)):
                print(f"deeplens eval: reusing the classical design in {lens_path}")
                return lens_path
        except (OSError, ValueError):
            pass
    sensor = Sensor(tuple(sc.resolution), sc.pixel_size_mm,
                    channels=None if sc.channels is None else [list(c) for c in sc.channels])
    waves = [float(w) for ch in sensor.channels for w in ch]
    lens = build_lens(lc.path, trainable=list(lc.trainable), dtype="float64",
                      plate="cubic" if plate else lc.plate, plate_surface=lc.plate_surface,
                      plate_alpha_mm=s["start_alpha_mm"] if plate else 0.0,
                      table_options=OmegaConf.to_container(lc.table_options),
                      focus_mm=lc.focus_mm, focus_wavelengths_nm=waves)
    if plate:
        lo, hi = (float(d) for d in cfg.scene.depths_mm)
        # depths uniform in 1/depth over the training range (as the scene samples them)
        depths = [1.0 / (1.0 / lo + (1.0 / hi - 1.0 / lo) * k / 3) for k in range(4)]
        merit = DepthInvarianceMerit(depths, waves, sensor.pixel_size_mm, blur_px=s["blur_px"],
                                     blur_weight=s["blur_weight"], n_freq=s["n_freq"],
                                     sampling=s["sampling"])
        what = f"depth invariance over {lo:g}-{hi:g} mm"
    else:
        fields = s["fields_deg"] if s["fields_deg"] is not None else list(
            cfg.scene.psf_fields_deg)
        merit = SpotMerit(fields_deg=fields, wavelengths_nm=waves, sampling=s["spot_sampling"])
        what = f"RMS spot over fields {fields} deg"
    variables = Variables(lens, list(lc.trainable))
    bounds = ([] if s["max_sag_mm"] is None
              else sag_departure_constraints(lens, float(s["max_sag_mm"])))
    res = optimize_lens(lens, variables, merit, method="dls", steps=s["steps"],
                        jacobian_mode="central", constraints=bounds)
    rec = {"key": key, "merit": what, "merit_before": res.merit_before,
           "merit_after": res.merit_after, "variables_before": res.variables_before,
           "variables_after": res.variables_after, "steps": res.steps,
           "seconds": res.seconds, "reason": res.reason}
    if bounds:
        rec["sag_departure_mm"] = {c.label: float(c.value(lens).detach()) for c in bounds}
    if plate:
        merit.prepare(lens)
        rec["blur_px"] = float(merit.blur_px)
        rec["invariance_after"] = float(merit.invariance(lens).detach())
    print(f"deeplens eval: classical design ({what}): merit {res.merit_before:.4g} -> "
          f"{res.merit_after:.4g} in {res.steps} steps, {res.seconds:.0f} s")
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / "classical_lens.tmp.json"
    save_lens(lens, tmp)
    tmp.replace(lens_path)
    write_text_atomic(rec_path, json.dumps(rec, indent=1))
    return lens_path
