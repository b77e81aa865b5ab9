"""Training and evaluation under tolerances: a new drawn lens every batch, the yield on the
right side of its threshold, evaluation deterministic for a seed, and N = 1 with zero
tolerances reproducing the nominal evaluation exactly."""

from __future__ import annotations

import json

import pytest
import torch

from deeplens.training.tolerance import tolerance_seed
from deeplens.evaluation.tolerance import summarize_samples, evaluate_drawn
from deeplens.training.train import build_objects

DOUBLET = ("experiment=doublet", "callbacks.image_logger=null")


def test_training_draws_a_new_lens_every_batch(cfg_factory, monkeypatch):
    """Each step renders through the lens its own seed draws (not one lens per run), and the
    nominal lens is untouched between steps."""
    cfg = cfg_factory(*DOUBLET, "tolerance=precision", "model.tolerance_training=true")
    objs = build_objects(cfg)
    module = objs["module"]
    lens = module.lens
    seen = []

    def capture(images, depths, seed, noise=True):
        seen.append((float(lens.d_sensor), float(lens.misalignments[1].dx),
                     float(lens.surfaces[1].c)))
        raise StopIteration

    monkeypatch.setattr(module, "capture", capture)
    images = torch.rand(2, 3, 32, 32)
    for step in (0, 1, 2):
        with pytest.raises(StopIteration):
            module.step_loss(images, step)
    tm = module.tolerance_draws.model
    nominal = (float(lens.d_sensor), float(lens.misalignments[1].dx), float(lens.surfaces[1].c))
    assert nominal[1] == 0.0
    assert len(set(seen)) == 3 and nominal not in seen
    for step, s in enumerate(seen):
        d = tm.draw(lens, tolerance_seed(cfg.seed, step))
        assert s[1] == pytest.approx(d.offsets["misalignments.1.dx"], rel=1e-6)  # float32 lens


def test_tolerance_training_needs_a_nonzero_group(cfg_factory):
    cfg = cfg_factory(*DOUBLET, "model.tolerance_training=true")  # tolerance=none
    with pytest.raises(ValueError, match="model.tolerance_training"):
        build_objects(cfg)
    cfg = cfg_factory(*DOUBLET, "tolerance=precision", "tolerance.decenter.std=-0.1")
    with pytest.raises(ValueError, match=r"tolerance\.decenter\.std"):
        build_objects(cfg)


def test_yield_counts_lenses_at_or_above_the_threshold():
    ps = [20.0, 24.0, 25.0, 26.0]  # >= 25: 2 of 4 (> : 1, <= : 3)
    samples = [{"test/psnr_restored/d1mm": p, "test/ssim_restored/d1mm": p / 100} for p in ps]
    s = summarize_samples(samples, [("1", "d1mm")], threshold_db=25.0)
    c = s["columns"]["1"]
    assert c["yield"] == pytest.approx(0.5)
    assert c["psnr_mean"] == pytest.approx(23.75)
    assert c["psnr_p5"] == pytest.approx(20.0 + 0.05 * 3 * 4.0)  # linear interpolation
    assert s["columns"]["mean"]["yield"] == pytest.approx(0.5)


def test_eval_under_tolerances_is_deterministic_and_zero_tolerance_is_nominal(cfg_factory):
    cfg = cfg_factory(*DOUBLET, "data.test_size=2")
    objs = build_objects(cfg)
    module, trainer, dm = objs["module"], objs["trainer"], objs["datamodule"]
    trainer.test(module, datamodule=dm, verbose=False)
    nominal = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("test/")}
    from deeplens.design.tolerance_groups import load_group

    zero = evaluate_drawn(module, trainer, dm, load_group("none"), n=1, seed=0)
    assert zero[0] == nominal  # exactly
    tm = load_group("commercial")
    a = evaluate_drawn(module, trainer, dm, tm, n=2, seed=3)
    b = evaluate_drawn(module, trainer, dm, tm, n=2, seed=3)
    assert a == b
    assert a[0] != a[1] and a[0] != nominal


def test_eval_writes_the_tolerance_table_json_and_histogram(cfg_factory, tmp_path):
    cfg = cfg_factory(*DOUBLET, "eval.variants=[frozen]", "eval.tolerance=commercial",
                      "eval.tolerance_samples=2", "eval.tolerance_yield_db=0",
                      "trainer.max_epochs=1", config_name="eval.yaml")
    from deeplens.evaluation.evaluate import evaluate

    evaluate(cfg)
    md = (tmp_path / "eval_table.md").read_text()
    assert "Under tolerances: group commercial, 2 drawn lenses" in md
    assert "| frozen | " in md.split("Under tolerances")[1]
    js = json.loads((tmp_path / "eval_table.json").read_text())["tolerance"]
    assert js["samples"] == 2 and js["group"] == "commercial"
    c = js["variants"]["frozen"][0]["columns"]["mean"]
    assert len(c["psnr"]) == 2 and c["yield"] == 1.0
    assert (tmp_path / "tolerance_hist.png").exists()


