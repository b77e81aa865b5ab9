"""Training scalars beside the losses: learning rates and the Wiener filter's noise ratio.

Logged every step by :class:`~deeplens.training.module.EndToEndModule` as ``lr/<group>`` (each
optimiser parameter group by its name: ``net``, the optics groups, ``discriminator``) and
``wiener/nsr_c<k>`` (the learned noise-to-signal power ratio of channel ``k``).
"""

from __future__ import annotations

import torch

__all__ = ["training_scalars"]


def training_scalars(optimizer, deconv=None) -> dict:
    """Scalars worth a curve beside the losses: each parameter group's learning rate
    (``lr/<group name>``) and, with a Wiener filter, its noise-to-signal ratio per channel
    (``wiener/nsr_c<k>``)."""
    out = {}
    for k, g in enumerate(optimizer.param_groups):
        out[f"lr/{g.get('name', f'group{k}')}"] = float(g["lr"])
    if deconv is not None:
        with torch.no_grad():
            for c, v in enumerate(deconv.nsr().reshape(-1).tolist()):
                out[f"wiener/nsr_c{c}"] = float(v)
    return out
