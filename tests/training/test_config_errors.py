"""One config-validation layer, one message format (issue 24).

Every bad value of a composed config (the real Hydra configs, ``configs/``) fails in
:func:`deeplens.training.train.check_config` (``eval.*``: :func:`deeplens.evaluation.evaluate.check_config`), before any lens, sensor, network, data module or
trainer is built, with a :class:`~deeplens.optics.errors.ConfigError` whose message is
``"{key}: expected {expected}, got {got!r}"`` (``"{key}: missing; expected ..."``,
``"{key}: unknown key(s) [...]; expected some of [...]"``) and whose ``key`` is the full
dotted config key.  The table has at least one row per validator of
:data:`~deeplens.training.train.STARTUP_CHECKS` (and of the type and rule tables); removing a
validator from the start-up checker makes its rows pass unnoticed, which
:func:`test_every_startup_validator_is_needed` shows for each one.
"""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import pytest

from deeplens.evaluation import evaluate as eval_mod
from deeplens.optics.errors import ConfigError, format_config_error
from deeplens.training import train as train_mod

ROOT = Path(__file__).resolve().parents[2]
TXT = ROOT / "tests" / "data" / "lenses" / "LA1131.txt"
EDOF = ("experiment=edof",)
DOUBLET = ("experiment=doublet",)
SEARCH = ("experiment=doublet_search",)
EVAL = "eval.yaml"

