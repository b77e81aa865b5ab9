"""Mistakes on a ``deeplens train|eval`` command line found before Hydra makes an output
folder, each reported as one line:

- a misspelt key (``trainer.max_epoch=3``): Hydra's own advice is to append a new key
  (``+trainer.max_epoch=3``); here the line names the closest keys of the composed config
  (:func:`difflib.get_close_matches` over every key path), e.g. ``did you mean
  trainer.max_epochs?``, and keeps ``+KEY=VALUE`` as the way to add a new key;
- a ``lens.path`` that names no file and no shipped lens: a traceback from deep inside
  ``train()`` after the run folder was made; here one line with the shipped names.

:func:`precheck` composes the configuration once with Hydra's compose API (about 0.3 s) and
never raises: a command line it does not understand is left to Hydra.
"""

from __future__ import annotations

import contextlib
import difflib
import io
import re
from pathlib import Path

from ..resources import lens_dir

__all__ = ["config_keys", "precheck", "suggest_keys"]


def config_keys(cfg) -> list[str]:
    """Every key path of ``cfg`` (nodes and leaves: ``trainer``, ``trainer.max_epochs``...)
    without resolving interpolations."""
    from omegaconf import DictConfig

    out = []

    def walk(node, prefix):
        for k in node.keys():
            path = f"{prefix}{k}"
            out.append(path)
            child = node._get_node(k)
            if isinstance(child, DictConfig) and not child._is_missing() \
                    and not child._is_none():
                walk(child, path + ".")

    walk(cfg, "")
    return out


def suggest_keys(key: str, keys: list[str], n: int = 3, cutoff: float = 0.7) -> list[str]:
    """The keys of ``keys`` closest to ``key``: first those under the same parent, compared by
    their last part (``trainer.max_epoch`` -> ``trainer.max_epochs``), then the whole paths."""
    parent, _, last = key.rpartition(".")
    siblings = {k.rpartition(".")[2]: k for k in keys if k.rpartition(".")[0] == parent}
    near = [siblings[s] for s in difflib.get_close_matches(last, list(siblings), n, cutoff)]
    for k in difflib.get_close_matches(key, keys, n, cutoff):
        if k not in near:
            near.append(k)
    return near[:n]


def _lens_problem(cfg) -> str | None:
    from omegaconf import OmegaConf

    try:
        path = OmegaConf.select(cfg, "lens.path", throw_on_resolution_failure=True)
        if OmegaConf.select(cfg, "lens.start", default=None) == "search":
            return None   # the lens comes from lens.search (the start-up check reads it)
    except Exception:   # an interpolation only Hydra's run can resolve: Hydra checks it
        return None
    shipped = ", ".join(sorted(q.stem for q in lens_dir().glob("*.json")))
    if path is None:
        return f"lens.path: expected a lens file or a shipped lens name ({shipped}), got null"
    p = Path(str(path))
    if p.exists() or (p.parent == Path(".") and p.suffix.lower() in ("", ".json")
                      and (lens_dir() / p.with_suffix(".json").name).is_file()):
        return None
    return (f"lens.path: no lens file {path} (from {Path.cwd()}), nor a shipped lens "
            f"({shipped})")


def precheck(kind: str, args: list[str], config_dir: str) -> str | None:
    """The one-line message for a misspelt key or a missing ``lens.path`` in the Hydra command
    line ``args`` of ``deeplens KIND`` (``"train"`` or ``"eval"``), or ``None``.

    Example:
        >>> precheck("train", ["trainer.max_epoch=3"], str(config_dir()))  # doctest: +SKIP
        "trainer.max_epoch is not a key of the train config: did you mean trainer.max_epochs?
        (a new key: +trainer.max_epoch=3)"
    """
    try:
        return _precheck(kind, args, config_dir)
    except Exception:       # never in the way of a run: Hydra reports what this cannot
        return None


def _precheck(kind, args, config_dir):
    from hydra import compose, initialize_config_dir
    from hydra._internal.utils import get_args_parser
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import ConfigCompositionException

    with contextlib.redirect_stderr(io.StringIO()):
        try:
            parsed = get_args_parser().parse_args(args)
        except SystemExit:  # Hydra's parser says what is wrong
            return None
    if (parsed.help or parsed.hydra_help or parsed.info or parsed.shell_completion
            or parsed.experimental_rerun):
        return None
    overrides = OverridesParser.create().parse_overrides(parsed.overrides)
    plain = [o.input_line for o in overrides if not o.is_sweep_override()]
    swept = [o for o in overrides if o.is_sweep_override()]
    with initialize_config_dir(config_dir=config_dir, version_base="1.3"):
        try:
            cfg = compose(f"{kind}.yaml", overrides=plain)
            bad = None
        except ConfigCompositionException as e:
            m = re.match(r"Could not override '([^']+)'", str(e))
            if not m:
                return None
            bad = m.group(1)
            cfg = compose(f"{kind}.yaml", overrides=[
                o.input_line for o in overrides
                if not o.is_sweep_override() and o.key_or_group != bad])
    keys = config_keys(cfg)
    if bad is None:     # a swept key (-m seed=0,1) must exist too
        bad = next((o.key_or_group for o in swept if not o.is_add()
                    and not o.key_or_group.startswith("hydra.")
                    and o.key_or_group not in keys), None)
    if bad is not None:
        near = suggest_keys(bad, keys)
        hint = f"did you mean {' or '.join(near)}?" if near else "no key is close"
        return (f"{bad} is not a key of the {kind} config: {hint} (a new key: "
                f"+{bad}=VALUE; every key: deeplens {kind} --cfg job)")
    if parsed.cfg:          # only printing the config
        return None
    return _lens_problem(cfg)
