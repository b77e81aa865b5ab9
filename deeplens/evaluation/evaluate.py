"""``evaluate(cfg)``: compare optical variants, each with its own restorer, on one test set.

For every variant and every seed of ``eval.seeds`` a restorer is trained for that variant's lens
with the experiment's settings (same budget), then tested per depth (and per field band when
the scene defines ``field_bands``).  Variants (``eval.variants``):

* ``none``: the lens with its phase plate flattened (all coefficients zero), optics frozen;
* ``cubic``: the analytic cubic plate of Dowski and Cathey, ``z = α ((x/R)^3 + (y/R)^3)``,
  optics frozen; ``eval.cubic_alpha_mm`` is one α or a list (a sweep): one variant per α, named
  ``cubic@<α in µm>um``;
* ``learned``: the optics (``lens.trainable``) and the restorer trained jointly (or loaded from
  ``eval.learned_ckpt``, single seed);
* ``frozen``: the lens as in its file with no optics training (for lenses without a plate,
  e.g. the doublet: measures the optics' share of the gain against ``learned``);
* ``classical``: the optics designed first by the design engine (the same variables as
  ``learned``: a depth-invariant plate for a lens with a plate, the smallest RMS spot over the
  scene's fields otherwise; :mod:`deeplens.evaluation.classical`, ``eval.classical``), then frozen
  while the restorer trains;
* ``refined``: ``learned`` started from the ``classical`` design (the same variables trained
  jointly with the restorer from there): what joint training adds on top of the classical one;
* ``searched``: the lens the design search makes from ``lens.search.spec`` (searched
  classically, :mod:`deeplens.training.lens_search`), frozen while the restorer trains.  With
  ``lens.start=search``, ``learned`` trains ``lens.search.trainable`` jointly from that lens;
  ``frozen``, ``classical`` and ``refined`` stay the file's lens (``lens.path``).  The search
  runs once per evaluation folder (``<folder>/search``);
* ``perfect``: the ceiling: an aberration-free lens (an ideal thin lens with the experiment's
  focal length and F-number, in focus at the scene's depth: :mod:`.perfect`; geometric delta
  PSF, diffraction left out), frozen while the restorer trains with the same budget, sensor,
  noise and renderer.

Every number is the mean over seeds; ``± std`` is the sample standard deviation over seeds
(``n - 1``; 0 for a single seed).  A seed changes everything that is random (network
initialisation, training and test images, noise), so the spread covers them all; within one
seed every variant sees the same test images.

``eval.reuse_runs`` (default true): a variant x seed run that already finished in the output
folder with the same configuration and the same input files (its ``eval_run.json`` records the
configuration and the SHA-256 of every file it names, e.g. the lens file:
:mod:`deeplens.training.input_digest`) is loaded, not trained again, so an evaluation killed part-way resumes
(``hydra.run.dir=<its folder>``), and variants or seeds run as separate processes into one
folder are then gathered by one more call.  A damaged record or a missing or corrupt tested
checkpoint means "train again", with a message saying why.

``eval.test_folder`` (a folder of the user's own images) does not change what a run trains: the
runs are the same (and reused), each tested on the procedural test set and then on the folder's
centre crops; the table carries a second block for the folder.

Outputs (in ``eval.output``'s folder, each written atomically): ``eval_table.md`` (a row per
variant and image, a column per depth or band), ``eval_table.json`` (see :func:`summarize`),
and the figures of :mod:`deeplens.evaluation.figures` (``*.png``, also logged to TensorBoard
under ``<output folder>/tensorboard``).
"""

from __future__ import annotations

import copy
import json
import math
import os
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig, OmegaConf, open_dict

from ..build_info import describe_source
from ..data.datamodule import CenterCropFolderDataset
from ..optics.errors import ConfigError
from ..render.splat import point_source_rays, trace_to_sensor_pixels
from ..training.checkpoint import (CheckpointError, migrate_missing_buffers, read_checkpoint,
                                   write_text_atomic)
from ..training.input_digest import digest_path, input_digests
from ..training.lens_search import (is_plate_search, search_dir, search_trainable,
                                    searched_lens)
from ..training.machine import describe_machine, machine_info
from ..training.settings import MODEL_SETTINGS, completed
from ..training.train import build_objects, train
from ..training.train import check_config as check_training_config
from . import tolerance as tolerance_eval
from .classical import check_classical_config, design_classical
from .fanout import check_fanout_config, cpu_seconds, job_cfg
from .fanout_stop import watch_parent
from .figures import write_figures
from .perfect import PERFECT_LENS, write_perfect_lens
from .variants import _VARIANTS, _alphas, _plain, seeds, variants