# (validator, overrides, config, key, kind, what the expected part must say)
# validator: the function of STARTUP_CHECKS whose key it is ("types" and "rules": the tables
# of train.py itself, run before STARTUP_CHECKS)
CASES = [
    # train.py: types and rules of the keys no room owns
    ("types", (*EDOF, "data.batch_size=abc"), None, "data.batch_size", "value", "int"),
    ("types", (*EDOF, "~data.val_size"), None, "data.val_size", "missing", "int"),
    ("types", (*EDOF, "seed=null"), None, "seed", "value", "int"),
    ("rules", (*EDOF, "seed=-1"), None, "seed", "value", r"int in \[0, 4294967295\]"),
    ("rules", (*EDOF, "scene.depths_mm=[0,1000]"), None, "scene.depths_mm", "value",
     "distances > 0 mm"),
    ("rules", (*EDOF, "render.kind=raytrace"), None, "render.kind", "value", "'mc' or 'psf'"),
    # lens_search.check_lens_config
    ("check_lens_config", (*EDOF, "lens.dtype=float16"), None, "lens.dtype", "value",
     "'float32' or 'float64'"),
    ("check_lens_config", (*EDOF, "lens.focus_mm=-5"), None, "lens.focus_mm", "value",
     "a depth > 0 mm"),
    ("check_lens_config", (*EDOF, "lens.plate_order=13"), None, "lens.plate_order", "value",
     r"an int in \[1, 12\]"),
    ("check_lens_config", (*EDOF, "lens.plate=cubic", "lens.plate_surface=null"), None,
     "lens.plate_surface", "missing", "to use lens.plate"),
    ("check_lens_config", (*DOUBLET, f"lens.path={TXT}", "+lens.table_options.stop_indx=1"),
     None, "lens.table_options", "unknown", "stop_index"),
    # lens_search.check_search_settings (through check_lens_config): lens.start, lens.search
    ("check_lens_config", (*SEARCH, "lens.start=sarch"), None, "lens.start", "value",
     "'file' .* or 'search'"),
    ("check_lens_config", (*DOUBLET, "lens.start=search"), None, "lens.search", "missing",
     "spec, config and trainable"),
    ("check_lens_config", (*SEARCH, "+lens.search.spek={}"), None, "lens.search", "unknown",
     "'spec'"),
    ("check_lens_config", (*SEARCH, "lens.search.spec.fno=-2"), None, "lens.search.spec.fno",
     "value", "positive"),
    ("check_lens_config", (*SEARCH, "lens.search.spec.elements=9"), None,
     "lens.search.spec.elements", "value", "1..8"),
    ("check_lens_config", (*SEARCH, "+lens.search.spec.focal_mm=10"), None,
     "lens.search.spec.focal_mm", "value", "unknown spec field"),
    ("check_lens_config", (*SEARCH, "lens.search.spec.glasses=N-BK8"), None,
     "lens.search.spec.glasses", "value", "N-BK8"),
    ("check_lens_config", (*SEARCH, "lens.search.config.starts=0"), None,
     "lens.search.config.starts", "value", "integer >= 1"),
    ("check_lens_config", (*SEARCH, "+lens.search.config.startz=2"), None,
     "lens.search.config", "unknown", "'starts'"),
    ("check_lens_config", (*SEARCH, "lens.search.config.screen=[{stepz:2}]"), None,
     r"lens.search.config.screen[0]", "unknown", "'steps'"),
    ("check_lens_config", (*SEARCH, "lens.search.config.polish=[{steps:2,method:newton}]"),
     None, r"lens.search.config.polish[0].method", "value", "'dls' or 'lbfgs'"),
    ("check_lens_config", (*SEARCH, "lens.search.trainable=[1]"), None,
     "lens.search.trainable", "value", "globs of the searched lens"),
    ("check_lens_config", (*SEARCH, "lens.plate_surface=2"), None, "lens.plate_surface",
     "value", "null with lens.start=search"),
    ("check_lens_config", (*SEARCH, f"lens.path={TXT}", "lens.table_options.scale=2.0"), None,
     "lens.table_options", "value", "null options with lens.start=search"),
    # train._check_channels
    ("_check_channels", (*EDOF, "sensor.channels=[[486.1],[656.3]]"), None, "sensor.channels",
     "value", "1 channel"),
    ("_check_channels", (*EDOF, "net.in_channels=1"), None, "net.in_channels", "value",
     "3 or null"),
    # train._check_render
    ("_check_render", (*EDOF, "render.compile=fastest"), None, "render.compile", "value",
     "'surface' or 'lens'"),
    ("_check_render", (*EDOF, "render.psf_model=wave"), None, "render.psf_model", "value",
     "one of geometric, diffraction, auto"),
    ("_check_render", (*EDOF, "render.kind=mc", "render.psf_model=diffraction"), None,
     "render.psf_model", "value", "diffraction needs render=psf"),
    # module_config.check_model_config (with depth_weighting and wiener)
    ("check_model_config", (*EDOF, "model.net_lr=2.0"), None, "model.net_lr", "value",
     r"\(0, 1\]"),
    ("types", (*EDOF, "model.optics_lr_mm=fast"), None, "model.optics_lr_mm", "value",
     "float"),  # a wrong type: the type table, before the module's own check
    ("check_model_config", (*EDOF, "+model.loss.mse2=1.0"), None, "model.loss", "unknown",
     "'mse'"),
    ("check_model_config", (*EDOF, "model.loss.ssim=-0.1"), None, "model.loss.ssim", "value",
     "finite weight >= 0"),
    ("check_model_config", (*EDOF, "model.loss.adversarial=0.1"), None,
     "model.loss.adversarial", "value", "without a discriminator"),
    ("check_model_config", (*EDOF, "model.optics_warmup_steps=-1"), None,
     "model.optics_warmup_steps", "value", "integer >= 0"),
    ("check_model_config", (*EDOF, "scene.margin=5"), None, "scene.margin", "value",
     r"\[0, 4\]"),
    ("check_model_config", (*EDOF, "model.worst_depth={bins:0}"), None,
     "model.worst_depth.bins", "value", "integer >= 1"),
    ("check_model_config", (*DOUBLET, "model.optics_worst_depth={temp:1}"), None,
     "model.optics_worst_depth", "unknown", "'temperature'"),
    ("check_model_config", (*EDOF, "model.deconvolution={depths:0}"), None,
     "model.deconvolution.depths", "value", "integer >= 1"),
    ("check_model_config", (*EDOF, "model.deconvolution={nsr:1.0e30}"), None,
     "model.deconvolution.nsr", "value", "float32 lens can hold"),
    ("check_model_config", (*DOUBLET, "model.deconvolution={nrs:0.1}"), None,
     "model.deconvolution", "unknown", "'nsr'"),
    # tolerance.check_tolerance_config (optics/tolerance_model's parser)
    ("check_tolerance_config", (*DOUBLET, "tolerance=precision",
                                "tolerance.decenter={shape:normal,std:-1}"), None,
     "tolerance.decenter.std", "value", "finite number >= 0"),
    ("check_tolerance_config", (*DOUBLET, "+tolerance.decentre={shape:normal,std:0.01}"),
     None, "tolerance", "unknown", "'decenter'"),
    ("check_tolerance_config", (*DOUBLET, "tolerance=precision",
                                "tolerance.compensator=centre"), None,
     "tolerance.compensator", "value", "refocus, center"),
    ("check_tolerance_config", (*DOUBLET, "model.calibrate=distortion"), None,
     "model.calibrate", "value", "null without model.tolerance_training"),
    ("check_tolerance_config", (*DOUBLET, "tolerance=precision", "model.tolerance_training=true",
                                "model.calibrate=warp"), None,
     "model.calibrate", "value", "one of distortion"),
    ("check_tolerance_config", (*EDOF, "tolerance=precision", "model.tolerance_training=true",
                                "model.calibrate=distortion"), None,
     "model.calibrate", "value", "a single training depth"),
    ("check_tolerance_config", (*DOUBLET, "model.tolerance_training=true"), None,
     "model.tolerance_training", "value", "non-zero tolerance"),
    # callbacks.check_callbacks_config
    ("check_callbacks_config", (*EDOF, "callbacks.image_logger.depths_mm=[0.0]"), None,
     "callbacks.image_logger.depths_mm", "value", "distances > 0 mm"),
    ("check_callbacks_config", (*EDOF, "callbacks.image_logger.every_n_epochs=0"), None,
     "callbacks.image_logger.every_n_epochs", "value", "int >= 1"),
    ("check_callbacks_config", (*EDOF, "+callbacks.image_logger.colour=1"), None,
     "callbacks.image_logger", "unknown", "'psf_rays'"),
    # evaluation: evaluate.check_eval_config (with classical, tolerance, fanout), the
    # evaluation floor's own validator (EVAL_CHECKS), run by evaluate.check_config
    ("check_eval_config", (*EDOF, "eval.variants=[none,cubicc]"), EVAL, "eval.variants", "value",
     "variants of none"),
    ("check_eval_config", (*DOUBLET, "eval.variants=[none]"), EVAL, "eval.variants", "value",
     "without a phase plate"),
    ("check_eval_config", (*EDOF, "eval.cubic_alpha_mm=[0.01,big]"), EVAL, "eval.cubic_alpha_mm",
     "value", "list of numbers"),
    ("check_eval_config", (*DOUBLET, "eval.variants=[searched]"), EVAL, "lens.search", "missing",
     "searched"),
    ("check_eval_config", (*EDOF, "eval.seeds=[0,0]"), EVAL, "eval.seeds", "value", "distinct"),
    ("check_eval_config", (*EDOF, "eval.seeds=[0,1]", "eval.learned_ckpt=x.ckpt"), EVAL,
     "eval.seeds", "value", "a single seed with eval.learned_ckpt"),
    ("check_eval_config", (*EDOF, "+eval.classical.stpes=3"), EVAL, "eval.classical", "unknown",
     "'steps'"),
    ("check_eval_config", (*EDOF, "eval.classical.steps=0"), EVAL, "eval.classical.steps", "value",
     "integer >= 1"),
    ("check_eval_config", (*DOUBLET, "eval.tolerance=precision", "eval.tolerance_samples=0"), EVAL,
     "eval.tolerance_samples", "value", "integer >= 1"),
    ("check_eval_config", (*DOUBLET, "eval.tolerance=precise"), EVAL, "eval.tolerance", "value",
     "a tolerance group"),
    ("check_eval_config", (*DOUBLET, "eval.tolerance=precision", "eval.calibrate=distorsion"), EVAL,
     "eval.calibrate", "value", "null .* or one of distortion"),
    ("check_eval_config", (*DOUBLET, "eval.calibrate=distortion"), EVAL, "eval.calibrate", "value",
     "null without eval.tolerance"),
    ("check_eval_config", (*EDOF, "eval.launcher=dask"), EVAL, "eval.launcher", "value",
     "joblib"),
    ("check_eval_config", (*EDOF, "eval.launcher=joblib", "eval.n_jobs=0"), EVAL, "eval.n_jobs",
     "value", "integer >= 1"),
    ("check_eval_config", (*EDOF, "eval.job=99", "eval.folder=x"), EVAL, "eval.job", "value",
     r"integer in \[0, "),
    ("check_eval_config", (*EDOF, "eval.job=0"), EVAL, "eval.folder", "missing", "output folder"),
]

