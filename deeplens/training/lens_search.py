"""``lens.start=search``: training starts from a lens the design search makes from a
specification (:mod:`deeplens.design.search`, issue 36) instead of a lens file.

Config (the ``lens`` group)::

    start: search          # file (default: lens.path) | search
    search:
      spec: {efl_mm: 10, fno: 4, hfov_deg: 20, elements: 2, ...}   # DesignSpec fields
      config: {starts: 4, hops: 2, seed: 0, screen: 10, ...}        # SearchConfig fields
      trainable: ["surfaces.*.c"]   # globs over the searched lens's parameter names

``spec`` holds :class:`~deeplens.design.search.DesignSpec` fields; ``wavelengths_nm``, when
absent, is the sensor's wavelengths (sorted, each once).  ``config`` holds
:class:`~deeplens.design.search.SearchConfig` fields; a stage field (``screen``,
``flat_screen``, ``polish``, ``hop``) is an integer (one DLS stage of that many steps on
``hexapolar:6``) or a list of :class:`~deeplens.design.search.Stage` mappings (``steps``,
``sampling``, ``aperture``, ``field``, ``rounds``, ``method``).  ``trainable`` replaces
``lens.trainable`` (whose indices name the file's surfaces, not the searched lens's).

The search runs once, before the lens is built (:func:`searched_lens`): its best design is
written to ``<folder>/best.json`` with ``result.json`` (``write_outputs``) and
``search_record.json`` (the key: the spec, the search settings, the deeplens version and the
SHA-256 of the search package's sources; and the digest of ``best.json``), and reused while the
key is unchanged.  ``<folder>`` is ``<run output folder>/search`` for a training run and
``<evaluation folder>/search`` for an evaluation (shared by its ``searched`` and ``learned``
variants and seeds).  The files are moved into place one by one (atomic renames), the record
last, so a search killed part-way is made again.

**A phase plate's search** (EDOF, :mod:`deeplens.design.plate_search`): with a plate
(``lens.plate_surface``), ``lens.search`` is ``{plate: {PlateSearchConfig fields}}`` instead::

    start: search
    search:
      plate: {starts: 16, steps: 8, box_mm: 0.006, seed: 0}

The file's lens keeps its plate surface, sensor focus and ``lens.trainable``; the search
(:func:`~deeplens.design.plate_search.plate_search`) sets the plate's trainable coefficients
from a zero plate to the best of its starts for the depth-invariance merit over the scene's
depth range (four depths uniform in 1/depth, as the ``classical`` variant) at the sensor's
wavelengths and pixel pitch, and training starts from that plate.  Its lens is
``<folder>/best.json`` with ``result.json`` (every start, the kept designs, the plate's terms)
and the same ``search_record.json``, keyed by the settings, the lens file's content and the
sources of the plate search and its merit.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import shutil
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from ..optics.errors import ConfigError
from ..optics.sampling import parse_sampling
from .checkpoint import write_text_atomic
from .input_digest import digest_path
from .lens_setup import build_lens, check_lens_settings

__all__ = ["START_CHOICES", "SEARCH_KEYS", "search_settings", "check_lens_config",
           "check_search_settings",
           "searched_lens", "search_trainable", "search_dir", "RECORD"]

#: the values of ``lens.start``
START_CHOICES = ("file", "search")
#: the keys of ``lens.search`` (``plate``: a phase plate's search, alone)
SEARCH_KEYS = ("spec", "config", "trainable", "plate")
#: the stage fields of a SearchConfig, and the keys of one stage
_STAGE_FIELDS = ("screen", "flat_screen", "polish", "hop", "prescreen_stage", "substitute",
                 "snap_stage")
_STAGE_KEYS = ("steps", "sampling", "aperture", "field", "rounds", "method")
#: the file holding the key of the search in its folder
RECORD = "search_record.json"


def _plain(v):
    return OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v


def _int(v, lo: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= lo


def _sampling(v) -> bool:
    if not isinstance(v, str):
        return False
    try:
        parse_sampling(v)
    except ValueError:
        return False
    return True


def _real(v, lo: float = 0.0) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            and v >= lo)


def _stages(value, key: str) -> tuple:
    from ..design.search import Stage

    if _int(value, 1):
        return (Stage(int(value)),)
    what = ("an integer >= 1 (one DLS stage of that many steps) or a non-empty list of stage "
            f"mappings ({', '.join(_STAGE_KEYS)})")
    if not isinstance(value, list) or not value:
        raise ConfigError(key, what, value)
    out = []
    for k, st in enumerate(value):
        at = f"{key}[{k}]"
        if not isinstance(st, dict):
            raise ConfigError(at, f"a stage mapping ({', '.join(_STAGE_KEYS)})", st)
        unknown = set(st) - set(_STAGE_KEYS)
        if unknown:
            raise ConfigError.unknown(at, unknown, _STAGE_KEYS)
        if "steps" not in st:
            raise ConfigError.missing(f"{at}.steps", "an integer >= 1")
        checks = {"steps": (lambda v: _int(v, 1), "an integer >= 1"),
                  "rounds": (lambda v: _int(v, 1), "an integer >= 1"),
                  "sampling": (lambda v: isinstance(v, str) and v, "a pupil sampling such as "
                               "'hexapolar:6'"),
                  "aperture": (lambda v: _real(v) and 0 < v <= 1, "a fraction in (0, 1]"),
                  "field": (lambda v: _real(v) and v <= 1, "a fraction in [0, 1]"),
                  "method": (lambda v: v in ("dls", "lbfgs"), "'dls' or 'lbfgs'")}
        for name, v in st.items():
            ok, expected = checks[name]
            if not ok(v):
                raise ConfigError(f"{at}.{name}", expected, v)
        out.append(Stage(**st))
    return tuple(out)


def _search_config(given, key: str):
    from ..design.search import SearchConfig
    from ..design.search.multistart import (REBALANCE_FLOORS, SEIDEL_RANKINGS,
                                            SUBSTITUTE_STRATEGIES, SUBSTITUTIONS)

    given = {} if given is None else given
    if not isinstance(given, dict):
        raise ConfigError(key, "null or a mapping of SearchConfig fields", given)
    known = [f.name for f in dataclasses.fields(SearchConfig)]
    unknown = set(given) - set(known)
    if unknown:
        raise ConfigError.unknown(key, unknown, known)
    vals = {}
    rules = {"starts": (lambda v: _int(v, 1), "an integer >= 1"),
             "polish_count": (lambda v: _int(v, 1), "an integer >= 1"),
             "keep": (lambda v: _int(v, 1), "an integer >= 1"),
             "hops": (lambda v: _int(v, 0), "an integer >= 0"),
             "seed": (lambda v: _int(v, 0), "an integer >= 0"),
             "hop_size": (_real, "a number >= 0"), "temperature": (_real, "a number >= 0"),
             "dedup_tol": (_real, "a number >= 0"),
             "start_kind": (lambda v: v in ("thin", "flat", "mixed"),
                            "'thin', 'flat' or 'mixed'"),
             "score_sampling": (_sampling, "a pupil sampling such as 'hexapolar:6'"),
             "final_sampling": (_sampling, "a pupil sampling such as 'hexapolar:12'"),
             "prescreen_sampling": (_sampling, "a pupil sampling such as 'hexapolar:4'"),
             "prescreen": (lambda v: _int(v, 0), "an integer >= 0"),
             "substitute_k": (lambda v: _int(v, 1), "an integer >= 1"),
             "glass_radius": (_real, "a number > 0"),
             "substitute_radius": (lambda v: v is None or _real(v), "null or a number > 0"),
             "time_limit_s": (lambda v: v is None or _real(v), "null or a number of seconds > 0"),
             "substitution": (lambda v: v in SUBSTITUTIONS, " or ".join(map(repr, SUBSTITUTIONS))),
             "snap_count": (lambda v: _int(v, 1), "an integer >= 1"),
             "rank_keep": (lambda v: _int(v, 0), "an integer >= 0"),
             "rank_k": (lambda v: _int(v, 1), "an integer >= 1"),
             "substitute_strategy": (lambda v: v in SUBSTITUTE_STRATEGIES,
                                     " or ".join(map(repr, SUBSTITUTE_STRATEGIES))),
             "converge_tol": (_real, "a number >= 0"),
             "converge_rounds": (lambda v: _int(v, 0), "an integer >= 0"),
             "seidel_screen": (lambda v: _int(v, 0), "an integer >= 0"),
             "seidel_steps": (lambda v: _int(v, 0), "an integer >= 0"),
             "seidel_rebalance": (lambda v: _int(v, 0), "an integer >= 0"),
             "seidel_rebalance_floor": (lambda v: v in REBALANCE_FLOORS,
                                        " or ".join(map(repr, REBALANCE_FLOORS))),
             "seidel_ranking": (lambda v: v in SEIDEL_RANKINGS,
                                " or ".join(map(repr, SEIDEL_RANKINGS))),
             "converge_steps": (lambda v: _int(v, 0), "an integer >= 0"),
             "converge_chunk": (lambda v: _int(v, 1), "an integer >= 1"),
             "combined_k": (lambda v: _int(v, 1), "an integer >= 1"),
             "combined_keep": (lambda v: _int(v, 1), "an integer >= 1")}
    for name, v in given.items():
        if name in _STAGE_FIELDS:
            vals[name] = _stages(v, f"{key}.{name}")
            continue
        ok, expected = rules[name]
        if not ok(v):
            raise ConfigError(f"{key}.{name}", expected, v)
        vals[name] = v
    try:
        return SearchConfig(**vals)
    except (TypeError, ValueError) as e:
        raise ConfigError(key, f"settings SearchConfig accepts ({e})", given) from None


def _waves(sensor_cfg) -> list[float] | None:
    """The sensor's wavelengths (sorted, each once), or ``None`` if they cannot be read."""
    if sensor_cfg is None:
        return None
    ch = sensor_cfg.get("channels")
    if ch is None:
        from ..render.sensor import RGB_WAVELENGTHS_NM
        return sorted(set(float(w) for w in RGB_WAVELENGTHS_NM))
    try:
        return sorted({float(w) for c in _plain(ch) for w in c})
    except (TypeError, ValueError):
        return None


