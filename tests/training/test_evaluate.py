"""The evaluation command: three variants, one table per depth."""

from __future__ import annotations

import torch

from deeplens.training.evaluate import _variant_cfg, evaluate
from deeplens.training.lens_setup import build_lens


def test_eval_writes_a_table_for_every_variant_and_depth(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=edof", "scene.val_depths_mm=[4500.0,8000.0]",
                      "callbacks.image_logger=null", config_name="eval.yaml")
    table, results = evaluate(cfg)
    assert set(results) == {"none", "cubic", "learned"}
    lines = table.splitlines()
    assert len(lines) == 2 + 2 + 1  # header, separator, 2 depths, mean
    assert lines[2].startswith("| 4.5 |") and lines[3].startswith("| 8 |")
    assert (tmp_path / "eval_table.md").read_text().count("|") > 20
    for v, m in results.items():
        assert "test/psnr_restored/d4500mm" in m and "test/ssim_sensor/d8000mm" in m
    # the variants really image differently: the cubic plate changes the sensor image
    assert abs(results["none"]["test/psnr_sensor"] - results["cubic"]["test/psnr_sensor"]) > 0.05


def test_variant_configs_set_the_plate(cfg_factory):
    cfg = cfg_factory("experiment=edof", config_name="eval.yaml")
    none, cubic = _variant_cfg(cfg, "none"), _variant_cfg(cfg, "cubic")
    assert list(none.lens.trainable) == [] and list(cubic.lens.trainable) == []
    lens = build_lens(cubic.lens.path, plate=cubic.lens.plate, plate_surface=4,
                      plate_alpha_mm=cubic.lens.plate_alpha_mm, dtype="float64")
    s = lens.surfaces[4]
    R = float(s.semi_diameter)
    x = torch.tensor([R], dtype=torch.float64)
    assert abs(float(s.sag(x, torch.zeros_like(x))) - cfg.eval.cubic_alpha_mm) < 1e-12
