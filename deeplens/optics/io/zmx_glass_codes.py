"""A ``.zmx`` glass named by its six-digit ``n_d``/``V_d`` code (``GLAS 847238 ...``): opt-in.

Some files written by other tools name every glass by its code, ``NNNVVV``: ``n_d = 1.NNN``,
``V_d = VV.V`` (``847238``: n_d 1.847, V_d 23.8), the convention CODE V uses for fictitious
glasses (its ``NNNNNN.VVVV`` form, n_d ``1.NNNNNN`` and V_d ``VV.VV``, is read too; both by
:func:`~.fictitious_glass.fictitious_glass`).  OpticStudio looks a ``GLAS`` name up in the loaded catalogues
only ("The glass name entered must be in one of the currently loaded glass catalogs", OpticStudio
User Guide, *Material*), and no vendor catalogue holds such names, so the default
(:data:`GLASS_CODES` ``"refuse"``) refuses the file at its ``GLAS`` line, as before, with a
clause naming the code's reading and the option that reads it.  ``"model"`` reads a code that
none of the catalogues the file names (``GCAT``) nor the user's holds as ``ModelGlass(n_d,
V_d)`` named by the code (a glass of that name in one of those still wins), before the exact-name
search of the shipped catalogues the file does not name, where a code is ambiguous (the previous
CHANCE and CORNING-FRANCE catalogues both list a ``620603``, two makers' glasses), with one located
:class:`~deeplens.optics.errors.ZemaxWarning` per file naming every such ``GLAS`` line and code
(:data:`GLASS_CODE_CAUSE`; at most four codes named, the rest counted), the reading and the
option that flips it.  A model glass matches the code's ``n_d`` and ``V_d`` only; its partial
dispersion and everything outside the visible are idealised.  Schott's nine-digit
``NNNVVV.DDD`` (density) code is not a fictitious-glass code and is never read as one.
"""

from __future__ import annotations

import re

from ..materials import ModelGlass
from .fictitious_glass import fictitious_glass
from .zmx_parse import Cause

__all__ = ["GLASS_CODES", "GLASS_CODE_CAUSE", "glass_code", "glass_code_hint", "glass_code_note"]

#: how a ``GLAS`` name that is a six-digit ``n_d``/``V_d`` code and in no searched catalogue is
#: read: ``"refuse"`` (default) a located error, as OpticStudio; ``"model"`` a model glass
GLASS_CODES = ("refuse", "model")


def glass_code(name: str) -> ModelGlass | None:
    """``ModelGlass(n_d, V_d)`` named ``name`` if ``name`` is a code (``NNNVVV`` or
    ``NNNNNN.VVVV``), else ``None`` (also for a code of no model glass: ``V_d = 0``)."""
    g = str(name).strip()
    if re.fullmatch(r"\d{6}", g):
        tok = f"{g[:3]}.{g[3:]}"            # CODE V's NNN.VVV: the same n_d, V_d
    elif re.fullmatch(r"\d{6}\.\d{4}", g):
        tok = g
    else:
        return None
    try:
        m = fictitious_glass(tok)
    except ValueError:
        return None
    return ModelGlass(m.n_d, m.v_d, name=g)


def glass_code_hint(m: ModelGlass) -> str:
    """The clause a refusal adds for a code name: its reading and the option that reads it."""
    return (f"; {m.name!r} is a six-digit n_d/V_d glass code (n_d {m.n_d:g}, V_d {m.v_d:g}): "
            f"glass_codes='model' (--glass-codes model) reads it as a model glass")


#: the one located warning of a file's codes read as model glasses (``{item}``: the code
#: quoted, ``{detail}``: :func:`glass_code_note`; several: the codes, at most four named)
GLASS_CODE_CAUSE = Cause(
    one="glass {item} is read as a six-digit n_d/V_d glass code: model glass {detail} "
        "(glass_codes='model'); OpticStudio's catalogues hold no such name, so OpticStudio would "
        "refuse it, as glass_codes='refuse' (the default) does; the partial dispersion is "
        "idealised",
    many="{n} glasses are read as six-digit n_d/V_d glass codes ({items}), NNNVVV as the model "
         "glass n_d 1.NNN, V_d VV.V (glass_codes='model'); OpticStudio's catalogues hold no such "
         "names, so OpticStudio would refuse them, as glass_codes='refuse' (the default) does; "
         "the partial dispersion is idealised")


def glass_code_note(m: ModelGlass) -> str:
    """What :data:`GLASS_CODE_CAUSE` says of code ``m`` alone (its ``{detail}``)."""
    return f"n_d {m.n_d:g}, V_d {m.v_d:g}"