__all__ = ["EVAL_CHECKS", "check_config", "check_eval_config", "evaluate", "format_table",
           "variants", "summarize", "psf_rms_px", "seeds"]

def _variant_cfg(cfg: DictConfig, name: str, kind: str | None = None,
                 alpha_mm: float | None = None, seed: int | None = None,
                 ) -> DictConfig:
    kind = kind or name
    c = copy.deepcopy(cfg)
    with open_dict(c):
        # <variant>/seed<s>: the same folder whichever other variants and seeds the call
        # holds, so that runs made by separate calls are found again (eval.reuse_runs)
        out = Path(cfg.paths.output_dir) / name.replace("@", "_")
        if seed is not None:
            c.seed = int(seed)
        out = out / f"seed{c.seed}"
        c.paths.output_dir = str(out)
        c.test = True
        if kind == "searched" or (kind == "learned" and cfg.lens.get("start") == "search"):
            # the design search's lens (lens_search.py), shared by the variants and seeds; the
            # spec stays in the run key (lens.search), with the content of best.json
            c.lens.path = str(search_dir(cfg) / "best.json")
            c.lens.trainable = [] if kind == "searched" else search_trainable(cfg)
            c.lens.search = {k: v for k, v in _plain(cfg.lens.search).items()
                             if k != "trainable" or kind == "learned"}
            if not is_plate_search(cfg.lens.search):  # a plate search keeps its plate
                # a searched lens has no phase plate (an EDOF config's searched variant)
                c.lens.plate = c.lens.plate_surface = c.lens.plate_order = None
            c.lens.learned_start_alpha_mm = None
        else:  # the file's lens: the search's settings do not change these runs
            c.lens.search = None
        c.lens.start = "file"
        if kind == "none":
            c.lens.plate, c.lens.trainable = "none", []
        elif kind == "cubic":
            c.lens.plate, c.lens.trainable = "cubic", []
            c.lens.plate_alpha_mm = float(_alphas(cfg)[0] if alpha_mm is None else alpha_mm)
        elif kind == "searched":
            pass  # set above
        elif kind == "perfect":  # the ceiling: an aberration-free lens (perfect.py)
            c.lens.path = str(perfect_dir(cfg) / PERFECT_LENS)
            c.lens.trainable, c.lens.focus_mm = [], None
            c.lens.plate = c.lens.plate_surface = c.lens.plate_order = None
            c.lens.learned_start_alpha_mm = None
            c.render.psf_model = "geometric"  # a delta PSF by construction (perfect.py)
        elif kind == "learned":
            if cfg.lens.plate_surface is not None:
                c.lens.plate = "learned"
        elif kind == "frozen":
            c.lens.trainable = []
        elif kind in ("classical", "refined"):  # the design engine's lens (classical.py)
            c.lens.path = str(classical_dir(cfg) / "classical_lens.json")
            c.lens.learned_start_alpha_mm = None  # a plate starts as designed, not cubic
            c.lens.plate = "learned" if cfg.lens.plate_surface is not None else None
            if kind == "classical":  # frozen; refined trains lens.trainable from there
                c.lens.trainable = []
        else:
            raise ConfigError("eval.variants", f"variants of {', '.join(_VARIANTS)}", kind)
    return c


def perfect_dir(cfg: DictConfig) -> Path:
    """The folder of the ``perfect`` variant, where its lens is written."""
    return Path(cfg.paths.output_dir) / "perfect"


def classical_dir(cfg: DictConfig) -> Path:
    """The folder of the ``classical`` variant, where its designed lens is written."""
    return Path(cfg.paths.output_dir) / "classical"


#: the record of one finished variant x seed run, in that run's output folder
RUN_RECORD = "eval_run.json"
#: config keys that do not change what a variant's run computes (where it writes, which other
#: variants and seeds the evaluation holds)
_NOT_IN_KEY = ("paths", "eval", "hydra", "task_name")


