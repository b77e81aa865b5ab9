"""Compose the real training config, shrunk for CPU tests (lightning-hydra-template style)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import open_dict

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = str(ROOT / "configs")

TINY = [
    "sensor.resolution=[16,16]",
    "data.image_size=32",
    "data.batch_size=2",
    "data.train_steps_per_epoch=2",
    "data.val_size=2",
    "data.test_size=2",
    "render.spp=2",
    "render.psf_rays=1024",
    "trainer.max_epochs=1",
    "trainer.log_every_n_steps=1",
    "callbacks.image_logger.psf_rays=256",
]


def compose_cfg(tmp_path, overrides=(), tiny=True, config_name="train.yaml"):
    """The composed training config with output under ``tmp_path``."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose(config_name=config_name, return_hydra_config=True,
                      overrides=(TINY if tiny else []) + list(overrides))
    HydraConfig().set_config(cfg)
    with open_dict(cfg):
        cfg.paths.output_dir = str(tmp_path)
        cfg.paths.root_dir = str(ROOT)
        cfg.paths.data_dir = str(ROOT / "data")
    return cfg


@pytest.fixture
def cfg_factory(tmp_path):
    def make(*overrides, tiny=True, config_name="train.yaml", out=None):
        """``out``: the run's output folder (default ``tmp_path``)."""
        return compose_cfg(tmp_path if out is None else out, overrides, tiny, config_name)

    yield make
    GlobalHydra.instance().clear()
