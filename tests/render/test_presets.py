"""The render presets (configs/render/): one base, each preset only what differs."""

from pathlib import Path

import yaml

RENDER = Path(__file__).resolve().parents[2] / "configs" / "render"
PRESETS = ("fast", "balanced", "accurate", "psf")


def _load(name):
    return yaml.safe_load((RENDER / f"{name}.yaml").read_text())


def test_presets_share_one_base_and_set_only_what_differs():
    base = _load("_base")
    assert "defaults" not in base
    for name in PRESETS:
        own = _load(name)
        assert own.pop("defaults") == ["_base", "_self_"], name
        assert own, f"{name} sets nothing: it would equal the base"
        for key, value in own.items():
            assert key in base, f"{name}.{key} is not a base setting"
            assert value != base[key], f"{name}.{key} repeats the base value {value!r}"


def test_composed_presets():
    """Hydra composes base + preset: what training and the benchmarks read."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(RENDER.parent), version_base=None):
        got = {name: dict(compose("train", overrides=[f"render={name}"]).render)
               for name in PRESETS}
    assert {k: (v["kind"], v["spp"]) for k, v in got.items()} == {
        "fast": ("mc", 4), "balanced": ("mc", 16), "accurate": ("mc", 64), "psf": ("psf", 16)}
    assert all(v["vignetting"] is False and v["decorrelate"] is True for v in got.values())