def _run_key(cfg: DictConfig) -> dict:
    key = {k: (OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v)
           for k, v in ((k, cfg[k]) for k in cfg if k not in _NOT_IN_KEY)}
    if key["lens"].get("start") == "file":  # the default: runs made before the key existed
        key["lens"].pop("start")
    if not key["lens"].get("trainable"):  # frozen optics: the optics' settings are unused
        for k in ("optics_lr_mm", "optics_warmup_steps", "optics_worst_depth",
                  "optics_invariance", "optics_psf_energy"):
            key["model"].pop(k, None)
        key["lens"].pop("learned_start_alpha_mm", None)
    key.get("data", {}).pop("test_folder", None)  # tested on it after training, not trained on
    # the content of the lens file and every other input (not the run's own outputs)
    key["inputs"] = input_digests(key, outputs=[cfg.paths.output_dir])
    return key


def _eval_folder_of(key: dict) -> str | None:
    """The evaluation folder a run key's run was made in: its ``trainer.default_root_dir`` is
    ``<folder>/<variant>/seed<s>`` (:func:`_variant_cfg`); ``None`` if the key has none."""
    trainer = key.get("trainer") if isinstance(key, dict) else None
    root = trainer.get("default_root_dir") if isinstance(trainer, dict) else None
    return str(Path(root).parent.parent) if isinstance(root, str) else None


def _relocated(x, folder: str | None):
    """``x`` with every string that is a path under ``folder`` written ``<eval>/...``
    (recursively), so that a run's key does not depend on where its folder lies."""
    if folder is None:
        return x
    if isinstance(x, dict):
        return {k: _relocated(v, folder) for k, v in x.items()}
    if isinstance(x, list):
        return [_relocated(v, folder) for v in x]
    if isinstance(x, str) and (x == folder or x.startswith(folder.rstrip("/") + "/")):
        return "<eval>" + x[len(folder.rstrip("/")):]
    return x


def _same_run(key: dict) -> dict:
    """A run key in a canonical form: nulls dropped (:func:`_drop_nulls`), paths inside the
    evaluation folder written relative to it (a folder moved, copied or linked elsewhere holds
    the same runs), and the module's dict settings given in part completed with their defaults
    (``{temperature: 0.25}`` and ``{temperature: 0.25, bins: 4, momentum: 0.9}`` are the same
    run)."""
    key = _drop_nulls(json.loads(json.dumps(key)))
    key = _relocated(key, _eval_folder_of(key))
    model = key.get("model") if isinstance(key, dict) else None
    if isinstance(model, dict):
        for name in MODEL_SETTINGS:   # worst_depth, ..., completed with their defaults
            if isinstance(model.get(name), dict):
                model[name] = completed(name, model[name])
    return key


def _drop_nulls(x):
    """``x`` without ``None`` entries of mappings (recursively): an option added later with a
    ``null`` default, meaning the old behaviour, does not make a finished run look different."""
    if isinstance(x, dict):
        return {k: _drop_nulls(v) for k, v in x.items() if v is not None}
    if isinstance(x, list):
        return [_drop_nulls(v) for v in x]
    return x


def _reuse(cfg: DictConfig):
    """``(metrics, objects)`` of a finished run of exactly this variant config in its output
    folder (its :data:`RUN_RECORD` and tested checkpoint), the module holding the tested
    weights; ``None`` when there is none or its config differs."""
    rec_path = Path(cfg.paths.output_dir) / RUN_RECORD
    if not rec_path.is_file():
        return None

    def again(why: str):
        print(f"deeplens eval: {rec_path} {why}: training again")

    try:
        rec = json.loads(rec_path.read_text())
        ok = (isinstance(rec, dict) and isinstance(rec.get("config"), dict)
              and isinstance(rec.get("metrics"), dict) and isinstance(rec.get("tested"), str))
        metrics = {k: float(v) for k, v in rec["metrics"].items()} if ok else None
    except (OSError, ValueError, TypeError, RecursionError) as e:
        return again(f"is damaged ({type(e).__name__}: {e})")
    if not ok:
        return again("is damaged (expected an object with 'config', 'metrics' and 'tested')")
    key = _run_key(cfg)
    if _same_run(rec["config"]) != _same_run(key):
        saved = rec["config"].get("inputs")
        saved = saved if isinstance(saved, dict) else {}
        changed = [k for k in dict.fromkeys([*saved, *key["inputs"]])
                   if saved.get(k) != key["inputs"].get(k)]
        return again(f"is a run of other input files (changed: {', '.join(changed)})" if changed
                     else "is a run of another configuration")
    tested = rec["tested"]
    was, now = _eval_folder_of(rec["config"]), _eval_folder_of(key)
    inside = _relocated(tested, was)
    if now is not None and inside != tested:
        # the folder was moved or copied: its checkpoint is where the folder is now
        tested = now.rstrip("/") + inside[len("<eval>"):]
    try:
        state = read_checkpoint(tested)["state_dict"]
    except (FileNotFoundError, CheckpointError) as e:
        return again(f"names a tested checkpoint that cannot be loaded ({e})")
    objs = build_objects(cfg)
    migrate_missing_buffers(state, objs["module"], tested)   # an earlier version's run
    objs["module"].load_state_dict(state)
    print(f"deeplens eval: reusing the finished run in {rec_path.parent}")
    return metrics, objs


