"""A test-only reading of OpticStudio's multi-configuration editor, independent of deeplens'
:mod:`deeplens.optics.io.zmx_mconf`: :func:`single_configuration` rewrites a ``.zmx`` file's own
records (``SURF`` blocks, system lines) with configuration ``k``'s operand values and drops the
``MNUM`` block, so that any single-configuration reader (optiland's, rayoptics', deeplens' own
without ``config``) reads configuration ``k``.

It works on the text lines only (no deeplens parsing); an operand it has no rule for raises
:class:`NotApplied` unless its value in configuration ``k`` is the saved configuration's (then it
changes nothing).  The rules, each OpticStudio's meaning of the operand (OpticStudio's manual,
"Summary of multi-configuration operands"; see docs/guide/zemax.md):

=============  ==============================================================================
``THIC s``     the ``DISZ`` line of ``SURF s`` (an object thickness of 1e10 or more: ``INFINITY``)
``CRVT s``     the value of the ``CURV`` line
``CONN s``     the ``CONI`` line
``GLSS s``     the ``GLAS`` line (``""``: none, air)
``SDIA s``     the value of the ``DIAM`` line
``PRAM s p``   the ``PARM p`` line (``p``: the row's sixth field); ``PAR1`` .. ``PAR8``: ``PARM n``
``EDVA s n``   the ``XDAT n`` line (``n``: the row's sixth field)
``APMN s`` /   the minimum / maximum radius of the ``CLAP`` or ``OBSC`` line
``APMX s``
``STPS``       the ``STOP`` line moves to ``SURF`` (value)
``APER``       the value of the system aperture line (``ENPD``, ``FNUM``, ``OBNA``, ...)
``YFIE f``     value ``f`` of the ``YFLN`` (and ``YFLD``) line; ``XFIE``: ``XFLN``/``XFLD``
``WAVE w``     the ``WAVM w`` line (and value ``w`` of ``WAVN``/``WAVL``)
``PRWV``       the ``PWAV`` line
``TEMP`` /     the ``ENVD`` line's temperature / pressure
``PRES``
``MOFF``, ``LTTL``, ``MCOM``, ``CWGT``, ``WLWT``, ``FLWT``: nothing (no optics)
=============  ==============================================================================
"""

from __future__ import annotations

import math
import re

from deeplens.optics.io.agf import decode_zemax_text

__all__ = ["NotApplied", "configurations", "single_configuration"]

_NOTHING = {"MOFF", "LTTL", "MCOM", "CWGT", "WLWT", "FLWT"}


class NotApplied(ValueError):
    """An operand this reader has no rule for, whose value differs from the saved one."""


def _rows(lines, start):
    """Operand rows after ``MNUM`` (line index ``start``): ``[(operand, number, configuration,
    value text, fields)]``; other lines are returned apart (kept in the output)."""
    rows, other = [], []
    for ln in lines[start + 1:]:
        f = ln.split()
        if len(f) >= 4 and len(f[0]) == 4 and f[1].isdigit() and f[2].isdigit():
            m = re.match(r'\s*\S+\s+\S+\s+\S+\s+("[^"]*"|\S+)', ln)
            rows.append((f[0].upper(), int(f[1]), int(f[2]), m.group(1).strip('"'), f))
        elif f and f[0].upper() == "CSUM":
            continue   # the editor's checksum
        else:
            other.append(ln)
    return rows, other


def _repeats(old, new) -> bool:
    """Whether the row value ``new`` repeats the record's ``old`` to 5e-13 relative (rows carry
    13 significant digits, records 17)."""
    try:
        a, b = float(old), float(new)
    except (TypeError, ValueError):
        return False
    return math.isfinite(a) and abs(a - b) <= 5e-13 * abs(a)


def configurations(path) -> tuple[int, int]:
    """``(number of configurations, active one)`` from the ``MNUM`` line (1, 1 without)."""
    m = re.search(r"^MNUM\s+(\d+)(?:\s+(\d+))?", decode_zemax_text(path), re.M)
    return (1, 1) if m is None else (int(m.group(1)), int(m.group(2) or 1))