_SHAPES = {"value": r"^{key}: expected .*{exp}.*, got .+$",
           "missing": r"^{key}: missing; expected .*{exp}.*$",
           "unknown": r"^{key}: unknown key\(s\) \[.+\]; expected some of \[.*{exp}.*\]$"}


def _ids():
    return [f"{c[0]}:{c[3]}:{c[4]}:{i}" for i, c in enumerate(CASES)]


def _compose(cfg_factory, case):
    _, overrides, config, *_ = case
    return cfg_factory(*overrides, config_name=config or "train.yaml")


def _assert_error(err: ConfigError, case) -> None:
    *_, key, kind, exp = case
    assert isinstance(err, ValueError)
    assert (err.key, err.kind) == (key, kind), str(err)
    assert str(err) == format_config_error(err.key, err.expected, err.got, err.kind)
    assert re.match(_SHAPES[kind].format(key=re.escape(key), exp=exp), str(err)), str(err)


@pytest.fixture
def nothing_built(monkeypatch):
    """Every builder of :func:`~deeplens.training.train.build_objects` fails if called."""
    import hydra
    import lightning

    def boom(*a, **k):
        raise AssertionError("something was built before the config was checked")

    for name in ("build_lens", "Sensor", "build_camera", "build_renderer", "preflight"):
        monkeypatch.setattr(train_mod, name, boom)
    monkeypatch.setattr(hydra.utils, "instantiate", boom)
    monkeypatch.setattr(lightning, "seed_everything", boom)


