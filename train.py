"""Train an end-to-end camera:  python train.py experiment=edof  (or experiment=doublet).

The same as the installed ``deeplens train experiment=edof`` (deeplens/evaluation/entry.py).
"""

from deeplens.evaluation.entry import run

if __name__ == "__main__":
    run("train", prog="train.py")
