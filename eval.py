"""Compare optical variants, each with its own restorer: python eval.py experiment=edof
(variants x seeds fanned out through a Hydra launcher: eval.launcher=joblib eval.n_jobs=2).

The same as the installed ``deeplens eval experiment=edof`` (deeplens/evaluation/entry.py).
"""

from deeplens.evaluation.entry import run

if __name__ == "__main__":
    run("eval", prog="eval.py", fanout=[__file__])
