"""The ``classical`` evaluation variant: the optics designed by the design engine, then frozen
while the restorer trains."""

from __future__ import annotations

import json

import pytest

from deeplens.optics.io import load_lens
from deeplens.evaluation.evaluate import evaluate


def test_edof_classical_plate_is_designed_frozen_and_reused(cfg_factory, tmp_path):
    over = ("experiment=edof", "scene.val_depths_mm=[4500.0,8000.0]",
            "eval.variants=[classical]", "eval.classical.steps=2",
            "eval.classical.sampling=grid:12", "eval.classical.n_freq=2",
            "callbacks.image_logger=null", "eval.figures=false")
    cfg = cfg_factory(*over, config_name="eval.yaml")
    _, results = evaluate(cfg)
    assert list(results) == ["classical"]
    rec = json.loads((tmp_path / "classical" / "classical_design.json").read_text())
    assert rec["merit_after"] < rec["merit_before"]
    designed = load_lens(tmp_path / "classical" / "classical_lens.json")
    tested = load_lens(tmp_path / "classical" / "seed0" / "checkpoints" / "best.lens.json")
    a_d = [float(v) for v in designed.surfaces[4].a]
    a_t = [float(v) for v in tested.surfaces[4].a]
    assert a_t == pytest.approx(a_d, abs=1e-12)  # frozen: the restorer's lens is the design
    # the design moved away from its 5 um cubic start (x^3 coefficient alpha / R^3)
    R = float(designed.surfaces[4].semi_diameter)
    assert rec["variables_after"] != rec["variables_before"]
    assert abs(a_d[6] * R ** 3 - 0.005) > 1e-9
    # a second call reuses the design (same settings) and the finished run
    mtime = (tmp_path / "classical" / "classical_lens.json").stat().st_mtime_ns
    evaluate(cfg_factory(*over, config_name="eval.yaml"))
    assert (tmp_path / "classical" / "classical_lens.json").stat().st_mtime_ns == mtime
    # other settings design again
    evaluate(cfg_factory(*over[:-2], "eval.classical.start_alpha_mm=0.0025",
                         "callbacks.image_logger=null", "eval.figures=false",
                         config_name="eval.yaml"))
    rec2 = json.loads((tmp_path / "classical" / "classical_design.json").read_text())
    assert rec2["key"]["settings"]["start_alpha_mm"] == 0.0025


def test_doublet_classical_design_reduces_the_spot(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=doublet", "eval.variants=[classical]",
                      "eval.classical.steps=2", "callbacks.image_logger=null",
                      "eval.figures=false", config_name="eval.yaml")
    _, results = evaluate(cfg)
    assert set(results["classical"]["restored_bands"]) == {"0-0.33", "0.33-0.66", "0.66-1"}
    rec = json.loads((tmp_path / "classical" / "classical_design.json").read_text())
    assert rec["merit_after"] < rec["merit_before"]
    assert "RMS spot over fields [0.0, 10.0, 20.0]" in rec["merit"]


def test_classical_settings_are_checked(cfg_factory):
    cfg = cfg_factory("experiment=edof", "eval.variants=[classical]",
                      "+eval.classical.stpes=3", config_name="eval.yaml")
    with pytest.raises(ValueError, match=r"eval.classical: unknown key\(s\) \['stpes'\]"):
        evaluate(cfg)


def test_refined_trains_from_the_classical_design(cfg_factory, tmp_path):
    """``refined``: end-to-end training started from the classical design (not the file's lens),
    the design made once and shared with ``classical``."""
    cfg = cfg_factory("experiment=doublet", "eval.variants=[refined]",
                      "eval.classical.steps=2", "callbacks.image_logger=null",
                      "eval.figures=false", config_name="eval.yaml")
    _, results = evaluate(cfg)
    assert list(results) == ["refined"]
    names = list(cfg.lens.trainable)

    def values(lens):
        p = dict(lens.named_parameters())
        return [float(p[n]) for n in names]

    start = values(load_lens(cfg.lens.path))
    designed = values(load_lens(tmp_path / "classical" / "classical_lens.json"))
    tested = values(load_lens(tmp_path / "refined" / "seed0" / "checkpoints" / "last.lens.json"))
    assert tested != pytest.approx(designed, rel=1e-9, abs=0)  # the optics trained
    for t, d, s in zip(tested, designed, start):  # ... from the design, a few small steps away
        assert abs(t - d) < 0.05 * abs(d - s)


def test_refined_variant_config(cfg_factory):
    from deeplens.evaluation.evaluate import _variant_cfg, classical_dir, variants

    cfg = cfg_factory("experiment=edof", "eval.variants=[classical,refined]",
                      config_name="eval.yaml")
    assert [v[1] for v in variants(cfg)] == ["classical", "refined"]
    design = str(classical_dir(cfg) / "classical_lens.json")
    frozen, refined = (_variant_cfg(cfg, k) for k in ("classical", "refined"))
    assert frozen.lens.path == refined.lens.path == design
    assert list(frozen.lens.trainable) == []
    assert list(refined.lens.trainable) == list(cfg.lens.trainable) != []
    # the plate starts as designed: a cubic start would overwrite it
    assert refined.lens.plate == "learned" and refined.lens.learned_start_alpha_mm is None


def test_classical_sag_bound_is_the_end_to_end_runs(cfg_factory, tmp_path):
    """``eval.classical.max_sag_mm=model``: the design keeps every designed surface within the
    end-to-end run's ``model.max_sag_mm`` of its start, where the unbounded design leaves it."""
    from deeplens.evaluation.classical import design_classical

    def design(bound, out):
        cfg = cfg_factory("experiment=doublet", "eval.classical.steps=3",
                          f"eval.classical.max_sag_mm={bound}", config_name="eval.yaml")
        design_classical(cfg, out)
        return (json.loads((out / "classical_design.json").read_text()),
                load_lens(out / "classical_lens.json"), cfg)

    free, free_lens, cfg = design("null", tmp_path / "free")
    held, held_lens, _ = design("model", tmp_path / "held")
    m = float(cfg.model.max_sag_mm)
    assert held["key"]["settings"]["max_sag_mm"] == m
    assert "max_sag_mm" not in free["key"]["settings"]  # designs made before the option: valid
    assert held["merit_after"] < held["merit_before"]
    start = load_lens(cfg.lens.path).double()
    for lens, within in ((held_lens, True), (free_lens, False)):
        worst = 0.0
        for i in (1, 3):  # the doublet's aspheres, departure over the constraint's grid
            from deeplens.training.constraints import SagDepartureConstraint

            grid = SagDepartureConstraint(start, m)
            X, Y = grid._points(start.surfaces[i], start.dtype, start.device)
            dep = lens.double().surfaces[i].sag(X, Y) - start.surfaces[i].sag(X, Y)
            worst = max(worst, float(dep.abs().max()))
        assert (worst <= m * (1 + 1e-6)) == within, worst
    assert held["sag_departure_mm"] and max(held["sag_departure_mm"].values()) <= m * (1 + 1e-6)


@pytest.mark.parametrize("bad", ["-0.1", "0", "tight"])
def test_classical_sag_bound_is_checked(cfg_factory, bad):
    cfg = cfg_factory("experiment=doublet", "eval.variants=[classical]",
                      f"eval.classical.max_sag_mm={bad}", config_name="eval.yaml")
    with pytest.raises(ValueError, match="eval.classical.max_sag_mm: expected"):
        evaluate(cfg)
