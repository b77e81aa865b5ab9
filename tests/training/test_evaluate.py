"""The evaluation command: variants x seeds, tables (markdown, JSON), figures, own test images."""

from __future__ import annotations

import json
import math

import pytest
import torch

from deeplens.evaluation.evaluate import _variant_cfg, evaluate, psf_rms_px, summarize
from deeplens.training.lens_setup import build_lens


def test_eval_writes_a_table_for_every_variant_and_depth(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=edof", "scene.val_depths_mm=[4500.0,8000.0]",
                      "eval.cubic_alpha_mm=[0.0025,0.01]", "eval.variants=[none,cubic,learned]",
                      "callbacks.image_logger=null", "eval.figures=false",
                      config_name="eval.yaml")
    table, results = evaluate(cfg)
    assert list(results) == ["none", "cubic@2.5um", "cubic@10um", "learned"]
    lines = table.splitlines()
    assert lines[0] == "| variant | image | 4.5 m | 8 m | mean over depths |"
    assert len(lines) == 2 + 2 * 4  # header, separator, sensor + restored per variant
    assert lines[2].startswith("| none | sensor |") and lines[-1].startswith("| learned | restored")
    assert (tmp_path / "eval_table.md").read_text().count("|") > 40
    assert (tmp_path / "cubic_10um" / "seed0" / "checkpoints" / "best.ckpt").exists()
    js = json.loads((tmp_path / "eval_table.json").read_text())
    assert js["seeds"] == [0] and list(js["variants"]) == list(results)
    for v, e in js["variants"].items():
        assert set(e["restored"]) == {"4500", "8000"} and set(e["psf_rms_px"]) == {"4500", "8000"}
        assert e["mean"]["psnr"] == pytest.approx(
            (e["restored"]["4500"]["psnr"] + e["restored"]["8000"]["psnr"]) / 2)
        assert e["worst"]["psnr"] == min(c["psnr"] for c in e["restored"].values())
    # the variants really image differently: the cubic plates change the sensor image and
    # widen the PSF, the stronger one more
    ps = {v: results[v]["sensor_mean"]["psnr"] for v in results}
    assert ps["none"] - ps["cubic@10um"] > ps["none"] - ps["cubic@2.5um"] > 0.05
    rms = {v: results[v]["psf_rms_px"]["8000"] for v in results}
    assert rms["cubic@10um"] > rms["cubic@2.5um"]


def test_summary_statistics_over_seeds():
    depths = [1000.0, 2000.0]

    def metrics(a, b):
        m = {}
        for img in ("sensor", "restored"):
            m[f"test/psnr_{img}/d1000mm"], m[f"test/psnr_{img}/d2000mm"] = a, b
            m[f"test/ssim_{img}/d1000mm"], m[f"test/ssim_{img}/d2000mm"] = a / 100, b / 100
        return m

    s = summarize({"x": [metrics(20.0, 30.0), metrics(22.0, 26.0), metrics(24.0, 28.0)]},
                  depths)["x"]
    assert s["seeds"] == 3
    assert s["restored"]["1000"]["psnr"] == pytest.approx(22.0)
    assert s["restored"]["1000"]["psnr_std"] == pytest.approx(2.0)  # sample std (n - 1)
    assert s["restored"]["2000"]["psnr_std"] == pytest.approx(2.0)
    # the mean over depths per seed is 25, 24, 26: mean 25, std 1
    assert s["mean"]["psnr"] == pytest.approx(25.0) and s["mean"]["psnr_std"] == pytest.approx(1.0)
    assert s["worst"] == pytest.approx({"depth_mm": 1000.0, "psnr": 22.0, "psnr_std": 2.0,
                                        "ssim": 0.22, "ssim_std": 0.02})
    assert s["spread_db"] == pytest.approx(6.0)


