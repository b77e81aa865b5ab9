"""``deeplens.design.tolerance_model``, the former home of the tolerance model (now
:mod:`deeplens.optics.tolerance_model`, its file loading :mod:`deeplens.design.tolerance_groups`):
still resolves for one release, warning once (at import) with a ``DeprecationWarning`` that
names the new paths."""

from __future__ import annotations

import importlib
import sys
import warnings

import deeplens.design
import deeplens.design.tolerance_groups as groups
import deeplens.optics.tolerance_model as model


def test_the_old_module_warns_once_and_resolves(monkeypatch):
    monkeypatch.delitem(sys.modules, "deeplens.design.tolerance_model", raising=False)
    monkeypatch.delattr(deeplens.design, "tolerance_model", raising=False)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        old = importlib.import_module("deeplens.design.tolerance_model")
        importlib.import_module("deeplens.design.tolerance_model")   # cached: no second warning
    dep = [str(w.message) for w in record if w.category is DeprecationWarning]
    assert len(dep) == 1 and "deeplens.optics.tolerance_model" in dep[0] \
        and "deeplens.design.tolerance_groups" in dep[0]
    for name in old.__all__:
        assert getattr(old, name) is getattr(groups if name in groups.__all__ else model, name)
