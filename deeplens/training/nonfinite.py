"""The non-finite guard of a training step: a NaN or infinite loss, gradient or parameter stops
training *before* the optimiser step, with the state just before it saved under
``checkpoints/nonfinite_step<step>.ckpt`` (:func:`stop`).

The functions take the :class:`~.module.EndToEndModule` (or anything with its ``lens``,
``restorer``, ``deconv``, ``named_buffers`` and ``trainer``) or the ``(name, parameter)`` pairs
of its trained parameters (:func:`trained_parameters`).
"""

from __future__ import annotations

from pathlib import Path

import torch

__all__ = ["NonFiniteLossError", "checkpoint_dir", "nonfinite_grad", "nonfinite_param", "stop",
           "trained_parameters"]


def trained_parameters(module):
    """The ``(name, parameter)`` pairs of ``module``'s trained parts: the lens, the restorer
    and the Wiener front end (``deconv``, when it has one), named as in its state dict."""
    yield from ((f"lens.{n}", p) for n, p in module.lens.named_parameters())
    yield from ((f"restorer.{n}", p) for n, p in module.restorer.named_parameters())
    if module.deconv is not None:
        yield from ((f"deconv.{n}", p) for n, p in module.deconv.named_parameters())


def checkpoint_dir(module) -> Path | None:
    """Where ``module``'s run writes checkpoints: the checkpoint callback's folder, else
    ``<default_root_dir>/checkpoints``; ``None`` without a trainer."""
    t = module._trainer
    if t is None:
        return None
    cb = t.checkpoint_callback
    if cb is not None and getattr(cb, "dirpath", None):
        return Path(cb.dirpath)
    return Path(t.default_root_dir) / "checkpoints"


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
    folder = checkpoint_dir(module)
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