def _run(cfg: DictConfig, ckpt: str | None, reuse: bool = False):
    """Train (or load ``ckpt``) and test one variant; returns ``(metrics, objects)``.

    With ``reuse``, a run of the same configuration that finished in the same output folder
    (an evaluation killed part-way and started again with ``hydra.run.dir`` set to its folder,
    or variants run as separate processes into one folder) is loaded instead of trained."""
    if ckpt is None:
        if reuse:
            done = _reuse(cfg)
            if done is not None:
                return done
        metrics, objs = train(cfg)
        tested = objs["tested"]  # None: tested with the final weights, nothing to reload
        if tested is not None:
            _atomic_write(Path(cfg.paths.output_dir) / RUN_RECORD, json.dumps(
                {"config": _run_key(cfg), "metrics": metrics, "tested": tested}, indent=1))
        return metrics, objs
    objs = build_objects(cfg)
    objs["trainer"].test(objs["module"], datamodule=objs["datamodule"], ckpt_path=ckpt,
                         verbose=False)
    return {k: float(v) for k, v in objs["trainer"].callback_metrics.items()}, objs


def _test_on_folder(cfg: DictConfig, objs: dict, folder) -> dict:
    """Test metrics of the module in ``objs`` (holding the tested weights) on the centre crops
    of ``folder`` (``eval.test_folder``), with the run's own data settings otherwise."""
    dm = hydra.utils.instantiate(cfg.data, test_folder=str(folder))
    objs["folder_datamodule"] = dm      # the evaluation's figures show these images
    trainer = objs["trainer"]
    trainer.test(objs["module"], datamodule=dm, verbose=False)
    return {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("test/")}


def _job(cfg: DictConfig, name: str, kind: str, alpha, seed: int):
    """Train (or reuse, or with ``eval.gather`` only load) and test one variant x seed."""
    vc = _variant_cfg(cfg, name, kind, alpha, seed=seed)
    gather = bool(cfg.eval.get("gather", False))
    if gather:
        done = _reuse(vc)
        if done is None:
            raise RuntimeError(f"eval.gather: no finished run of {name} seed {seed} with this "
                               f"configuration in {vc.paths.output_dir}")
        return done
    if kind in ("classical", "refined"):
        fc = copy.deepcopy(cfg)  # the file's lens: its design does not depend on lens.search
        with open_dict(fc):
            fc.lens.pop("start", None)
            fc.lens.pop("search", None)
        design_classical(fc, classical_dir(cfg))
    if kind == "searched" or (kind == "learned" and cfg.lens.get("start") == "search"):
        searched_lens(cfg, search_dir(cfg))
    if kind == "perfect":
        write_perfect_lens(cfg, perfect_dir(cfg))
    ckpt = cfg.eval.learned_ckpt if kind == "learned" else None
    torch.manual_seed(seed)
    return _run(vc, ckpt, reuse=bool(cfg.eval.get("reuse_runs", True)))


def provenance(cfg: DictConfig) -> str:
    """One line: the renderer, threads, CPU capability, the deeplens version and commit (of
    the imported package, whatever the working directory: :mod:`deeplens.build_info`) and
    CPU time so far."""
    psf_model = cfg.render.get("psf_model", None)
    render = (f"render.psf_model={psf_model}" if psf_model is not None
              else "geometric ray-traced PSFs (no render.psf_model)")
    return (f"renderer: {render}, render.kind={cfg.render.get('kind', '?')}; "
            f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, torch threads "
            f"{torch.get_num_threads()}, CPU {torch.backends.cpu.get_cpu_capability()}; "
            f"{describe_source()}; CPU time {cpu_seconds() / 60:.1f} min (this process and its "
            f"jobs)")