def _is_eval_row(case) -> bool:
    return case[0] in {c.__name__ for c in eval_mod.EVAL_CHECKS}


@pytest.mark.parametrize("case", CASES, ids=_ids())
def test_bad_config_fails_at_startup_in_one_format(cfg_factory, nothing_built, case):
    cfg = _compose(cfg_factory, case)
    with pytest.raises(ConfigError) as e:
        # eval.* is the evaluation floor's: evaluate() checks it (with everything else) first
        (eval_mod.evaluate if _is_eval_row(case) else train_mod.build_objects)(cfg)
    _assert_error(e.value, case)


def test_every_startup_validator_is_needed(cfg_factory, monkeypatch):
    """Mutation check: with any one validator taken out of ``STARTUP_CHECKS`` (or of the
    evaluation's ``EVAL_CHECKS``), the table's rows of that validator are no longer caught with
    their key (so the table test fails)."""
    for mod, attr in ((train_mod, "STARTUP_CHECKS"), (eval_mod, "EVAL_CHECKS")):
        checks = getattr(mod, attr)
        names = {c.__name__ for c in checks}
        assert names <= {c[0] for c in CASES}, "a start-up validator without a row in the table"
        for dropped in checks:
            monkeypatch.setattr(mod, attr, tuple(c for c in checks if c is not dropped))
            rows = [c for c in CASES if c[0] == dropped.__name__]
            missed = 0
            for case in rows:
                try:
                    eval_mod.check_config(_compose(cfg_factory, case))
                except ConfigError as err:
                    missed += err.key != case[3]
                else:
                    missed += 1
            assert missed >= 1, f"{dropped.__name__} removed, yet its rows still fail"
        monkeypatch.setattr(mod, attr, checks)


