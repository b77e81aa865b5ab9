"""Resuming is exact: a resumed run ends bit-identical to an uninterrupted one with the same
seed, restores the checkpoint's lens, network and optimiser bit for bit, and tests its own
best checkpoint."""

from __future__ import annotations

import copy
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from deeplens.data.datamodule import TextureDataModule, derive_seed
from deeplens.training.checkpoint import checksum_path, read_checkpoint
from deeplens.training.train import train

ROOT = Path(__file__).resolve().parents[2]
FAST = ("experiment=doublet", "callbacks.image_logger=null", "~logger",
        "trainer.enable_progress_bar=false")


def test_training_loader_takes_its_epoch_when_the_pass_starts():
    """Lightning builds the training loader (and starts its first pass) before it restores
    the loops of a resumed run: the loader must take the epoch from the loop's processed-epoch
    count at iteration time, not from ``current_epoch`` at construction."""
    dm = TextureDataModule(image_size=8, batch_size=2, train_steps_per_epoch=1, val_size=1,
                           test_size=1, seed=3)
    progress = SimpleNamespace(processed=0)
    dm.trainer = SimpleNamespace(current_epoch=0,
                                 fit_loop=SimpleNamespace(
                                     epoch_progress=SimpleNamespace(current=progress)))
    loader = dm.train_dataloader()   # built while the loops still read epoch 0
    progress.processed = 2           # ... then restored: two epochs done
    seeds = next(iter(loader))["seed"].tolist()
    assert seeds == [derive_seed(3, 2, i) for i in range(2)]
    progress.processed = 3
    assert next(iter(loader))["seed"].tolist() == [derive_seed(3, 3, i) for i in range(2)]


def _states(module) -> dict:
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


def _assert_same(a: dict, b: dict):
    diff = [k for k in a if not torch.equal(a[k], b[k])]
    assert not diff, f"{len(diff)} of {len(a)} tensors differ, e.g. {diff[:3]}"


