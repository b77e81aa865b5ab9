"""The module's dict settings as small frozen dataclasses: one source for the check, the
default and the run key.

``model.worst_depth`` / ``model.optics_worst_depth`` (:class:`SoftMax`), ``model.optics_invariance``
(:class:`Invariance`) and ``model.deconvolution``
(:class:`~deeplens.training.wiener.Deconvolution`) are mappings in a config; each class checks
one (``from_config``: :class:`~deeplens.optics.errors.ConfigError` naming
``model.<key>.<field>``), fills in its defaults (the dataclass's own field defaults), and gives
the evaluation's run key the same defaults (:data:`MODEL_SETTINGS`, :func:`completed`), so that
``{temperature: 0.25}`` and ``{temperature: 0.25, bins: 4, momentum: 0.9}`` are one run.

>>> SoftMax.from_config("worst_depth", {"temperature": 0.25})
SoftMax(temperature=0.25, bins=4, momentum=0.9)
>>> completed("optics_invariance", {"weight": 2.0})
{'weight': 2.0, 'slack': 0.0}
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from ..optics.errors import ConfigError
from .wiener import Deconvolution

__all__ = ["Invariance", "MODEL_SETTINGS", "SoftMax", "completed", "defaults"]


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _mapping(key: str, value, what: str) -> dict:
    """``value`` as a dict, else :class:`ConfigError` naming ``model.<key>``."""
    if isinstance(value, dict):
        return value
    try:
        return dict(value)
    except (TypeError, ValueError):
        raise ConfigError(f"model.{key}", what, value) from None


@dataclass(frozen=True)
class SoftMax:
    """A soft maximum over depth bins (``model.worst_depth``, ``model.optics_worst_depth``;
    :class:`~deeplens.training.depth_weighting.DepthSoftMax`).  The training range is cut into
    ``K`` bins uniform in 1/depth; each bin keeps a running mean ``E_b`` (momentum ``m``) of
    the per-image loss of its samples, and a sample of bin ``b`` is weighted by
    ``K softmax_b(log E_b / T)`` (mean weight 1 over bins, so ``T -> inf`` is the plain mean
    and small ``T`` trains on the worst bin).

    Attributes:
        temperature: ``T > 0``: a sample of bin ``b`` weighs ``K softmax_b(log E_b / T)``.
        bins: ``K >= 1`` bins uniform in 1/depth over the training range.
        momentum: ``m`` in ``[0, 1)``, of each bin's running mean loss ``E_b``.
    """

    temperature: float = 0.5
    bins: int = 4
    momentum: float = 0.9

    @classmethod
    def from_config(cls, key: str, value) -> SoftMax | None:
        """``model.<key>`` checked, defaults filled: ``None`` or a :class:`SoftMax`; else
        :class:`ConfigError` naming ``model.<key>[.<field>]``."""
        if value is None:
            return None
        value = _mapping(key, value, "null or a mapping {temperature, bins, momentum}")
        known = defaults(cls)
        unknown = set(value) - set(known)
        if unknown:
            raise ConfigError.unknown(f"model.{key}", unknown, known)
        s = {**known, **value}
        T, K, mom = s["temperature"], s["bins"], s["momentum"]
        if not (_number(T) and math.isfinite(T) and T > 0):
            raise ConfigError(f"model.{key}.temperature", "a number > 0", T)
        if not (isinstance(K, int) and not isinstance(K, bool) and K >= 1):
            raise ConfigError(f"model.{key}.bins", "an integer >= 1", K)
        if not (_number(mom) and 0 <= mom < 1):
            raise ConfigError(f"model.{key}.momentum", "a number in [0, 1)", mom)
        return cls(float(T), K, float(mom))


@dataclass(frozen=True)
class Invariance:
    """``model.optics_invariance``: while the optics move, the loss gains
    ``weight relu(R / R_0 - 1 - slack)^2``, ``R`` the fraction of the OTF's power that changes
    over the training depths (:func:`~deeplens.training.wiener.depth_change`, from the Wiener
    front end's PSFs of the same step) and ``R_0`` its value at the first step the optics
    move: the optics may change anything except become less depth-invariant than they started
    (by more than the fraction ``slack``;
    :class:`~deeplens.training.depth_weighting.InvariancePenalty`).

    Attributes:
        weight: a finite number > 0.
        slack: a finite number >= 0 (the fraction by which ``R`` may exceed ``R_0``).
    """

    weight: float = 1.0
    slack: float = 0.0

    @classmethod
    def from_config(cls, value, deconvolution) -> Invariance | None:
        """``model.optics_invariance`` checked: ``None``, or a mapping of known keys completed
        with the defaults; it needs ``model.deconvolution`` (the PSF change over depth is
        measured on the Wiener front end's OTFs) with more than one depth.  Else
        :class:`ConfigError` naming ``model.optics_invariance[.<key>]``."""
        if value is None:
            return None
        if not isinstance(value, dict):
            raise ConfigError("model.optics_invariance", "null or a mapping {weight, slack}",
                              value)
        known = defaults(cls)
        unknown = set(value) - set(known)
        if unknown:
            raise ConfigError.unknown("model.optics_invariance", unknown, known)
        s = {**known, **value}
        for k, lo in (("weight", None), ("slack", 0.0)):
            v = s[k]
            if not (_number(v) and math.isfinite(v) and (v > 0 if lo is None else v >= lo)):
                raise ConfigError(f"model.optics_invariance.{k}", "a finite number > 0"
                                  if lo is None else "a finite number >= 0", v)
        if deconvolution is None:
            raise ConfigError("model.optics_invariance", "null without model.deconvolution (the "
                              "PSF change over depth is measured on the Wiener front end's "
                              "OTFs)", value)
        if deconvolution.get("depths", Deconvolution.depths) == 1:
            raise ConfigError("model.optics_invariance", "null with model.deconvolution.depths = "
                              "1 (one depth has no PSF change to hold)", value)
        return cls(float(s["weight"]), float(s["slack"]))


#: ``model.<key>`` -> the class of its setting (the run key completes a setting given in part
#: with the class's defaults: :func:`completed`)
MODEL_SETTINGS = {"worst_depth": SoftMax, "optics_worst_depth": SoftMax,
                  "deconvolution": Deconvolution, "optics_invariance": Invariance}


def defaults(cls) -> dict:
    """``{field: default}`` of a settings class, in field order."""
    return {f.name: f.default for f in dataclasses.fields(cls)}


def completed(key: str, value: dict) -> dict:
    """``value`` (``model.<key>`` given in part, a plain dict) completed with the defaults of
    its class (:data:`MODEL_SETTINGS`): the form a run key compares."""
    return {**defaults(MODEL_SETTINGS[key]), **value}
