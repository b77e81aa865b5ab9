"""The paper's classical and inverse-design applications, one module each.

Each module exposes ``add_arguments(parser)`` (its own command-line options) and
``run(args) -> dict`` (the JSON result; PNG figures go to ``args.out``).  ``deeplens design NAME``
imports the module lazily by name through :data:`APPS`, so a missing module only matters when it
is asked for.
"""

from __future__ import annotations

import importlib

from ...resources import lens_dir

__all__ = ["APPS", "load_app", "describe_app", "DATA_DIR"]

#: command name -> module name in this package
APPS = {"spherical-aberration": "spherical_aberration", "nikon": "nikon",
        "sensitivity": "sensitivity", "caustic": "caustic", "misalignment": "misalignment",
        "search": "search"}

#: the shipped lens files (packaged with the wheel, or the checkout's data/lenses)
DATA_DIR = lens_dir()


def load_app(name: str):
    """The application module for ``name``.

    Raises:
        ValueError: an unknown name (the message lists the known ones), or a known name whose
            module is not present in this checkout.
    """
    if name not in APPS:
        raise ValueError(f"unknown design application {name!r}; known: {', '.join(APPS)}")
    mod = f"{__name__}.{APPS[name]}"
    try:
        return importlib.import_module(mod)
    except ModuleNotFoundError as e:
        if e.name == mod:
            raise ValueError(f"design application {name!r} is not available in this checkout "
                             f"(module {mod} is missing)") from None
        raise


def describe_app(name: str) -> str:
    """The first paragraph of the application's module docstring, whole (one line)."""
    doc = (load_app(name).__doc__ or "").strip()
    text = " ".join(doc.split("\n\n")[0].split())
    lead = f"``deeplens design {name}``: "
    if text.startswith(lead):  # the command's own name repeated in its docstring
        text = text[len(lead)].upper() + text[len(lead) + 1:]
    return text
