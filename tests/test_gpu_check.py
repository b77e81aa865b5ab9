"""benchmarks/gpu_check.{sh,py}: every section writes numbers or a recorded error into the one
results file; the shell script's budgets are the script's and fit the GPU's six minutes.

The sections run here on the CPU at tiny sizes (the GPU sizes need a GPU); the whole
``gpu_check.sh --dry-run`` is the slow test."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "benchmarks" / "gpu_check.py"
SHELL = REPO / "benchmarks" / "gpu_check.sh"


@pytest.fixture
def gc(monkeypatch):
    """The gpu_check module (it puts benchmarks/ on sys.path; undone afterwards)."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    spec = importlib.util.spec_from_file_location("gpu_check_under_test", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _tiny_plan(gc):
    return dict(gc.DRY_PLAN, trace_rays=[300, 600], render_resolution=(8, 8), render_spp=[1, 2],
                render_plain_spp=[1], render_chunk_rays=32)


def _finite_positive(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v) and v > 0


def test_sections_in_process_give_numbers_or_recorded_errors(gc, tmp_path, monkeypatch):
    """env, trace and adjoint_render run (CPU, tiny); a section that raises keeps its rows and
    records the error; one killed by ``timeout`` (exit 124, part still "running") and one never
    run are reported as such; the results file has every section, a table each, and JSON."""
    ctx = gc.Context(tmp_path, dry_run=True, plan=_tiny_plan(gc))
    assert ctx.device == "cpu" and not ctx.cuda
    for name in ("env", "trace", "adjoint_render"):
        assert gc.run_section(name, ctx).status == "ok"

    def broken(sec):
        sec.guarded("a row that fails", lambda: 1 / 0, sensor_px=16)
        sec.row(name="a row that worked", step_s=0.5, wall_s=0.6)
        raise RuntimeError("the section stops here")

    monkeypatch.setitem(gc.FUNCS, "train_step", broken)
    sec = gc.run_section("train_step", ctx)
    assert sec.status == "error" and "RuntimeError: the section stops here" in sec.error
    # a section killed by `timeout` leaves its part file "running" and the shell writes the rc
    killed = gc.Section("cuda_tests", ctx, budget_s=60)
    killed.row(name="tests.optics.test_lens::test_x", outcome="passed", wall_s=0.1)
    (ctx.parts / "cuda_tests.rc").write_text("124\n")

    path = gc.report(tmp_path, dry_run=True)
    assert path == tmp_path / "gpu_check.md"
    res = gc.read_results(path)
    secs = res["sections"]
    assert list(secs) == list(gc.SECTIONS) and res["dry_run"] is True
    assert res["env"]["torch"] == torch.__version__ and res["env"]["device"] == "cpu"

    env = secs["env"]["rows"][0]
    assert env["cpu_count"] == os.cpu_count() and env["cuda_available"] == \
        torch.cuda.is_available()

    trace = secs["trace"]["rows"]
    assert secs["trace"]["status"] == "ok" and len(trace) == 4
    assert {(r["name"], r["rays"]) for r in trace} == {
        (k, n) for k in ("forward (no grad)", "trace + RMS spot + backward") for n in (300, 600)}
    for r in trace:
        assert r["device"] == "cpu" and r["dtype"] == "float32" and r["torch"] == torch.__version__
        assert r["surfaces"] == 11  # the double Gauss
        assert all(_finite_positive(r[k]) for k in ("s", "rays_per_s", "wall_s"))
        assert r["ray_surfaces_per_s"] == pytest.approx(r["rays_per_s"] * 11, rel=1e-12)
        assert r["rays_per_s"] == pytest.approx(r["rays"] / r["s"], rel=1e-12)
        assert r["memory"] == "cpu peak RSS" and "peak_mib" in r

    render = secs["adjoint_render"]["rows"]
    assert secs["adjoint_render"]["status"] == "ok"
    assert [(r["mode"], r["spp"]) for r in render] == [("adjoint", 1), ("plain", 1),
                                                       ("adjoint", 2)]
    for r in render:
        assert r["rays"] == 8 * 8 * r["spp"] and r["resolution"] == [8, 8]
        assert r["chunks"] == math.ceil(64 / (32 // r["spp"]))
        assert all(_finite_positive(r[k]) for k in ("fwd_s", "bwd_s", "s", "rays_per_s", "loss"))
        assert r["ray_surfaces_per_s"] == pytest.approx(r["rays_per_s"] * r["surfaces"])
    # the same samples in both modes: the same gradient (float32 sums in another order)
    assert render[1]["grad_cos_vs_other_mode"] == pytest.approx(1.0, abs=1e-5)

    ts = secs["train_step"]
    assert ts["status"] == "error" and "the section stops here" in ts["error"]
    assert "ZeroDivisionError" in ts["rows"][0]["error"] and ts["rows"][0]["sensor_px"] == 16
    assert ts["rows"][1]["step_s"] == 0.5

    ct = secs["cuda_tests"]
    assert ct["status"] == "error" and ct["error"].startswith("timed out after")
    assert ct["rows"][0]["outcome"] == "passed"  # kept
    assert secs["e2e"] == {"status": "error", "rows": [], "error": "not run"}

    text = path.read_text()
    for name in gc.SECTIONS:
        assert re.search(rf"^## {name}: (ok|error|partial)", text, re.M), name
    assert len(re.findall(r"^\| forward \(no grad\) \|", text, re.M)) == 2  # one per size
    assert json.loads(text.split("```json\n")[1].split("\n```")[0]) == res


def test_a_failing_row_makes_the_section_partial_and_the_next_row_runs(gc, tmp_path):
    ctx = gc.Context(tmp_path, dry_run=True, plan=_tiny_plan(gc))
    sec = gc.Section("trace", ctx, budget_s=30)
    assert sec.guarded("bad", lambda: {}["missing"], rays=5) is None
    assert sec.guarded("good", lambda: {"s": 1.0}, rays=6)["s"] == 1.0
    sec.finish()
    data = json.loads((ctx.parts / "trace.json").read_text())
    assert data["status"] == "partial"
    assert data["rows"][0]["error"].startswith("KeyError: 'missing'")
    assert data["rows"][1]["rays"] == 6 and "error" not in data["rows"][1]
    # the budget: a step predicted past what is left is skipped, an unknown one runs
    assert sec.fits(None) and sec.fits(1.0) and not sec.fits(3600.0)


def test_full_sizes_without_cuda_record_why(gc, tmp_path):
    """Without --dry-run on a machine without CUDA every section but env records that the full
    sizes need a GPU, instead of running for an hour on the CPU."""
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")  # reason names cuda: allowed by conftest
    ctx = gc.Context(tmp_path, dry_run=False)
    sec = gc.run_section("trace", ctx)
    assert sec.status == "error" and "--dry-run" in sec.error and sec.rows == []


def test_gpu_plan_budgets_and_shell_agree(gc):
    """The shell runs the script's sections in order with the script's GPU budgets, which fit
    the ~6 minutes left of an 8-minute device slot after the ~2-minute set-up; the plan has
    the issue's sizes."""
    text = SHELL.read_text()
    gpu = re.search(r'budgets="(env:[^"]*)"\n\s*fi', text)
    assert gpu, "gpu_check.sh: no GPU budgets line"
    pairs = [e.split(":") for e in gpu.group(1).split()]
    assert [n for n, _ in pairs] == list(gc.SECTIONS)
    assert {n: int(s) for n, s in pairs} == gc.GPU_BUDGETS
    assert sum(gc.GPU_BUDGETS.values()) <= 360
    assert re.search(r"GPU_CHECK_TOTAL_S:-360\}", text)
    assert gc.GPU_PLAN["train_px"] == [256, 512]
    assert "trainer=gpu" in gc.GPU_PLAN["e2e"] and "trainer=cpu" in gc.DRY_PLAN["e2e"]
    assert set(gc.FUNCS) == set(gc.SECTIONS)


def test_cuda_test_files_are_found(gc):
    files = gc.cuda_test_files()
    for f in ("tests/optics/test_lens.py", "tests/optics/test_materials.py",
              "tests/render/test_render.py", "tests/render/test_diffraction.py"):
        assert f in files
    # and each has a test that `pytest -k cuda` selects
    for f in files:
        assert re.search(r"^def test_\w*cuda\w*\(", (REPO / f).read_text(), re.M), f


def test_e2e_reads_the_test_rows_of_the_run_summary(gc):
    """The rows come from the summary ``train.py`` prints (its own function writes it here)."""
    from types import SimpleNamespace

    from omegaconf import OmegaConf

    from deeplens.training.train import summary

    metrics = {}
    for tag, vals in (("d4500mm", (20.46, 0.489, 17.98, 0.365)),
                      ("d8000mm", (20.7, 0.521, 7.98, 0.058))):
        for key, v in zip(("psnr_restored", "ssim_restored", "psnr_sensor", "ssim_sensor"), vals):
            metrics[f"test/{key}/{tag}"] = v
    trainer = SimpleNamespace(current_epoch=1, global_step=2, checkpoint_callback=None)
    log = "some output\n" + summary(OmegaConf.create({"task_name": "edof"}), metrics, trainer,
                                    None) + "\nmore output\n"
    assert gc.parse_summary(log) == [
        {"name": "test 4.5 m", "psnr_restored_db": 20.46, "ssim_restored": 0.489,
         "psnr_sensor_db": 17.98, "ssim_sensor": 0.365},
        {"name": "test 8 m", "psnr_restored_db": 20.7, "ssim_restored": 0.521,
         "psnr_sensor_db": 7.98, "ssim_sensor": 0.058}]


def test_read_results_names_a_file_without_json(tmp_path, gc):
    p = tmp_path / "x.md"
    p.write_text("# no json here\n")
    with pytest.raises(ValueError, match=r"x\.md: no ```json block"):
        gc.read_results(p)


@pytest.mark.slow
def test_dry_run_script_runs_every_section(tmp_path):
    """``bash benchmarks/gpu_check.sh --dry-run``: every section ok on the CPU with its numbers
    (~50-90 s at OMP_NUM_THREADS=1 on a shared 2-core machine)."""
    env = dict(os.environ, GPU_CHECK_PYTHON=sys.executable, OMP_NUM_THREADS="1")
    r = subprocess.run(["bash", str(SHELL), "--dry-run", "--out", str(tmp_path)], cwd=REPO,
                       env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    spec = importlib.util.spec_from_file_location("gpu_check_read", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    path = list(sys.path)
    try:
        spec.loader.exec_module(mod)
    finally:
        sys.path[:] = path
    res = mod.read_results(tmp_path / "gpu_check.md")
    secs = res["sections"]
    for name in mod.SECTIONS:
        assert secs[name]["status"] == "ok", (name, secs[name].get("error"))
        assert secs[name]["rows"] and not any("error" in x for x in secs[name]["rows"])
    tests = secs["cuda_tests"]["rows"]
    total = tests[-1]
    assert total["n_passed"] + total["n_skipped"] == len(tests) - 1 >= 4
    if not torch.cuda.is_available():
        assert all(t["outcome"] == "skipped" and "CUDA" in t["message"] for t in tests[:-1])
    steps = {(x["experiment"], x["sensor_px"]) for x in secs["train_step"]["rows"]}
    assert steps == {(e, n) for e in ("edof", "doublet") for n in mod.DRY_PLAN["train_px"]}
    assert all(_finite_positive(x["step_s"]) for x in secs["train_step"]["rows"])
    e2e, *tested = secs["e2e"]["rows"]
    assert e2e["returncode"] == 0 and e2e["steps"] == 2 and e2e["last_ckpt"] is True
    assert [t["name"] for t in tested] == ["test 4.5 m", "test 5.5 m", "test 6.5 m", "test 8 m"]
    assert all(_finite_positive(t["psnr_restored_db"]) for t in tested)
