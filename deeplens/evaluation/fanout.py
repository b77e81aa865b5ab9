"""Variants x seeds of an evaluation fanned out through a Hydra launcher, then gathered.

``python eval.py experiment=edof eval.seeds=[0,1,2] eval.launcher=joblib eval.n_jobs=2``:

1. **fan-out** (:func:`fan_out`): this process starts one Hydra multirun,
   ``python eval.py -m <the same overrides> hydra/launcher=<launcher> eval.job=range(0,N)``, whose
   ``N`` jobs (one per variant x seed, :func:`jobs`) each train and test one variant for one
   seed into ``<output folder>/<variant>/seed<s>`` (``eval.folder``), as the sequential
   evaluation would.  ``joblib`` runs them on this machine, ``eval.n_jobs`` at a time (each
   with the caller's ``OMP_NUM_THREADS``); ``submitit_local`` / ``submitit_slurm`` (the
   ``hydra-submitit-launcher`` plugin, ``pip install deeplens-do[cluster]``) on a cluster, with
   ``hydra.launcher.*`` overrides for the partition, time and so on.
2. **gather**: the same process then runs the evaluation with ``eval.gather=true``: every
   variant x seed is loaded from its finished run (``eval.reuse_runs``), nothing trains (a
   missing run is an error naming it), and the tables and figures are written.

Stopping: SIGTERM, Ctrl-C or SIGHUP to the evaluation stop the multirun and every job it started
(:func:`~.fanout_stop.run_process_tree`: the multirun runs as its own process group, which gets
SIGTERM, then SIGKILL after :data:`~.fanout_stop.STOP_GRACE_S` seconds).  ``kill -9`` of the
evaluation cannot be caught: the multirun then gets SIGTERM from the kernel (Linux
``PR_SET_PDEATHSIG``) and each joblib job, which watches the evaluation's process
(:func:`~.fanout_stop.watch_parent`), ends itself within half a second without writing a further
checkpoint.

``eval.launcher=null`` (the default) runs the variants and seeds one after the other in this
process.  ``eval.gather=true`` on its own rebuilds the table of a finished folder
(``hydra.run.dir=<folder>``).
"""

from __future__ import annotations

import copy
import os
import re
import resource
import sys
import time
from pathlib import Path

from omegaconf import DictConfig, open_dict

from ..optics.errors import ConfigError
from .fanout_stop import PARENT_ENV, parent_token, run_process_tree
from .variants import seeds, variants

__all__ = ["jobs", "fan_out", "job_cfg", "LAUNCHERS", "check_fanout_config", "cpu_seconds",
           "hydra_quote"]

LAUNCHERS = ("joblib", "submitit_local", "submitit_slurm")


def jobs(cfg: DictConfig) -> list[tuple[str, str, float | None, int]]:
    """``(variant name, kind, alpha_mm, seed)`` of every job, variants outer, seeds inner."""
    return [(n, k, a, s) for n, k, a in variants(cfg) for s in seeds(cfg)]


def job_cfg(cfg: DictConfig) -> tuple[DictConfig, tuple]:
    """For ``eval.job = k``: the config of job ``k`` (output in ``eval.folder``) and its
    ``(name, kind, alpha, seed)``."""
    todo = _check_job(cfg)
    k = cfg.eval.job
    c = copy.deepcopy(cfg)
    with open_dict(c):
        c.paths.output_dir = str(cfg.eval.folder)
    return c, todo[k]


def _check_job(cfg: DictConfig) -> list:
    """``eval.job`` (set) checked against the jobs of ``cfg``, and ``eval.folder`` set;
    returns the jobs."""
    todo = jobs(cfg)
    k = cfg.eval.job
    if not (isinstance(k, int) and not isinstance(k, bool) and 0 <= k < len(todo)):
        raise ConfigError("eval.job", f"an integer in [0, {len(todo) - 1}] (one per variant x "
                          f"seed)", k)
    if cfg.eval.get("folder") is None:
        raise ConfigError.missing("eval.folder", "the evaluation's output folder (with "
                                  "eval.job)")
    return todo