def test_eval_tolerance_settings_are_checked_before_training(cfg_factory):
    from deeplens.evaluation.evaluate import evaluate

    cfg = cfg_factory(*DOUBLET, "eval.tolerance=precise", config_name="eval.yaml")
    with pytest.raises(ValueError, match=r"eval.tolerance: expected a tolerance group "
                                         r"\(.*\).*, got 'precise'"):
        evaluate(cfg)
    cfg = cfg_factory(*DOUBLET, "eval.tolerance=precision", "eval.tolerance_samples=0",
                      config_name="eval.yaml")
    with pytest.raises(ValueError, match="eval.tolerance_samples"):
        evaluate(cfg)


def test_tolerance_training_runs_and_leaves_the_nominal_lens(cfg_factory, tmp_path):
    """A short fit under tolerances: the optics still train (the nominal aspheres move), the
    lens is the nominal one afterwards, and the checkpoint holds the nominal lens's keys."""
    from deeplens.optics.tolerance_model import PerturbedMaterial
    from deeplens.training.checkpoint import read_checkpoint

    cfg = cfg_factory(*DOUBLET, "tolerance=commercial", "model.tolerance_training=true",
                      "test=false")
    objs = build_objects(cfg)
    module = objs["module"]
    lens = module.lens
    at_backward = []
    backward = module.manual_backward

    def spy(loss, *a, **k):  # the adjoint render re-traces here: the drawn lens must be in place
        at_backward.append(float(lens.misalignments[1].dx))
        return backward(loss, *a, **k)

    module.manual_backward = spy
    objs["trainer"].fit(module, datamodule=objs["datamodule"])
    metrics = {k: float(v) for k, v in objs["trainer"].callback_metrics.items()}
    assert len(at_backward) == 2 and len(set(at_backward)) == 2 and 0.0 not in at_backward
    assert not any(isinstance(m, PerturbedMaterial) for m in lens.materials)
    assert all(isinstance(p, torch.nn.Parameter) for p in lens.parameters())
    assert float(lens.misalignments[1].dx) == 0.0
    from deeplens.optics.io import load_lens

    a0 = float(load_lens("data/lenses/wide_doublet.json").surfaces[1].a[0])
    assert abs(float(lens.surfaces[1].a[0].detach()) - a0) > 0
    ck = read_checkpoint(next((tmp_path / "checkpoints").glob("last*.ckpt")))
    keys = {k for k in ck["state_dict"] if k.startswith("lens.")}
    assert keys == {f"lens.{k}" for k in lens.state_dict()}
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())


def test_eval_tolerance_group_takes_the_composed_group(cfg_factory):
    from deeplens.evaluation.tolerance import EvalTolerance

    cfg = cfg_factory(*DOUBLET, "tolerance=precision", "eval.tolerance=group",
                      "tolerance.decenter.std=0.5", config_name="eval.yaml")
    et = EvalTolerance.from_cfg(cfg)
    assert et.group == "precision" and et.model.dists["decenter"].scale == 0.5
    assert EvalTolerance.from_cfg(cfg_factory(*DOUBLET, config_name="eval.yaml")).model is None


def test_tolerance_training_with_an_optics_warm_up(cfg_factory, tmp_path):
    """Tolerance training with ``optics_warmup_steps`` and the centring compensator (whose
    misalignments are functions of the trained coefficients): the warm-up step freezes the
    nominal parameters before the drawn lens replaces them (it used to try to freeze the drawn,
    non-leaf values: "you can only change requires_grad flags of leaf variables"), the optics
    stay put during the warm-up and train after it, and the trainable set is restored."""
    cfg = cfg_factory(*DOUBLET, "tolerance=commercial_aligned", "model.tolerance_training=true",
                      "model.optics_warmup_steps=1", "test=false")
    objs = build_objects(cfg)
    module = objs["module"]
    lens = module.lens
    def coeffs():
        return torch.stack([c.detach().clone() for c in lens.surfaces[1].a])

    seen = []
    backward = module.manual_backward

    def spy(loss, *args, **kw):
        seen.append(coeffs())
        return backward(loss, *args, **kw)

    module.manual_backward = spy
    objs["trainer"].fit(module, datamodule=objs["datamodule"])
    assert len(seen) == 2
    assert torch.equal(seen[0], seen[1])          # the warm-up step moved nothing
    assert not torch.equal(coeffs(), seen[1])     # the step after it did
    assert lens.surfaces[1].a[0].requires_grad and all(isinstance(p, torch.nn.Parameter) for p in lens.parameters())