def test_shipped_experiments_pass(cfg_factory):
    for exp in ("edof", "doublet", "doublet_search"):
        train_mod.check_config(cfg_factory(f"experiment={exp}", tiny=False))
        eval_mod.check_config(cfg_factory(f"experiment={exp}", tiny=False, config_name=EVAL))


def test_eval_checks_every_key_before_anything_runs(cfg_factory, monkeypatch):
    """``evaluate`` and ``deeplens eval`` (with a fan-out) check first: nothing trains, no job
    is fanned out."""
    from deeplens.evaluation import entry, evaluate, fanout

    def boom(*a, **k):
        raise AssertionError("ran before the config was checked")

    monkeypatch.setattr(evaluate, "_job", boom)
    monkeypatch.setattr(fanout, "fan_out", boom)
    cfg = cfg_factory(*EDOF, "model.deconvolution={depths:0}", config_name=EVAL)
    with pytest.raises(ConfigError, match=r"^model\.deconvolution\.depths: expected"):
        evaluate.evaluate(cfg)
    cfg = cfg_factory(*DOUBLET, "eval.variants=[frozen,classical]", "lens.trainable=[]",
                      config_name=EVAL)
    with pytest.raises(ConfigError, match=r"^lens\.trainable: expected the variables the "
                                          r"classical variant designs .*, got \[\]$"):
        evaluate.evaluate(cfg)
    cfg = cfg_factory(*EDOF, "eval.launcher=joblib", "model.net_lr=0", config_name=EVAL)
    with pytest.raises(ConfigError, match=r"^model\.net_lr: expected"):
        entry._eval_task(cfg, ["-m", "deeplens", "eval"])


def test_config_error_formats_and_attributes(tmp_path):
    e = ConfigError("model.deconvolution.nsr", "a number > 0", -1.0)
    assert str(e) == "model.deconvolution.nsr: expected a number > 0, got -1.0"
    assert (e.key, e.expected, e.got, e.kind, e.source) == (
        "model.deconvolution.nsr", "a number > 0", -1.0, "value", None)
    assert str(ConfigError.missing("eval.folder", "a folder")) == (
        "eval.folder: missing; expected a folder")
    u = ConfigError.unknown("model.loss", {"msee", "l2"}, ["mse", "l1"])
    assert str(u) == "model.loss: unknown key(s) ['l2', 'msee']; expected some of ['mse', 'l1']"
    assert u.got == ["l2", "msee"]
    f = e.with_source(tmp_path / "g.yaml")
    assert str(f) == f"{tmp_path / 'g.yaml'}: {e}" and f.key == e.key
    p = pickle.loads(pickle.dumps(u))
    assert (str(p), p.key, p.kind, p.got) == (str(u), u.key, u.kind, u.got)


def test_tolerance_file_errors_name_the_file_and_the_key(tmp_path):
    from deeplens.design.tolerance_groups import load_group

    g = tmp_path / "mine.yaml"
    g.write_text("decenter: {shape: uniform, half_width: -0.01}\n")
    with pytest.raises(ConfigError) as e:
        load_group(str(g), where="eval.tolerance")
    assert e.value.key == "eval.tolerance.decenter.half_width"
    assert e.value.source == str(g)
    assert str(e.value) == (f"{g}: eval.tolerance.decenter.half_width: expected a finite "
                            f"number >= 0, got -0.01")
