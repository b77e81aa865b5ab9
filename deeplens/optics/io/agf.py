r"""Zemax glass catalogues (``.agf``): read the user's own vendor files into materials.

Dispersion formulas (λ in micrometres, ``c0, c1, ...`` the ``CD`` record), by the formula number
of the ``NM`` record::

    1  Schott       n² = c0 + c1 λ² + c2 λ⁻² + c3 λ⁻⁴ + c4 λ⁻⁶ + c5 λ⁻⁸
    2  Sellmeier 1  n² = 1 + Σ_{i=0..2} c_{2i} λ² / (λ² − c_{2i+1})
    3  Herzberger   n  = c0 + c1 L + c2 L² + c3 λ² + c4 λ⁴ + c5 λ⁶,   L = 1 / (λ² − 0.028)
    4  Sellmeier 2  n² = 1 + c0 + c1 λ² / (λ² − c2) + c3 λ² / (λ² − c4)
    5  Conrady      n  = c0 + c1 / λ + c2 / λ^3.5
    6  Sellmeier 3  n² = 1 + Σ_{i=0..3} c_{2i} λ² / (λ² − c_{2i+1})
    7  Handbook 1   n² = c0 + c1 / (λ² − c2) − c3 λ²
    8  Handbook 2   n² = c0 + c1 λ² / (λ² − c2) − c3 λ²
    9  Sellmeier 4  n² = c0 + c1 λ² / (λ² − c2) + c3 λ² / (λ² − c4)
    10 Extended     n² = c0 + c1 λ² + c2 λ⁻² + c3 λ⁻⁴ + c4 λ⁻⁶ + c5 λ⁻⁸ + c6 λ⁻¹⁰ + c7 λ⁻¹²
    11 Sellmeier 5  n² = 1 + Σ_{i=0..4} c_{2i} λ² / (λ² − c_{2i+1})
    12 Extended 2   n² = c0 + c1 λ² + c2 λ⁻² + c3 λ⁻⁴ + c4 λ⁻⁶ + c5 λ⁻⁸ + c6 λ⁴ + c7 λ⁶
    13 Extended 3   n² = c0 + c1 λ² + c2 λ⁴ + c3 λ⁻² + c4 λ⁻⁴ + c5 λ⁻⁶ + c6 λ⁻⁸ + c7 λ⁻¹⁰ + c8 λ⁻¹²

Records read: ``NM name formula MIL n_d V_d ...`` (starts a glass), ``CD`` (coefficients), ``LD
λmin λmax`` (validity range in µm; converted to nm and enforced by
:func:`~deeplens.optics.materials.check_wavelength_nm`).  ``TD`` (thermal dispersion) is ignored:
indices are those at the catalogue's reference temperature, and :attr:`GlassCatalogue.notes` says
so once.  ``CC``, ``ED``, ``OD``, ``IT`` and ``GC`` carry no index data and are skipped.  The
``n_d`` of the ``NM`` record is checked against the formula at 587.5618 nm (a mismatch above
1e-4 is a warning: it usually means the formula number or a coefficient is wrong).

deeplens ships no vendor catalogue; point :func:`read_agf` at the files of your own Zemax
installation or the vendors' web sites.  Glass names are matched exactly (case-insensitive),
never approximately.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import NamedTuple

import torch

from ..errors import LensFileError, format_lines
from ..materials import DEFAULT_RANGE_NM, LINE_D, Material
from .filecheck import read_file_bytes
from .zmx_notes import listed

__all__ = ["FORMULAS", "AGFGlass", "AgfError", "AgfRecord", "GlassCatalogue", "read_agf"]

FORMULAS = {1: ("Schott", 6), 2: ("Sellmeier 1", 6), 3: ("Herzberger", 6),
            4: ("Sellmeier 2", 5), 5: ("Conrady", 3), 6: ("Sellmeier 3", 8),
            7: ("Handbook 1", 4), 8: ("Handbook 2", 4), 9: ("Sellmeier 4", 5),
            10: ("Extended", 8), 11: ("Sellmeier 5", 10), 12: ("Extended 2", 8),
            13: ("Extended 3", 9)}
"""Formula number -> (name, number of coefficients used)."""


class AgfError(ValueError):
    """A glass catalogue that cannot be read; the message names the file and line."""


class AGFGlass(Material):
    """A glass from a Zemax catalogue: one of the :data:`FORMULAS`, λ in µm.

    Args:
        name: the glass name (upper case, as in the catalogue).
        formula: the AGF formula number (1..13).
        coefficients: the ``CD`` values (at least as many as the formula uses).
        wavelength_range_nm: validity range in nm (the ``LD`` record).
        catalogue: the catalogue name (file stem), for messages.
    """

    def __init__(self, name: str, formula: int, coefficients, wavelength_range_nm=DEFAULT_RANGE_NM,
                 catalogue: str = ""):
        super().__init__(name, wavelength_range_nm)
        if formula not in FORMULAS:
            raise ValueError(f"glass {name!r}: unknown AGF formula {formula!r}; known: "
                             f"{', '.join(f'{k} {v[0]}' for k, v in FORMULAS.items())}")
        need = FORMULAS[formula][1]
        c = [float(v) for v in coefficients]
        if len(c) < need:
            raise ValueError(f"glass {name!r}: formula {formula} ({FORMULAS[formula][0]}) needs "
                             f"{need} coefficients, got {len(c)}")
        self.formula = int(formula)
        self.coefficients = tuple(c[:need])
        self.catalogue = catalogue

    def _index(self, w: torch.Tensor) -> torch.Tensor:
        lam = w / 1000.0
        l2 = lam * lam
        c = self.coefficients
        f = self.formula

        def sellmeier(terms):
            n2 = 1.0
            for i in range(terms):
                n2 = n2 + c[2 * i] * l2 / (l2 - c[2 * i + 1])
            return n2

        if f == 1:
            return torch.sqrt(c[0] + c[1] * l2 + c[2] / l2 + c[3] / l2 ** 2 + c[4] / l2 ** 3
                              + c[5] / l2 ** 4)
        if f == 2:
            return torch.sqrt(sellmeier(3))
        if f == 3:
            L = 1.0 / (l2 - 0.028)
            return c[0] + c[1] * L + c[2] * L * L + c[3] * l2 + c[4] * l2 ** 2 + c[5] * l2 ** 3
        if f == 4:
            return torch.sqrt(1.0 + c[0] + c[1] * l2 / (l2 - c[2]) + c[3] * l2 / (l2 - c[4]))
        if f == 5:
            return c[0] + c[1] / lam + c[2] / lam ** 3.5
        if f == 6:
            return torch.sqrt(sellmeier(4))
        if f == 7:
            return torch.sqrt(c[0] + c[1] / (l2 - c[2]) - c[3] * l2)
        if f == 8:
            return torch.sqrt(c[0] + c[1] * l2 / (l2 - c[2]) - c[3] * l2)
        if f == 9:
            return torch.sqrt(c[0] + c[1] * l2 / (l2 - c[2]) + c[3] * l2 / (l2 - c[4]))
        if f == 10:
            return torch.sqrt(c[0] + c[1] * l2 + sum(c[k] / l2 ** (k - 1) for k in range(2, 8)))
        if f == 11:
            return torch.sqrt(sellmeier(5))
        if f == 12:
            return torch.sqrt(c[0] + c[1] * l2 + sum(c[k] / l2 ** (k - 1) for k in range(2, 6))
                              + c[6] * l2 ** 2 + c[7] * l2 ** 3)
        if f == 13:
            return torch.sqrt(c[0] + c[1] * l2 + c[2] * l2 ** 2
                              + sum(c[k] / l2 ** (k - 2) for k in range(3, 9)))
        raise AssertionError(f)  # pragma: no cover

    def extra_repr(self) -> str:
        return f"{self.name} ({self.catalogue}, {FORMULAS[self.formula][0]})"


class AgfRecord(NamedTuple):
    """One glass of a catalogue: what :class:`AGFGlass` is built from, and where it was read."""

    name: str
    formula: int
    coefficients: tuple
    range_nm: tuple
    nd: float
    vd: float
    line: int


class GlassCatalogue:
    """A glass catalogue read from an ``.agf`` file (immutable after reading).

    Attributes:
        name: the catalogue name Zemax files use in ``GCAT`` (the file stem, upper case).
        path: the file.
        records: glass name (upper case) -> :class:`AgfRecord`.
        notes: what was read but not used (e.g. the ``TD`` thermal data).
    """

    def __init__(self, name: str, path, records: dict, notes=()):
        self.name = name.upper()
        self.path = Path(path)
        self.records = dict(records)
        self.notes = tuple(notes)

    def __contains__(self, glass: str) -> bool:
        return glass.strip().upper() in self.records

    def __len__(self) -> int:
        return len(self.records)

    def get(self, glass: str) -> AGFGlass | None:
        """A new :class:`AGFGlass` for ``glass`` (exact name, case-insensitive), or ``None``."""
        rec = self.records.get(glass.strip().upper())
        if rec is None:
            return None
        glass = AGFGlass(rec.name, rec.formula, rec.coefficients, rec.range_nm, self.name)
        glass.source = f"{self.path}:{rec.line}"   # where it is defined, for messages
        return glass

    def __repr__(self) -> str:
        return f"GlassCatalogue({self.name!r}, {len(self)} glasses, {str(self.path)!r})"


def decode_zemax_text(path: Path, what: str = "Zemax file") -> str:
    """Text of a Zemax file (``.agf``, ``.zmx``): UTF-16 with a byte-order mark, UTF-16 LE or BE
    without a mark (OpticStudio writes it too: every other byte zero; found by that NUL-byte
    pattern, :func:`_utf16_without_mark`), UTF-8, else Latin-1 (old catalogues have 8-bit
    comments; their index data is ASCII).

    Raises:
        LensFileError: not a regular file, or too large (:func:`.filecheck.read_file_bytes`).
    """
    raw = read_file_bytes(path, what)   # a regular file of a sane size (.filecheck)
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return raw.decode("utf-16")
    utf16 = _utf16_without_mark(raw)
    if utf16 is not None:   # before UTF-8: ASCII in UTF-16 is valid UTF-8 (with NUL bytes)
        return raw[:len(raw) // 2 * 2].decode(utf16)   # a cut-off file may end mid-unit
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def _utf16_without_mark(raw: bytes) -> str | None:
    """``"utf-16-le"`` or ``"utf-16-be"`` when ``raw`` (no byte-order mark) looks like UTF-16
    text of mostly ASCII characters, else ``None``: in its first 400 bytes the high bytes of
    the code units (odd bytes in little-endian, even bytes in big-endian) are nearly all NUL
    and the low bytes nearly none.  Zemax files are ASCII keywords and numbers."""
    head = raw[:400]
    if len(head) < 4:
        return None
    even, odd = head[0::2], head[1::2]
    nul_even, nul_odd = even.count(0) / len(even), odd.count(0) / len(odd)
    if nul_odd > 0.9 and nul_even < 0.1:
        return "utf-16-le"
    if nul_even > 0.9 and nul_odd < 0.1:
        return "utf-16-be"
    return None


def read_agf(path, name: str | None = None) -> GlassCatalogue:
    """Read a Zemax ``.agf`` glass catalogue.

    Args:
        path: the ``.agf`` file (UTF-16 with byte-order mark, UTF-8 or Latin-1).
        name: the catalogue name (default: the file stem, upper case, as Zemax's ``GCAT``).

    Returns:
        A :class:`GlassCatalogue`.

    Raises:
        FileNotFoundError: no such file.
        AgfError: a malformed record (``file:line`` and what was expected), a glass without a
            ``CD`` record (truncated file), an unknown formula number, a glass defined twice,
            or no glass at all; a path that is not a regular file (a device, a FIFO, a
            directory, symbolic links followed) or a file larger than 64 MiB.

    Example::

        cat = read_agf("MYVENDOR.agf")
        glass = cat.get("N-BK7")            # an AGFGlass (a Material), or None
        glass.n(torch.tensor([486.1, 587.6, 656.3], dtype=torch.float64))
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"glass catalogue not found: {path}")
    try:
        text = decode_zemax_text(path, "glass catalogue")
    except LensFileError as e:
        raise AgfError(str(e)) from None
    cat_name = (name or path.stem).upper()
    records: dict[str, AgfRecord] = {}
    notes: list[str] = []
    unknown: dict[str, tuple[int, int]] = {}   # record kind -> (first line, count)
    off_nd: list[tuple[int, str, float, float]] = []   # (line, glass, formula's n_d, NM's n_d)
    cur: dict | None = None

    def fail(ln, msg):
        raise AgfError(f"{path}:{ln}: {msg}")

    def nums(toks, ln, what, lo=0):
        out = []
        for t in toks[lo:]:
            try:
                v = float(t)
            except ValueError:
                fail(ln, f"{what}: expected numbers, got {t!r}")
            if not math.isfinite(v):
                fail(ln, f"{what}: expected finite numbers, got {t!r}")
            out.append(v)
        return out

    def finish():
        if cur is None:
            return
        if cur["cd"] is None:
            fail(cur["line"], f"glass {cur['name']!r} has no CD (dispersion coefficient) record: "
                              f"truncated or malformed catalogue")
        need = FORMULAS[cur["formula"]][1]
        if len(cur["cd"]) < need:
            fail(cur["cd_line"], f"glass {cur['name']!r}: formula {cur['formula']} "
                                 f"({FORMULAS[cur['formula']][0]}) needs {need} coefficients, the "
                                 f"CD record has {len(cur['cd'])}")
        rec = AgfRecord(cur["name"], cur["formula"], tuple(cur["cd"][:need]), cur["range"],
                        cur["nd"], cur["vd"], cur["line"])
        glass = AGFGlass(rec.name, rec.formula, rec.coefficients, rec.range_nm, cat_name)
        lo, hi = rec.range_nm
        if rec.nd > 0 and lo <= LINE_D <= hi:
            nd = float(glass.n(LINE_D))
            if not math.isfinite(nd) or abs(nd - rec.nd) > 1e-4:
                off_nd.append((rec.line, rec.name, nd, rec.nd))
        records[rec.name] = rec

    for ln, line in enumerate(text.splitlines(), start=1):
        toks = line.split()
        if not toks:
            continue
        key = toks[0].upper()
        if key == "NM":
            finish()
            if len(toks) < 3:
                fail(ln, f"an NM record needs 'NM name formula MIL n_d V_d ...', got "
                         f"{line.strip()!r}")
            gname = toks[1].upper()
            if gname in records:
                fail(ln, f"glass {gname!r} is defined twice (first on line "
                         f"{records[gname].line})")
            try:
                formula = float(toks[2])
            except ValueError:
                fail(ln, f"glass {gname!r}: the formula number must be a number, got {toks[2]!r}")
            if not math.isfinite(formula) or formula != int(formula) or int(formula) not in FORMULAS:
                fail(ln, f"glass {gname!r}: unknown dispersion formula {toks[2]!r}; known: "
                         f"{', '.join(f'{k} ({v[0]})' for k, v in FORMULAS.items())}")
            vals = nums(toks[4:6], ln, "NM n_d/V_d") if len(toks) >= 6 else [0.0, 0.0]
            cur = {"name": gname, "formula": int(formula), "line": ln, "cd": None,
                   "range": DEFAULT_RANGE_NM, "nd": vals[0], "vd": vals[1]}
        elif key in ("CD", "LD", "TD", "ED", "OD", "IT"):
            if cur is None:
                fail(ln, f"a {key} record before the first NM (glass name) record")
            if key == "CD":
                cur["cd"] = nums(toks, ln, "CD record", 1)
                cur["cd_line"] = ln
            elif key == "LD":
                v = nums(toks, ln, "LD record", 1)
                if len(v) < 2 or not 0 < v[0] < v[1]:
                    fail(ln, f"glass {cur['name']!r}: LD needs 'LD min max' (µm, 0 < min < max), "
                             f"got {line.strip()!r}")
                cur["range"] = (v[0] * 1000.0, v[1] * 1000.0)
            elif key == "TD" and not notes:
                notes.append(f"{path}: TD (thermal dispersion) records are ignored: indices are "
                             f"those at each catalogue's reference temperature")
        elif key in ("CC", "GC", "MD", "BD") or key.startswith("!"):
            continue   # comments, glass comments, and newer catalogues' melt/bulk data records
        else:
            first, count = unknown.get(toks[0], (ln, 0))
            unknown[toks[0]] = (first, count + 1)
    finish()
    if off_nd:   # one warning per catalogue, not per glass (zmx_notes: one per cause)
        ln, g, nd, said = off_nd[0]
        what = (f"glass {g!r}: the formula gives n_d = {nd:.6f} but the NM record says "
                f"{said:.6f}" if len(off_nd) == 1 else
                f"{len(off_nd)} glasses ({listed([repr(o[1]) for o in off_nd])}): the formula "
                f"gives another n_d than the NM record says")
        warnings.warn(f"{path}:{format_lines(o[0] for o in off_nd)}: {what} (check the formula "
                      f"number and the CD record)", stacklevel=2)
    for rec_key, (first, count) in unknown.items():   # one warning per kind, not per line
        warnings.warn(f"{path}:{first}: unknown record {rec_key!r} ignored ({count} line(s); "
                      f"known: CC, NM, GC, ED, CD, TD, OD, LD, IT, MD, BD)", stacklevel=2)
    if not records:
        raise AgfError(f"{path}: no glass (NM record) found: not a Zemax .agf catalogue?")
    return GlassCatalogue(cat_name, path, records, notes)