def search_settings(search, sensor_cfg=None):
    """``(spec, config, trainable)`` of a ``lens.search`` mapping: the
    :class:`~deeplens.design.search.DesignSpec`, the
    :class:`~deeplens.design.search.SearchConfig` and the list of ``trainable`` globs.

    Raises:
        ConfigError: naming ``lens.search``, ``lens.search.spec.<field>``,
            ``lens.search.config.<field>`` or ``lens.search.trainable``.
    """
    from ..design.search import DesignSpec, SpecError

    s = _plain(search)
    if not isinstance(s, dict):
        raise ConfigError("lens.search", f"a mapping with {', '.join(SEARCH_KEYS)} (needed by "
                          f"lens.start=search and the searched variant)", s)
    unknown = set(s) - set(SEARCH_KEYS)
    if unknown:
        raise ConfigError.unknown("lens.search", unknown, SEARCH_KEYS)
    if "plate" in s:
        raise ConfigError("lens.search", "spec, config and trainable (a lens search); "
                          "lens.search.plate (a phase plate's search) goes alone, with "
                          "lens.plate_surface", s)
    spec = s.get("spec")
    if not isinstance(spec, dict):
        raise ConfigError("lens.search.spec", "a mapping of DesignSpec fields (efl_mm, fno or "
                          "epd_mm, hfov_deg, elements, ...)", spec)
    spec = dict(spec)
    if "wavelengths_nm" not in spec:
        waves = _waves(sensor_cfg)
        if waves is not None:
            spec["wavelengths_nm"] = waves
    try:
        spec = DesignSpec.from_dict(spec)
    except SpecError as e:
        field = e.field
        key = f"lens.search.spec.{field}" if field else "lens.search.spec"
        raise ConfigError(key, str(e).split(": ", 1)[-1], spec.get(field)) from None
    config = _search_config(s.get("config"), "lens.search.config")
    trainable = s.get("trainable", [])
    trainable = [] if trainable is None else trainable
    if not (isinstance(trainable, list) and all(isinstance(t, str) and t for t in trainable)):
        raise ConfigError("lens.search.trainable", "a list of parameter names or globs of the "
                          "searched lens (e.g. 'surfaces.*.c')", trainable)
    return spec, config, list(trainable)


