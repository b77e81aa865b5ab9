"""The evaluation fan-out passes its folder to Hydra quoted (issue 38 item 4): a folder named
``E2 (copy)`` or ``E2,v2`` made the multirun fail (a comma is a sweep, parentheses a
function call in Hydra's override grammar)."""

from __future__ import annotations

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf

from deeplens.evaluation.fanout import fan_out, hydra_quote

NAMES = ["/data/E2 (copy)", "/data/E2,v2", "/data/it's", "/data/a\\b", "/data/trail\\",
         "/data/[a]=b", "/data/x${y}", "/data/a\\'b", "/data/ü é", "/data/glob*?"]


def read_back(override: str):
    """The value a Hydra command line gives ``override``'s key, as the job's config has it."""
    (o,) = OverridesParser.create().parse_overrides([override])
    assert not o.is_sweep_override()
    return OmegaConf.create({"v": o.value()}).v


@pytest.mark.parametrize("name", NAMES)
def test_a_quoted_value_reads_back_as_itself(name):
    assert read_back(f"eval.folder={hydra_quote(name)}") == name


def test_the_fan_out_command_reads_back_the_folder(cfg_factory, tmp_path, monkeypatch):
    import deeplens.evaluation.fanout as fanout

    out = tmp_path / "E2 (copy),v2"
    calls = []
    monkeypatch.setattr(fanout, "run_process_tree", lambda cmd, env=None: calls.append(cmd) or 0)
    cfg = cfg_factory("experiment=edof", "eval.launcher=joblib", config_name="eval.yaml",
                      out=out)
    fan_out(cfg, ["-m", "deeplens", "eval"], ["experiment=edof", "eval.launcher=joblib"])
    (cmd,) = calls
    args = cmd[cmd.index("-m", 3) + 1:]
    parsed = OverridesParser.create().parse_overrides(args)   # the multirun's own parse
    values = {o.get_key_element(): o for o in parsed}
    for key in ("eval.folder", "hydra.sweep.dir"):
        assert not values[key].is_sweep_override()
        assert OmegaConf.create({"v": values[key].value()}).v == str(out.resolve())
