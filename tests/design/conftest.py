"""Fixtures shared by the design tests."""

import warnings

import pytest

from deeplens.design.search.glass_region import GlassRegion


@pytest.fixture
def quiet_warnings():
    """Warnings silenced for the test (design runs warn about rays and steps that the tests do
    not check); a module opts in with ``pytestmark = pytest.mark.usefixtures("quiet_warnings")``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


@pytest.fixture(scope="module")
def schott():
    """The SCHOTT catalogue's glass region (built once per module)."""
    return GlassRegion("SCHOTT")