def check_search_settings(lc, sensor_cfg=None) -> None:
    """``lens.start`` and ``lens.search`` of the lens config ``lc`` (and the settings
    ``start: search`` refuses: a phase plate, ``table_options``); raises
    :class:`~deeplens.optics.errors.ConfigError` naming the key."""
    start = lc.get("start", "file")
    start = "file" if start is None else start
    if start not in START_CHOICES:
        raise ConfigError("lens.start", "'file' (lens.path) or 'search' (lens.search)", start)
    search = lc.get("search")
    if start == "file" and search is None:
        return
    if start == "search" and search is None:
        raise ConfigError.missing("lens.search", "the search's spec, config and trainable "
                                  "(lens.start=search)")
    if is_plate_search(search):
        if start == "search":
            _check_plate_search(lc)
        else:  # an evaluation variant's run from the searched plate (its lens.path)
            plate_search_config(search)
        return
    search_settings(search, sensor_cfg)
    if start != "search":
        return
    refused = [("lens.plate_surface", lc.get("plate_surface") is not None),
               ("lens.plate", lc.get("plate") in ("none", "cubic")),
               ("lens.plate_order", lc.get("plate_order") is not None),
               ("lens.learned_start_alpha_mm", lc.get("learned_start_alpha_mm") is not None)]
    for key, bad in refused:
        if bad:
            raise ConfigError(key, "null with lens.start=search (a searched lens has no "
                              "phase plate)", _plain(lc.get(key.split(".")[1])))
    opts = {k: v for k, v in (_plain(lc.get("table_options")) or {}).items() if v is not None}
    if opts:
        raise ConfigError("lens.table_options", "null options with lens.start=search (they "
                          "apply to the authors' .txt tables only)", opts)


