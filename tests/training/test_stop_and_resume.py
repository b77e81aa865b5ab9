"""Stopping and resuming (issue 25, items 2-4 and 6): a run stopped mid-epoch (a
``val_check_interval`` checkpoint, SIGTERM, SIGINT) resumes to the same weights as an
uninterrupted one; last.ckpt holds the final step; a signal exits non-zero naming the
checkpoint; changed learning rates apply on resume and are reported; one live run per folder."""

from __future__ import annotations

import logging
import os
import shutil
import signal

import pytest
import torch

from deeplens.training.checkpoint import checksum_path, read_checkpoint
from deeplens.training.module import EndToEndModule
from deeplens.training.run_lock import FolderInUseError, hold_output_folder
from deeplens.training.stop_signals import StoppedBySignal
from deeplens.training.train import train

# 3 batches per epoch, validation (and a checkpoint) after batch 2 of each epoch: steps 2, 5
FAST = ("experiment=doublet", "callbacks.image_logger=null", "~logger",
        "trainer.enable_progress_bar=false", "test=false", "data.train_steps_per_epoch=3",
        "+trainer.val_check_interval=2", "trainer.max_epochs=2")


def _same(a: dict, b: dict):
    diff = [k for k in a if not torch.equal(a[k], b[k])]
    assert not diff, f"{len(diff)} of {len(a)} tensors differ, e.g. {diff[:3]}"


def _keep(src, folder):
    """Copy a checkpoint and its digest out of the run's folder (the next run may overwrite)."""
    folder.mkdir(exist_ok=True)
    for f in (src, checksum_path(src)):
        shutil.copy(f, folder / f.name)
    return folder / src.name


def _signal_at(step: int, sig):
    """Patch the module so that the process sends itself ``sig`` after training step ``step``."""
    orig = EndToEndModule.on_train_batch_end

    def on_train_batch_end(self, outputs, batch, batch_idx):
        if self.global_step == step:
            os.kill(os.getpid(), sig)
        return orig(self, outputs, batch, batch_idx)

    EndToEndModule.on_train_batch_end = on_train_batch_end
    return lambda: setattr(EndToEndModule, "on_train_batch_end", orig)


def test_mid_epoch_stops_resume_exactly(cfg_factory, tmp_path, caplog):
    _, full = train(cfg_factory(*FAST, out=tmp_path / "full"))
    last = read_checkpoint(tmp_path / "full" / "checkpoints" / "last.ckpt")
    # the final step comes after the last validation (step 5): last.ckpt must still hold it
    assert full["trainer"].global_step == 6 and last["global_step"] == 6
    _same(last["state_dict"], full["module"].state_dict())
    want = {k: v.clone() for k, v in full["module"].state_dict().items()}

    for sig, step, code in ((signal.SIGTERM, 2, 143), (signal.SIGINT, 4, 130)):
        run = tmp_path / sig.name
        undo = _signal_at(step, sig)
        try:
            with pytest.raises(StoppedBySignal) as e:
                train(cfg_factory(*FAST, out=run))
        finally:
            undo()
        path = run / "checkpoints" / "last.ckpt"
        assert e.value.code == code and e.value.checkpoint == str(path)
        assert f"stopped by {sig.name} after step {step}" in str(e.value)
        assert f"ckpt_path={path}" in str(e.value)
        assert read_checkpoint(path)["global_step"] == step  # mid-epoch (3 steps per epoch)
        ckpt = _keep(path, tmp_path / f"kept_{sig.name}")
        _, resumed = train(cfg_factory(*FAST, f"ckpt_path={ckpt}", out=tmp_path / f"r_{sig.name}"))
        assert resumed["trainer"].global_step == 6
        _same(want, resumed["module"].state_dict())
        # TensorBoard's step (batches that stepped) is not shifted by the resume
        assert resumed["trainer"].fit_loop.epoch_loop._batches_that_stepped == 6

    # changed learning rates on resume: applied, and said
    with caplog.at_level(logging.INFO):
        _, changed = train(cfg_factory(*FAST, "model.net_lr=3e-4", "trainer.max_epochs=1",
                                       f"ckpt_path={tmp_path / 'kept_SIGTERM' / 'last.ckpt'}",
                                       out=tmp_path / "lr"))
    groups = changed["trainer"].optimizers[0].param_groups
    assert groups[0]["name"] == "net" and groups[0]["lr"] == 3e-4
    assert "net: 0.001 -> 0.0003" in caplog.text and "this run's learning rates" in caplog.text


