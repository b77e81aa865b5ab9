"""The files deeplens ships: default lens prescriptions and the Hydra training configs.

In an installed wheel they are package data, ``deeplens/_resources/lenses/*.json`` and
``deeplens/_resources/configs/**`` (copied there at build time from the repository's
``data/lenses/`` and ``configs/``, see ``setup.py``), found with :mod:`importlib.resources`.
In a source checkout (or an editable install) that folder does not exist and the repository's
own ``data/lenses/`` and ``configs/`` are used, so there is one copy of each file in git.

Every path returned is a real directory on disk (wheels install unzipped).
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["resource_dir", "lens_dir", "data_dir", "config_dir", "lens_path"]

#: resource name -> (folder inside the installed package, folder inside a source checkout)
_WHERE = {"lenses": ("_resources/lenses", "data/lenses"),
          "configs": ("_resources/configs", "configs")}


def resource_dir(name: str) -> Path:
    """The folder of the shipped resource ``name`` (``"lenses"`` or ``"configs"``).

    Raises:
        ValueError: an unknown name.
        FileNotFoundError: neither the packaged folder nor the checkout's exists (a broken
            installation); the message names both places looked at.
    """
    if name not in _WHERE:
        raise ValueError(f"unknown deeplens resource {name!r}; known: {', '.join(_WHERE)}")
    packaged_rel, checkout_rel = _WHERE[name]
    packaged = Path(str(files("deeplens").joinpath(packaged_rel)))
    if packaged.is_dir():
        return packaged
    checkout = Path(__file__).resolve().parents[1] / checkout_rel
    if checkout.is_dir():
        return checkout
    raise FileNotFoundError(f"deeplens resource {name!r} not found: neither the installed "
                            f"package's {packaged} nor the source checkout's {checkout} exists "
                            f"(reinstall with `pip install deeplens-do`)")


def lens_dir() -> Path:
    """The folder of the default lens files (``double_gauss.json``, ``edof_achromat.json``...)."""
    return resource_dir("lenses")


def data_dir() -> Path:
    """The folder that holds ``lenses/`` (the training configs' ``paths.data_dir``)."""
    return lens_dir().parent


def config_dir() -> Path:
    """The folder of the Hydra configs (``train.yaml``, ``eval.yaml``, ``experiment/``...)."""
    return resource_dir("configs")


def lens_path(name: str) -> Path:
    """The shipped lens file ``name`` (e.g. ``"double_gauss.json"``, or without ``.json``).

    Raises:
        FileNotFoundError: no such shipped lens; the message lists those that exist.
    """
    d = lens_dir()
    p = d / (name if name.endswith(".json") else f"{name}.json")
    if not p.is_file():
        known = ", ".join(sorted(q.name for q in d.glob("*.json")))
        raise FileNotFoundError(f"no shipped lens {name!r} in {d}; shipped: {known}")
    return p
