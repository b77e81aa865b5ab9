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
from .checkpoint import write_text_atomic
from .input_digest import digest_path

__all__ = ["START_CHOICES", "SEARCH_KEYS", "search_settings", "check_search_settings",
           "searched_lens", "search_trainable", "search_dir", "RECORD"]

#: the values of ``lens.start``
START_CHOICES = ("file", "search")
#: the keys of ``lens.search``
SEARCH_KEYS = ("spec", "config", "trainable")
#: the stage fields of a SearchConfig, and the keys of one stage
_STAGE_FIELDS = ("screen", "flat_screen", "polish", "hop")
_STAGE_KEYS = ("steps", "sampling", "aperture", "field", "rounds", "method")
#: the file holding the key of the search in its folder
RECORD = "search_record.json"


def _plain(v):
    return OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v


def _int(v, lo: int) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= lo


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
             "score_sampling": (lambda v: isinstance(v, str) and v, "a pupil sampling such as "
                                "'hexapolar:6'"),
             "final_sampling": (lambda v: isinstance(v, str) and v, "a pupil sampling such as "
                                "'hexapolar:12'")}
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
    """``lens.search.trainable`` of ``cfg`` (checked)."""
    return search_settings(cfg.lens.search, cfg.get("sensor"))[2]


def search_dir(cfg: DictConfig) -> Path:
    """Where the search of ``cfg`` writes: ``<paths.output_dir>/search``."""
    return Path(cfg.paths.output_dir) / "search"


def _code_digest() -> str:
    """SHA-256 over the search package's sources (names and contents, sorted)."""
    import deeplens.design.search as pkg

    root = Path(pkg.__file__).resolve().parent
    h = hashlib.sha256()
    for f in sorted(root.glob("*.py")):
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return "sha256:" + h.hexdigest()


def search_key(cfg: DictConfig) -> dict:
    """What a search's result depends on: the spec and settings as used, the code's version."""
    from .. import __version__

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