def test_a_folder_held_by_a_live_run_is_refused(cfg_factory, tmp_path):
    cfg = cfg_factory(*FAST, "train=false", out=tmp_path)
    with hold_output_folder(tmp_path):
        with pytest.raises(FolderInUseError, match=rf"{tmp_path} is in use by another live run "
                                                   rf"\(pid {os.getpid()}"):
            train(cfg)
        with pytest.raises(FolderInUseError):  # a second holder in the same process, too
            with hold_output_folder(tmp_path):
                pass
    with hold_output_folder(tmp_path):  # released when the holder ends
        pass


def test_resume_from_a_bare_state_dict_is_named(cfg_factory, tmp_path):
    from deeplens.training.checkpoint import CheckpointError

    p = tmp_path / "weights.pt"
    torch.save({"restorer.w": torch.zeros(2)}, p)
    with pytest.warns(UserWarning, match="no digest"):
        with pytest.raises(CheckpointError, match="bare state dict"):
            train(cfg_factory(*FAST, f"ckpt_path={p}", out=tmp_path / "run"))


def test_resume_from_a_nonfinite_step_checkpoint_keeps_the_logging_step(cfg_factory, tmp_path):
    """The state saved before a non-finite step resumes with TensorBoard's step equal to the
    global step (it used to be one ahead: every logged point after the resume shifted)."""
    from deeplens.training.module import NonFiniteLossError

    orig = EndToEndModule.image_loss

    def nan_at_step_1(self, pred, gt, depths=None):
        terms = orig(self, pred, gt, depths)
        if self.global_step == 1:
            terms["mse"] = terms["mse"] * float("nan")
        return terms

    EndToEndModule.image_loss = nan_at_step_1
    try:
        with pytest.raises(NonFiniteLossError, match="resume with ckpt_path="):
            train(cfg_factory(*FAST, out=tmp_path / "nan"))
    finally:
        EndToEndModule.image_loss = orig
    ckpt = tmp_path / "nan" / "checkpoints" / "nonfinite_step1.ckpt"
    _, objs = train(cfg_factory(*FAST, "trainer.max_epochs=1", f"ckpt_path={ckpt}",
                                out=tmp_path / "resumed"))
    trainer = objs["trainer"]
    assert trainer.global_step == 3
    assert trainer.fit_loop.epoch_loop._batches_that_stepped == trainer.global_step


@pytest.mark.slow
def test_train_py_exits_143_on_sigterm_naming_the_checkpoint(tmp_path):
    """The real entry point under a real SIGTERM (what a scheduler sends): exit status 143 (it
    was 0), and stderr names the resumable checkpoint."""
    import subprocess
    import sys
    import time
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    run = tmp_path / "run"
    cmd = [sys.executable, str(root / "train.py"), "experiment=doublet",
           "sensor.resolution=[16,16]", "data.image_size=32", "data.batch_size=2",
           "data.train_steps_per_epoch=50", "data.val_size=2", "data.test_size=2",
           "render.spp=2", "trainer.max_epochs=20", "test=false", "callbacks.image_logger=null",
           "trainer.enable_progress_bar=false", f"hydra.run.dir={run}"]
    p = subprocess.Popen(cmd, env={**os.environ, "PYTHONPATH": str(root)}, cwd=root,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    last = run / "checkpoints" / "last.ckpt"
    t0 = time.time()
    while not last.exists() and p.poll() is None and time.time() - t0 < 600:
        time.sleep(0.1)
    time.sleep(1.0)
    assert p.poll() is None, "the run ended before the signal"
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=600)
    assert p.returncode == 143, err[-2000:]
    assert "training stopped by SIGTERM" in err and f"ckpt_path={last}" in err
    assert read_checkpoint(last)["global_step"] > 50