def test_eval_seed_loop_test_folder_and_figures(cfg_factory, tmp_path, monkeypatch):
    """Two seeds of two variants on a folder of the user's own images: one run per variant and
    seed, the test set is those images, and every figure is written."""
    from torchvision.io import write_png

    folder = tmp_path / "mine"
    folder.mkdir()
    g = torch.Generator().manual_seed(3)
    for k in range(3):
        write_png((torch.rand(3, 40 + 10 * k, 50, generator=g) * 255).to(torch.uint8),
                  str(folder / f"im{k}.png"))
    cfg = cfg_factory("experiment=edof", "scene.val_depths_mm=[4500.0,8000.0]",
                      "eval.variants=[none,learned]", "eval.seeds=[0,1]",
                      f"eval.test_folder={folder}", "callbacks.image_logger=null",
                      config_name="eval.yaml")
    import deeplens.evaluation.evaluate as ev

    seen = {}
    real = ev.write_figures

    def spy(summary, kept, depths, out, **kw):
        seen.update(summary=summary, kept=kept, **kw)
        return real(summary, kept, depths, out, **kw)

    monkeypatch.setattr(ev, "write_figures", spy)
    table, results = evaluate(cfg)
    # the figures show the user's images (issue 35), not the textures
    rec = json.loads((tmp_path / "eval_table.json").read_text())["test_folder"]["variants"]
    for v in ("none", "learned"):
        assert seen["kept"][v]["datamodule"].test_folder == folder
        assert seen["summary"][v]["restored"] == rec[v]["restored"]
    assert seen["test_set"] == f"the images of {folder}"
    assert "±" in table and "mine" in (tmp_path / "eval_table.md").read_text()
    for v in ("none", "learned"):
        assert results[v]["seeds"] == 2
        for s in (0, 1):
            assert (tmp_path / v / f"seed{s}" / "checkpoints" / "best.ckpt").exists()
    for name in ("psnr_vs_depth", "psfs", "samples", "plates"):
        assert (tmp_path / f"{name}.png").stat().st_size > 1000
    assert list((tmp_path / "tensorboard").glob("events.*"))


def test_eval_folder_errors(cfg_factory, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    cfg = cfg_factory("experiment=edof", "eval.variants=[none]", f"eval.test_folder={empty}",
                      config_name="eval.yaml")
    with pytest.raises(FileNotFoundError, match="eval.test_folder: .*contains no images"):
        evaluate(cfg)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "broken.png").write_bytes(b"not a png")
    cfg = cfg_factory("experiment=edof", "eval.variants=[none]", f"eval.test_folder={bad}",
                      config_name="eval.yaml")
    with pytest.raises(RuntimeError, match="eval.test_folder: could not decode .*broken.png"):
        evaluate(cfg)
    assert not list(tmp_path.rglob("*.ckpt"))
    from deeplens.data import TextureDataModule

    dm = TextureDataModule(image_size=16, batch_size=1, val_size=1, test_size=1,
                           test_folder=bad)
    dm.setup()
    with pytest.raises(RuntimeError, match="broken.png"):
        dm.test_set[0]


def test_test_folder_gives_centre_crops(tmp_path):
    from torchvision.io import write_png

    from deeplens.data import TextureDataModule

    img = torch.zeros(3, 20, 30, dtype=torch.uint8)
    img[:, 10, 15] = 255  # the centre pixel of the 16 x 16 centre crop is (8, 8)
    write_png(img, str(tmp_path / "a.png"))
    dm = TextureDataModule(image_size=16, batch_size=1, val_size=1, test_size=5,
                           test_folder=tmp_path)
    dm.setup()
    assert len(dm.test_set) == 1  # every file, test_size ignored
    x = dm.test_set[0]["image"]
    assert x.shape == (3, 16, 16)
    assert float(x[:, 8, 8].min()) == 1.0 and float(x.sum()) == 3.0


def test_doublet_eval_compares_frozen_and_learned_per_band(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=doublet", "callbacks.image_logger=null", "eval.figures=false",
                      "eval.variants=[frozen,learned]", config_name="eval.yaml")
    table, results = evaluate(cfg)
    assert list(results) == ["frozen", "learned"]
    assert "band 0.66-1" in table.splitlines()[0]
    for v in results.values():
        assert set(v["restored_bands"]) == {"0-0.33", "0.33-0.66", "0.66-1"}
    # frozen really is frozen: its exported lens equals the file's; the learned aspheres moved
    from deeplens.optics.io import load_lens

    start = load_lens("data/lenses/wide_doublet.json")
    frozen = load_lens(tmp_path / "frozen" / "seed0" / "checkpoints" / "best.lens.json")
    learned = load_lens(tmp_path / "learned" / "seed0" / "checkpoints" / "best.lens.json")
    a0, af, al = (float(L.surfaces[1].a[0]) for L in (start, frozen, learned))
    assert af == pytest.approx(a0, abs=1e-12) and abs(al - a0) > 1e-12


