"""A fanned-out evaluation's jobs stop with it (issue 38 item 5).

Before: SIGTERM, Ctrl-C or ``kill -9`` to ``deeplens eval eval.launcher=joblib`` ended that one
process; the multirun and its joblib workers went on training and writing checkpoints.  These
tests build the same process tree from small Python programs (no torch, about a second): a
driver running :func:`run_process_tree` (the evaluation), its command (the multirun) and two
grandchildren (the joblib workers) that write a heartbeat file every 20 ms.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from deeplens.evaluation.fanout_stop import (ORPHAN_STATUS, PARENT_ENV, parent_alive, parent_token,
                                           process_start)

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX process groups")

# a worker: watches the evaluation (as every job of a fan-out does), writes a heartbeat,
# ignores SIGTERM when asked to (a job stuck in a step)
WORKER = textwrap.dedent("""
    import os, signal, sys, time
    from deeplens.evaluation.fanout_stop import watch_parent
    if sys.argv[2] == "stubborn":
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    watch_parent(poll_s=0.05)
    beat = sys.argv[1]
    with open(beat + ".pid", "w") as f:
        f.write(str(os.getpid()))
    n = 0
    while True:
        n += 1
        with open(beat, "w") as f:
            f.write(str(n))
        time.sleep(0.02)
""")

# the multirun: starts two workers and goes on (as loky's manager would), not watching anything
MULTIRUN = textwrap.dedent("""
    import os, subprocess, sys, time
    worker, folder = sys.argv[1], sys.argv[2]
    ps = [subprocess.Popen([sys.executable, worker, f"{folder}/beat{k}", kind])
          for k, kind in enumerate(["plain", "stubborn"])]
    with open(f"{folder}/multirun.pid", "w") as f:
        f.write(str(os.getpid()))
    while True:
        time.sleep(0.05)
""")

# the evaluation: names itself to its jobs and runs the multirun as a process tree
DRIVER = textwrap.dedent("""
    import os, sys
    from deeplens.evaluation.fanout_stop import PARENT_ENV, parent_token, run_process_tree
    env = {**os.environ, PARENT_ENV: parent_token()}
    run_process_tree([sys.executable, *sys.argv[1:]], env=env, grace_s=float(os.environ["GRACE"]),
                     poll_s=0.05)
