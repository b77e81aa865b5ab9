"""Write several configurations of one lens (zoom, focus) as one multi-configuration ``.zmx``
file: :func:`write_zmx_configs`, the inverse of :func:`.zmx_configs.read_zmx_configs`.

Configuration 1 is written as the saved (active) lens by :func:`.zmx_write.write_zmx`; every
other configuration is written the same way, and each line where it differs from
configuration 1's file becomes a multi-configuration operand row after ``MNUM n 1`` (the
operands :mod:`.zmx_mconf` applies when reading):

==================================  ==============================
a line that differs                 operand (number)
==================================  ==============================
``DISZ`` of ``SURF s``              ``THIC s`` (``SURF 0``: the object distance)
``CURV`` of ``SURF s``              ``CRVT s``
``CONI`` of ``SURF s``              ``CONN s``
``GLAS`` of ``SURF s``              ``GLSS s`` (catalogue glasses and mirrors only)
``PARM p`` of ``SURF s``            ``PRAM s`` with ``p`` in the row's sixth field
``XDAT n`` of ``SURF s``            ``EDVA s`` with ``n`` in the row's sixth field
``CLAP`` / ``OBSC`` radii           ``APMN s`` / ``APMX s`` (minimum / maximum radius)
``ENPD`` / ``FNUM``                 ``APER 0``
``YFLN`` / ``XFLN`` value ``f``     ``YFIE f`` / ``XFIE f``
``WAVM w``                          ``WAVE w``
``PWAV``                            ``PRWV 0``
``GCAT``                            none: every configuration's catalogues
``DIAM`` of ``SURF s``              ``SDIA s`` (a surface :func:`.zmx_configs.share_surfaces`
                                    shares has one semi-diameter, the largest, in every lens)
``NAME``                            none: configuration 1's
==================================  ==============================

Anything else that differs (a surface's type, the number of surfaces, fields or wavelengths --
a coordinate break that one configuration has with tilts 0 and deeplens therefore drops --, a
model glass, the stop) has no operand deeplens writes: it is refused with a :class:`ValueError`
naming the configuration and the record.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

from .zmx_write import write_zmx

__all__ = ["write_zmx_configs"]

#: a SURF block's record -> its operand
_SURFACE_OPERANDS = {"DISZ": "THIC", "CURV": "CRVT", "CONI": "CONN", "GLAS": "GLSS"}


def _lines(lens, tmp: Path, k: int) -> list[str]:
    p = tmp / f"config{k}.zmx"
    write_zmx(lens, p)
    return p.read_text(encoding="utf-8").splitlines()


def _where(lines: list[str]) -> list[int | None]:
    """The ``SURF`` number each line belongs to (``None`` for system lines)."""
    out, cur = [], None
    for ln in lines:
        m = re.match(r"SURF\s+(\d+)", ln)
        if m:
            cur = int(m.group(1))
        out.append(cur)
    return out


def write_zmx_configs(lenses: list, path, encoding: str = "utf-8") -> None:
    """Write ``lenses`` (configuration 1 first) as one multi-configuration ``.zmx`` file that
    :func:`~.zmx_configs.read_zmx_configs` reads back as the same configurations (and
    :func:`~.zmx_read.read_zmx` ``(path, config=N)`` as configuration ``N``).

    The lenses are configurations of one design: the same surfaces (type, aspheric terms,
    apertures' kinds), fields and wavelengths in number, differing in gaps, curvatures, conics,
    catalogue glasses, surface parameters and extra data, semi-diameters and aperture radii, the
    aperture value, field and wavelength values and the primary wavelength (see the module's
    table).  One lens writes a plain file (no ``MNUM``).

    Args:
        lenses: the configurations, each a :class:`~deeplens.optics.lens.Lens`.
        path: output file.
        encoding: ``"utf-8"`` (default) or ``"utf-16"``.

    Raises:
        ValueError: no lens, or a configuration that differs from configuration 1 in a record
            no operand carries (named with the configuration, the ``SURF`` and the record).
        ZemaxFileError: a lens :func:`~.zmx_write.write_zmx` cannot write.
    """
    lenses = list(lenses)
    if not lenses:
        raise ValueError("write_zmx_configs: no configuration given")
    with tempfile.TemporaryDirectory() as tmp:
        texts = [_lines(lens, Path(tmp), k) for k, lens in enumerate(lenses, start=1)]
    base = texts[0]
    where = _where(base)
    # (operand, number, second number) -> {config: value}; the second number: PRAM's
    # parameter, EDVA's extra-data number (the row's sixth field), 0 for the others
    rows: dict[tuple[str, int, int], dict[int, str]] = {}
    first: dict[tuple[str, int, int], str] = {}   # configuration 1's value of each row

    def put(op: str, num: int, k: int, value: str, second: int = 0, base_value=None) -> None:
        rows.setdefault((op, num, second), {})[k] = value
        if base_value is not None:
            first[(op, num, second)] = base_value

    out = list(base)
    for k, lines in enumerate(texts[1:], start=2):
        def refuse(i: int, why: str, k=k) -> None:
            at = f"SURF {where[i]}" if i < len(where) and where[i] is not None else "system data"
            raise ValueError(f"write_zmx_configs: configuration {k} differs from configuration 1 "
                             f"in {at}, {why}: no multi-configuration operand carries it")
        if len(lines) != len(base) or _where(lines) != where:
            refuse(min(len(lines), len(base)) - 1, "in its records (number of surfaces, their "
                   "kinds or records, fields or wavelengths)")
        for i, (a, b) in enumerate(zip(base, lines)):
            if a == b:
                continue
            ta, tb = a.split(), b.split()
            key = ta[0] if ta else ""
            if not tb or tb[0] != key:
                refuse(i, f"record {a.strip()!r} vs {b.strip()!r}")
            s = where[i]
            if s is not None:
                if key == "DIAM" and ta[2:] == tb[2:]:
                    put("SDIA", s, k, tb[1], 0, ta[1])
                elif key in _SURFACE_OPERANDS and key != "GLAS" and ta[2:] == tb[2:]:
                    put(_SURFACE_OPERANDS[key], s, k, tb[1])
                elif key == "GLAS" and len(ta) > 2 and len(tb) > 2 and ta[2] == tb[2] == "0":
                    put("GLSS", s, k, tb[1])   # catalogue glasses (code 0) and MIRROR
                elif key in ("PARM", "XDAT") and len(ta) == len(tb) == 3 and ta[1] == tb[1]:
                    put("PRAM" if key == "PARM" else "EDVA", s, k, tb[2], int(ta[1]), ta[2])
                elif (key in ("CLAP", "OBSC") and len(ta) == len(tb) and ta[3:] == tb[3:]
                      and (key == "CLAP" or not _has_record(base, where, s, "CLAP"))):
                    # the reader applies APMN / APMX to the CLAP, or without one to the OBSC
                    for op, j in (("APMN", 1), ("APMX", 2)):
                        if ta[j] != tb[j]:
                            put(op, s, k, tb[j], 0, ta[j])
                else:
                    refuse(i, f"record {a.strip()!r} vs {b.strip()!r}")
            elif key in ("ENPD", "FNUM") and ta[2:] == tb[2:]:
                put("APER", 0, k, tb[1])
            elif key in ("YFLN", "XFLN") and len(ta) == len(tb):
                for f, (va, vb) in enumerate(zip(ta[1:], tb[1:]), start=1):
                    if va != vb:
                        put(key[0] + "FIE", f, k, vb)
            elif key == "WAVM" and ta[1] == tb[1] and ta[3:] == tb[3:]:
                put("WAVE", int(ta[1]), k, tb[2])
            elif key == "PWAV":
                put("PRWV", 0, k, tb[1])
            elif key == "GCAT":   # every configuration's catalogues
                cats = out[i].split()
                out[i] = " ".join(cats + [c for c in tb[1:] if c not in cats])
            elif key != "NAME":
                refuse(i, f"record {a.strip()!r} vs {b.strip()!r}")
    n = len(lenses)
    if n > 1:
        # configuration 1's value in every operand's row too (the saved lens's)
        for (op, num, second) in rows:
            if (op, num, second) not in first:
                first[(op, num, second)] = _value_in_base(base, where, op, num)
        out.append(f"MNUM {n} 1")
        for (op, num, second), vals in rows.items():
            v1 = first[(op, num, second)]
            for k in range(1, n + 1):
                v = v1 if k == 1 else vals.get(k, v1)
                if op == "GLSS" and v.upper() == "AIR":
                    v = '""'
                out.append(f'{op} {num:3d} {k:3d} {v} 0 {second} 0 1 1 1 0 0 "" 0')
    Path(path).write_text("\n".join(out) + "\n", encoding=encoding)


def _has_record(base: list[str], where: list, s: int, key: str) -> bool:
    """Whether ``SURF s`` of configuration 1's file has a ``key`` line."""
    return any(w == s and ln.split()[:1] == [key] for ln, w in zip(base, where))


def _value_in_base(base: list[str], where: list, op: str, num: int) -> str:
    """Configuration 1's value of operand ``op`` ``num`` (the token of its line)."""
    if op in _SURFACE_OPERANDS.values():
        key = {v: k for k, v in _SURFACE_OPERANDS.items()}[op]
        for ln, s in zip(base, where):
            t = ln.split()
            if s == num and t and t[0] == key:
                return t[1]
        raise AssertionError(f"{op} {num}: configuration 1 has no {key} line")  # compared above
    for ln in base:
        t = ln.split()
        if op == "APER" and t and t[0] in ("ENPD", "FNUM"):
            return t[1]
        if op in ("YFIE", "XFIE") and t and t[0] == op[0] + "FLN":
            return t[num]
        if op == "WAVE" and t and t[0] == "WAVM" and int(t[1]) == num:
            return t[2]
        if op == "PRWV" and t and t[0] == "PWAV":
            return t[1]
    raise AssertionError(f"{op} {num}: not in configuration 1's file")
