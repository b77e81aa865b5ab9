"""``deeplens.analysis.paraxial``, the former home of :mod:`deeplens.optics.paraxial`: still
resolves for one release, warning once (at import) with a ``DeprecationWarning`` that names the
new path."""

from __future__ import annotations

import importlib
import sys
import warnings

import pytest

import deeplens.analysis
import deeplens.optics.paraxial as new


def test_the_old_module_warns_once_and_resolves(monkeypatch):
    # a fresh import (another module of the process may have imported it already)
    monkeypatch.delitem(sys.modules, "deeplens.analysis.paraxial", raising=False)
    monkeypatch.delattr(deeplens.analysis, "paraxial", raising=False)
    with pytest.warns(DeprecationWarning, match=r"deeplens\.optics\.paraxial") as record:
        old = importlib.import_module("deeplens.analysis.paraxial")
    assert len([w for w in record if w.category is DeprecationWarning]) == 1
    for name in ("paraxial", "ParaxialData", "exit_pupil", "chief_ray_scale"):
        assert getattr(old, name) is getattr(new, name)
    with warnings.catch_warnings(record=True) as again:   # once: later imports are cached
        warnings.simplefilter("always")
        importlib.import_module("deeplens.analysis.paraxial")
    assert not [w for w in again if w.category is DeprecationWarning]