def search_trainable(cfg: DictConfig) -> list[str]:
    """``lens.search.trainable`` of ``cfg`` (checked); a plate search: ``lens.trainable``."""
    if is_plate_search(cfg.lens.search):
        return list(_plain(cfg.lens.trainable) or [])
    return search_settings(cfg.lens.search, cfg.get("sensor"))[2]


def is_plate_search(search) -> bool:
    """Whether ``lens.search`` asks for a phase plate's search (it has a ``plate`` key)."""
    s = _plain(search)
    return isinstance(s, dict) and "plate" in s


def plate_search_config(search):
    """The :class:`~deeplens.design.plate_search.PlateSearchConfig` of ``lens.search.plate``.

    Raises:
        ConfigError: naming ``lens.search`` or ``lens.search.plate[.<field>]``.
    """
    from ..design.plate_search import PlateSearchConfig

    s = _plain(search)
    other = set(s) - {"plate"}
    if other:
        raise ConfigError("lens.search", "only plate (a phase plate's search); spec, config and "
                          "trainable belong to a lens search", s)
    given = {} if s["plate"] is None else s["plate"]
    if not isinstance(given, dict):
        raise ConfigError("lens.search.plate", "null or a mapping of PlateSearchConfig fields",
                          given)
    known = [f.name for f in dataclasses.fields(PlateSearchConfig)]
    unknown = set(given) - set(known)
    if unknown:
        raise ConfigError.unknown("lens.search.plate", unknown, known)
    try:
        return PlateSearchConfig(**given)
    except ValueError as e:
        field = next((k for k in given if f" {k} " in f" {e} "), None)
        key = f"lens.search.plate.{field}" if field else "lens.search.plate"
        raise ConfigError(key, str(e).split(": ", 1)[-1], given.get(field, given)) from None