def test_calibrated_eval_zero_tolerance_is_nominal_and_deterministic(cfg_factory):
    """eval.calibrate=distortion: N = 1 with zero tolerances reproduces the nominal evaluation
    exactly (the unit's map is zero); two runs give the same numbers; under commercial the
    calibration changes them (it is applied), and the hook is cleared afterwards."""
    cfg = cfg_factory(*DOUBLET, "data.test_size=2")
    objs = build_objects(cfg)
    module, trainer, dm = objs["module"], objs["trainer"], objs["datamodule"]
    trainer.test(module, datamodule=dm, verbose=False)
    nominal = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("test/")}
    from deeplens.design.tolerance_groups import load_group

    zero = evaluate_drawn(module, trainer, dm, load_group("none"), n=1, seed=0,
                          calibrate="distortion")
    assert zero[0] == nominal  # exactly
    tm = load_group("commercial_aligned")
    a = evaluate_drawn(module, trainer, dm, tm, n=2, seed=3, calibrate="distortion")
    b = evaluate_drawn(module, trainer, dm, tm, n=2, seed=3, calibrate="distortion")
    raw = evaluate_drawn(module, trainer, dm, tm, n=2, seed=3)
    assert a == b
    key = "test/psnr_restored/d10000mm"
    assert all(x[key] != r[key] for x, r in zip(a, raw))
    assert all(x["test/psnr_sensor/d10000mm"] == r["test/psnr_sensor/d10000mm"]
               for x, r in zip(a, raw))  # only the restored image is registered
    assert module.calibration is None


def test_calibrated_eval_registers_a_translated_lens(cfg_factory):
    """A drawn lens that is the nominal one moved rigidly by one pixel across the axis: the
    restored image moves with it, and the calibrated score is the nominal one within 0.3 dB
    (the uncalibrated one is far below)."""
    from deeplens.optics.tolerance_model import LensDraw

    cfg = cfg_factory(*DOUBLET, "data.test_size=2", "sensor.resolution=[24,24]",
                      "render.spp=8")
    objs = build_objects(cfg)
    module, trainer, dm = objs["module"], objs["trainer"], objs["datamodule"]
    module.restorer = torch.nn.Identity()  # the restorer passes the capture through
    trainer.test(module, datamodule=dm, verbose=False)
    key = "test/psnr_restored/band0-0.33"  # the centre: away from the edge a shift empties
    nominal = float(trainer.callback_metrics[key])
    lens = module.lens
    p = float(module.sensor.pixel_size_mm)
    off = {}
    for e in range(len(lens.elements)):
        off[f"misalignments.{e}.dx"] = -p

    class Rigid:  # a "group" drawing the translated lens
        def draws(self, lens, n, seed):
            return [LensDraw(seed=0, offsets=off)]

    cal = evaluate_drawn(module, trainer, dm, Rigid(), n=1, calibrate="distortion")[0][key]
    raw = evaluate_drawn(module, trainer, dm, Rigid(), n=1)[0][key]
    assert abs(cal - nominal) < 0.3, (nominal, cal, raw)
    assert raw < nominal - 2.0, (nominal, raw)


def test_tolerance_training_with_calibration_registers_the_restored_image(cfg_factory,
                                                                          monkeypatch):
    """model.calibrate=distortion: within a step the drawn unit's registration is in place
    (its map measured against the nominal lens's, non-zero under commercial_aligned), the
    loss is taken on the registered output (it differs from the unregistered one), gradients
    still reach the optics, and nothing is left in place after the step."""
    from deeplens.render import calibration

    cfg = cfg_factory(*DOUBLET, "tolerance=commercial_aligned", "model.tolerance_training=true",
                      "model.calibrate=distortion")
    module = build_objects(cfg)["module"]
    seen = []
    real = calibration.warp

    def spy(img, d):
        seen.append(float(d.abs().max()))
        return real(img, d)

    monkeypatch.setattr("deeplens.training.tolerance.warp", spy)
    images = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    with module.drawn_lens(1):
        loss, *_ = module.step_loss(images, 1)
        loss.backward()
    assert len(seen) == 1 and seen[0] > 1e-4  # px: the drawn lens's image moved
    g = [p.grad for p in module.lens.parameters() if p.requires_grad]
    assert g and all(x is not None and torch.isfinite(x).all() for x in g)
    assert any(float(x.abs().max()) > 0 for x in g)
    assert module.tolerance_draws.register is None
    module.tolerance_draws.calibration = None  # the same step without calibration
    for p in module.parameters():
        p.grad = None
    with module.drawn_lens(1):
        loss_raw, *_ = module.step_loss(images, 1)
    assert float(loss_raw.detach()) != float(loss.detach())
