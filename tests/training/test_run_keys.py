"""The run keys of shipped configs do not change (issue 39): a finished variant x seed run is
reused (``eval.reuse_runs``) and a killed evaluation resumes only while the canonical run key
(:func:`deeplens.evaluation.evaluate._same_run` of ``_run_key``) of its config is what it was
when the run was made.  The values below were computed on main before the settings became
dataclasses and the evaluation its own floor (the sha256 of the canonical key as sorted JSON,
with the checkout's path written ``<root>`` and the input files' digests left out: they follow
the data files, not the code; the names of the inputs are kept)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from deeplens.evaluation import evaluate as ev

ROOT = Path(__file__).resolve().parents[2]

#: config name -> (overrides, variants whose keys are checked)
CASES = {
    "edof": (("experiment=edof",), ("none", "cubic@1.25um", "classical", "learned")),
    "doublet": (("experiment=doublet",), ("frozen", "classical", "learned", "refined")),
    # settings given in part (completed with the defaults in the canonical key)
    "edof_settings": (("experiment=edof", "model.worst_depth={temperature:0.25}",
                       "model.optics_worst_depth={bins:3,momentum:0.5}",
                       "model.deconvolution={depths:3,rays:512}",
                       "model.optics_invariance={weight:2.0}"), ("learned", "none")),
    # settings given in full: the same key as given in part would be
    "doublet_full_settings": (("experiment=doublet",
                               "model.worst_depth={temperature:0.5,bins:4,momentum:0.9}",
                               "model.deconvolution={depths:5}"), ("learned",)),
}

#: computed on main (commit 2cb94b0) with this file's ``canonical_key``
EXPECTED = {
    "edof/none": ("87471247eaa683f2", ["lens.path"]),
    "edof/cubic@1.25um": ("49fb97309c5f6f92", ["lens.path"]),
    "edof/classical": ("88195a0b52ea1504", []),
    "edof/learned": ("8ec2ab6867a96d4b", ["lens.path"]),
    "doublet/frozen": ("eda344411a4d2eaf", ["lens.path"]),
    "doublet/classical": ("5f79f1712bde821b", []),
    "doublet/learned": ("1dae02183230dfe1", ["lens.path"]),
    "doublet/refined": ("16e08ae2f0f54770", []),
    "edof_settings/learned": ("8c4f91192a6968d2", ["lens.path"]),
    "edof_settings/none": ("d2d59b7647095ec2", ["lens.path"]),
    "doublet_full_settings/learned": ("0d89f285932fe448", ["lens.path"]),
}


def canonical_key(cfg, variant: str) -> tuple[str, list[str], str]:
    """``(sha256[:16] of the canonical key without the input digests, the input names, the
    key as JSON)`` of ``variant`` (seed 0) of the evaluation config ``cfg``."""
    kind = variant.split("@")[0]
    alpha = 0.00125 if kind == "cubic" else None
    vc = ev._variant_cfg(cfg, variant, kind, alpha, seed=0)
    key = ev._same_run(ev._run_key(vc))
    inputs = sorted(key.pop("inputs", {}))
    text = json.dumps(key, sort_keys=True).replace(str(ROOT), "<root>")
    return hashlib.sha256(text.encode()).hexdigest()[:16], inputs, text


@pytest.mark.parametrize("name", sorted(CASES))
def test_run_keys_of_shipped_configs_are_unchanged(name, cfg_factory, tmp_path):
    overrides, variants = CASES[name]
    cfg = cfg_factory(*overrides, tiny=False, config_name="eval.yaml", out=tmp_path / "ev")
    for v in variants:
        digest, inputs, text = canonical_key(cfg, v)
        assert (digest, inputs) == EXPECTED[f"{name}/{v}"], f"{name}/{v}: the run key " \
            f"changed (finished runs would train again); it is now {text}"


def test_partial_and_full_settings_give_one_key(cfg_factory, tmp_path):
    """The canonical key completes a setting given in part with its defaults (the check
    above would not see a default that changed on both sides)."""
    part = cfg_factory("experiment=doublet", "model.worst_depth={bins:4}",
                       "model.deconvolution={depths:5}", tiny=False, config_name="eval.yaml",
                       out=tmp_path / "a")
    full = cfg_factory(*CASES["doublet_full_settings"][0], tiny=False, config_name="eval.yaml",
                       out=tmp_path / "b")
    assert canonical_key(part, "learned")[0] == canonical_key(full, "learned")[0] \
        == EXPECTED["doublet_full_settings/learned"][0]
    other = cfg_factory("experiment=doublet", "model.worst_depth={bins:3}",
                        "model.deconvolution={depths:5}", tiny=False, config_name="eval.yaml",
                        out=tmp_path / "c")
    assert canonical_key(other, "learned")[0] != canonical_key(full, "learned")[0]