def psf_rms_px(lens, sensor, depth_mm: float, n_rays: int = 4096, seed: int = 0) -> float:
    """Geometric rms radius (pixels) of the on-axis PSF at ``depth_mm``, about its centroid,
    averaged over the sensor's wavelengths (each channel's wavelengths, equally weighted)."""
    vals = []
    with torch.no_grad():
        for ch in sensor.channels:
            for w in ch:
                rays = point_source_rays(lens, (0.0, 0.0), depth_mm, float(w), n_rays, seed)
                i, j, valid = trace_to_sensor_pixels(lens, sensor, rays)
                if not bool(valid.any()):
                    raise ValueError(f"psf_rms_px: no on-axis ray at {depth_mm:g} mm and "
                                     f"{float(w):g} nm reaches the sensor")
                i, j = i[valid].double(), j[valid].double()
                vals.append(float(((i - i.mean()) ** 2 + (j - j.mean()) ** 2).mean().sqrt()))
    return sum(vals) / len(vals)


def _columns(cfg: DictConfig) -> list[tuple[str, str]]:
    """``(label, metric suffix)`` of every table column: depths, then field bands."""
    cols = [(f"{d:g}", f"d{d:g}mm") for d in cfg.scene.val_depths_mm]
    fb = cfg.scene.field_bands
    if fb is not None:
        fb = list(fb)
        cols += [(f"band {fb[k]:g}-{fb[k + 1]:g}", f"band{fb[k]:g}-{fb[k + 1]:g}")
                 for k in range(len(fb) - 1)]
    return cols


def _stats(values: list[float]) -> tuple[float, float]:
    n = len(values)
    m = sum(values) / n
    sd = math.sqrt(sum((v - m) ** 2 for v in values) / (n - 1)) if n > 1 else 0.0
    return m, sd


def summarize(runs: dict[str, list[dict]], depths, bands=None, psf_rms=None) -> dict:
    """Per-variant summary of test metrics over seeds.

    Args:
        runs: ``{variant: [metrics of seed 0, metrics of seed 1, ...]}`` (the test metrics, keys
            ``test/{psnr,ssim}_{sensor,restored}/d<depth>mm`` and ``.../band<lo>-<hi>``).
        depths: test depths (mm).
        bands: field-band edges or ``None``.
        psf_rms: ``{variant: {depth: rms px}}`` or ``None``.

    Returns:
        ``{variant: {"sensor"|"restored": {depth_mm: {"psnr", "psnr_std", "ssim", "ssim_std"}},
        "mean": {...restored, averaged over depths}, "sensor_mean": {...}, "worst": {"depth_mm", ...restored at the
        depth of lowest mean PSNR}, "spread_db": max - min restored PSNR over depths,
        "psf_rms_px": {depth_mm: value}, "seeds": n, ["sensor_bands"|"restored_bands": {band:
        {...}}]}}``.  Depth keys are strings of the depth in mm (JSON keys).
    """
    out = {}
    for v, seeds_metrics in runs.items():
        entry: dict = {"seeds": len(seeds_metrics)}

        def cell(key_psnr, key_ssim):
            p = _stats([m[key_psnr] for m in seeds_metrics])
            s = _stats([m[key_ssim] for m in seeds_metrics])
            return {"psnr": p[0], "psnr_std": p[1], "ssim": s[0], "ssim_std": s[1]}

        for img in ("sensor", "restored"):
            entry[img] = {f"{d:g}": cell(f"test/psnr_{img}/d{d:g}mm", f"test/ssim_{img}/d{d:g}mm")
                          for d in depths}
            if bands is not None:
                entry[f"{img}_bands"] = {
                    f"{bands[k]:g}-{bands[k + 1]:g}": cell(
                        f"test/psnr_{img}/band{bands[k]:g}-{bands[k + 1]:g}",
                        f"test/ssim_{img}/band{bands[k]:g}-{bands[k + 1]:g}")
                    for k in range(len(bands) - 1)}
        # the mean over depths of each seed, then its spread over seeds
        for img, key in (("restored", "mean"), ("sensor", "sensor_mean")):
            p = _stats([sum(m[f"test/psnr_{img}/d{d:g}mm"] for d in depths) / len(depths)
                        for m in seeds_metrics])
            q = _stats([sum(m[f"test/ssim_{img}/d{d:g}mm"] for d in depths) / len(depths)
                        for m in seeds_metrics])
            entry[key] = {"psnr": p[0], "psnr_std": p[1], "ssim": q[0], "ssim_std": q[1]}
        r = entry["restored"]
        worst = min(r, key=lambda k: r[k]["psnr"])
        entry["worst"] = {"depth_mm": float(worst), **r[worst]}
        entry["spread_db"] = max(c["psnr"] for c in r.values()) - r[worst]["psnr"]
        if psf_rms is not None and v in psf_rms:
            entry["psf_rms_px"] = {f"{d:g}": psf_rms[v][d] for d in depths}
        out[v] = entry
    return out


