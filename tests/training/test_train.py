"""End-to-end training: configs compose and run, logs, checkpoints, resume, bad input."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from deeplens.training.train import build_objects, train

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = sorted(p.stem for p in (ROOT / "configs" / "experiment").glob("*.yaml"))
#: per experiment, overrides that shrink what the tiny configs do not (a design search: a
#: singlet, one start of 2 DLS steps, no hops; the shipped spec and globs, searched with a small
#: budget: tests/training/test_lens_search.py, slow; the plate search: one start, one step)
SHRINK = {"doublet_search": ("lens.search.spec.elements=1", "lens.search.spec.aspheres=0",
                             "lens.search.spec.glasses=N-BK7",
                             "lens.search.config={starts:1,hops:0,screen:2,polish:2,"
                             "polish_count:1,keep:1,seed:0,converge_steps:0}",
                             "lens.search.trainable=[surfaces.*.c]",
                             "render.psf_model=geometric"),
          # a plate search: one start of one DLS step on a coarse merit
          "edof_search": ("lens.search.plate={starts:1,steps:1,box_mm:0.006,"
                          "blur_alpha_mm:0.005,sampling:'grid:8',n_freq:2,seed:0}",),
          # the restoration merit's plate search: one start of one step at two depths
          "edof_search_restoration": ("lens.search.plate={starts:1,steps:1,box_mm:0.006,"
                                      "seed:0,merit:restoration,restoration_depths:2}",),
          # the same search; the plate's depth invariance held while it trains
          "edof_search_held": ("lens.search.plate={starts:1,steps:1,box_mm:0.006,"
                               "seed:0,merit:restoration,restoration_depths:2}",)}


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_fast_dev_run(cfg_factory, experiment):
    cfg = cfg_factory(f"experiment={experiment}", "debug=fdr", *SHRINK.get(experiment, ()))
    metrics, objs = train(cfg)
    assert math.isfinite(metrics["train/loss"])


def _read_events(logdir):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    files = list(Path(logdir).rglob("events.out.tfevents*"))
    assert files, f"no event file under {logdir}"
    acc = EventAccumulator(str(files[0].parent), size_guidance={"images": 0, "scalars": 0})
    acc.Reload()
    return acc


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_short_run_logs_scalars_images_and_checkpoints(cfg_factory, tmp_path, experiment):
    cfg = cfg_factory(f"experiment={experiment}", "test=false", *SHRINK.get(experiment, ()))
    metrics, objs = train(cfg)
    acc = _read_events(tmp_path / "tensorboard")
    scalars = set(acc.Tags()["scalars"])
    images = set(acc.Tags()["images"])
    assert "train/loss" in scalars
    depth_tags = [t for t in scalars if t.startswith("val/psnr_restored/")]
    assert depth_tags and any(t.startswith("val/psnr_sensor/") for t in scalars)
    assert any(t.startswith("val/ssim_restored/") for t in scalars)
    assert any(t.startswith("images/") for t in images)
    assert "psf/depth_rows_field_cols" in images
    panel = acc.Images("psf/depth_rows_field_cols")[-1]     # a labelled figure, not a thumbnail
    assert panel.width >= 300 and panel.height >= 200
    # the loss terms say what they are (train/loss_ssim = 1 - SSIM; val/ssim_* = SSIM)
    assert any(t.startswith("train/loss_") for t in scalars)
    assert not {"train/ssim", "train/mse", "train/l1"} & scalars
    assert "lr/net" in scalars and any(t.startswith("lr/") and t != "lr/net" for t in scalars)
    edof = experiment.startswith("edof")   # edof and edof_search: a plate, depths
    if edof:        # its Wiener filter learns the noise ratio
        assert "wiener/nsr_c0" in scalars
    assert any(t.startswith("lens_params/") for t in scalars)
    if edof:
        assert "lens/phase_plate_height" in images
        assert any("d4500mm" in t for t in depth_tags)
    else:
        assert any("band" in t for t in depth_tags)
    figs = acc.Tags().get("images", [])
    assert "lens/layout" in figs
    ckpts = tmp_path / "checkpoints"
    assert (ckpts / "last.ckpt").exists() and (ckpts / "last.lens.json").exists()
    assert (ckpts / "best.ckpt").exists() and (ckpts / "best.lens.json").exists()
    assert not list(ckpts.glob("*.tmp"))


def test_training_steps_change_optics_and_network(cfg_factory):
    # two steps: the restorer's zero-initialised head makes it the identity at step 0, so only
    # the head (and the lens) get a gradient on the very first step
    cfg = cfg_factory("experiment=doublet", "trainer.max_steps=2", "test=false",
                      "trainer.limit_val_batches=0")
    objs = build_objects(cfg)
    module = objs["module"]
    lens_before = {n: p.detach().clone() for n, p in module.lens.named_parameters()
                   if p.requires_grad}
    net_before = [p.detach().clone() for p in module.restorer.parameters()]
    objs["trainer"].fit(module, datamodule=objs["datamodule"])
    assert lens_before
    for n, p in module.lens.named_parameters():
        if n in lens_before:
            assert not torch.equal(p.detach(), lens_before[n]), n
    changed = sum(not torch.equal(a, b.detach()) for a, b in
                  zip(net_before, module.restorer.parameters()))
    assert changed > 0.9 * len(net_before)


def test_overfit_lowers_the_loss(cfg_factory):
    cfg = cfg_factory("experiment=edof", "debug=overfit", "trainer.max_epochs=15", "test=false",
                      "lens.learned_start_alpha_mm=null",
                      "trainer.limit_val_batches=0", "callbacks.image_logger=null",
                      "callbacks.model_checkpoint=null")
    objs = build_objects(cfg)
    losses = []
    module = objs["module"]
    orig = module.training_step

    def step(batch, batch_idx):
        out = orig(batch, batch_idx)
        losses.append(float(out))
        return out

    module.training_step = step
    objs["trainer"].fit(module, datamodule=objs["datamodule"])
    assert len(losses) >= 10
    assert sum(losses[-3:]) / 3 < 0.7 * sum(losses[:3]) / 3


def test_unknown_key_and_wrong_type_fail_at_startup(cfg_factory):
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException, match="rende"):
        cfg_factory("rende.spp=3")
    with pytest.raises(ConfigCompositionException, match="spq"):
        cfg_factory("render.spq=3")
    cfg = cfg_factory("render.spp=abc")
    with pytest.raises(ValueError, match=r"render\.spp.*int.*abc"):
        build_objects(cfg)


def test_fully_vignetting_lens_fails_before_training(cfg_factory, tmp_path):
    import json

    lens = json.loads((ROOT / "data/lenses/wide_doublet.json").read_text())
    # the stop decentred by 5 mm: no ray can pass both it and the doublet (2.6 mm semi-diameter)
    lens["misalignment"] = [{"dx_mm": 5.0}, {}]
    p = tmp_path / "blocked.json"
    p.write_text(json.dumps(lens))
    cfg = cfg_factory("experiment=doublet", f"lens.path={p}")
    with pytest.raises(ValueError, match=r"field .* deg"):
        build_objects(cfg)


def _fit_until_stopped(cfg_factory, plant):
    """Fit a tiny EDOF run whose step 1 is broken by ``plant(module)``; returns the error, the
    module state at the start of step 1 and the module."""
    from deeplens.training.module import NonFiniteLossError

    # no optics warm-up: during one the optics are fixed for the whole step and have no
    # gradient at all (so there is none to break)
    objs = build_objects(cfg_factory("experiment=edof", "test=false", "trainer.max_epochs=1",
                                     "callbacks.image_logger=null", "~logger",
                                     "model.optics_warmup_steps=null"))
    module = objs["module"]
    before = {}
    orig = module.training_step

    def step(batch, batch_idx=0):
        if module.global_step == 1:
            before.update({k: v.detach().clone() for k, v in module.state_dict().items()})
            plant(module)
        return orig(batch, batch_idx)

    module.training_step = step
    with pytest.raises(NonFiniteLossError) as e:
        objs["trainer"].fit(module, datamodule=objs["datamodule"])
    return str(e.value), before, module


def _saved_state_is(path, state):
    from deeplens.training.checkpoint import read_checkpoint

    saved = read_checkpoint(path)["state_dict"]
    assert saved.keys() == state.keys()
    for k, v in state.items():
        assert torch.equal(saved[k], v), k
        assert torch.isfinite(v).all() or not v.is_floating_point(), k


def test_nan_loss_stops_with_step_and_saves_the_state_before_it(cfg_factory, tmp_path):
    """The state saved is the one the failing step started from (finite), in checkpoints/ (not
    under tensorboard/), verified by its digest; the message names the step and the file."""
    def plant(module):
        orig = module.image_loss

        def bad_loss(pred, gt, depths=None):
            terms = orig(pred, gt, depths)
            terms["mse"] = terms["mse"] * float("nan")
            return terms

        module.image_loss = bad_loss

    msg, before, _ = _fit_until_stopped(cfg_factory, plant)
    path = tmp_path / "checkpoints" / "nonfinite_step1.ckpt"
    assert "non-finite loss nan at step 1" in msg and str(path) in msg
    _saved_state_is(path, before)


@pytest.mark.parametrize("where", ["lens", "restorer"])
def test_nonfinite_gradient_stops_before_the_optimiser_step(cfg_factory, tmp_path, where):
    """A NaN gradient (of a lens parameter or of a network weight) stops training before Adam
    uses it: the message names the parameter and the step, and the saved state is the one
    before the step (an unchecked network gradient would turn the weights into NaN)."""
    def plant(module):
        p = (module.lens.surfaces[4].a[6] if where == "lens"
             else next(module.restorer.parameters()))
        p.register_hook(lambda g: g * float("nan"))

    msg, before, module = _fit_until_stopped(cfg_factory, plant)
    first = next(iter(dict(module.restorer.named_parameters())))
    name = "lens.surfaces.4.a.6" if where == "lens" else f"restorer.{first}"
    assert f"non-finite gradient of {name} at step 1" in msg
    path = tmp_path / "checkpoints" / "nonfinite_step1.ckpt"
    assert str(path) in msg
    _saved_state_is(path, before)
    for k, v in module.state_dict().items():  # no step was taken with the NaN gradient
        assert torch.equal(v, before[k]), k


@pytest.mark.slow
def test_ddp_two_processes_on_cpu(cfg_factory):
    """Lightning DDP (gloo) with 2 CPU processes: both ranks train and stay in sync."""
    cfg = cfg_factory("experiment=edof", "trainer=ddp_cpu", "test=false",
                      "callbacks.image_logger=null")
    metrics, objs = train(cfg)
    assert math.isfinite(metrics["train/loss"])
    assert objs["trainer"].world_size == 2


def test_constraint_bounds_departure_from_the_initial_surface(cfg_factory):
    """Zero at the start (the doublet's curved surfaces are not penalised for their own sag),
    positive past the bound, and its gradient matches a central finite difference."""
    objs = build_objects(cfg_factory("experiment=doublet"))
    m = objs["module"]
    assert float(m.constraint_loss()) == 0.0
    a4 = m.lens.surfaces[1].a[0]
    with torch.no_grad():
        a4 += 0.1 / 2.6 ** 4  # ~0.1 mm departure at the rim: twice the 0.05 mm bound
    c = m.constraint_loss()
    assert float(c) > 0
    (g,) = torch.autograd.grad(c, a4)
    h = 1e-3 / 2.6 ** 4
    with torch.no_grad():
        a4 += h
        cp = float(m.constraint_loss())
        a4 -= 2 * h
        cm = float(m.constraint_loss())
        a4 += h
    assert float(g) == pytest.approx((cp - cm) / (2 * h), rel=1e-3)


def test_authors_table_lens_trains_with_table_options(cfg_factory):
    """A .txt prescription without an 'A' row trains once lens.table_options names the stop;
    without it, or with a misspelt option, start-up fails naming the config key."""
    from deeplens.optics.io import LensFileError

    txt = ROOT / "tests" / "data" / "lenses" / "LA1131.txt"
    base = ("experiment=doublet", f"lens.path={txt}", "lens.trainable=[surfaces.0.c]",
            "debug=fdr")
    with pytest.raises(LensFileError, match=r"lens\.table_options\.stop_index"):
        build_objects(cfg_factory(*base))
    with pytest.raises(ValueError, match=r"lens.table_options: unknown key\(s\) \['stop_indx'\]"):
        build_objects(cfg_factory(*base, "+lens.table_options.stop_indx=1"))
    with pytest.raises(ValueError, match=r"apply to the authors' \.txt tables only"):
        build_objects(cfg_factory("experiment=doublet", "lens.table_options.scale=2.0"))
    objs = build_objects(cfg_factory(*base, "lens.table_options.stop_index=0"))
    assert objs["lens"].stop_index == 0
    c0 = float(objs["lens"].surfaces[0].c)
    objs["trainer"].fit(objs["module"], datamodule=objs["datamodule"])
    assert float(objs["lens"].surfaces[0].c) != c0


def test_monochrome_sensor_trains_grey_with_one_channel_networks(cfg_factory):
    """sensor.channels with one (panchromatic) channel: textures become grey, the restorer (and
    an opt-in discriminator) take one channel, and a step trains optics and network."""
    cfg = cfg_factory("experiment=edof", "sensor.channels=[[486.1,587.6,656.3]]",
                      "test=false", "trainer.limit_val_batches=1", "model.optics_warmup_steps=0",
                      "model.loss.adversarial=0.01",
                      "+model.discriminator={_target_:deeplens.nets.PatchGANDiscriminator,"
                      "base_channels:8,n_layers:1}")
    objs = build_objects(cfg)
    m = objs["module"]
    img = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    y, gt = m.capture(img, [5000.0, 6000.0], seed=1, noise=False)
    assert y.shape == gt.shape == (2, 1, 16, 16)
    assert m.restorer(y).shape == (2, 1, 16, 16)
    a0 = [float(a) for a in m.lens.surfaces[4].a]
    objs["trainer"].fit(m, datamodule=objs["datamodule"])
    assert [float(a) for a in m.lens.surfaces[4].a] != a0
    assert math.isfinite(float(objs["trainer"].callback_metrics["val/psnr_restored"]))


def test_sensor_and_network_channel_mismatch_fails_at_startup(cfg_factory):
    with pytest.raises(ValueError, match=r"net\.in_channels: expected 1 or null \(the sensor's channel count"):
        build_objects(cfg_factory("experiment=edof", "sensor.channels=[[587.6]]",
                                  "net.in_channels=3"))
    with pytest.raises(ValueError, match=r"sensor\.channels: expected 1 channel .* or 3 "
                                         r"\(the training textures are RGB\)"):
        build_objects(cfg_factory("experiment=edof", "sensor.channels=[[486.1],[656.3]]"))


_MEANINGLESS = [  # (key, value of the right type, what the message must say is expected)
    ("scene.depths_mm", [0.0, 1000.0], "distances > 0 mm"),
    ("scene.depths_mm", [-4500.0, 8000.0], "distances > 0 mm"),
    ("scene.depths_mm", [4500.0, math.inf], "finite"),
    ("scene.val_depths_mm", [0.0], "distances > 0 mm"),
    ("scene.field_bands", [0.0, 0.6, 0.5, 1.0], "increasing band edges"),
    ("scene.psf_fields_deg", [0.0, 95.0], r"\[0, 90\)"),
    ("model.optics_lr_mm", math.inf, r"finite learning rate in \(0, 1\]"),
    ("model.optics_lr_mm", 1e6, r"\(0, 1\]"),
    ("model.net_lr", 0.0, r"\(0, 1\]"),
    ("model.net_lr", math.nan, r"finite"),
    ("model.disc_lr", -1e-4, r"\(0, 1\]"),
    ("model.loss.mse", math.nan, r"finite weight >= 0"),
    ("model.loss.ssim", -0.1, r"finite weight >= 0"),
    ("model.max_sag_mm", -0.05, r"> 0"),
    ("seed", -1, r"int in \[0, 4294967295\]"),
    ("seed", 2 ** 32, r"int in \[0, 4294967295\]"),
    ("sensor.pixel_size_mm", 0.0, r"> 0"),
    ("sensor.full_well", -1.0, r">= 0"),
    ("sensor.read_noise", math.inf, r"finite"),
    ("sensor.resolution", [16, 0], r"both >= 6"),
    ("render.spp", 0, r"int >= 1"),
    ("render.newton_tol", 0.0, r"> 0"),
    ("render.psf_patches", [3], r"\[rows, cols\]"),
    ("data.batch_size", 0, r"int >= 1"),
    ("lens.plate_surface", -1, r"int >= 0"),
    ("callbacks.image_logger.psf_rays", 0, r"int >= 1"),
]


def test_meaningless_values_fail_at_startup_naming_the_key(cfg_factory):
    """Values of the right type but no meaning (a depth of 0 divides by zero in training, an
    infinite learning rate gives NaN parameters, 1e6 runs away, a negative seed breaks numpy)
    stop before anything is built, naming the key, what was expected and the value."""
    import re

    from omegaconf import OmegaConf

    from deeplens.optics.errors import ConfigError
    from deeplens.training.train import check_config

    base = cfg_factory("experiment=edof")
    check_config(base)
    for key, value, expected in _MEANINGLESS:
        cfg = base.copy()
        OmegaConf.update(cfg, key, value, merge=False)
        with pytest.raises(ConfigError, match=rf"^{re.escape(key)}: expected .*{expected}.*, "
                                              rf"got ") as e:
            check_config(cfg)
        assert e.value.key == key


def test_module_checks_learning_rates_and_loss_weights_itself():
    """Built without the config (a script, a notebook): the same checks, naming model.*."""
    from deeplens.training.module import check_learning_rate

    assert check_learning_rate("net_lr", 1e-3) == 1e-3
    for bad in (float("inf"), float("nan"), 0.0, -1e-3, 2.0, "fast"):
        with pytest.raises(ValueError, match="model.net_lr"):
            check_learning_rate("net_lr", bad)


def test_default_configs_pass_the_checks(cfg_factory):
    from deeplens.training.train import check_config

    for experiment in EXPERIMENTS:
        check_config(cfg_factory(f"experiment={experiment}", tiny=False))


def test_scene_margin_extends_the_texture_beyond_the_frame(cfg_factory):
    """With ``scene.margin = m`` a texture spans ``1 + 2m`` fields of view: a texture that is 1
    on its central ``1 / (1 + 2m)`` and 0 outside fills the whole frame with 1 (ground truth);
    a uniform scene keeps its brightness through the blur, where a texture filling the frame
    exactly brings black in at the edges."""
    m = 0.25
    objs = build_objects(cfg_factory("experiment=edof", f"scene.margin={m}",
                                     "callbacks.image_logger=null",
                                     "lens.learned_start_alpha_mm=null"))  # flat plate
    module = objs["module"]
    n = 60
    tex = torch.zeros(1, 3, n, n)
    inner = round(n / (1 + 2 * m))  # 40 of 60 texels: the field of view
    a = (n - inner) // 2
    tex[..., a:a + inner, a:a + inner] = 1.0
    with torch.no_grad():
        _, gt = module.capture(tex, [8000.0], seed=0, noise=False)
        assert float(gt[..., 1:-1, 1:-1].min()) > 0.99  # bilinear edges of the inner square
        assert float(gt[..., 0, :].max()) > 0.99
        y0, _ = module.capture(torch.ones(1, 3, 8, 8), [8000.0], seed=0, noise=False)
        module.scene_margin = 0.0  # the same uniform texture filling the frame exactly
        y1, _ = module.capture(torch.ones(1, 3, 8, 8), [8000.0], seed=0, noise=False)
    assert float(y0.mean()) > 0.97
    assert float(y1.mean()) < float(y0.mean()) - 0.05  # black blurred in at the edges
    with pytest.raises(ValueError, match="scene.margin"):
        build_objects(cfg_factory("experiment=edof", "scene.margin=-0.5"))


def test_worst_depth_weights_are_a_soft_maximum_over_depth_bins(cfg_factory):
    """``model.worst_depth``: bins uniform in 1/depth, running mean loss per bin, weights
    ``K softmax(log E / T)``: the bin with the larger loss gets the larger weight, by the ratio
    ``(E_a / E_b)^(1/T)``; the weighted MSE term equals the hand-computed weighted mean."""
    cfg = cfg_factory("experiment=edof", "model.worst_depth={temperature:0.5,bins:2,momentum:0.5}")
    m = build_objects(cfg)["module"]
    near, far = 4500.0, 8000.0  # the range's ends: bins 1 and 0
    assert m.depth_softmax.bin([far, near, 7999.0, 4501.0]).tolist() == [0, 1, 0, 1]
    gt = torch.full((2, 3, 8, 8), 0.5)
    pred = gt.clone()
    pred[0] += 0.1    # far sample: MSE 0.01
    pred[1] += 0.05   # near sample: MSE 0.0025
    m.loss_w.update(ssim=0.0)
    terms = m.image_loss(pred, gt, [far, near])
    ratio = (0.01 / 0.0025) ** (1 / 0.5)  # 16: the far bin's weight over the near bin's
    w_far, w_near = 2 * ratio / (1 + ratio), 2 / (1 + ratio)
    assert torch.allclose(m.depth_softmax.loss_ema, torch.tensor([0.01, 0.0025], dtype=torch.float64))
    assert float(terms["mse"]) == pytest.approx((w_far * 0.01 + w_near * 0.0025) / 2, rel=1e-5)
    # running means: momentum 0.5 towards the new values
    m.image_loss(pred.flip(0), gt, [far, near])  # far now MSE 0.0025, near 0.01
    assert torch.allclose(m.depth_softmax.loss_ema, torch.tensor([0.00625, 0.00625], dtype=torch.float64))
    # a plain run's loss is the batch mean
    plain = build_objects(cfg_factory("experiment=edof"))["module"]
    plain.loss_w.update(ssim=0.0)
    assert float(plain.image_loss(pred, gt, [far, near])["mse"]) == pytest.approx(
        (0.01 + 0.0025) / 2, rel=1e-5)
    with pytest.raises(ValueError, match="model.worst_depth.temperature"):
        build_objects(cfg_factory("experiment=edof", "model.worst_depth={temperature:0}"))
    with pytest.raises(ValueError, match="model.worst_depth.bins"):
        build_objects(cfg_factory("experiment=edof", "model.worst_depth={bins:0}"))
    with pytest.raises(ValueError, match="model.worst_depth.momentum"):
        build_objects(cfg_factory("experiment=edof", "model.worst_depth={momentum:1.0}"))
    with pytest.raises(ValueError, match=r"model.worst_depth: unknown key\(s\) \['temp'\]"):
        build_objects(cfg_factory("experiment=edof", "model.worst_depth={temp:1.0}"))


def test_render_compile_switch_reaches_the_tracer(cfg_factory):
    """``render.compile`` is passed to the tracer's options (nothing compiles at build time);
    a wrong value names the key."""
    from deeplens.training.train import build_renderer

    objs = build_objects(cfg_factory("experiment=edof"))
    assert objs["renderer"].options.compile == "default"   # decided after the first step
    off = build_renderer(cfg_factory("experiment=edof", "render.compile=false"), objs["lens"],
                         objs["sensor"])
    assert off.options.compile is False
    cfg = cfg_factory("experiment=edof", "render.compile=true")
    r = build_renderer(cfg, objs["lens"], objs["sensor"])
    assert r.options.compile == "auto"
    with pytest.raises(ValueError, match=r"render.compile: expected 'default', false, .*, "
                                         r"got 'fastest'"):
        build_renderer(cfg_factory("experiment=edof", "render.compile=fastest"), objs["lens"],
                       objs["sensor"])


def test_deconvolution_front_end_trains_with_the_lens_and_is_checkpointed(cfg_factory, tmp_path):
    """``model.deconvolution``: the restorer sees the Wiener-deconvolved image, the noise ratio
    trains in the network's group, the plate's gradient includes the filter's, and the state
    is checkpointed; bad keys are refused by name."""
    cfg = cfg_factory("experiment=edof", "render=psf", "render.psf_patches=[1,1]",
                      "render.psf_rays=1024", "trainer.max_steps=2", "test=false",
                      "model.deconvolution={depths:2,rays:1024,nsr:0.02}")
    objs = build_objects(cfg)
    m = objs["module"]
    assert m.deconv is not None and m.deconv.depths_mm == pytest.approx([8000.0, 4500.0])
    net = m._param_groups()[0]
    assert net["name"] == "net" and any(p is m.deconv.log_nsr for p in net["params"])
    y = torch.rand(1, 3, 16, 16)
    assert torch.allclose(m(y), m.restorer(m.deconv(y)))
    # the plate's gradient through the filter alone (fixed sensor image) is not zero
    plate = [p for n, p in m.lens.named_parameters() if p.requires_grad]
    g = torch.autograd.grad(m.deconv(y).square().sum(), plate, allow_unused=True)
    assert any(x is not None and float(x.abs().max()) > 0 for x in g)
    before = m.deconv.log_nsr.detach().clone()
    objs["trainer"].fit(m, datamodule=objs["datamodule"])
    assert not torch.equal(m.deconv.log_nsr.detach(), before)
    state = torch.load(tmp_path / "checkpoints" / "last.ckpt", weights_only=False)["state_dict"]
    assert torch.equal(state["deconv.log_nsr"], m.deconv.log_nsr.detach())
    with pytest.raises(ValueError, match=r"model.deconvolution: unknown key\(s\) \['nrs'\]"):
        build_objects(cfg_factory("experiment=doublet", "model.deconvolution={nrs:0.1}"))


def test_optics_warmup_keeps_the_lens_fixed_for_its_steps(cfg_factory):
    """``model.optics_warmup_steps=N``: the lens does not move in the first N steps (the
    restorer does), and moves after; a negative value is refused by name."""

    def run(steps, warmup):
        cfg = cfg_factory("experiment=doublet", f"trainer.max_steps={steps}", "test=false",
                          "trainer.limit_val_batches=0", f"model.optics_warmup_steps={warmup}")
        objs = build_objects(cfg)
        m = objs["module"]
        lens0 = [p.detach().clone() for p in m.lens.parameters() if p.requires_grad]
        net0 = [p.detach().clone() for p in m.restorer.parameters()]
        objs["trainer"].fit(m, datamodule=objs["datamodule"])
        lens_moved = any(not torch.equal(a, p.detach()) for a, p in
                         zip(lens0, [p for p in m.lens.parameters() if p.requires_grad]))
        net_moved = any(not torch.equal(a, p.detach()) for a, p in
                        zip(net0, m.restorer.parameters()))
        return lens_moved, net_moved

    assert run(2, 2) == (False, True)
    assert run(2, 1) == (True, True)
    with pytest.raises(ValueError, match="model.optics_warmup_steps"):
        build_objects(cfg_factory("experiment=doublet", "model.optics_warmup_steps=-1"))


def test_optics_warmup_traces_the_lens_without_gradients(cfg_factory):
    """During ``optics_warmup_steps`` the render and the Wiener filter run with the lens
    parameters not requiring gradients (their gradients were discarded anyway), giving the same
    loss; afterwards, and after the step, the parameters require gradients again."""
    over = ("experiment=edof", "render.psf_rays=512", "model.deconvolution.rays=256",
            "model.optics_warmup_steps=3")
    m = build_objects(cfg_factory(*over))["module"]
    trained = [p for p in m.lens.parameters() if p.requires_grad]
    assert trained
    seen, render = [], m.renderer.forward

    def spy(*args, **kwargs):
        seen.append(any(p.requires_grad for p in m.lens.parameters()))
        return render(*args, **kwargs)

    m.renderer.forward = spy
    images = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    fixed, *_ = m.step_loss(images, 2)
    assert all(p.requires_grad for p in trained)
    moving, *_ = m.step_loss(images, 3)
    assert seen == [False, True]
    m.optics_warmup_steps = 0  # step 2 again, the lens traced with gradients: the same loss
    again, *_ = m.step_loss(images, 2)
    assert seen[-1] is True
    assert torch.equal(fixed.detach(), again.detach())
    assert fixed.grad_fn is not None  # the restorer still trains


def test_optics_worst_depth_weights_only_the_optics_gradient(cfg_factory):
    """``model.optics_worst_depth``: the restorer's gradient is the plain mean's, the lens's
    is that of the per-sample losses weighted by the depth bins' soft maximum (computed here
    from the samples' own losses with momentum 0), not the plain mean's."""
    from kornia.metrics import ssim as kssim

    over = ("experiment=edof", "render.psf_rays=512", "model.deconvolution.rays=256",
            "data.batch_size=4", "model.optics_worst_depth={temperature:0.3,bins:2,momentum:0}",
            "model.optics_warmup_steps=0")
    m = build_objects(cfg_factory(*over))["module"]
    images = torch.rand(4, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    depths = m.sample_depths(4, 5)
    bins = m.optics_depth_softmax.bin(depths)
    assert len(set(bins.tolist())) == 2  # both bins in the batch (else the test is vacuous)
    lens_p = [p for p in m.lens.parameters() if p.requires_grad]
    net_p = list(m.restorer.parameters())
    loss, *_ = m.step_loss(images, 5)
    g = torch.autograd.grad(loss, lens_p + net_p)
    g_lens, g_net = g[:len(lens_p)], g[len(lens_p):]

    # the reference: the same step by hand
    y, gt = m.capture(images, depths, seed=m.seed * 1_000_003 + 5)
    pred = m.restorer(m.deconv(y))
    w = m.loss_w
    per = (w["mse"] * ((pred - gt) ** 2).flatten(1).mean(1)
           + w["ssim"] * (1 - kssim(pred.clamp(0, 1), gt, 11).flatten(1).mean(1)))
    E = torch.stack([per.detach()[bins == b].mean() for b in range(2)]).double()
    wt = (2 * torch.softmax(E.log() / 0.3, 0))[bins].to(per.dtype)
    assert float(wt.max() / wt.min()) > 1.01
    ref_lens = torch.autograd.grad((wt * per).mean(), lens_p, retain_graph=True)
    plain_lens = torch.autograd.grad(per.mean(), lens_p, retain_graph=True)
    ref_net = torch.autograd.grad(per.mean(), net_p)
    for a, b, c in zip(g_lens, ref_lens, plain_lens):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-12 + 1e-4 * float(b.abs().max()))
    assert max(float((a - c).abs().max() / c.abs().max()) for a, c in
               zip(g_lens, plain_lens)) > 1e-3
    for a, b in zip(g_net, ref_net):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-7)
    with pytest.raises(ValueError, match="model.optics_worst_depth.temperature"):
        build_objects(cfg_factory("experiment=edof", "model.optics_worst_depth={temperature:0}"))


@pytest.mark.numerics
def test_optics_invariance_holds_the_plate_to_its_starting_depth_invariance(cfg_factory):
    """``model.optics_invariance``: the first moving step records ``R_0`` (penalty 0); a plate
    made less depth-invariant (a weaker cubic) is penalised by ``w relu(R / R_0 - 1 - s)^2``
    with ``R`` from the same step's Wiener moments, the loss's lens gradient is the image
    loss's plus ``w`` times the penalty's, and a step down the penalty's gradient makes the
    plate more depth-invariant.  ``R_0`` is checkpointed state."""
    from deeplens.training.lens_setup import cubic_phase_plate
    from deeplens.training.wiener import depth_change

    over = ("experiment=edof", "render.psf_rays=512", "model.deconvolution.rays=1024",
            "model.deconvolution.depths=3", "model.optics_warmup_steps=0",
            "model.optics_worst_depth=null", "model.optics_invariance={weight:3.0,slack:0.05}")
    m = build_objects(cfg_factory(*over))["module"]
    images = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    loss, terms, *_ = m.step_loss(images, 0)
    R0 = float(m.invariance.ref)
    assert 0 < R0 < 1 and float(terms["invariance"].detach()) == 0.0
    assert "invariance_ref" in m.state_dict()
    lens_p = [p for p in m.lens.parameters() if p.requires_grad]
    with torch.no_grad():  # the 5 um start made a 1.25 um plate: its PSF changes with depth
        cubic_phase_plate(m.lens, 4, 0.00125)
    loss, terms, y, *_ = m.step_loss(images, 1)
    assert float(m.invariance.ref) == R0  # the reference stays
    pen = terms["invariance"]
    g_all = torch.autograd.grad(loss, lens_p, retain_graph=True)
    g_pen = torch.autograd.grad(pen, lens_p, retain_graph=True)
    g_img = torch.autograd.grad(loss - 3.0 * pen, lens_p)
    for a, b, c in zip(g_all, g_img, g_pen):
        assert torch.allclose(a, b + 3.0 * c, rtol=1e-4, atol=1e-4 * float(a.abs().max()))
    # the penalty by hand from the filter's moments of the same lens
    with torch.no_grad():
        H, W = y.shape[-2:]
        size = (H + 2 * (H // 2), W + 2 * (W // 2))  # the filter's FFT size (half-frame margins)
        R = float(depth_change(*m.deconv.otf_moments(size)))
    assert R > 1.05 * R0
    assert float(pen) == pytest.approx((R / R0 - 1.05) ** 2, rel=1e-3)
    # a step down the penalty's gradient lowers R, by more than float32's rounding of R (about
    # 100 eps32 R: a 1e-4 step moved R by +4e-6 under ATEN_CPU_CAPABILITY=default and -3e-6
    # under AVX-512, noise; a 1e-2 step moves it by -2.5e-3, in the linear regime)
    with torch.no_grad():
        for p, g in zip(lens_p, g_pen):
            p -= 1e-2 * float(p.abs().max() + 1e-12) * g / float(g.abs().max() + 1e-30)
        R1 = float(depth_change(*m.deconv.otf_moments(size)))
    assert R - R1 > 1e3 * torch.finfo(torch.float32).eps * R


@pytest.mark.parametrize("setting, match", [
    ("model.optics_invariance={weight:0}", r"model.optics_invariance.weight: expected a finite "
     r"number > 0"),
    ("model.optics_invariance={slack:-1}", r"model.optics_invariance.slack"),
    ("model.optics_invariance={wieght:1}", r"model.optics_invariance: unknown key"),
    ("model.optics_invariance={weight:1} model.deconvolution=null",
     r"model.optics_invariance: expected null without model.deconvolution"),
])
def test_bad_optics_invariance_is_refused_by_name(cfg_factory, setting, match):
    with pytest.raises(ValueError, match=match):
        build_objects(cfg_factory("experiment=edof", *setting.split()))


def test_optics_invariance_is_dropped_for_frozen_optics(cfg_factory):
    m = build_objects(cfg_factory("experiment=edof", "lens.plate=cubic", "lens.trainable=[]",
                                  "lens.plate_alpha_mm=0.005", "model.deconvolution.rays=256",
                                  "model.optics_invariance={weight:1}"))["module"]
    assert m.optics_invariance is None and "invariance_ref" not in m.state_dict()
