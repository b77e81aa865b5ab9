"""``model.optics_psf_energy`` (deeplens/training/psf_energy.py): the share of a field's light in
its own pixel, against a closed form, its gradient against central differences, and the
module's use of it (an optics-only term)."""

from __future__ import annotations

import json
import math

import pytest
import torch

from deeplens.evaluation.perfect import perfect_lens_dict
from deeplens.optics.errors import ConfigError
from deeplens.render import IdealCamera, Sensor
from deeplens.training.lens_setup import build_lens
from deeplens.training.psf_energy import PsfEnergy, pixel_energy
from deeplens.training.train import build_objects

PITCH = 0.0804            # configs/sensor/doublet.yaml
WAVES = (486.1327, 587.5618, 656.2725)


def _tent_disk(rho: float) -> float:
    """The mean of ``(1 - |x|)(1 - |y|)`` over a uniform disk of radius ``rho <= 1`` (pixels):
    ``1 - 8 rho / (3 pi) + rho^2 / (2 pi)`` (the disk's integrals of 1, ``|x|`` and
    ``|x||y|``: ``pi rho^2``, ``4 rho^3 / 3``, ``rho^4 / 2``)."""
    return 1 - 8 * rho / (3 * math.pi) + rho ** 2 / (2 * math.pi)


@pytest.mark.parametrize("rho", [0.0, 0.5, 0.9])
def test_pixel_energy_of_a_defocused_perfect_lens_is_the_closed_form(tmp_path, rho):
    """A perfect lens (f 10 mm, F/4) with its sensor moved by ``delta`` behind focus images an
    on-axis point at 10 m to a uniform disk of radius ``a delta / v`` (``a`` the stop's
    semi-diameter, ``v`` the image distance): ``E`` is :func:`_tent_disk` of that radius in
    pixels.  A tent of the wrong width, or a spot measured from the wrong centre, fails."""
    sensor = Sensor((16, 16), PITCH, channels=[[w] for w in WAVES])
    d = perfect_lens_dict(10.0, 4.0, 10000.0, sensor.half_diagonal_mm, WAVES)
    v, a = d["sensor"]["distance_mm"], 10.0 / 8.0
    d["sensor"]["distance_mm"] = v + rho * PITCH * v / a
    p = tmp_path / "perfect.json"
    p.write_text(json.dumps(d))
    lens = build_lens(str(p), dtype="float64")
    ideal = IdealCamera(lens, sensor)
    e = pixel_energy(lens, sensor, ideal, [0.0], [10000.0], "hexapolar:128")
    # the hexapolar rings sample the disk's area to ~1/128 of its radius at its rim (where
    # the stop cuts the 1.1 x overfilled pattern): |dE/drho| rho / 128 <= 0.85 * 0.9 / 128
    assert e.shape == (3,)
    assert torch.allclose(e, torch.full_like(e, _tent_disk(rho)), atol=0.006, rtol=0)
    if rho == 0:   # in focus, every field's light at its ideal image (on the diagonal)
        e = pixel_energy(lens, sensor, ideal, [0.5, 1.0], [10000.0], "hexapolar:8")
        assert e.shape == (6,)
        assert torch.allclose(e, torch.ones_like(e), atol=1e-9, rtol=0)


def test_pixel_energy_gradient_matches_central_differences():
    """float64: ``dE/dθ`` of the shipped doublet's curvature and a4 against central
    differences (step 1e-7 relative: truncation O(h^2) ~ 1e-14, round-off eps / h ~ 1e-9; a
    tent kink crossed inside +-h would be a jump, not seen at these rays)."""
    sensor = Sensor((64, 64), PITCH, channels=[[w] for w in WAVES])
    lens = build_lens("data/lenses/wide_doublet.json", dtype="float64",
                      trainable=["surfaces.1.c", "surfaces.3.a.0"])
    ideal = IdealCamera(lens, sensor)
    params = [p for p in lens.parameters() if p.requires_grad]

    def energy():
        return pixel_energy(lens, sensor, ideal, [0.7, 1.0], [10000.0], "hexapolar:6").sum()

    e0 = energy()
    assert 0.05 < float(e0.detach()) / 6 < 0.95          # blurred, not a vacuous 0 or 1
    grads = torch.autograd.grad(e0, params)
    # steps: 1e-7 of the curvature; 1e-9 mm^-3 of a4 (a sag change of ~5e-9 mm at the rim)
    for p, g, h in zip(params, grads, (1e-7 * abs(float(params[0])), 1e-9)):
        with torch.no_grad():
            p += h
            up = float(energy())
            p -= 2 * h
            down = float(energy())
            p += h
        fd = (up - down) / (2 * h)
        noise = 1e-15 * 6 / h                   # round-off of the sums over a few hundred rays
        assert abs(fd) > 1e3 * noise            # a gradient worth checking
        assert float(g) == pytest.approx(fd, rel=1e-5, abs=noise)


