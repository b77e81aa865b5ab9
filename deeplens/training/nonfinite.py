"""The non-finite guard of a training step: a NaN or infinite loss, gradient or parameter stops
training *before* the optimiser step, with the state just before it saved under
``checkpoints/nonfinite_step<step>.ckpt`` (:func:`stop`).

The functions take the :class:`~.module.EndToEndModule` (or anything with its
``_named_trained``/``named_buffers``/``checkpoint_dir``/``trainer``); the module's methods
``_nonfinite_grad``, ``_nonfinite_param`` and ``_stop`` delegate here.
"""

from __future__ import annotations

import torch

__all__ = ["NonFiniteLossError", "nonfinite_grad", "nonfinite_param", "stop"]


class NonFiniteLossError(FloatingPointError):
    """Raised when the training loss or a gradient is NaN or infinite; the message names the
    step (and parameter) and the checkpoint holding the state just before that step."""


def nonfinite_grad(named) -> str | None:
    """Name of the first of the ``(name, parameter)`` pairs ``named`` whose gradient is NaN or
    infinite; ``None`` if none is."""
    for n, p in named:
        if p.grad is not None and not torch.isfinite(p.grad).all():
            return n
    return None


def nonfinite_param(named) -> str | None:
    """Name of the first trainable parameter of ``named`` (``(name, parameter)`` pairs) whose
    value is NaN or infinite; ``None`` if none is."""
    for n, p in named:
        if p.requires_grad and not torch.isfinite(p).all():
            return n
    return None


def stop(module, step: int, what: str):
    """Save the state ``module``'s step ``step`` started from (no optimiser step has used the
    bad values; the buffers its forward pass changed, ``module._buffers_before``, are put
    back) as ``checkpoints/nonfinite_step<step>.ckpt`` and raise :class:`NonFiniteLossError`
    with ``what`` and that path."""
    with torch.no_grad():
        buffers = dict(module.named_buffers())
        for n, b in getattr(module, "_buffers_before", {}).items():
            buffers[n].copy_(b)
    folder = module.checkpoint_dir()
    path = None
    if folder is not None:
        path = folder / f"nonfinite_step{step}.ckpt"
        # Lightning counts a checkpoint written inside a step as written after it and adds
        # one to the logging step on restart; this step never stepped: saved one lower, a
        # resumed run logs at its global step (no shift of every TensorBoard point)
        loop = module.trainer.fit_loop.epoch_loop
        loop._batches_that_stepped -= 1
        try:
            module.trainer.save_checkpoint(str(path))
        finally:
            loop._batches_that_stepped += 1
    raise NonFiniteLossError(f"{what}; training stopped before the optimiser step, the "
                             f"state just before it saved to {path} (resume with "
                             f"ckpt_path={path}; changed model.net_lr / optics_lr_mm "
                             f"settings apply on resume)")
