"""Two runs with one seed on one machine agree bit for bit, and the machine facts that results
depend on (CPU vector capability, threads) are recorded and can be pinned (issue 25, item 15)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import torch

from deeplens.training.machine import describe_machine, machine_info
from deeplens.training.train import train

ROOT = Path(__file__).resolve().parents[2]
FAST = ("experiment=edof", "callbacks.image_logger=null", "~logger",
        "trainer.enable_progress_bar=false", "test=true", "scene.val_depths_mm=[4500.0]")


def test_two_runs_agree_bit_for_bit(cfg_factory, tmp_path):
    m1, a = train(cfg_factory(*FAST, out=tmp_path / "a"))
    torch.rand(7)  # the global generator moved between the runs: the seed must reset it
    m2, b = train(cfg_factory(*FAST, out=tmp_path / "b"))
    assert a["trainer"].global_step == b["trainer"].global_step == 2
    sa, sb = a["module"].state_dict(), b["module"].state_dict()
    assert sa.keys() == sb.keys()
    for k in sa:
        assert torch.equal(sa[k], sb[k]) or (torch.isnan(sa[k]).all() and torch.isnan(sb[k]).all()), k
    assert m1 == m2  # every logged and test number, exactly
    assert describe_machine() in a["summary"]  # the summary states capability and threads


def test_cpu_capability_is_recorded_and_can_be_pinned():
    info = machine_info()
    assert info["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert info["threads"] == torch.get_num_threads()
    env = {**os.environ, "ATEN_CPU_CAPABILITY": "default", "OMP_NUM_THREADS": "1",
           "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", "import json; from deeplens.training.machine "
                          "import machine_info; print('MACHINE=' + json.dumps(machine_info()))"],
                         env=env, capture_output=True, text=True, cwd=ROOT)
    # whatever else a library prints on some machine, the marked line is the answer; a failure
    # shows the child's output rather than a bare CalledProcessError
    found = [ln for ln in out.stdout.splitlines() if ln.startswith("MACHINE=")]
    assert out.returncode == 0 and found, f"stdout: {out.stdout}\nstderr: {out.stderr}"
    pinned = json.loads(found[-1][len("MACHINE="):])
    # the scalar path: "DEFAULT" on x86 (torch names it so whatever the CPU has)
    assert pinned["cpu_capability"] == "DEFAULT" and pinned["threads"] == 1, pinned
    assert pinned["aten_cpu_capability_env"] == "default"