def _check_plate_search(lc) -> None:
    plate_search_config(lc.get("search"))
    if lc.get("plate_surface") is None:
        raise ConfigError.missing("lens.plate_surface", "the plate's surface index (to use "
                                  "lens.search.plate)")
    if lc.get("plate") not in (None, "learned"):
        raise ConfigError("lens.plate", "null or 'learned' with lens.search.plate (the search "
                          "sets the plate)", lc.get("plate"))
    if lc.get("learned_start_alpha_mm") is not None:
        raise ConfigError("lens.learned_start_alpha_mm", "null with lens.search.plate (the "
                          "plate starts from the search's)", lc.get("learned_start_alpha_mm"))
    prefix = f"surfaces.{lc.get('plate_surface')}.a."
    if not any(isinstance(t, str) and t.startswith(prefix)
               for t in (_plain(lc.get("trainable")) or [])):
        raise ConfigError("lens.trainable", f"some of the plate's coefficients ({prefix}*: what "
                          f"lens.search.plate searches)", _plain(lc.get("trainable")))


def search_dir(cfg: DictConfig) -> Path:
    """Where the search of ``cfg`` writes: ``<paths.output_dir>/search``."""
    return Path(cfg.paths.output_dir) / "search"


def _code_digest(files=None) -> str:
    """SHA-256 over the search package's sources (names and contents, sorted), or ``files``."""
    import deeplens.design.search as pkg

    if files is None:
        files = Path(pkg.__file__).resolve().parent.glob("*.py")
    h = hashlib.sha256()
    for f in sorted(files):
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return "sha256:" + h.hexdigest()


def search_key(cfg: DictConfig) -> dict:
    """What a search's result depends on: the spec and settings as used, the code's version."""
    from .. import __version__

    if is_plate_search(cfg.lens.search):
        return _plate_key(cfg)
    spec, config, _ = search_settings(cfg.lens.search, cfg.get("sensor"))
    return json.loads(json.dumps({"spec": spec.to_dict(), "config": config.to_dict(),
                                  "code": {"deeplens": __version__,
                                           "design.search": _code_digest()}}))


def _reusable(out: Path, key: dict) -> bool:
    best, rec = out / "best.json", out / RECORD
    if not (best.is_file() and rec.is_file()):
        return False
    try:
        r = json.loads(rec.read_text())
        return (isinstance(r, dict) and r.get("key") == key
                and r.get("best_digest") == digest_path(best))
    except (OSError, ValueError):
        return False


