"""Diffraction figures of a lens whose edge field loses its marginal rays (the shipped Cooke
triplet at 11.86 deg): drawn without that field, saying so, unless the user asked for it."""

import pytest

from deeplens.analysis.checks import AnalysisError
from deeplens.analysis.diffraction import frequency_steps
from deeplens.analysis.plot import _diffraction_fields, psf_figure
from deeplens.optics.io import load_lens


@pytest.fixture(scope="module")
def cooke():
    return load_lens("cooke_triplet").double()


def test_edge_field_left_out_with_a_note(cooke):
    with pytest.raises(AnalysisError, match="misses a surface"):   # the premise
        frequency_steps(cooke, 11.86, 587.5618, 16)
    keep, note = _diffraction_fields(cooke, [0.0, 8.3, 11.86], [587.5618], "sensor", None,
                                     explicit=False)
    assert keep == [0.0, 8.3] and "left out: 11.86 deg" in note
    keep, note = _diffraction_fields(cooke, [0.0, 8.3], [587.5618], "sensor", None, False)
    assert keep == [0.0, 8.3] and note == ""
    with pytest.raises(AnalysisError, match="11.86 deg"):
        _diffraction_fields(cooke, [0.0, 11.86], [587.5618], "sensor", None, explicit=True)


def test_psf_figure_of_the_files_fields_draws_the_rest(cooke):
    fig = psf_figure(cooke, n=64)
    titles = [a.get_title() for a in fig.axes if a.get_images()]
    assert [t.split(",")[0] for t in titles] == ["0 deg", "8.3 deg"]
    assert "left out: 11.86 deg" in fig._suptitle.get_text()
    with pytest.raises(AnalysisError):
        psf_figure(cooke, fields_deg=[11.86], n=32)
