"""Small ``.zmx`` files written by the tests: ``SURF`` blocks as lists of lines (:func:`surf`)
after a short sequential system header (:func:`zmx_file`).  Imported by test modules as
``from zmx_blocks import surf, zmx_file`` (pytest puts this folder on ``sys.path``)."""

from __future__ import annotations

import warnings

__all__ = ["glass_singlet", "read_noting", "surf", "zmx_file"]


def surf(typ="STANDARD", curv=0.0, disz=0.0, glas=None, parms=None, stop=False, diam=None):
    """The lines of one ``SURF`` block (indented, without the ``SURF k`` line): ``STOP`` when
    ``stop``, ``TYPE``, ``CURV`` (1/mm), ``PARM 1..`` from ``parms``, ``DISZ`` (mm, or a string
    such as ``"INFINITY"``), ``GLAS glas`` and a fixed ``DIAM`` (mm) when given."""
    out = (["  STOP"] if stop else []) + [f"  TYPE {typ}", f"  CURV {curv!r}"]
    out += [f"  PARM {i} {v!r}" for i, v in enumerate(parms or (), start=1)]
    out.append(f"  DISZ {disz if isinstance(disz, str) else repr(disz)}")
    out += [f"  GLAS {glas}"] if glas else []
    out += [f'  DIAM {diam!r} 1 0 0 1 ""'] if diam is not None else []
    return out


def zmx_file(blocks, name: str, aperture: str = "ENPD 10.0",
             fields: str = "FTYP 0 0 1 1 0 0 0\nYFLN 0",
             waves: str = "WAVM 1 0.5875618 1\n") -> str:
    """The text of a sequential ``.zmx`` file in mm: ``VERS``, ``MODE SEQ``, ``NAME name``,
    ``UNIT MM``, the ``aperture`` line, the ``fields`` lines, the ``waves`` lines (each ending
    in a newline; ``""`` for none) and ``PWAV 1``, then ``SURF k`` and ``blocks[k]``'s lines
    (:func:`surf`) for each block, ``SURF 0`` the object."""
    head = (f"VERS 170912 299 123456\nMODE SEQ\nNAME {name}\nUNIT MM X W X CM MR CPMM\n"
            f"{aperture}\n{fields}\n{waves}PWAV 1\n")
    lines = []
    for k, b in enumerate(blocks):
        lines += [f"SURF {k}"] + b
    return head + "\n".join(lines) + "\n"


_GLASS_SINGLET = """VERS 170912 299 123456
MODE SEQ
UNIT MM X W X CM MR CPMM
ENPD 10
FTYP 0 0 1 1 0 0 0
WAVM 1 {wave} 1
PWAV 1
YFLN 0
GCAT {gcat}
SURF 0
  TYPE STANDARD
  CURV 0
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV 0.02
  DISZ 5
  GLAS {glass} 0 0 1.5 40 0 0 0 0 0 0
SURF 2
  TYPE STANDARD
  CURV -0.01
  DISZ 60
SURF 3
  TYPE STANDARD
  CURV 0
  DISZ 0
"""


def glass_singlet(wave, gcat: str, glass: str) -> str:
    """A ``.zmx`` singlet for the glass tests: one wavelength ``wave`` (µm, as ``WAVM`` writes
    it), the ``GCAT`` line's catalogues ``gcat``, the glass ``glass`` between a face of
    curvature 0.02/mm and one of -0.01/mm, 5 mm apart, its ``GLAS`` line with OpticStudio's
    1.5/40 placeholder; the stop on the first face, EPD 10 mm, the image 60 mm on."""
    return _GLASS_SINGLET.format(wave=wave, gcat=gcat, glass=glass)


def read_noting(path):
    """``(lens, notes)``: :func:`~deeplens.optics.io.read_zmx` of ``path`` and the
    :class:`~deeplens.optics.io.ZemaxWarning` messages it issued (every one, none filtered)."""
    from deeplens.optics.io import ZemaxWarning, read_zmx

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        lens = read_zmx(path)
    return lens, [x.message for x in w if isinstance(x.message, ZemaxWarning)]