def searched_lens(cfg: DictConfig, out_dir=None, progress=print) -> Path:
    """The path of the searched lens of ``cfg`` (``lens.search``) in ``out_dir`` (default
    :func:`search_dir`): reused when its record's key matches (module docstring), else the
    search runs (progress lines through ``progress``) and its outputs are written."""
    from ..design.search import search, write_outputs

    out = search_dir(cfg) if out_dir is None else Path(out_dir)
    key = search_key(cfg)
    best = out / "best.json"
    if _reusable(out, key):
        progress(f"deeplens: reusing the searched lens {best}")
        return best
    if is_plate_search(cfg.lens.search):
        return _searched_plate(cfg, out, key, progress)
    spec, config, _ = search_settings(cfg.lens.search, cfg.get("sensor"))
    progress(f"deeplens: design search for lens.search.spec ({spec.elements} element(s), "
             f"f {spec.efl_mm:g} mm F/{spec.f_number:.3g}, HFOV {spec.hfov_deg:g} deg; "
             f"{config.starts} start(s), {config.hops} hop(s), seed {config.seed}) into {out}")
    result = search(spec, config, progress=lambda t: progress(f"deeplens: search: {t}"))
    out.mkdir(parents=True, exist_ok=True)
    (out / RECORD).unlink(missing_ok=True)   # from here on the folder is not reusable
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        write_outputs(tmp, result, spec)
        for f in sorted(tmp.iterdir()):
            os.replace(f, out / f.name)   # each file atomically, best.json among them
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    m = result.best.metrics
    write_text_atomic(out / RECORD, json.dumps(
        {"key": key, "best_digest": digest_path(best), "rms_um": m["rms_um"],
         "efl_mm": m["efl_mm"], "feasible": m["feasible"], "seconds": result.seconds},
        indent=1))
    progress(f"deeplens: searched lens {best}: RMS spot {m['rms_um']:.3g} um, EFL "
             f"{m['efl_mm']:.4g} mm, {'feasible' if m['feasible'] else 'INFEASIBLE'}, "
             f"{result.seconds:.0f} s")
    return best


def _plate_problem(cfg: DictConfig):
    """``(depths_mm, wavelengths_nm, pixel_mm, focus_wavelengths_nm)`` of a plate search: four
    depths uniform in 1/depth over ``scene.depths_mm`` (the ``classical`` variant's), the
    sensor's wavelengths (each once, in channel order), its pixel pitch, and every channel's
    wavelengths (with repeats, as training focuses the sensor)."""
    from ..render.sensor import Sensor

    lo, hi = (float(d) for d in cfg.scene.depths_mm)
    depths = [1.0 / (1.0 / lo + (1.0 / hi - 1.0 / lo) * k / 3) for k in range(4)]
    sc = cfg.sensor
    sensor = Sensor(tuple(sc.resolution), sc.pixel_size_mm,
                    channels=None if sc.channels is None else [list(c) for c in sc.channels])
    focus = [float(w) for ch in sensor.channels for w in ch]
    return depths, list(dict.fromkeys(focus)), float(sc.pixel_size_mm), focus


def _plate_sensor(cfg: DictConfig):
    """The run's sensor (float64: pixel grid, channels, noise) for the restoration merit."""
    import torch

    from ..render.sensor import Sensor

    sc = cfg.sensor
    return Sensor(tuple(sc.resolution), sc.pixel_size_mm,
                  channels=None if sc.channels is None else [list(c) for c in sc.channels],
                  full_well=float(sc.get("full_well", 0.0) or 0.0),
                  read_noise=float(sc.get("read_noise", 0.0) or 0.0)).to(torch.float64)


def _plate_key(cfg: DictConfig) -> dict:
    import deeplens.design.depth_invariance as di
    import deeplens.design.plate_search as ps
    import deeplens.design.restoration_merit as rm

    from .. import __version__

    lc = cfg.lens
    depths, waves, pixel, _ = _plate_problem(cfg)
    lens = {k: _plain(lc.get(k)) for k in ("path", "trainable", "plate_surface", "plate_order",
                                           "focus_mm", "table_options")}
    config = plate_search_config(lc.search)
    extra = {}
    if config.merit == "restoration":   # the merit reads the sensor's noise
        extra["sensor_noise"] = [float(cfg.sensor.get("full_well", 0.0) or 0.0),
                                 float(cfg.sensor.get("read_noise", 0.0) or 0.0)]
    return json.loads(json.dumps({
        "plate": config.to_dict(), "lens": lens,
        "lens_file": digest_path(lc.path), "depths_mm": depths, "wavelengths_nm": waves,
        "pixel_mm": pixel, **extra,
        "code": {"deeplens": __version__,
                 "plate_search": _code_digest([Path(ps.__file__), Path(di.__file__),
                                               Path(rm.__file__)])}}))


