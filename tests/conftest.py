"""Test-wide set-up: put ``tests/`` on ``sys.path`` (for ``import helpers``) and seed torch."""

import sys
from pathlib import Path

import pytest
import torch

_TESTS = str(Path(__file__).resolve().parent)
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)


@pytest.fixture(autouse=True)
def _seed_torch():
    """Every test starts from the same global torch seed (tests also pass their own generators)."""
    torch.manual_seed(0)
    yield
