"""The differentiable ray tracer: pure torch, never imports Lightning, Hydra or anything above.

The names most programs need are importable from here::

    from deeplens.optics import Lens, load_lens, Rays
"""

import warnings

from .errors import LensError, LensFileError
from .intersect import DEPRECATED_OPTIONS
from .options import TraceOptions
from .lens import Lens, LensSpec
from .rays import Rays
from .io import lens_from_dict, lens_to_dict, load_lens, save_lens

__all__ = ["Lens", "LensSpec", "Rays", "TraceOptions", "load_lens", "save_lens",
           "lens_from_dict", "lens_to_dict", "LensError", "LensFileError"]


def __getattr__(name: str):
    """``IntersectOptions``, the former name of :class:`TraceOptions`: one release of a
    ``DeprecationWarning``."""
    if name == "IntersectOptions":
        warnings.warn(DEPRECATED_OPTIONS, DeprecationWarning, stacklevel=2)
        return TraceOptions
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
