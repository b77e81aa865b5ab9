"""The differentiable ray tracer: pure torch, never imports Lightning, Hydra or anything above.

The names most programs need are importable from here::

    from deeplens.optics import Lens, load_lens, Rays

The lens-file names (``load_lens``, ``save_lens``, ``lens_from_dict``, ``lens_to_dict``) are
loaded on first use (module ``__getattr__``): importing the tracer does not load the file
readers and writers of :mod:`deeplens.optics.io` (Zemax, CODE V, glass catalogues).
"""

import warnings

from .errors import LensError, LensFileError
from .intersect import DEPRECATED_OPTIONS
from .options import TraceOptions
from .lens import Lens, LensSpec
from .rays import Rays

__all__ = ["Lens", "LensSpec", "Rays", "TraceOptions", "load_lens", "save_lens",
           "lens_from_dict", "lens_to_dict", "LensError", "LensFileError"]

#: names served from :mod:`deeplens.optics.io` on first access
_IO_NAMES = frozenset({"load_lens", "save_lens", "lens_from_dict", "lens_to_dict"})


def __getattr__(name: str):
    """The lens-file names, loaded from :mod:`deeplens.optics.io` on first access; and
    ``IntersectOptions``, the former name of :class:`TraceOptions` (one release of a
    ``DeprecationWarning``)."""
    if name in _IO_NAMES:
        from . import io   # the file formats, loaded on first use only

        return getattr(io, name)
    if name == "IntersectOptions":
        warnings.warn(DEPRECATED_OPTIONS, DeprecationWarning, stacklevel=2)
        return TraceOptions
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | _IO_NAMES)