def _check_launcher(cfg: DictConfig, launcher) -> None:
    if launcher not in LAUNCHERS:
        raise ConfigError("eval.launcher", f"null or one of {', '.join(LAUNCHERS)}", launcher)
    n_jobs = cfg.eval.get("n_jobs", 1)
    if not (isinstance(n_jobs, int) and not isinstance(n_jobs, bool)
            and (n_jobs >= 1 or n_jobs == -1)):
        raise ConfigError("eval.n_jobs", "an integer >= 1 (or -1: every core)", n_jobs)


def check_fanout_config(cfg: DictConfig) -> None:
    """Start-up check of ``eval.launcher`` and ``eval.n_jobs`` (when a launcher is set) and of
    ``eval.job`` / ``eval.folder`` (when a job is set); raises
    :class:`~deeplens.optics.errors.ConfigError` naming the key."""
    ev = cfg.eval
    if ev.get("launcher") is not None:
        _check_launcher(cfg, ev.launcher)
    if ev.get("job") is not None:
        _check_job(cfg)


def cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and its finished children."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def hydra_quote(value: str) -> str:
    """``value`` as a quoted value of a Hydra command-line override, read back as ``value``
    whatever it holds (spaces, commas, brackets, ``=``, quotes, backslashes, ``${``): single
    quotes; a quote and the backslashes before a quote or the end escaped by a backslash
    (Hydra's override grammar), ``${`` escaped as ``\\${`` (OmegaConf's escape of an
    interpolation: the value resolves to the literal text)."""
    v = re.sub(r"(\\+)(?='|$)", lambda m: m.group(1) * 2, str(value))
    v = v.replace("'", "\\'").replace("${", "\\${")
    return f"'{v}'"


def fan_out(cfg: DictConfig, script: str | list[str], overrides: list[str]) -> float:
    """Run every variant x seed as a job of a Hydra multirun of ``script`` with the launcher
    ``eval.launcher`` (module docstring); returns the wall seconds.  ``script`` is the
    evaluation script's path (``eval.py``) or the interpreter arguments that start it (``["-m",
    "deeplens", "eval"]`` for ``deeplens eval``).  ``overrides`` are this call's command-line
    overrides (``HydraConfig.get().overrides.task``).

    Raises:
        ValueError: an unknown launcher or ``eval.n_jobs``; RuntimeError: a job failed (the
            multirun's exit status and its output folder are named).
    """
    launcher = cfg.eval.launcher
    _check_launcher(cfg, launcher)
    n_jobs = cfg.eval.get("n_jobs", 1)
    out = Path(cfg.paths.output_dir).resolve()
    n = len(jobs(cfg))
    drop = ("eval.launcher=", "eval.job=", "eval.folder=", "eval.gather=", "eval.n_jobs=")
    keep = [o for o in overrides if not o.lstrip("+~").startswith(drop)]
    start = [script] if isinstance(script, str) else list(script)
    cmd = [sys.executable, *start, "-m", *keep, f"hydra/launcher={launcher}",
           f"eval.job=range(0,{n})", f"eval.folder={hydra_quote(out)}", "eval.figures=false",
           f"hydra.sweep.dir={hydra_quote(out)}", "hydra.sweep.subdir=jobs/${hydra.job.num}"]
    if launcher == "joblib":
        cmd.append(f"hydra.launcher.n_jobs={n_jobs}")
    print(f"deeplens eval: fanning {n} variant x seed jobs out through the {launcher} "
          f"launcher: {' '.join(cmd)}", flush=True)
    t0 = time.perf_counter()
    env = dict(os.environ)
    if launcher == "joblib":   # the jobs run on this machine: they watch this process
        env[PARENT_ENV] = parent_token()
    rc = run_process_tree(cmd, env=env)
    if rc != 0:
        raise RuntimeError(f"eval.launcher={launcher}: the multirun exited with status {rc}; "
                           f"the jobs' logs are in {out}/jobs/")
    return time.perf_counter() - t0
