"""Optional dependencies (the ``pip install "deeplens-do[EXTRA]"`` extras of pyproject.toml),
checked before a command does any work, so that a missing one is one line naming the extra to
install instead of a ``No module named ...`` traceback after minutes of tracing.

:data:`EXTRAS` lists, per extra, the import names a command of that extra needs (the
distributions of pyproject.toml's ``[project.optional-dependencies]``: ``matplotlib``,
``pyyaml`` -> ``yaml``, ``scikit-image`` -> ``skimage``, Pillow comes with matplotlib).
:func:`missing_extra` finds modules without importing them (:func:`importlib.util.find_spec`),
so the check costs milliseconds.
"""

from __future__ import annotations

import importlib.util
import sys

__all__ = ["EXTRAS", "install_line", "missing_extra"]

#: extra -> import names its commands need
EXTRAS = {
    "plot": ("matplotlib", "PIL", "yaml", "skimage"),
    "train": ("matplotlib", "PIL", "yaml", "skimage", "hydra", "omegaconf", "lightning",
              "torchvision", "kornia", "tensorboard"),
}


def install_line(extra: str) -> str:
    """The pip command that installs ``extra`` (``pip install "deeplens-do[train]"``)."""
    return f'pip install "deeplens-do[{extra}]"'


def _absent(module: str) -> bool:
    if module in sys.modules:            # imported already, or blocked (set to None)
        return sys.modules[module] is None
    try:
        return importlib.util.find_spec(module) is None
    except (ImportError, ValueError):    # a broken parent package
        return True


def missing_extra(extra: str, what: str, modules=None) -> str | None:
    """``None`` when the modules of ``extra`` (or just ``modules``) are importable, else the one
    line to print: which modules are missing, that ``what`` needs them, and the pip command.

    Example:
        >>> missing_extra("plot", "deeplens plot") is None  # with matplotlib installed
        True

    Raises:
        KeyError: an unknown extra.
    """
    need = EXTRAS[extra] if modules is None else tuple(modules)
    gone = [m for m in need if _absent(m)]
    if not gone:
        return None
    names = ", ".join(gone)
    return (f"{what} needs the '{extra}' extra ({names} not installed): "
            f"{install_line(extra)}")
