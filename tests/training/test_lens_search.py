"""``lens.start=search``: training and the ``searched`` evaluation variant start from the lens
the design search makes from ``lens.search.spec`` (deeplens/training/lens_search.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

import deeplens.design.search as design_search
from deeplens.optics.io import load_lens
from deeplens.evaluation.evaluate import _run_key, _same_run, _variant_cfg, evaluate
from deeplens.training.lens_search import RECORD, searched_lens
from deeplens.training.train import build_objects

SEARCH = ("experiment=doublet_search",)
# a singlet of N-BK7, one start of 2 DLS steps, no hops: a search of about 2 s
SHRINK = ("lens.search.spec.elements=1", "lens.search.spec.aspheres=0",
          "lens.search.spec.glasses=N-BK7",
          "lens.search.config={starts:1,hops:0,screen:2,polish:2,polish_count:1,keep:1,seed:0,"
          "converge_steps:0}",
          "lens.search.trainable=[surfaces.*.c]", "render.psf_model=geometric",
          "callbacks.image_logger=null")


@pytest.fixture
def searches(monkeypatch):
    """The design searches asked for (the package's ``search``, spied on; a search asked for
    again with the same spec and settings returns the first one's result, without the time)."""
    calls, done = [], {}
    real = design_search.search

    def spy(spec, config=None, **kw):
        calls.append(spec)
        key = repr((spec, config))
        if key not in done:
            done[key] = real(spec, config, **kw)
        return done[key]

    monkeypatch.setattr(design_search, "search", spy)
    return calls


def _params(lens) -> dict[str, torch.Tensor]:
    return {n: p.detach().double().clone() for n, p in lens.named_parameters()}


def test_search_runs_once_is_the_start_and_is_reused(cfg_factory, tmp_path, searches):
    objs = build_objects(cfg_factory(*SEARCH, *SHRINK))
    assert len(searches) == 1
    best = tmp_path / "search" / "best.json"
    assert best.is_file() and (tmp_path / "search" / "result.json").is_file()
    # the lens training starts from is best.json (cast to float32), and the globs chose
    # exactly its two curvatures
    lens, searched = objs["lens"], load_lens(best)
    want = _params(searched)
    got = _params(lens)
    assert set(got) == set(want)
    for n, v in want.items():
        assert torch.equal(got[n], v.float().double()), n
    assert [n for n, p in lens.named_parameters() if p.requires_grad] == [
        "surfaces.1.c", "surfaces.2.c"]
    rec = json.loads((tmp_path / "search" / RECORD).read_text())
    assert rec["key"]["spec"]["elements"] == 1
    # the sensor's wavelengths (R, G, B lines), the spec giving none
    assert rec["key"]["spec"]["wavelengths_nm"] == [486.1327, 587.5618, 656.2725]
    # a second build reuses it: no search, the same file
    mtime = best.stat().st_mtime_ns
    with pytest.raises(ValueError, match=r"lens\.search\.trainable"):   # a glob of nothing
        build_objects(cfg_factory(*SEARCH, *SHRINK, "lens.search.trainable=[surfaces.9.c]"))
    assert len(searches) == 1 and best.stat().st_mtime_ns == mtime
    # a changed spec searches again
    changed = cfg_factory(*SEARCH, *SHRINK, "lens.search.spec.efl_mm=12.0")
    searched_lens(changed)
    assert len(searches) == 2
    assert json.loads((tmp_path / "search" / RECORD).read_text())["key"]["spec"][
        "efl_mm"] == 12.0
    searched_lens(changed)
    assert len(searches) == 2
    # a search killed before its record was written is made again; an edited best.json too
    (tmp_path / "search" / RECORD).unlink()
    searched_lens(changed)
    assert len(searches) == 3
    best.write_text(best.read_text().replace('"N-BK7"', '"N-BK10"'))
    searched_lens(changed)
    assert len(searches) == 4


def test_variant_configs_and_run_keys_of_a_search(cfg_factory, tmp_path):
    cfg = cfg_factory(*SEARCH, *SHRINK, config_name="eval.yaml")
    best = str(tmp_path / "search" / "best.json")
    learned, searched = _variant_cfg(cfg, "learned"), _variant_cfg(cfg, "searched")
    assert learned.lens.path == best and list(learned.lens.trainable) == ["surfaces.*.c"]
    assert searched.lens.path == best and list(searched.lens.trainable) == []
    assert learned.lens.start == searched.lens.start == "file"
    # the spec is in the searched runs' keys: a changed spec trains them again
    cfg2 = cfg_factory(*SEARCH, *SHRINK, "lens.search.spec.fno=5.0", config_name="eval.yaml")
    for v in ("searched", "learned"):
        assert (_same_run(_run_key(_variant_cfg(cfg, v)))
                != _same_run(_run_key(_variant_cfg(cfg2, v)))), v
    # ... but not in the file lens's runs: frozen is the doublet experiment's frozen run, and
    # a record written before lens.start / lens.search existed is still the same run
    frozen = _same_run(_run_key(_variant_cfg(cfg, "frozen")))
    assert frozen == _same_run(_run_key(_variant_cfg(cfg2, "frozen")))
    plain = cfg_factory("experiment=doublet", "render.psf_model=geometric",
                        "callbacks.image_logger=null", config_name="eval.yaml")
    assert frozen == _same_run(_run_key(_variant_cfg(plain, "frozen")))
    old = _run_key(_variant_cfg(plain, "frozen"))
    del old["lens"]["search"]
    assert "start" not in old["lens"] and _same_run(old) == frozen
    # start: search evaluates searched and learned by default
    from deeplens.evaluation.evaluate import variants

    assert [v for v, _, _ in variants(cfg)] == ["searched", "learned"]


def test_searched_variant_is_frozen_in_the_eval_table(cfg_factory, tmp_path, searches):
    cfg = cfg_factory(*SEARCH, *SHRINK, "eval.variants=[searched,learned]",
                      "eval.figures=false", config_name="eval.yaml")
    table, summary = evaluate(cfg)
    assert list(summary) == ["searched", "learned"]
    assert "| searched | restored |" in table and "| learned | restored |" in table
    assert len(searches) == 1      # one search for both variants
    designed = _params(load_lens(tmp_path / "search" / "best.json"))
    tested = _params(load_lens(tmp_path / "searched" / "seed0" / "checkpoints"
                               / "best.lens.json"))
    for n, v in designed.items():  # frozen: the restorer's lens is the search's (float32)
        assert torch.equal(tested[n], v.float().double()), n
    rec = json.loads((tmp_path / "learned" / "seed0" / "eval_run.json").read_text())
    assert rec["config"]["lens"]["path"].endswith("search/best.json")
    assert rec["config"]["lens"]["trainable"] == ["surfaces.*.c"]
    assert rec["config"]["lens"]["search"]["spec"]["elements"] == 1


def test_a_fanned_out_evaluation_searches_before_its_jobs(cfg_factory, tmp_path, monkeypatch,
                                                          searches):
    """The jobs of a fan-out run at once: the evaluation searches first, the jobs reuse it."""
    from deeplens.evaluation import entry, evaluate as evaluate_mod, fanout

    found = []
    monkeypatch.setattr(fanout, "fan_out", lambda cfg, *a: found.append(
        (tmp_path / "search" / RECORD).is_file()))
    monkeypatch.setattr(evaluate_mod, "evaluate", lambda cfg: ("", {}))
    cfg = cfg_factory(*SEARCH, *SHRINK, "eval.launcher=joblib", config_name="eval.yaml")
    entry._eval_task(cfg, ["-m", "deeplens", "eval"])
    assert found == [True] and len(searches) == 1


def test_precheck_needs_no_lens_file_for_a_search():
    from hydra.core.global_hydra import GlobalHydra

    from deeplens.training.precheck import precheck

    configs = str(Path(__file__).resolve().parents[2] / "configs")

    GlobalHydra.instance().clear()
    assert precheck("train", ["experiment=doublet_search", "lens.path=null"],
                    configs) is None
    GlobalHydra.instance().clear()
    assert precheck("train", ["experiment=doublet", "lens.path=null"],
                    configs).startswith("lens.path: expected a lens file")
    GlobalHydra.instance().clear()


@pytest.mark.slow
def test_the_shipped_experiment_trains_its_curvatures_and_aspheres(cfg_factory, tmp_path):
    """configs/experiment/doublet_search.yaml as shipped (two elements, aspheres), with a
    one-start budget: its globs choose every refracting surface's c, a4 and a6 (not the
    conics, gaps or the stop), and a step trains."""
    from deeplens.training.train import train

    # (the one-start lens is blurred enough that render.psf_model=auto picks diffraction, which
    # the Monte Carlo renderer refuses: geometric, as SHRINK in test_train.py)
    cfg = cfg_factory(*SEARCH, "debug=fdr", "lens.search.config={starts:1,hops:0,screen:2,"
                      "polish:2,polish_count:1,keep:1,seed:0,converge_steps:0}",
                      "render.psf_model=geometric")
    metrics, objs = train(cfg)
    assert [n for n, p in objs["lens"].named_parameters() if p.requires_grad] == [
        f"surfaces.{i}.{v}" for i in (1, 2, 3, 4) for v in ("c", "a.0", "a.1")]
    assert len(load_lens(tmp_path / "search" / "best.json").surfaces) == 5
    assert torch.isfinite(torch.tensor(metrics["train/loss"]))


# the EDOF plate search (lens.search.plate): two plate terms, the zero plate and one start of
# one DLS step on a coarse merit (a 6 x 6 pupil grid, one frequency step, one wavelength), a
# given blur
PLATE = ("experiment=edof_search", "render.psf_model=geometric", "callbacks.image_logger=null",
         "render.psf_rays=512", "model.deconvolution.rays=256",
         "lens.trainable=[surfaces.4.a.6,surfaces.4.a.9]",
         "lens.search.plate.starts=1", "lens.search.plate.steps=1",
         "lens.search.plate.sampling=grid:6", "lens.search.plate.n_freq=1",
         "+lens.search.plate.blur_px=6.0", "sensor.channels=[[587.5618]]")


def test_plate_search_is_the_learned_plates_start_and_is_reused(cfg_factory, tmp_path,
                                                                 monkeypatch):
    import deeplens.design.plate_search as ps

    calls, real = [], ps.plate_search
    monkeypatch.setattr(ps, "plate_search", lambda *a, **k: calls.append(a) or real(*a, **k))
    objs = build_objects(cfg_factory(*PLATE))
    assert len(calls) == 1
    best = tmp_path / "search" / "best.json"
    assert best.is_file() and (tmp_path / "search" / "result.json").is_file()
    lens, searched = objs["lens"], load_lens(best)
    plate = [float(a) for a in searched.surfaces[4].a]
    assert any(v != 0.0 for v in plate)            # the search moved the zero plate
    assert all(plate[k] == 0.0 for k in range(10) if k not in (6, 9))
    for k in range(10):   # training starts from the searched plate (float32), same focus
        assert float(lens.surfaces[4].a[k].detach()) == pytest.approx(plate[k], rel=1e-6, abs=0.0)
    assert float(lens.d_sensor) == pytest.approx(float(searched.d_sensor), rel=1e-6)
    assert [n for n, p in lens.named_parameters() if p.requires_grad] == [
        "surfaces.4.a.6", "surfaces.4.a.9"]
    rec = json.loads((tmp_path / "search" / RECORD).read_text())
    assert rec["key"]["plate"]["starts"] == 1 and len(rec["key"]["depths_mm"]) == 4
    res = json.loads((tmp_path / "search" / "result.json").read_text())
    assert res["runs"][0]["origin"] == "zero plate" and res["plate_terms_mm_at_rim"]
    # reused while unchanged; a changed setting or lens file is another search
    searched_lens(cfg_factory(*PLATE))
    assert len(calls) == 1
    from deeplens.training.lens_search import search_key

    key = search_key(cfg_factory(*PLATE))
    assert key == rec["key"]
    assert search_key(cfg_factory(*PLATE, "lens.search.plate.seed=1")) != key
    assert search_key(cfg_factory(*PLATE, "lens.focus_mm=6000.0")) != key


def test_the_restoration_merits_search_is_keyed_on_the_sensors_noise(cfg_factory):
    """lens.search.plate.merit=restoration reads the sensor's noise: the key holds it (and
    the merit's source, in the code digest), so another noise level is another search; the
    invariance merit's key is unchanged by the option's existence."""
    from deeplens.training.lens_search import search_key

    inv = search_key(cfg_factory(*PLATE))
    assert "sensor_noise" not in inv
    rest = search_key(cfg_factory(*PLATE, "+lens.search.plate.merit=restoration"))
    assert rest["plate"]["merit"] == "restoration" and rest["sensor_noise"] == [2000.0, 0.005]
    assert rest != inv
    assert search_key(cfg_factory(*PLATE, "+lens.search.plate.merit=restoration",
                                  "sensor.read_noise=0.01")) != rest
    with pytest.raises(ValueError, match=r"lens\.search\.plate"):
        search_key(cfg_factory(*PLATE, "+lens.search.plate.merit=sharpness"))


def test_plate_search_variants_keep_the_plate_and_bad_settings_are_named(cfg_factory,
                                                                        tmp_path):
    from deeplens.training.lens_search import check_lens_config

    cfg = cfg_factory(*PLATE, config_name="eval.yaml")
    best = str(tmp_path / "search" / "best.json")
    learned, searched = _variant_cfg(cfg, "learned"), _variant_cfg(cfg, "searched")
    for v in (learned, searched):
        assert v.lens.path == best and v.lens.plate_surface == 4 and v.lens.plate == "learned"
        assert v.lens.learned_start_alpha_mm is None and v.lens.start == "file"
    assert list(learned.lens.trainable) == ["surfaces.4.a.6", "surfaces.4.a.9"]
    assert list(searched.lens.trainable) == []
    for v in (learned, searched):   # the variants' runs pass the start-up checks
        check_lens_config(v)
    for over, key in (("lens.learned_start_alpha_mm=0.005", "lens.learned_start_alpha_mm"),
                      ("lens.search.plate.starts=0", "lens.search.plate.starts"),
                      ("+lens.search.plate.stepz=3", "lens.search.plate"),
                      ("+lens.search.spec={efl_mm:10}", "lens.search"),
                      ("lens.plate=cubic", "lens.plate"),
                      ("lens.trainable=[d_sensor]", "lens.trainable")):
        with pytest.raises(ValueError, match=key.replace(".", r"\.")):
            check_lens_config(cfg_factory(*PLATE, over))


def test_every_search_config_field_is_checked_and_accepted():
    """Each SearchConfig field (the glass search's too) has a rule: its default passes through
    lens.search.config to an equal SearchConfig, and a wrong value is a ConfigError naming the
    key (never a KeyError)."""
    import dataclasses

    from deeplens.design.search import SearchConfig
    from deeplens.optics.errors import ConfigError
    from deeplens.training.lens_search import _search_config

    default = SearchConfig()
    for f in dataclasses.fields(SearchConfig):
        v = getattr(default, f.name)
        if isinstance(v, tuple):   # stages: given as plain mappings in a config
            v = [{"steps": st.steps, "sampling": st.sampling, "aperture": st.aperture,
                  "field": st.field, "rounds": st.rounds, "method": st.method} for st in v]
        got = _search_config({f.name: v}, "lens.search.config")
        assert getattr(got, f.name) == getattr(default, f.name), f.name
        with pytest.raises(ConfigError) as e:
            _search_config({f.name: "nonsense!"}, "lens.search.config")
        assert "lens.search.config" in str(e.value), f.name
