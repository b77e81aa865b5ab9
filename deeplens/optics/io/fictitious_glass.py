"""CODE V's fictitious-glass code, ``NNNNNN.VVVV``: a model glass of ``n_d``/``V_d``.

Shared by the CODE V reader (:mod:`.codev`, its ``_fictitious``) and the ``.zmx`` reader's
six-digit glass codes (:mod:`.zmx_glass_codes`); its own module so that neither imports the
other.
"""

from __future__ import annotations

import re
from decimal import Decimal

from ..materials import ModelGlass

__all__ = ["fictitious_glass"]


def fictitious_glass(tok: str) -> ModelGlass | None:
    """``NNNNNN.VVVV`` -> ModelGlass(1.NNNNNN, VV.VV), or ``None`` if ``tok`` is not one
    (``ValueError`` for a code of no model glass, ``V_d = 0``)."""
    m = re.fullmatch(r"(\d+)\.(\d+)", tok)
    if m is None:
        return None
    n_d = float(Decimal("1." + m.group(1)))
    v_d = float(Decimal("0." + m.group(2)) * 100)
    return ModelGlass(n_d, v_d)