def format_table(summary: dict, columns: list[tuple[str, str]]) -> str:
    """Markdown table: a row per variant and image (sensor, restored), a column per depth or
    band and the mean over depths; cells ``PSNR ± std / SSIM`` (± only with several seeds)."""
    head = ("| variant | image | " + " | ".join(
        f"{float(lab) / 1000:g} m" if not lab.startswith("band") else lab for lab, _ in columns)
        + " | mean over depths |")
    rows = [head, "|---|---|" + "---|" * (len(columns) + 1)]
    for v, e in summary.items():
        multi = e["seeds"] > 1

        def fmt(c):
            pm = f" ± {c['psnr_std']:.2f}" if multi else ""
            return f"{c['psnr']:.2f}{pm} / {c['ssim']:.3f}"

        for img in ("sensor", "restored"):
            cells = []
            for lab, suffix in columns:
                if suffix.startswith("band"):
                    cells.append(fmt(e[f"{img}_bands"][lab[len("band "):]]))
                else:
                    cells.append(fmt(e[img][lab]))
            cells.append(fmt(e["mean" if img == "restored" else "sensor_mean"]))
            rows.append(f"| {v} | {img} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def _atomic_write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, text)


def _check_test_folder(folder, image_size) -> None:
    """Read every image of ``eval.test_folder`` once before anything trains."""
    try:
        ds = CenterCropFolderDataset(folder, image_size)
        for k in range(len(ds)):
            ds[k]
    except (FileNotFoundError, RuntimeError) as err:
        raise type(err)(f"eval.test_folder: {err}") from None


def check_eval_config(cfg: DictConfig) -> None:
    """Start-up check of ``eval.*`` (nothing when the config has no ``eval``): the variants
    and cubic plates, the seeds (one with ``eval.learned_ckpt``), the classical design's
    settings (:mod:`.classical`), the tolerance test's (:mod:`.tolerance`) and the
    fan-out's (:mod:`.fanout`); raises :class:`~deeplens.optics.errors.ConfigError` naming
    the key.  Run by :func:`check_config` (:data:`EVAL_CHECKS`)."""
    if cfg.get("eval") is None:
        return
    variants(cfg)
    seed_list = seeds(cfg)
    if cfg.eval.get("learned_ckpt") is not None and len(seed_list) > 1:
        raise ConfigError("eval.seeds", "a single seed with eval.learned_ckpt (one trained "
                          "run)", seed_list)
    check_classical_config(cfg)
    tolerance_eval.check_tolerance_eval_config(cfg)
    check_fanout_config(cfg)


#: the evaluation's validators of its own keys, run by :func:`check_config` after the training
#: floor's (:data:`deeplens.training.train.STARTUP_CHECKS`)
EVAL_CHECKS = (check_eval_config,)


def check_config(cfg: DictConfig) -> None:
    """The one start-up check of an evaluation's composed config: the training floor's
    (:func:`deeplens.training.train.check_config`) with :data:`EVAL_CHECKS` (``eval.*``) run
    after its validators, before the sizes; raises
    :class:`~deeplens.optics.errors.ConfigError` naming the key."""
    check_training_config(cfg, extra=EVAL_CHECKS)


def evaluate(cfg: DictConfig) -> tuple[str, dict]:
    """Train/test each variant for each seed; write the markdown and JSON tables and the
    figures; return ``(markdown table, summary)`` (see :func:`summarize`)."""
    check_config(cfg)  # every key, before anything is read or trained (train.py)
    if cfg.eval.get("job") is not None:  # one variant x seed of a fan-out (fanout.py)
        jc, (name, kind, alpha, s) = job_cfg(cfg)
        watch_parent()   # stop when the evaluation that fanned the job out is gone (kill -9)
        _job(jc, name, kind, alpha, s)
        return "", {}
    todo = variants(cfg)
    seed_list = seeds(cfg)
    if any(k in ("classical", "refined") for _, k, _ in todo) and not list(cfg.lens.trainable):
        # not in check_eval_config: a classical variant's own config has no trainable terms
        raise ConfigError("lens.trainable", "the variables the classical variant designs "
                          "(eval.variants has classical or refined), not an empty list", [])
    if cfg.eval.test_folder is not None:
        _check_test_folder(cfg.eval.test_folder, cfg.data.image_size)
    tol = tolerance_eval.EvalTolerance.from_cfg(cfg)  # checked before anything trains
    depths = [float(d) for d in cfg.scene.val_depths_mm]
    bands = None if cfg.scene.field_bands is None else [float(b) for b in cfg.scene.field_bands]
    runs: dict[str, list[dict]] = {}
    folder_runs: dict[str, list[dict]] = {}
    psf_rms: dict[str, dict[float, float]] = {}
    keep: dict[str, dict] = {}
    for name, kind, alpha in todo:
        runs[name], folder_runs[name] = [], []
        rms_seeds = []
        for s in seed_list:
            metrics, objs = _job(cfg, name, kind, alpha, s)
            runs[name].append(metrics)
            if cfg.eval.test_folder is not None:
                vc = _variant_cfg(cfg, name, kind, alpha, seed=s)
                folder_runs[name].append(_test_on_folder(vc, objs, cfg.eval.test_folder))
            module = objs["module"]
            rms_seeds.append({d: psf_rms_px(module.lens, module.sensor, d) for d in depths})
            tol.run(name, objs)
            if s == seed_list[0]:
                # the figures show the test set the table ends with: the user's images when
                # eval.test_folder is set, else the procedural textures
                keep[name] = {"module": module, "kind": kind,
                              "datamodule": objs.get("folder_datamodule", objs["datamodule"])}
        psf_rms[name] = {d: sum(r[d] for r in rms_seeds) / len(rms_seeds) for d in depths}
    summary = summarize(runs, depths, bands, psf_rms)
    table = format_table(summary, _columns(cfg))
    out = Path(cfg.eval.output)
    cubic = [a for _, kind, a in todo if kind == "cubic"]
    plates = (f"cubic plate alpha = {', '.join(f'{a * 1e3:g}' for a in cubic)} um (sag at the "
              f"rim); " if cubic else "")
    machine = machine_info()
    text = (f"# Optical variants, each with its own restorer ({cfg.task_name})\n\n"
            f"seeds {seed_list} (mean ± std over seeds); {plates}PSNR (dB) / SSIM; "
            f"{describe_machine(machine)}\n\n{provenance(cfg)}\n\n"
            f"## Test set: {cfg.data.test_size} procedural textures\n\n{table}\n")
    record = {"task": str(cfg.task_name), "seeds": seed_list, "machine": machine,
              "variants": summary}
    if cfg.eval.test_folder is not None:
        folder_summary = summarize(folder_runs, depths, bands)
        folder_table = format_table(folder_summary, _columns(cfg))
        head = f"## Test set: the images of {cfg.eval.test_folder} (centre crops)"
        text += f"\n{head}\n\n{folder_table}\n"
        table += f"\n\n{head}\n\n{folder_table}"
        record["test_folder"] = {"path": str(cfg.eval.test_folder),
                                 "digest": digest_path(cfg.eval.test_folder),
                                 "variants": folder_summary}
    text += tol.markdown(_columns(cfg))
    record.update(tol.json())
    _atomic_write(out, text)
    _atomic_write(out.with_suffix(".json"), json.dumps(record, indent=2))
    tol.figures(out.parent, bool(cfg.eval.figures))
    if cfg.eval.figures:
        folder = cfg.eval.test_folder
        shown = summary if folder is None else {  # the textures' PSF sizes pick the focus
            v: {**e, "psf_rms_px": summary[v].get("psf_rms_px")} for v, e in folder_summary.items()}
        figs = write_figures(shown, keep, depths,
                             out.parent, plate_surface=cfg.lens.plate_surface,
                             test_set=(f"{cfg.data.test_size} procedural textures"
                                       if folder is None else f"the images of {folder}"))
        print(f"deeplens eval: figures {', '.join(p.name for p in figs)} in {out.parent}")
    print(f"deeplens eval: table in {out} and {out.with_suffix('.json')}")
    return table, summary
