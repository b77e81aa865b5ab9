"""A training run's choice of tracer under ``render.compile=default``: decided once, stored in
the checkpoints.

``TraceOptions(compile="default")`` alone decides call by call (the ski-rental ledger of
:mod:`deeplens.optics.compile_policy`); its account depends on every trace a process has made,
including set-up, validation and caches that checkpoints do not hold, so a resumed run would
switch at another step than the uninterrupted one and lose bit-exact resumption.  A training
run knows its own future instead: after its first training step, the module reads from the
ledger what that step's traces would save compiled (modelled seconds per kernel signature),
multiplies by the steps left (``trainer.estimated_stepping_batches``) and compiles from the
second step on when that repays compiling each signature (:data:`COMPILE_COST_S` each) — else
it traces eager for the rest of the run.  The choice replaces ``camera.options`` (so every
trace of a step, renderer, Wiener filter and PSF model, follows it), is printed with its
numbers, and is stored in every checkpoint; a resumed run applies it before its first step.
Other settings of ``render.compile`` (``false``, ``true``, ``surface``, ``lens``) are kept as
they are and nothing is decided.
"""

from __future__ import annotations

import math

from lightning.pytorch.utilities import rank_zero_info

from ..optics import compile_policy as P

__all__ = ["CHOICE_KEY", "begin_step", "decide", "end_step", "restore", "store"]

#: the checkpoint entry holding the choice (``"auto"`` or ``False``)
CHOICE_KEY = "deeplens_compile_choice"


def decide(delta: dict[str, float], already: int, remaining_steps: float):
    """``("auto" | False, reason)``: whether compiling pays for the rest of a run.

    Args:
        delta: per kernel signature, the seconds compiled kernels would have saved on one
            training step (the ledger's growth over the step).
        already: signatures the ledger had switched to compiled by then (their cost is spent).
        remaining_steps: training steps left (``inf`` for an open-ended run).
    """
    n = sum(1 for v in delta.values() if v > 0)
    saving = sum(delta.values())
    if already:
        return "auto", f"{already} kernel signature(s) already compiled during the first step"
    if n == 0:
        return False, "no trace of a training step has compilable surfaces and enough rays"
    total = saving * remaining_steps
    why = (f"{saving:.3g} s saved per step x {remaining_steps:g} steps left = {total:.3g} s vs "
           f"{P.COMPILE_COST_S:g} s to compile each of {n} kernel signature(s)")
    return ("auto", why) if total >= P.COMPILE_COST_S * n else (False, why)


def begin_step(module) -> None:
    """Before a training step: remember the ledger while the choice is still open."""
    if module.__dict__.get("_compile_choice") is not None:
        return
    if module.camera.options.compile != "default":
        return
    module._ledger_at_step = dict(module.camera.options.ledger.saved)


def end_step(module) -> None:
    """After the first training step of an undecided run: decide (:func:`decide`) and apply."""
    before = module.__dict__.pop("_ledger_at_step", None)
    if before is None:
        return
    opts = module.camera.options
    after = opts.ledger.saved
    delta = {k: v - before.get(k, 0.0) for k, v in after.items()}
    already = sum(1 for k in after if opts.ledger.paid(k))
    trainer = module.trainer
    left = trainer.estimated_stepping_batches
    left = math.inf if left is None or not math.isfinite(left) else max(
        0, int(left) - int(trainer.global_step))
    choice, why = decide(delta, already, left)
    if choice and not opts.ledger.can_compile(module.camera.device):
        choice, why = False, why + "; no compiler found"
    _apply(module, choice)
    rank_zero_info(f"deeplens: render.compile=default: tracing "
                   f"{'compiled' if choice else 'eager'} from step {int(trainer.global_step)} "
                   f"on ({why})")


def _apply(module, choice) -> None:
    module._compile_choice = choice
    module.camera.options = module.camera.options.replace(compile=choice)


def store(module, checkpoint: dict) -> None:
    """Write the run's choice (``None`` while undecided) into ``checkpoint``."""
    checkpoint[CHOICE_KEY] = module.__dict__.get("_compile_choice")


def restore(module, checkpoint: dict) -> None:
    """Apply a choice stored in ``checkpoint`` (older checkpoints hold none: the run decides
    after its next step, as a new run would)."""
    choice = checkpoint.get(CHOICE_KEY)
    if choice is not None and module.camera.options.compile == "default":
        _apply(module, choice)
