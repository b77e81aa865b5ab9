"""Fixtures shared by the optics tests."""

import pytest

import deeplens.optics.compiled as C


@pytest.fixture
def uncompiled(monkeypatch):
    """The fused (compiled) path's logic with the plain functions instead of their
    ``torch.compile``d wrappers: no compiler runs, the kernels' arithmetic is the same."""
    for name, fn in (("compiled_surface_run", C.surface_run),
                     ("compiled_newton_start", C.newton_start),
                     ("compiled_newton_more", C.newton_more),
                     ("compiled_newton_last_check", C.newton_last_check),
                     ("compiled_newton_refract", C.newton_refract)):
        monkeypatch.setattr(C, name, fn)
