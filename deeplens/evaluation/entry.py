"""The training and evaluation commands: ``deeplens train`` / ``deeplens eval`` (installed
entry points) and the repository's thin ``train.py`` / ``eval.py``, all one code path.

Both are Hydra applications over the shipped configs (:func:`deeplens.resources.config_dir`:
the wheel's packaged copy, or the checkout's ``configs/``); every argument is a Hydra override
(``deeplens train experiment=doublet trainer.max_epochs=1``).  The default lenses are found the
same way: ``paths.data_dir`` is ``$DEEPLENS_DATA_DIR``, which :func:`run` sets to the shipped
data folder unless it is already set, so a run works from any working directory.  Outputs go
to ``outputs/`` under the working directory.
"""

from __future__ import annotations

import os
import sys

from ..resources import config_dir, data_dir

__all__ = ["run"]


def _train_task(cfg) -> float | None:
    from ..training.console import quiet_console
    from ..training.train import train

    with quiet_console():
        metrics, _ = train(cfg)
    return metrics.get("val/psnr_restored")


def _eval_task(cfg, fanout: list[str]) -> None:
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import open_dict

    from ..training.console import quiet_console
    from ..training.lens_search import search_dir, searched_lens
    from .evaluate import check_config, evaluate, variants
    from .fanout import fan_out

    check_config(cfg)  # every key, before a job is fanned out
    if cfg.eval.get("launcher") and cfg.eval.get("job") is None and not cfg.eval.get("gather"):
        if any(k == "searched" or (k == "learned" and cfg.lens.get("start") == "search")
               for _, k, _ in variants(cfg)):   # one search here, not one per job at once
            searched_lens(cfg, search_dir(cfg))
        fan_out(cfg, fanout, list(HydraConfig.get().overrides.task))
        with open_dict(cfg):
            cfg.eval.gather = True
    with quiet_console():
        table, _ = evaluate(cfg)
    print(table)


def run(kind: str, argv: list[str] | None = None, prog: str | None = None,
        fanout: list[str] | None = None) -> None:
    """Run ``deeplens train`` (``kind="train"``) or ``deeplens eval`` (``"eval"``) with the
    Hydra overrides ``argv`` (default: ``sys.argv[1:]``); ``prog`` is the program name shown in
    messages.  ``fanout``: the interpreter arguments that start one more evaluation when
    ``eval.launcher`` fans variants x seeds out (default ``["-m", "deeplens", "eval"]``;
    ``eval.py`` passes its own path).

    Raises:
        ValueError: an unknown ``kind``.
        SystemExit: (status 2) a module of the ``train`` extra is missing; one line on stderr
            names it and the pip command (:mod:`deeplens.extras`); or a misspelt key or a
            missing ``lens.path`` (:mod:`deeplens.training.precheck`), before any folder is made.
    """
    if kind not in ("train", "eval"):
        raise ValueError(f"unknown deeplens task {kind!r}; expected 'train' or 'eval'")
    from ..extras import missing_extra

    msg = missing_extra("train", prog or f"deeplens {kind}")
    if msg:         # one line naming the extra, before Hydra is imported
        print(f"{prog or f'deeplens {kind}'}: error: {msg}", file=sys.stderr)
        raise SystemExit(2)
    import hydra

    start = ["-m", "deeplens", "eval"] if fanout is None else list(fanout)

    def task(cfg):
        return _train_task(cfg) if kind == "train" else _eval_task(cfg, start)

    # Hydra names a job after the task function's module (the log file `train.log`, the
    # `--help` title, `hydra.job.name`); here that module is this one, so the task says it is
    # `train` / `eval`.  (An override `hydra.job.name=...` appended to the command line would
    # break `deeplens train experiment=doublet --cfg job`: Hydra's parser takes overrides only
    # before its flags.)
    task.__module__ = kind
    os.environ.setdefault("DEEPLENS_DATA_DIR", str(data_dir()))
    main = hydra.main(version_base="1.3", config_path=str(config_dir()),
                      config_name=f"{kind}.yaml")(task)
    args = list(sys.argv[1:] if argv is None else argv)
    from ..training.precheck import precheck

    problem = precheck(kind, args, str(config_dir()))
    if problem:     # a misspelt key, a missing lens: before Hydra makes the run's folder
        print(f"{prog or f'deeplens {kind}'}: error: {problem}", file=sys.stderr)
        raise SystemExit(2)
    saved = sys.argv
    sys.argv = [prog or f"deeplens {kind}", *args]
    try:
        main()
    finally:
        sys.argv = saved
