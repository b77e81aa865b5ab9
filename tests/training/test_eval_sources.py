"""The evaluation's figures show what the run used (issue 35): the user's test images when
``eval.test_folder`` is set, the run's own PSF model (diffraction or geometric, named in the
title); its table names the deeplens version and commit from any working directory."""

import json
import subprocess
from pathlib import Path

import pytest
import torch

from deeplens import __version__
from deeplens.build_info import describe_source, source_commit
from deeplens.evaluation.figures import psfs_figure, run_psf
from deeplens.training.train import build_objects

ROOT = Path(__file__).resolve().parents[2]


def test_source_commit_of_this_checkout_from_anywhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)                   # not a checkout
    want = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                          capture_output=True, text=True).stdout.strip()
    commit, where = source_commit()
    assert where == "checkout" and commit.split("+")[0] == want
    assert describe_source().startswith(f"deeplens {__version__}, commit {want}")


def test_source_commit_recorded_at_build_and_unknown(tmp_path):
    pkg = tmp_path / "site" / "deeplens"           # an installed package: no git around it
    (pkg / "_resources").mkdir(parents=True)
    assert source_commit(pkg) == (None, "unknown")
    assert describe_source(pkg) == f"deeplens {__version__}, commit unknown"
    (pkg / "_resources" / "build.json").write_text(json.dumps({"commit": "abc1234",
                                                               "modified": False}))
    assert source_commit(pkg) == ("abc1234", "build")
    assert describe_source(pkg).endswith("commit abc1234 (recorded at build)")


def test_provenance_names_version_and_commit_outside_the_checkout(cfg_factory, tmp_path):
    from omegaconf import open_dict

    from deeplens.evaluation.evaluate import provenance

    cfg = cfg_factory("experiment=doublet")
    with open_dict(cfg):
        cfg.paths.root_dir = str(tmp_path)         # eval.py run from another folder
    line = provenance(cfg)
    assert f"deeplens {__version__}, commit " in line and "commit unknown" not in line


@pytest.fixture(scope="module")
def diffraction_run(tmp_path_factory):
    """A tiny doublet camera built by the run's own code with the diffraction PSF model."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    from conftest import CONFIGS, TINY

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose("train.yaml", return_hydra_config=True, overrides=TINY + [
            "experiment=doublet", "render=psf", "render.psf_model=diffraction",
            "render.psf_patches=[1,1]", "~logger", "callbacks.image_logger=null"])
    HydraConfig().set_config(cfg)
    with open_dict(cfg):
        cfg.paths.output_dir = str(tmp_path_factory.mktemp("run"))
        cfg.paths.data_dir = str(ROOT / "data")
    objs = build_objects(cfg)
    GlobalHydra.instance().clear()
    return objs


def test_psfs_are_drawn_by_the_runs_psf_model(diffraction_run):
    m = diffraction_run["module"]
    ch = m.sensor.channels[len(m.sensor.channels) // 2]
    k, model = run_psf(m, 10000.0, ch, kernel=9)
    assert model == "diffraction" and k.shape == (9, 9)
    want = m.renderer.psf_model.diffraction(m.camera, None, [((0.0, 0.0), 10000.0, float(w))
                                                             for w in ch])
    K = want[0].shape[-1]
    full = sum(want)
    if K >= 9:      # the centre 9 x 9 of the model's kernel
        r = (K - 9) // 2
        assert torch.equal(k, full.detach()[r:r + 9, r:r + 9])
    else:           # padded with zeros around it
        r = (9 - K) // 2
        assert torch.equal(k[r:r + K, r:r + K], full.detach())
        rest = k.clone()
        rest[r:r + K, r:r + K] = 0
        assert not rest.any()
    fig = psfs_figure({"learned": m}, [10000.0], kernel=9)
    assert "diffraction" in fig._suptitle.get_text()