def _searched_plate(cfg: DictConfig, out: Path, key: dict, progress) -> Path:
    """Run the plate search of ``cfg`` and write ``best.json``, ``result.json`` and the record
    into ``out``; returns the path of ``best.json``."""
    from ..design.plate_search import describe_plate, plate_search
    from ..optics.io import save_lens

    lc = cfg.lens
    config = plate_search_config(lc.search)
    depths, waves, pixel, focus = _plate_problem(cfg)
    lens = build_lens(lc.path, trainable=list(lc.trainable), dtype="float64", plate="none",
                      plate_surface=lc.plate_surface,
                      table_options=_plain(lc.get("table_options")), focus_mm=lc.focus_mm,
                      plate_order=lc.get("plate_order"), focus_wavelengths_nm=focus)
    prefix = f"surfaces.{lc.plate_surface}.a."
    names = [n for n, p in lens.named_parameters() if p.requires_grad and n.startswith(prefix)]
    progress(f"deeplens: plate search over {len(names)} coefficients of surface "
             f"{lc.plate_surface} ({config.starts} Sobol starts + the zero plate, "
             f"{config.steps} DLS steps each, seed {config.seed}) into {out}")
    sensor = _plate_sensor(cfg) if config.merit == "restoration" else None
    result = plate_search(lens, int(lc.plate_surface), names, depths, waves, pixel, config,
                          progress=lambda t: progress(f"deeplens: plate search: {t}"),
                          sensor=sensor)
    terms = describe_plate(lens.surfaces[int(lc.plate_surface)])
    out.mkdir(parents=True, exist_ok=True)
    (out / RECORD).unlink(missing_ok=True)   # from here on the folder is not reusable
    best = out / "best.json"
    tmp = out / f".best.tmp-{os.getpid()}.json"
    save_lens(lens, tmp)
    os.replace(tmp, best)
    res = {"labels": result.labels, "blur_px": result.blur_px, "skipped": result.skipped,
           "seconds": result.seconds, "config": result.config,
           "designs": [dataclasses.asdict(d) for d in result.designs],
           "runs": [dataclasses.asdict(d) for d in result.runs],
           "plate_terms_mm_at_rim": [[m, c] for m, c in terms]}
    write_text_atomic(out / "result.json", json.dumps(res, indent=1))
    b = result.best
    write_text_atomic(out / RECORD, json.dumps(
        {"key": key, "best_digest": digest_path(best), "score": b.score,
         "invariance": b.invariance, "blur_px": b.blur_px, "psnr_db": b.psnr_db,
         "seconds": result.seconds}, indent=1))
    lead = ", ".join(f"{m} {c * 1e3:+.2f}" for m, c in terms[:4])
    what = (f"worst-depth expected PSNR {b.psnr_db:.2f} dB" if b.psnr_db is not None
            else f"invariance {b.invariance:.3g}, blur {b.blur_px:.2f} px")
    progress(f"deeplens: searched plate {best}: score {b.score:.4g} ({what}, from {b.origin}); "
             f"terms (um of sag at the rim) {lead}; {result.seconds:.0f} s")
    return best


def check_lens_config(cfg) -> None:
    """Start-up check of ``lens.*`` in a composed config (:func:`~.lens_setup.check_lens_settings`;
    ``lens.start`` and ``lens.search``: :func:`check_search_settings`)."""
    lc = cfg.lens
    opts = lc.get("table_options")
    check_lens_settings(lc.get("path"), plate=lc.get("plate"),
                        plate_surface=lc.get("plate_surface"),
                        plate_alpha_mm=lc.get("plate_alpha_mm", 0.0),
                        table_options=(OmegaConf.to_container(opts, resolve=True)
                                       if OmegaConf.is_config(opts) else opts),
                        focus_mm=lc.get("focus_mm"),
                        learned_start_alpha_mm=lc.get("learned_start_alpha_mm"),
                        plate_order=lc.get("plate_order"), dtype=lc.get("dtype", "float32"))
    check_search_settings(lc, cfg.get("sensor"))
