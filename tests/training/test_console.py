"""What a run prints (issue 35): each log line once, no Lightning tips, no known-noise
warnings (:mod:`deeplens.training.console`), and ``train/*`` scalars even from a two-step run
(:func:`deeplens.training.train.log_every_n_steps`)."""

import logging
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from deeplens.training.console import quiet_console
from deeplens.training.train import log_every_n_steps

ROOT = Path(__file__).resolve().parents[2]


class _Keep(logging.Handler):
    def __init__(self):
        super().__init__()
        self.lines = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def test_lightning_lines_once_tips_dropped_and_restored_after(monkeypatch):
    from lightning.pytorch.utilities import rank_zero_info

    root, light = logging.getLogger(), logging.getLogger("lightning.pytorch")
    keep = _Keep()
    console = logging.StreamHandler(sys.stderr)     # what Lightning adds when imported
    seen = _Keep()                                  # stands for that console's output
    monkeypatch.setattr(console, "emit", seen.emit)
    monkeypatch.setattr(light, "propagate", False)
    monkeypatch.setattr(light, "handlers", [console])
    root.addHandler(keep)
    try:
        with quiet_console():
            rank_zero_info("GPU available: False")
            rank_zero_info("💡 Tip: For seamless cloud logging, try installing litlogger")
            logging.getLogger("deeplens.x").info("mine")
        assert light.handlers == [console] and light.propagate is False   # restored
    finally:
        root.removeHandler(keep)
    assert seen.lines == []                                   # Lightning's own console: off
    assert [m for m in keep.lines if "GPU" in m] == ["GPU available: False"]
    assert not any("Tip" in m for m in keep.lines)


def test_known_noisy_warnings_are_ignored_and_others_shown():
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        with quiet_console():
            warnings.warn("`isinstance(treespec, LeafSpec)` is deprecated, use ...")
            warnings.warn("Your `IterableDataset` has `__len__` defined. In combination ...")
            warnings.warn("something the user must see")
        warnings.warn("`isinstance(treespec, LeafSpec)` is deprecated, use ...")  # after: shown
    assert [str(w.message)[:14] for w in got] == ["something the ", "`isinstance(tr"]


@pytest.mark.parametrize("overrides, expected", [
    ([], 1),                                         # the tests' own TINY setting
    (["trainer.log_every_n_steps=10"], 2),          # the README's two steps: logged once
    (["trainer.log_every_n_steps=10", "data.train_steps_per_epoch=60"], 10),
    (["trainer.log_every_n_steps=10", "data.train_steps_per_epoch=60",
      "trainer.max_steps=3"], 3),
    (["trainer.log_every_n_steps=10", "data.train_steps_per_epoch=60", "debug=overfit"], 1),
    (["~trainer.log_every_n_steps", "data.train_steps_per_epoch=60"], 50),   # Lightning's
])
def test_log_every_n_steps_fits_short_runs(cfg_factory, overrides, expected):
    assert log_every_n_steps(cfg_factory(*overrides)) == expected


@pytest.mark.slow
def test_readme_tiny_run_prints_each_line_once_and_logs_train_scalars(tmp_path):
    """The README's tiny run, as a user types it (a separate interpreter, Hydra's logging):
    ~10 s."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "deeplens", "train", "experiment=doublet",
           "sensor.resolution=[16,16]", "data.image_size=32", "data.batch_size=2",
           "data.train_steps_per_epoch=2", "data.val_size=2", "data.test_size=2",
           "render.spp=2", "render.psf_rays=1024", "trainer.max_epochs=1",
           "callbacks.image_logger.psf_rays=256", "trainer.enable_progress_bar=false"]
    p = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    text = p.stdout + p.stderr
    assert text.count("Seed set to 0") == 1
    assert text.count("GPU available") == 1
    assert text.count("misplaces") == 1              # the PSF model's sentence
    for noise in ("Tip", "LeafSpec", "IterableDataset", "log_every_n_steps", "INFO: "):
        assert noise not in text, noise
    events = sorted(tmp_path.glob("outputs/doublet/*/tensorboard/events*"))
    tags = set()
    for e in events:
        ea = EventAccumulator(str(e))
        ea.Reload()
        tags |= set(ea.Tags()["scalars"])
    assert "train/loss" in tags
