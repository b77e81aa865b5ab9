"""Training and evaluation under manufacturing tolerances (the ``tolerance/`` config group).

Training (``model.tolerance_training: true``): step ``s`` renders through the lens drawn by
seed ``tolerance_seed(run seed, s)`` around the *current* nominal lens
(:func:`deeplens.design.tolerance_model.drawn`), so every batch sees another manufactured lens
and the optics' gradient is taken through the drawn lens to the nominal parameters.

Evaluation under tolerances: :mod:`.tolerance_eval`.
"""

from __future__ import annotations


from ..design.tolerance_model import ToleranceModel, drawn, load_group

__all__ = ["load_group", "tolerance_seed", "TrainingDraws"]


def tolerance_seed(run_seed: int, step: int) -> int:
    """The seed of the lens drawn at training ``step`` (a new lens every step)."""
    return (int(run_seed) * 2_000_003 + 7 * int(step) + 104_729) % (2 ** 62)


class TrainingDraws:
    """Per-step drawn lenses for :class:`~deeplens.training.module.EndToEndModule`."""

    def __init__(self, model: ToleranceModel, run_seed: int):
        if not model:
            raise ValueError("model.tolerance_training: true needs a tolerance group with a "
                             "non-zero tolerance (e.g. tolerance=precision); the group has none")
        self.model, self.run_seed = model, int(run_seed)

    def at(self, lens, step: int):
        """The context in which ``lens`` is the lens drawn for ``step``."""
        return drawn(lens, self.model.draw(lens, tolerance_seed(self.run_seed, step)))