def test_psf_rms_grows_away_from_focus():
    from deeplens.render import Sensor

    lens = build_lens("data/lenses/edof_achromat.json", dtype="float64")
    sensor = Sensor((32, 32), 0.0138)
    r = {d: psf_rms_px(lens, sensor, d) for d in (3000.0, 5500.0, 20000.0)}
    assert r[5500.0] < r[3000.0] and r[5500.0] < r[20000.0]
    assert all(math.isfinite(v) and v > 0 for v in r.values())
    # pixels: half the pixel size, twice the radius in pixels
    half = Sensor((32, 32), 0.0069)
    assert psf_rms_px(lens, half, 3000.0) == pytest.approx(2 * r[3000.0], rel=1e-9)


def test_eval_rejects_bad_variants_and_alphas_before_training(cfg_factory, tmp_path):
    cfg = cfg_factory("experiment=edof", "eval.variants=[none,cubicc]", config_name="eval.yaml")
    with pytest.raises(ValueError, match=r"eval.variants: expected variants of none, .*, got \['none', 'cubicc'\]"):
        evaluate(cfg)
    cfg = cfg_factory("experiment=doublet", "eval.variants=[none,learned]",
                      config_name="eval.yaml")
    with pytest.raises(ValueError, match=r"eval.variants: expected variants of a lens without a phase plate"):
        evaluate(cfg)
    cfg = cfg_factory("experiment=edof", "eval.seeds=[0,0]", config_name="eval.yaml")
    with pytest.raises(ValueError, match=r"eval.seeds: expected .*distinct.*, got \[0, 0\]"):
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


def test_best_focus_minimises_the_rms_spot():
    """The closed-form best focus equals a brute-force scan of the RMS spot over the sensor
    position, and the EDOF config's focus moves the sensor the same way for every variant."""
    from deeplens.render.splat import point_source_rays
    from deeplens.training.lens_setup import best_focus_distance

    lens = build_lens("data/lenses/edof_achromat.json", dtype="float64")
    ws = (486.1, 587.6, 656.3)
    d = best_focus_distance(lens, 5760.0, ws)
    z_last = float(lens.z_vertices()[-1])

    def rms(ds):
        tot = []
        for w in ws:
            out = lens.trace_to_sensor(point_source_rays(lens, (0.0, 0.0), 5760.0, w, 4096, 0),
                                       z_image=z_last + ds)
            tot.append(out.o[out.valid][:, :2])
        x = torch.cat(tot)
        return float(((x - x.mean(0)) ** 2).sum(1).mean())

    grid = [d + k * 0.02 for k in range(-5, 6)]
    vals = [rms(g) for g in grid]
    assert min(range(11), key=vals.__getitem__) == 5  # the scan's minimum is the closed form's
    assert rms(d) < rms(d - 0.005) and rms(d) < rms(d + 0.005)
    # thin-lens sanity: focusing nearer moves the sensor back
    assert best_focus_distance(lens, 3000.0, ws) > d > best_focus_distance(lens, 20000.0, ws)
    lenses = [build_lens("data/lenses/edof_achromat.json", dtype="float64", plate=p,
                         plate_surface=4, plate_alpha_mm=0.005, focus_mm=5760.0,
                         focus_wavelengths_nm=ws) for p in ("none", "cubic", "learned")]
    assert all(float(L.d_sensor) == pytest.approx(d, abs=1e-12) for L in lenses)
    with pytest.raises(ValueError, match="lens.focus_mm: expected a depth > 0"):
        build_lens("data/lenses/edof_achromat.json", focus_mm=-1.0)


