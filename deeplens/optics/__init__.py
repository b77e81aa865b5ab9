"""The differentiable ray tracer: pure torch, never imports Lightning, Hydra or anything above.

The names most programs need are importable from here::

    from deeplens.optics import Lens, load_lens, Rays
"""

from .errors import LensError, LensFileError
from .intersect import IntersectOptions  # the former name of TraceOptions
from .options import TraceOptions
from .lens import Lens, LensSpec
from .rays import Rays
from .io import lens_from_dict, lens_to_dict, load_lens, save_lens

__all__ = ["Lens", "LensSpec", "Rays", "TraceOptions", "IntersectOptions", "load_lens", "save_lens",
           "lens_from_dict", "lens_to_dict", "LensError", "LensFileError"]
