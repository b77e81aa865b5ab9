"""``SpotMerit(reference="polychromatic")``: every wavelength of a field about the field's
common centroid, checked against the spots of :func:`deeplens.analysis.spot.spot_diagram`
traced independently over the same pupil regions."""

from __future__ import annotations

import pytest
import torch

from deeplens.analysis.spot import spot_diagram
from deeplens.design.merit import SpotMerit
from deeplens.optics.io import load_lens


def test_polychromatic_reference_is_the_weighted_common_centroid():
    lens = load_lens("cooke_triplet.json").to(torch.float64)
    waves = [486.1327, 587.5618, 656.2725]
    w = torch.tensor([[1.0, 2.0, 0.5], [1.0, 1.0, 1.0]], dtype=torch.float64)
    m = SpotMerit([0.0, 11.86], waves, weights=w, sampling="hexapolar:3",
                  reference="polychromatic").prepare(lens)
    mono = SpotMerit([0.0, 11.86], waves, weights=w, sampling="hexapolar:3").prepare(lens)
    with torch.no_grad():
        rms, rms_mono = m.rms(lens), mono.rms(lens)
        r = m.residuals(lens)
    for i, f in enumerate([0.0, 11.86]):
        pts = [spot_diagram(lens, f, wl, "hexapolar:3", region=m.regions[(f, wl)]).points
               for wl in waves]
        w2 = w[i] ** 2
        ref = sum(w2[j] * p.mean(0) for j, p in enumerate(pts)) / w2.sum()
        for j, p in enumerate(pts):
            expect = torch.sqrt(((p - ref) ** 2).sum(-1).mean())
            assert float(rms[i, j]) == pytest.approx(float(expect), rel=1e-10)
            assert float(rms[i, j]) >= float(rms_mono[i, j]) * (1 - 1e-12)
    # lateral colour shows off axis only: on axis the centroids coincide (symmetry)
    assert torch.allclose(rms[0], rms_mono[0], rtol=1e-9)
    assert float((rms[1] - rms_mono[1]).abs().max()) > 1e-4
    assert float((r * r).sum()) == pytest.approx(float((w ** 2 * rms ** 2).sum()), rel=1e-12)


def test_unknown_reference_is_named():
    with pytest.raises(ValueError, match="'centroid', 'chief' or 'polychromatic'"):
        SpotMerit(reference="poly")
