"""Deprecated alias: the tolerance model moved to :mod:`deeplens.optics.tolerance_model` and
its file loading (``load_group``, ``CONFIG_DIR``) to :mod:`deeplens.design.tolerance_groups`.
Importing this module warns once (``DeprecationWarning``) and re-exports the same objects; it
goes in the next release."""

import warnings

from ..optics.tolerance_model import (COMPENSATORS, KINDS, Distribution, LensDraw,
                                      PerturbedMaterial, ToleranceModel, axis_image, call_drawn,
                                      drawn)
from .tolerance_groups import CONFIG_DIR, load_group

warnings.warn("deeplens.design.tolerance_model is deprecated and will be removed in the next "
              "release: import the model from deeplens.optics.tolerance_model and load_group / "
              "CONFIG_DIR from deeplens.design.tolerance_groups (the same objects)",
              DeprecationWarning, stacklevel=2)

__all__ = ["CONFIG_DIR", "load_group", "KINDS", "COMPENSATORS", "Distribution", "ToleranceModel",
           "LensDraw", "PerturbedMaterial", "drawn", "call_drawn", "axis_image"]
