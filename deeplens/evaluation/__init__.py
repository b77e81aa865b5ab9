"""Evaluation: optical variants x seeds, each with its own restorer, on one test set.

The floor above :mod:`deeplens.training`: :mod:`.evaluate` (``evaluate(cfg)``, the tables,
the run keys that reuse finished runs), :mod:`.variants` (``eval.variants`` and
``eval.seeds``), :mod:`.classical` (the classical baseline, designed by
:mod:`deeplens.design`), :mod:`.fanout` and :mod:`.fanout_stop` (variants x seeds as the jobs
of a Hydra launcher), :mod:`.tolerance` (the test under manufacturing tolerances),
:mod:`.figures` (PNG and TensorBoard figures) and :mod:`.entry` (the ``deeplens train`` /
``deeplens eval`` commands).  It imports the training floor; the training floor never imports
it.  Importing this package pulls in Lightning and Hydra, as :mod:`deeplens.training` does.
"""