def test_resumed_run_is_bit_identical_and_tests_its_own_best(cfg_factory, tmp_path):
    """Uninterrupted 2 epochs == 1 epoch + resume to 2 (new folder), bit for bit; at the
    start of the resumed fit the lens, network and Adam state equal the checkpoint's; the
    resumed run then tests its own best.ckpt, and never the first run's (deleted) one."""
    # monitoring the epoch with mode=min, epoch 2 never improves: last.ckpt must still hold it
    _, objs_a = train(cfg_factory(*FAST, "trainer.max_epochs=2", "test=false",
                                  "callbacks.model_checkpoint.monitor=epoch",
                                  "callbacks.model_checkpoint.mode=min", out=tmp_path / "a"))
    assert read_checkpoint(tmp_path / "a" / "checkpoints" / "last.ckpt")["global_step"] == 4
    assert read_checkpoint(tmp_path / "a" / "checkpoints" / "best.ckpt")["global_step"] == 2
    train(cfg_factory(*FAST, "trainer.max_epochs=1", "test=false",
                                  out=tmp_path / "b"))
    # the run to resume from lives elsewhere and is then deleted: its checkpoint still names
    # b/checkpoints/best.ckpt as the best path
    keep = tmp_path / "kept"
    keep.mkdir()
    src = tmp_path / "b" / "checkpoints" / "last.ckpt"
    for f in (src, checksum_path(src)):
        shutil.copy(f, keep / f.name)
    shutil.rmtree(tmp_path / "b")
    ckpt = keep / "last.ckpt"
    saved = read_checkpoint(ckpt)

    cfg = cfg_factory(*FAST, "trainer.max_epochs=2", "test=true", f"ckpt_path={ckpt}",
                      out=tmp_path / "c")
    seen = {}
    from deeplens.training.module import EndToEndModule

    orig = EndToEndModule.on_train_start

    def on_train_start(self):
        seen["state"] = _states(self)
        seen["opt"] = copy.deepcopy(self.optimizers().optimizer.state_dict())
        return orig(self)

    EndToEndModule.on_train_start = on_train_start
    try:
        metrics, objs_c = train(cfg)
    finally:
        EndToEndModule.on_train_start = orig
    # restored bit for bit
    _assert_same(saved["state_dict"], seen["state"])
    opt_saved = saved["optimizer_states"][0]["state"]
    assert seen["opt"]["state"]
    for i, st in seen["opt"]["state"].items():
        for k in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(st[k], opt_saved[i][k]), (i, k)
    # ends where the uninterrupted run ended
    assert objs_c["trainer"].global_step == objs_a["trainer"].global_step == 4
    _assert_same(_states(objs_a["module"]), _states(objs_c["module"]))
    # tested its own best checkpoint, not the deleted run's
    best = tmp_path / "c" / "checkpoints" / "best.ckpt"
    assert objs_c["trainer"].ckpt_path == str(best)
    # the closing summary: test PSNR / SSIM per depth and field band, files, nothing stale
    summary = objs_c["summary"]
    assert f"tested checkpoint: {best}" in summary
    assert f"exported lens:     {best.with_suffix('.lens.json')}" in summary
    for row, tag in (("10 m", "d10000mm"), ("band0-0.33", "band0-0.33"),
                     ("band0.66-1", "band0.66-1")):
        line = next(x for x in summary.splitlines() if x.strip().startswith(row))
        psnr = metrics["test/psnr_restored/" + tag]
        assert f"{psnr:6.2f}" in line
    assert str(tmp_path / "b") not in summary
    assert "test/psnr_restored" in metrics
    # resumed with nothing left to train: no best of its own, so it tests the restored weights
    # (Lightning would carry over b/checkpoints/best.ckpt, which no longer exists)
    metrics, objs_d = train(cfg_factory(*FAST, "trainer.max_epochs=1", "test=true",
                                        f"ckpt_path={ckpt}", out=tmp_path / "d"))
    assert objs_d["trainer"].global_step == 2 and objs_d["trainer"].ckpt_path is None
    _assert_same(saved["state_dict"], _states(objs_d["module"]))
    assert "test/psnr_restored" in metrics


@pytest.mark.slow
def test_run_killed_and_resumed_ends_bit_identical(tmp_path):
    """``python train.py`` killed with SIGKILL after its first checkpoint and resumed from
    ``last.ckpt`` ends with the same lens and network as an uninterrupted run."""
    tiny = ["experiment=doublet", "sensor.resolution=[16,16]", "data.image_size=32",
            "data.batch_size=2", "data.train_steps_per_epoch=3", "data.val_size=2",
            "data.test_size=2", "render.spp=2", "trainer.max_epochs=4", "test=false",
            "callbacks.image_logger=null", "trainer.enable_progress_bar=false"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}

    def cmd(out, *extra):
        return [sys.executable, str(ROOT / "train.py"), *tiny, f"hydra.run.dir={out}", *extra]

    subprocess.run(cmd(tmp_path / "full"), check=True, env=env, cwd=ROOT,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=1200)
    run = tmp_path / "killed"
    proc = subprocess.Popen(cmd(run), env=env, cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    last = run / "checkpoints" / "last.ckpt"
    t0 = time.time()
    while not last.exists() and proc.poll() is None and time.time() - t0 < 1200:
        time.sleep(0.05)
    assert proc.poll() is None, "the run finished before it could be killed"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert read_checkpoint(last)["global_step"] < 12
    subprocess.run(cmd(tmp_path / "resumed", f"ckpt_path={last}"), check=True, env=env,
                   cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=1200)
    a = read_checkpoint(tmp_path / "full" / "checkpoints" / "last.ckpt")
    b = read_checkpoint(tmp_path / "resumed" / "checkpoints" / "last.ckpt")
    assert a["global_step"] == b["global_step"] == 12
    _assert_same(a["state_dict"], b["state_dict"])
