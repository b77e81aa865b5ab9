"""The evaluation command: three variants, one table per depth."""

from __future__ import annotations

import pytest
import torch

from deeplens.training.evaluate import _variant_cfg, evaluate
from deeplens.training.lens_setup import build_lens


def test_eval_writes_a_table_for_every_variant_and_depth(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=edof", "scene.val_depths_mm=[4500.0,8000.0]",
                      "eval.cubic_alpha_mm=[0.0025,0.01]",
                      "callbacks.image_logger=null", config_name="eval.yaml")
    table, results = evaluate(cfg)
    assert list(results) == ["none", "cubic@2.5um", "cubic@10um", "learned"]
    lines = table.splitlines()
    assert lines[0] == "| variant | image | 4.5 m | 8 m | mean |"
    assert len(lines) == 2 + 2 * 4  # header, separator, sensor + restored per variant
    assert lines[2].startswith("| none | sensor |") and lines[-1].startswith("| learned | restored")
    assert (tmp_path / "eval_table.md").read_text().count("|") > 40
    assert (tmp_path / "cubic_10um" / "checkpoints" / "best.ckpt").exists()
    for v, m in results.items():
        assert "test/psnr_restored/d4500mm" in m and "test/ssim_sensor/d8000mm" in m
    # the variants really image differently: the cubic plates change the sensor image, the
    # stronger one more
    ps = {v: results[v]["test/psnr_sensor"] for v in results}
    assert ps["none"] - ps["cubic@10um"] > ps["none"] - ps["cubic@2.5um"] > 0.05


def test_eval_rejects_bad_variants_and_alphas_before_training(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=edof", "eval.variants=[none,cubicc]", config_name="eval.yaml")
    with pytest.raises(ValueError, match="eval.variants: unknown variant 'cubicc'"):
        evaluate(cfg)
    cfg = cfg_factory("experiment=edof", "eval.cubic_alpha_mm=[0.01,big]",
                      config_name="eval.yaml")
    with pytest.raises(ValueError, match="eval.cubic_alpha_mm: expected a number"):
        evaluate(cfg)
    assert not list(tmp_path.rglob("*.ckpt"))


def test_variant_configs_set_the_plate(cfg_factory):
    cfg = cfg_factory("experiment=edof", config_name="eval.yaml")
    none, cubic = _variant_cfg(cfg, "none"), _variant_cfg(cfg, "cubic", "cubic", 0.01)
    assert list(none.lens.trainable) == [] and list(cubic.lens.trainable) == []
    lens = build_lens(cubic.lens.path, plate=cubic.lens.plate, plate_surface=4,
                      plate_alpha_mm=cubic.lens.plate_alpha_mm, dtype="float64")
    s = lens.surfaces[4]
    R = float(s.semi_diameter)
    x = torch.tensor([R], dtype=torch.float64)
    assert abs(float(s.sag(x, torch.zeros_like(x))) - 0.01) < 1e-12