def single_configuration(path, k: int) -> str:
    """The text of ``path`` as a single-configuration file holding configuration ``k``.  A row
    value that repeats the saved record's to the 13 significant digits OpticStudio writes rows
    with (within 5e-13 relative) leaves the saved record as it is (17 digits)."""
    lines = decode_zemax_text(path).splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("MNUM"))
    n, active = configurations(path)
    rows, other = _rows(lines, start)
    head = lines[:start]
    active_value = {(op, num, f[5] if op in ("PRAM", "EDVA") else ""): v
                    for op, num, cfg, v, f in rows if cfg == active}

    def block(s):
        """Line indices ``[first, end)`` of ``SURF s`` (its header excluded)."""
        i = next((j for j, ln in enumerate(head) if re.match(rf"SURF\s+{s}\s*$", ln)), None)
        if i is None:
            raise NotApplied(f"no SURF {s}")
        j = i + 1
        while j < len(head) and head[j].startswith(" "):
            j += 1
        return i + 1, j

    def surf_line(s, key):
        a, b = block(s)
        for j in range(a, b):
            f = head[j].split()
            if f and f[0] == key:
                return j
        return None

    def set_surf(s, key, text, nth=1, new=None):
        """Put ``text`` as field ``nth`` of ``SURF s``'s ``key`` line (``new``: the line to add
        where there is none; ``text`` None: remove the line)."""
        j = surf_line(s, key)
        if text is None:
            if j is not None:
                del head[j]
            return
        if j is None:
            head.insert(block(s)[1], new if new is not None else f"  {key} {text}")
            return
        f = head[j].split()
        if not _repeats(f[nth] if nth < len(f) else None, text):
            f[nth] = text
        head[j] = "  " + " ".join(f)

    def set_system(key, idx, text):
        for j, ln in enumerate(head):
            f = ln.split()
            if f and f[0] == key and not ln.startswith(" "):
                if idx >= len(f):
                    raise NotApplied(f"{key} has no field {idx}")
                if not _repeats(f[idx], text):
                    f[idx] = text
                head[j] = " ".join(f)
                return True
        return False

    for op, num, cfg, v, f in rows:
        if cfg != k or op in _NOTHING:
            continue
        if op == "THIC":
            if num == 0 and v.upper() != "INFINITY" and float(v) >= 1e10:
                v = "INFINITY"   # OpticStudio: an object thickness of 1e10 or more is infinite
            set_surf(num, "DISZ", v)
        elif op == "CRVT":
            set_surf(num, "CURV", v, new=f"  CURV {v} 0 0 0 0 \"\"")
        elif op == "CONN":
            set_surf(num, "CONI", v)
        elif op == "GLSS":
            name = v.strip()
            set_surf(num, "GLAS", None)
            if name and name.upper() != "AIR":
                set_surf(num, "GLAS", name, new=f"  GLAS {name} 0 0 1.5 50 0 0 0 0 0 0")
        elif op == "SDIA":
            set_surf(num, "DIAM", v, new=f"  DIAM {v} 0 0 0 1 \"\"")
        elif op in ("PRAM", "EDVA") or re.fullmatch(r"PAR[1-8]", op):
            p = f[5] if op in ("PRAM", "EDVA") else op[3]
            key = "XDAT" if op == "EDVA" else "PARM"
            a, b = block(num)
            j = next((j for j in range(a, b) if head[j].split()[:2] == [key, p]), None)
            if j is None:
                head.insert(b, f"  {key} {p} {v}")
            else:
                fl = head[j].split()
                if not _repeats(fl[2], v):
                    fl[2] = v
                head[j] = "  " + " ".join(fl)
        elif op in ("APMN", "APMX"):
            key = "CLAP" if surf_line(num, "CLAP") is not None else "OBSC"
            if surf_line(num, key) is None:
                raise NotApplied(f"{op} {num}: SURF {num} has no CLAP or OBSC line")
            set_surf(num, key, v, nth=1 if op == "APMN" else 2)
        elif op == "STPS":
            s = int(float(v))
            for j in [j for j, ln in enumerate(head) if ln.strip() == "STOP"][::-1]:
                del head[j]
            head.insert(block(s)[0], "  STOP")
        elif op == "APER":
            if not any(set_system(key, 1, v) for key in ("ENPD", "FNUM", "OBNA", "OBSN")):
                raise NotApplied("APER: no aperture line with a value (FLOA?)")
        elif op in ("YFIE", "XFIE"):
            a = op[0]
            if not set_system(f"{a}FLN", num, v):
                raise NotApplied(f"{op}: no {a}FLN line")
            set_system(f"{a}FLD", num, v)
        elif op == "WAVE":
            done = False
            for j, ln in enumerate(head):
                fl = ln.split()
                if fl[:2] == ["WAVM", str(num)] and not _repeats(fl[2], v):
                    fl[2] = v
                    head[j] = " ".join(fl)
                    done = True
            done |= set_system("WAVN", num, v)
            set_system("WAVL", num, v) if len(next((ln.split() for ln in head
                                                    if ln.startswith("WAVL ")), [])) > num else None
            if not done:
                raise NotApplied(f"WAVE {num}: no wavelength line")
        elif op == "PRWV":
            if not set_system("PWAV", 1, str(int(float(v)))):
                head.insert(start, f"PWAV {int(float(v))}")
        elif op in ("TEMP", "PRES"):
            if not set_system("ENVD", 1 if op == "TEMP" else 2, v):
                raise NotApplied(f"{op}: no ENVD line")
        elif active_value.get((op, num, f[5] if op in ("PRAM", "EDVA") else "")) != v:
            raise NotApplied(f"{op} {num}: value {v!r} in configuration {k}, "
                             f"{active_value.get((op, num, ''))!r} saved")
    if k != active:
        # OpticStudio solves a parameter's pick-up (PPAR p src scale offset 0: scale times SURF
        # src's PARM p plus offset) and a thickness pick-up (PZUP) again for the configuration; the saved PARM is the active
        # one's, and other readers of the one-configuration file do not solve pick-ups
        nums = [int(m.group(1)) for ln in head if (m := re.match(r"SURF\s+(\d+)\s*$", ln))]
        for s in nums:
            a, b = block(s)
            for j in range(a, b):
                fl = head[j].split()
                if fl[:1] != ["PPAR"] or len(fl) < 6 or int(fl[2]) < 0 or fl[5] != "0":
                    continue
                sa, sb = block(int(fl[2]))
                src = next((i for i in range(sa, sb) if head[i].split()[:2] == ["PARM", fl[1]]),
                           None)
                dst = next((i for i in range(a, b) if head[i].split()[:2] == ["PARM", fl[1]]),
                           None)
                if src is None or dst is None:
                    raise NotApplied(f"SURF {s}: PPAR {fl[1]} without its PARM lines")
                val = float(fl[3]) * float(head[src].split()[2]) + float(fl[4])
                ft = head[dst].split()
                ft[2] = repr(val)
                head[dst] = "  " + " ".join(ft)
            # a thickness pick-up (PZUP src scale offset column 0): scale times SURF src's DISZ
            # plus offset, solved again as well (a material pick-up, GLAS NAME 2 src, stays in
            # the file: single-configuration readers take SURF src's material as written)
            j = surf_line(s, "PZUP")
            if j is not None:
                fl = head[j].split()
                if len(fl) > 4 and fl[4] != "0":
                    raise NotApplied(f"SURF {s}: PZUP from column {fl[4]}")
                src = surf_line(int(float(fl[1])), "DISZ")
                dst = surf_line(s, "DISZ")
                if src is None or dst is None:
                    raise NotApplied(f"SURF {s}: PZUP without the DISZ lines")
                val = float(fl[2]) * float(head[src].split()[1]) + float(fl[3])
                ft = head[dst].split()
                ft[1] = repr(val)
                head[dst] = "  " + " ".join(ft)
    del n
    return "\n".join(head + other) + "\n"
