"""Shared fixtures of the data tests."""

import pytest
import torch


@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    """Generate as DataLoader workers do (one intra-op thread): many small ops, no thread hand-off
    (on a loaded 2-core machine that hand-off can cost more than the work)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
