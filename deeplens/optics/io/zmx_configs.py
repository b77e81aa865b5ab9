"""Every configuration of a multi-configuration ``.zmx`` file (:mod:`.zmx_mconf`), one
:class:`~deeplens.optics.lens.Lens` each, the surfaces no configuration changes shared by object:
:func:`read_zmx_configs`."""

from __future__ import annotations

import torch

from .zmx_parse import parse
from .zmx_read import read_zmx

__all__ = ["read_zmx_configs", "share_surfaces"]


def _same_but_size(a, b) -> bool:
    """Whether surfaces ``a`` and ``b`` are the same but for their semi-diameters: one type,
    equal parameters and buffers (every other state_dict entry) and equal plain attributes."""
    if type(a) is not type(b):
        return False
    sa, sb = a.state_dict(), b.state_dict()
    if sa.keys() != sb.keys():
        return False
    for key in sa:
        if key.split(".")[-1] == "semi_diameter":
            continue
        x, y = sa[key], sb[key]
        if x.shape != y.shape or x.dtype != y.dtype or not torch.equal(x, y):
            return False
    plain = {k: v for k, v in vars(a).items() if not k.startswith("_")}
    other = {k: v for k, v in vars(b).items() if not k.startswith("_")}
    return plain.keys() == other.keys() and all(
        _plain_equal(plain[k], other[k]) for k in plain)


def _plain_equal(x, y) -> bool:
    try:
        return bool(x == y)
    except Exception:   # noqa: BLE001 - arrays and the like: compare their text
        return repr(x) == repr(y)


def share_surfaces(lenses: list) -> list[int]:
    """Make the lenses of one file's configurations share their unchanged surfaces, in place:
    surface ``i`` becomes one module object in every lens when every configuration has the
    same surface there but for its semi-diameter (:func:`_same_but_size`), and it is not a stop
    whose radius differs between configurations (the stop's radius is each configuration's
    pupil).  The shared surface's semi-diameter is the largest of the configurations' (an
    automatic semi-diameter is one configuration's beam footprint; one physical surface passes
    every configuration's beam).  Returns the shared indices.  Lenses with different numbers of
    surfaces share nothing."""
    first = lenses[0]
    if len(lenses) < 2 or any(len(L.surfaces) != len(first.surfaces) for L in lenses):
        return []
    shared = []
    for i, s in enumerate(first.surfaces):
        others = [L.surfaces[i] for L in lenses[1:]]
        if not all(_same_but_size(s, o) for o in others):
            continue
        sizes = [float(L.surfaces[i].semi_diameter) for L in lenses]
        if any(L.stop_index == i for L in lenses) and max(sizes) != min(sizes):
            continue
        with torch.no_grad():
            s.semi_diameter.fill_(max(sizes))
        for L in lenses[1:]:
            L.surfaces[i] = s
        shared.append(i)
    return shared


def read_zmx_configs(path, **options) -> list:
    """Every configuration of a ``.zmx`` file, as one :class:`~deeplens.optics.lens.Lens` each
    (configuration 1 first; a file without ``MNUM`` gives one lens).

    Each lens is :func:`~.zmx_read.read_zmx` ``(path, config=N, **options)``; then the surfaces
    no configuration changes are shared **by object** (:func:`share_surfaces`):
    ``lenses[0].surfaces[i] is lenses[1].surfaces[i]`` for a surface equal in every
    configuration but for its semi-diameter (an automatic one depends on the configuration's
    beam; the shared one is the largest, and a stop whose radius differs is not shared), so a
    change to a shared surface's parameters (an optimiser step) changes every configuration.
    Gaps, fields, wavelengths and apertures stay each lens's own; a surface an operand changes
    (``CRVT``, ``CONN``) is each configuration's own object.

    Raises:
        ZemaxFileError: as :func:`~.zmx_read.read_zmx` for any configuration, or a shared
            surface whose largest semi-diameter does not fit a configuration (surfaces that
            then cross), located at that ``SURF`` block.
    """
    sysd, _, _ = parse(path)
    n = sysd["mnum"][0] if sysd.get("mnum") else 1
    lenses = [read_zmx(path, config=k, **options) for k in range(1, n + 1)]
    share_surfaces(lenses)
    for k, lens in enumerate(lenses, start=1):
        try:
            lens.check()
        except ValueError as e:
            _, _, p = parse(path)
            p.fail(sysd["mnum"][2], f"configuration {k}, with the surfaces shared between the "
                                    f"configurations (each the largest semi-diameter of "
                                    f"any configuration): {e}")
    return lenses
