"""Variants x seeds fanned out through the Hydra joblib launcher, then gathered."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import open_dict

from deeplens.evaluation.evaluate import evaluate
from deeplens.evaluation.fanout import fan_out, jobs

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("_training_conftest",
                                               Path(__file__).with_name("conftest.py"))
_conf = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_conf)
TINY = _conf.TINY  # the shrunk training settings of tests/training/conftest.py

FAST = TINY + ["callbacks.image_logger=null", "eval.figures=false", "experiment=edof",
               "scene.val_depths_mm=[4500.0,8000.0]", "eval.variants=[none,cubic]",
               "eval.cubic_alpha_mm=[0.005]"]


def test_jobs_cover_variants_times_seeds_and_a_job_runs_one(cfg_factory, tmp_path):
    cfg = cfg_factory(*FAST[len(TINY):], "eval.seeds=[0,1]", config_name="eval.yaml")
    assert [(n, s) for n, _, _, s in jobs(cfg)] == [
        ("none", 0), ("none", 1), ("cubic@5um", 0), ("cubic@5um", 1)]
    # job 2 (cubic seed 0) runs alone into eval.folder, nothing else trains
    folder = tmp_path / "eval"
    job = cfg_factory(*FAST[len(TINY):], "eval.seeds=[0,1]", "eval.job=2",
                      f"eval.folder={folder}", config_name="eval.yaml", out=tmp_path / "job")
    assert evaluate(job) == ("", {})
    assert (folder / "cubic_5um" / "seed0" / "eval_run.json").is_file()
    assert not (folder / "none").exists() and not (folder / "cubic_5um" / "seed1").exists()
    # gathering needs every run: the missing ones are named
    with open_dict(cfg):
        cfg.paths.output_dir, cfg.eval.gather = str(folder), True
    with pytest.raises(RuntimeError, match="no finished run of none seed 0"):
        evaluate(cfg)
    bad = cfg_factory(*FAST[len(TINY):], "eval.job=9", f"eval.folder={folder}",
                      config_name="eval.yaml")
    with pytest.raises(ValueError, match=r"eval.job: expected an integer in \[0, 1\]"):
        evaluate(bad)
    with open_dict(cfg):
        cfg.eval.launcher = "slurmm"
    with pytest.raises(ValueError, match="eval.launcher: expected null or one of joblib"):
        fan_out(cfg, "eval.py", [])


def test_deeplens_eval_fans_its_jobs_out_as_python_m_deeplens_eval(cfg_factory, tmp_path,
                                                                    monkeypatch):
    """``deeplens eval`` (no script file) starts its jobs as ``python -m deeplens eval -m ...``
    with the caller's overrides, less the fan-out's own."""
    import deeplens.evaluation.fanout as fanout

    from deeplens.evaluation.fanout_stop import PARENT_ENV, parent_token

    calls, envs = [], []
    monkeypatch.setattr(fanout, "run_process_tree",
                        lambda cmd, env=None: calls.append(cmd) or envs.append(env) or 0)
    cfg = cfg_factory(*FAST[len(TINY):], "eval.launcher=joblib", config_name="eval.yaml")
    fan_out(cfg, ["-m", "deeplens", "eval"], ["experiment=edof", "eval.launcher=joblib"])
    (cmd,) = calls
    # the jobs are told which process to watch (they stop when it is gone, even by kill -9)
    assert envs[0][PARENT_ENV] == parent_token()
    assert cmd[:5] == [sys.executable, "-m", "deeplens", "eval", "-m"]
    assert "experiment=edof" in cmd and "hydra/launcher=joblib" in cmd
    assert not any(c.startswith("eval.launcher=") for c in cmd)


@pytest.mark.slow
def test_eval_fans_out_through_joblib_and_gathers(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, str(ROOT / "eval.py"), *FAST, "eval.seeds=[0,1]",
           "eval.launcher=joblib", "eval.n_jobs=2", f"hydra.run.dir={out}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    assert sorted(p.name for p in (out / "jobs").iterdir()) == ["0", "1", "2", "3"]
    js = json.loads((out / "eval_table.json").read_text())
    assert list(js["variants"]) == ["none", "cubic@5um"] and js["seeds"] == [0, 1]
    assert all(e["seeds"] == 2 for e in js["variants"].values())
    # the table was gathered: the parent process trained nothing
    assert r.stdout.count("reusing the finished run") + r.stderr.count(
        "reusing the finished run") == 4
    assert "OMP_NUM_THREADS=1" in (out / "eval_table.md").read_text()