def test_eval_resumes_finished_runs_and_retrains_changed_ones(cfg_factory, tmp_path,
                                                              monkeypatch):
    """A second evaluation into the same folder loads each finished variant x seed run (same
    metrics, the module holding the tested weights) instead of training it again; a run whose
    configuration changed is trained again."""
    import deeplens.evaluation.evaluate as ev
    from deeplens.training.checkpoint import read_checkpoint

    args = ("experiment=edof", "scene.val_depths_mm=[4500.0,8000.0]",
            "eval.variants=[none,learned]", "callbacks.image_logger=null", "eval.figures=false")
    _, first = evaluate(cfg_factory(*args, config_name="eval.yaml"))
    rec = json.loads((tmp_path / "learned" / "seed0" / ev.RUN_RECORD).read_text())
    assert rec["metrics"]["test/psnr_restored/d4500mm"] == pytest.approx(
        first["learned"]["restored"]["4500"]["psnr"])

    # a record written before an option existed (its default null: the old behaviour) still
    # matches
    path = tmp_path / "learned" / "seed0" / ev.RUN_RECORD
    old = json.loads(path.read_text())
    assert old["config"]["model"].pop("worst_depth") is None
    # ... and so does one that gave a dict setting in part (the rest its defaults)
    assert old["config"]["model"]["optics_worst_depth"].pop("bins") == 4
    assert old["config"]["model"]["deconvolution"].pop("learn_nsr") is True
    path.write_text(json.dumps(old))

    def no_training(cfg):
        raise AssertionError(f"trained again: {cfg.paths.output_dir}")

    monkeypatch.setattr(ev, "train", no_training)
    kept = {}
    real_run = ev._run

    def spy(cfg, ckpt, reuse=False):
        out = real_run(cfg, ckpt, reuse)
        kept[cfg.paths.output_dir] = out[1]["module"]
        return out

    monkeypatch.setattr(ev, "_run", spy)
    _, again = evaluate(cfg_factory(*args, config_name="eval.yaml"))
    assert again == first
    # the reloaded module is the tested checkpoint (optics included), not a fresh build
    module = kept[str(tmp_path / "learned" / "seed0")]
    state = read_checkpoint(rec["tested"])["state_dict"]
    for k, v in module.state_dict().items():  # bit for bit (a depth bin not seen yet: NaN)
        torch.testing.assert_close(v, state[k], rtol=0, atol=0, equal_nan=True, msg=k)
    with pytest.raises(AssertionError, match="trained again"):
        evaluate(cfg_factory(*args, "render.psf_rays=999", config_name="eval.yaml"))
    with pytest.raises(AssertionError, match="trained again"):
        evaluate(cfg_factory(*args, "model.optics_worst_depth.bins=3", config_name="eval.yaml"))


def test_run_key_of_optics_invariance(cfg_factory):
    """``model.optics_invariance`` is part of a learned run's key (in part given = completed
    with its defaults) and not of a frozen plate's, whose optics it cannot touch."""
    import deeplens.evaluation.evaluate as ev

    def key(name, *over):
        cfg = cfg_factory("experiment=edof", *over, config_name="eval.yaml")
        return ev._same_run(ev._run_key(ev._variant_cfg(cfg, name)))

    plain = key("learned")
    inv = key("learned", "model.optics_invariance={weight:2.0}")
    assert inv != plain and inv["model"]["optics_invariance"] == {"weight": 2.0, "slack": 0.0}
    assert inv == key("learned", "model.optics_invariance={weight:2.0,slack:0.0}")
    assert key("cubic", "model.optics_invariance={weight:2.0}") == key("cubic")


def test_a_moved_evaluation_folder_still_holds_its_runs(cfg_factory, tmp_path, monkeypatch):
    """Finished runs are found again after their evaluation folder is moved (their keys hold
    the folder's paths, written relative to it, and the tested checkpoint is looked up where
    the folder is now); a run of another configuration there still trains again."""
    import shutil

    import deeplens.evaluation.evaluate as ev

    args = ("experiment=edof", "scene.val_depths_mm=[4500.0,8000.0]", "eval.variants=[none]",
            "callbacks.image_logger=null", "eval.figures=false")
    a, b = tmp_path / "a", tmp_path / "b"
    _, first = evaluate(cfg_factory(*args, config_name="eval.yaml", out=a))
    shutil.move(str(a), str(b))  # the old checkpoint path is gone

    def no_training(cfg):
        raise AssertionError(f"trained again: {cfg.paths.output_dir}")

    monkeypatch.setattr(ev, "train", no_training)
    _, again = evaluate(cfg_factory(*args, config_name="eval.yaml", out=b))
    assert again == first
    with pytest.raises(AssertionError, match="trained again"):
        evaluate(cfg_factory(*args, "render.psf_rays=999", config_name="eval.yaml", out=b))