""")


def _start(tmp_path, grace_s=1.0):
    for name, text in (("worker.py", WORKER), ("multirun.py", MULTIRUN), ("driver.py", DRIVER)):
        (tmp_path / name).write_text(text)
    env = {**os.environ, "GRACE": str(grace_s), "PYTHONPATH": str(ROOT)}
    env.pop(PARENT_ENV, None)
    driver = subprocess.Popen([sys.executable, str(tmp_path / "driver.py"),
                               str(tmp_path / "multirun.py"), str(tmp_path / "worker.py"),
                               str(tmp_path)], env=env, stderr=subprocess.PIPE, text=True)
    beats = [tmp_path / "beat0", tmp_path / "beat1"]
    t0 = time.monotonic()
    while not all(b.exists() and Path(f"{b}.pid").exists() and Path(f"{b}.pid").read_text()
                  for b in beats):
        assert time.monotonic() - t0 < 20 and driver.poll() is None, "the workers did not start"
        time.sleep(0.02)
    while not (tmp_path / "multirun.pid").exists() or not (tmp_path / "multirun.pid").read_text():
        assert time.monotonic() - t0 < 20, "the multirun did not start"
        time.sleep(0.02)
    pids = [int(Path(f"{b}.pid").read_text()) for b in beats]
    return driver, beats, pids + [int((tmp_path / "multirun.pid").read_text())]


def _all_gone(pids, within_s):
    t0 = time.monotonic()
    while any(process_start(p) is not None for p in pids):
        if time.monotonic() - t0 > within_s:
            return False
        time.sleep(0.02)
    return True


def _still(beats, for_s=0.3):
    before = [b.read_text() for b in beats]
    time.sleep(for_s)
    return [b.read_text() for b in beats] == before


def _kill_left(pids):
    for p in pids:
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_to_the_evaluation_stops_every_job(tmp_path, signum):
    driver, beats, pids = _start(tmp_path, grace_s=1.5)
    plain, stubborn, multirun = pids
    try:
        driver.send_signal(signum)
        # SIGTERM to the whole tree: the multirun and the plain worker stop at once; the
        # stubborn worker (SIGTERM ignored) beats on until SIGKILL after the grace
        assert _all_gone([plain, multirun], within_s=1.0), "SIGTERM did not reach the tree"
        assert process_start(stubborn) is not None
        rc = driver.wait(timeout=15)
        _, err = driver.communicate()
        assert rc == 128 + signum, err
        assert f"stopped by {signal.Signals(signum).name}" in err
        assert _all_gone(pids, within_s=1.0), "a job outlived the evaluation"
        assert _still(beats)
    finally:
        _kill_left(pids)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_kill_9_of_the_evaluation_stops_every_job(tmp_path):
    """kill -9 cannot be caught: the multirun gets SIGTERM from the kernel (PDEATHSIG; Linux)
    and the workers, the stubborn one too, end themselves (their watchdog), writing nothing
    further."""
    driver, beats, pids = _start(tmp_path, grace_s=30.0)
    try:
        driver.kill()         # not reaped yet: a zombie counts as gone
        assert _all_gone(pids, within_s=3.0), "a job outlived the killed evaluation"
        assert _still(beats)
        driver.wait(timeout=5)
    finally:
        _kill_left(pids)


def test_a_watched_parent_and_the_values_that_watch_nothing():
    me = parent_token()
    assert me.startswith(f"{os.getpid()}:") and parent_alive(me)
    pid, start, host = me.split(":", 2)
    if start:   # /proc: another process that reused the pid is not the parent
        assert not parent_alive(f"{pid}:{int(start) + 1}:{host}")
    assert parent_alive(f"{pid}::{host}")
    assert parent_alive("junk") and parent_alive(f"{pid}:{start}:another-host")
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    assert not parent_alive(f"{p.pid}::{host}")   # gone
    assert ORPHAN_STATUS == 129


def test_a_fanned_out_job_watches_the_evaluation(cfg_factory, tmp_path, monkeypatch):
    """``evaluate`` with ``eval.job`` (what every joblib worker runs) starts the watchdog before
    the job trains."""
    import deeplens.evaluation.evaluate as ev

    order = []
    monkeypatch.setattr(ev, "watch_parent", lambda *a, **k: order.append("watch"))
    monkeypatch.setattr(ev, "_job", lambda *a, **k: order.append("job"))
    cfg = cfg_factory("experiment=edof", "eval.variants=[none]", "eval.job=0",
                      f"eval.folder={tmp_path / 'eval'}", config_name="eval.yaml")
    ev.evaluate(cfg)
    assert order == ["watch", "job"]


def _carrying(token_prefix: str) -> list[int]:
    """The processes whose environment holds ``DEEPLENS_FANOUT_PARENT=<token_prefix>...``."""
    needle = f"{PARENT_ENV}={token_prefix}".encode()
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if needle in (d / "environ").read_bytes() and process_start(int(d.name)):
                    out.append(int(d.name))
            except OSError:
                pass
    return out


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs /proc")
@pytest.mark.parametrize("how", ["SIGTERM", "kill -9"])
def test_a_real_joblib_fan_out_stops_with_the_evaluation(tmp_path, how):
    """``eval.py ... eval.launcher=joblib eval.n_jobs=2``: once both jobs train, SIGTERM (or
    kill -9) to the evaluation leaves no process of the fan-out behind within a few seconds,
    and no job writes into the folder afterwards."""
    out = tmp_path / "run"
    cmd = [sys.executable, str(ROOT / "eval.py"), "experiment=edof", "sensor.resolution=[16,16]",
           "data.image_size=32", "data.batch_size=2", "data.train_steps_per_epoch=2000",
           "data.val_size=2", "data.test_size=2", "render.spp=2", "render.psf_rays=1024",
           "trainer.max_epochs=1", "callbacks.image_logger=null", "eval.figures=false",
           "scene.val_depths_mm=[4500.0,8000.0]", "eval.variants=[none]", "eval.seeds=[0,1]",
           "eval.launcher=joblib", "eval.n_jobs=2", f"hydra.run.dir={out}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    env.pop(PARENT_ENV, None)
    ev = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        while not all((out / "none" / f"seed{s}").is_dir() for s in (0, 1)):
            assert ev.poll() is None and time.monotonic() - t0 < 240, "the jobs did not start"
            time.sleep(0.2)
        time.sleep(2.0)   # both jobs import and start training
        tree = _carrying(f"{ev.pid}:")
        assert len(tree) >= 2, tree     # the multirun and its workers
        if how == "SIGTERM":
            ev.send_signal(signal.SIGTERM)
            assert ev.wait(timeout=60) == 128 + signal.SIGTERM
        else:
            ev.kill()
        assert _all_gone(tree, within_s=20.0), [p for p in tree if process_start(p)]
        ev.wait(timeout=10)
        files = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
        time.sleep(1.0)
        assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == files
    finally:
        if ev.poll() is None:
            ev.kill()
        _kill_left(_carrying(f"{ev.pid}:"))
