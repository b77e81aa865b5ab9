"""Former names that still resolve for one release, each with a ``DeprecationWarning``."""

from __future__ import annotations

import pytest

import deeplens.optics as optics
from deeplens.optics import intersect
from deeplens.optics.options import TraceOptions


@pytest.mark.parametrize("module", [optics, intersect], ids=["optics", "intersect"])
def test_intersect_options_is_trace_options_with_a_warning(module):
    with pytest.warns(DeprecationWarning, match="IntersectOptions is deprecated.*TraceOptions"):
        cls = module.IntersectOptions
    assert cls is TraceOptions
    with pytest.raises(AttributeError, match="no attribute 'NoSuchName'"):
        module.NoSuchName  # noqa: B018


def test_the_former_name_imports_with_a_warning():
    with pytest.warns(DeprecationWarning):
        from deeplens.optics.intersect import IntersectOptions   # noqa: F401
