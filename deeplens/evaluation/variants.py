"""The variants and seeds of an evaluation (``eval.variants``, ``eval.cubic_alpha_mm``,
``eval.seeds``), checked: what :mod:`.evaluate` runs and :mod:`.fanout` fans out, variants outer,
seeds inner (see :mod:`.evaluate` for what each variant is)."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from ..optics.errors import ConfigError

__all__ = ["seeds", "variants"]

_PLATE_KINDS = ("none", "cubic")
#: the variants of ``eval.variants``
_VARIANTS = ("none", "cubic", "classical", "learned", "refined", "frozen", "searched",
             "perfect")


def _alphas(cfg: DictConfig) -> list[float]:
    a = cfg.eval.cubic_alpha_mm
    vals = list(a) if OmegaConf.is_list(a) or isinstance(a, (list, tuple)) else [a]
    what = "a number or a non-empty list of numbers (mm)"
    try:
        vals = [float(v) for v in vals]
    except (TypeError, ValueError):
        raise ConfigError("eval.cubic_alpha_mm", what, _plain(a)) from None
    if not vals:
        raise ConfigError("eval.cubic_alpha_mm", what, [])
    return vals


def _plain(v):
    """A config node as plain Python (for messages)."""
    return OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v


def seeds(cfg: DictConfig) -> list[int]:
    """The seeds of ``eval.seeds`` (``null``: the run's ``seed``), checked."""
    s = cfg.eval.seeds
    vals = [cfg.seed] if s is None else (list(s) if OmegaConf.is_list(s)
                                         or isinstance(s, (list, tuple)) else [s])
    what = "null or a non-empty list of distinct integers >= 0"
    if not vals:
        raise ConfigError("eval.seeds", what, [])
    for v in vals:
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            raise ConfigError("eval.seeds", what, _plain(s))
    if len(set(vals)) != len(vals):
        raise ConfigError("eval.seeds", what, vals)
    return [int(v) for v in vals]


def variants(cfg: DictConfig) -> list[tuple[str, str, float | None]]:
    """``(name, kind, alpha_mm)`` of every variant to evaluate, in table order.

    Raises:
        ValueError: an unknown variant, or ``none``/``cubic`` for a lens without a plate.
    """
    out = []
    names = cfg.eval.variants
    if names is None:
        names = (["none", "cubic", "classical", "learned"] if cfg.lens.plate_surface is not None
                 else ["searched", "learned"] if cfg.lens.get("start") == "search"
                 else ["frozen", "classical", "learned"])
    for v in names:
        if v in _PLATE_KINDS and cfg.lens.plate_surface is None:
            raise ConfigError("eval.variants", "variants of a lens without a phase plate "
                              "(lens.plate_surface is null): frozen, classical, learned, "
                              "refined, searched, perfect", _plain(names))
        if v == "searched" and cfg.lens.get("search") is None:
            raise ConfigError.missing("lens.search", "the design search's spec (eval.variants "
                                      "has searched)")
        if v == "cubic":
            out += [(f"cubic@{a * 1e3:g}um", "cubic", a) for a in _alphas(cfg)]
        elif v in ("none", "learned", "frozen", "classical", "refined", "searched", "perfect"):
            out.append((v, v, None))
        else:
            raise ConfigError("eval.variants", f"variants of {', '.join(_VARIANTS)}",
                              _plain(names))
    if not out:
        raise ConfigError("eval.variants", f"null or a non-empty list of {', '.join(_VARIANTS)}",
                          _plain(names))
    return out