def test_psf_energy_settings_are_checked():
    assert PsfEnergy.from_config(None) is None
    s = PsfEnergy.from_config({"weight": 0.5})
    assert s == PsfEnergy(0.5, (0.7, 0.85, 1.0), "hexapolar:8")
    for bad, key in [({"weight": 0}, "weight"), ({"weight": float("nan")}, "weight"),
                     ({"fields": [1.2]}, "fields"), ({"fields": []}, "fields"),
                     ({"sampling": "random"}, "sampling"), ({"sampling": "hex"}, "sampling"),
                     ({"weights": 1}, "")]:
        with pytest.raises(ConfigError, match=f"model.optics_psf_energy.?{key}"):
            PsfEnergy.from_config(bad)


@pytest.mark.slow
def test_module_adds_the_term_to_the_lens_gradient_only(cfg_factory):
    """With ``model.optics_psf_energy`` the training loss gains ``weight mean(1 - E)``: the
    restorer's gradient is unchanged, the lens's gains the term's own; with frozen optics the
    setting is ignored."""
    over = ("experiment=doublet", "model.optics_warmup_steps=0")
    plain = build_objects(cfg_factory(*over))["module"]
    m = build_objects(cfg_factory(*over, "model.optics_psf_energy={weight:0.3}"))["module"]
    m.restorer.load_state_dict(plain.restorer.state_dict())
    images = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    lens_p = [p for p in m.lens.parameters() if p.requires_grad]
    net_p = list(m.restorer.parameters())
    loss, terms, *_ = m.step_loss(images, 1)
    ref, ref_terms, *_ = plain.step_loss(images, 1)
    assert "psf_energy" in terms and "psf_energy" not in ref_terms
    e = pixel_energy(m.camera, None, m.ideal, [0.7, 0.85, 1.0], m.val_depths_mm, "hexapolar:8")
    assert float(terms["psf_energy"]) == pytest.approx(0.3 * float((1 - e).mean()), rel=1e-6)
    assert float(loss) == pytest.approx(float(ref) + float(terms["psf_energy"]), rel=1e-6)
    g = torch.autograd.grad(loss, lens_p + net_p)
    g_ref = torch.autograd.grad(ref, [p for p in plain.lens.parameters() if p.requires_grad]
                                + list(plain.restorer.parameters()))
    g_term = torch.autograd.grad(0.3 * (1 - pixel_energy(
        m.camera, None, m.ideal, [0.7, 0.85, 1.0], m.val_depths_mm, "hexapolar:8")).mean(),
        lens_p)
    n = len(lens_p)
    for a, b, c in zip(g[:n], g_ref[:n], g_term):
        assert torch.allclose(a, b + c, rtol=1e-4, atol=1e-6 * float((b + c).abs().max()))
    assert max(float(c.abs().max()) for c in g_term) > 0
    for a, b in zip(g[n:], g_ref[n:]):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-8)
    frozen = build_objects(cfg_factory(*over, "lens.trainable=[]",
                                       "model.optics_psf_energy={weight:0.3}"))["module"]
    assert frozen.optics_psf_energy is None
    with pytest.raises(ConfigError, match="model.optics_psf_energy.weight"):
        build_objects(cfg_factory(*over, "model.optics_psf_energy={weight:-1}"))
