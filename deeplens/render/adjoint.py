"""Adjoint back-propagation of a rendered image (paper Sec. II-D, Eq. 8).

Three stages: (i) the image is rendered chunk by chunk *without* a graph; (ii) autograd
back-propagates the loss to ``ΔI = dL/dI`` as usual; (iii) :meth:`_AdjointRender.backward`
re-traces every chunk with the same random numbers (only seeds are kept, not rays), and
accumulates the vector-Jacobian product ``J_p^T ΔI`` for all trainable lens parameters (and the
textures, if they require grad) with one ``torch.autograd.grad`` call per chunk.  Peak memory is
one chunk's graph, whatever the number of rays; the price is tracing twice.

With ``renderer.decorrelate`` the re-trace draws independent samples (seed
:func:`decorrelated_seed`): the gradient becomes ``J_B^T ΔI(I_A)``, free of the bias that shared
samples give a loss non-linear in the image (see :class:`~.backward.MonteCarloRenderer`).
"""

from __future__ import annotations

import torch
from torch.nn.utils.stateless import _reparametrize_module

__all__ = ["adjoint_render", "decorrelated_seed"]


def decorrelated_seed(seed: int) -> int:
    """The seed of the independent Jacobian samples paired with a render of ``seed`` (an LCG step,
    so it does not collide with the consecutive seeds of successive renders)."""
    return (int(seed) * 6364136223846793005 + 1442695040888963407) % (2 ** 62)


class _AdjointRender(torch.autograd.Function):
    @staticmethod
    def forward(ctx, renderer, plan, scene, textures, names, *params):
        ctx.renderer, ctx.plan, ctx.scene, ctx.names = renderer, plan, scene, names
        ctx.n_params = len(params)
        with torch.no_grad():
            img = renderer.render_plain(plan, scene)
        return img

    @staticmethod
    def backward(ctx, grad_img):
        renderer, plan, scene = ctx.renderer, ctx.plan, ctx.scene
        if renderer.decorrelate:
            plan = plan.with_seed(decorrelated_seed(plan.seed))
        # the lens's trainable tensors as they are now, each re-entered as a leaf of its own:
        # within a drawn lens (optics.tolerance_model.drawn) some are functions of others (a
        # compensator's translation depends on the trained coefficients), and a gradient with
        # respect to the original tensors would count those paths twice (here and in the
        # autograd graph outside, which receives the returned gradients and chains them)
        current = dict(renderer.lens.named_parameters())
        names = [n for n, p in current.items() if p.requires_grad]
        if names != ctx.names:
            raise RuntimeError("adjoint render: the lens's trainable tensors changed between the "
                               f"render ({ctx.names}) and its backward pass ({names}); run the "
                               "backward inside the context the render ran in (e.g. the drawn "
                               "lens of optics.tolerance_model.drawn)")
        leaves = {n: current[n].detach().requires_grad_(True) for n in names}
        params = list(leaves.values())
        tex = scene.textures
        want_tex = ctx.needs_input_grad[3]
        inputs = params + ([tex] if want_tex else [])
        grads = [torch.zeros_like(p) for p in inputs]
        B, C, H, W = grad_img.shape
        g = grad_img.reshape(B, C, H * W)
        for job, (channel, _, _) in enumerate(plan.jobs):
            for k in range(renderer.n_chunks(plan)):
                pix = renderer.chunk_pixels(plan, k)
                gk = g[:, channel, pix]
                if not bool(gk.any()):
                    continue
                with torch.enable_grad(), _reparametrize_module(renderer.lens, leaves,
                                                                strict=False):
                    val = renderer.render_chunk(plan, scene, job, k)
                    if not val.requires_grad:
                        continue
                    out = torch.autograd.grad((val * gk).sum(), inputs, allow_unused=True)
                for acc, o in zip(grads, out):
                    if o is not None:
                        acc += o
        p_grads = grads[:len(params)]
        t_grad = grads[len(params)] if want_tex else None
        return (None, None, None, t_grad, None, *p_grads)


def adjoint_render(renderer, plan, scene) -> torch.Tensor:
    """Render with adjoint back-propagation (see the module docstring)."""
    named = [(n, p) for n, p in renderer.lens.named_parameters() if p.requires_grad]
    return _AdjointRender.apply(renderer, plan, scene, scene.textures, [n for n, _ in named],
                                *(p for _, p in named))
