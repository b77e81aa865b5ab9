"""One located warning per cause, not per line (issue 37: a user pays a round trip per file and
messages must be short): the notes of one :class:`~deeplens.optics.io.zmx_parse.Cause` (a glass
read from its six-digit code, a model-glass fallback, ...) become one ``ZemaxWarning`` naming
every line, at most four items named and the rest counted, still naming the choice made and
the option that flips it; two causes stay two warnings."""

from __future__ import annotations

import warnings

import pytest
import torch

from deeplens.optics.errors import ZemaxWarning, format_lines
from deeplens.optics.io.zmx import read_zmx
from deeplens.optics.io.zmx_parse import Cause, Locator, listed
from deeplens.optics.paraxial import paraxial

# a cemented triplet, every glass a six-digit code (n_d 1.NNN, V_d VV.V)
CODES = ("847238", "620603", "516641")
CURVS = (0.03, -0.02, 0.015, -0.01)
THICK = (4.0, 2.0, 3.0)

TRIPLET = """VERS 190513 80 123457
MODE SEQ
NAME grouped warnings
UNIT MM X W X CM MR CPMM
ENPD 10
GCAT SCHOTT
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.5875618 1
PWAV 1
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV {c0}
  DISZ {t0}
  GLAS {g0} 0 0 1.5 4.0E+1 0 0 0 0 0 0
  DIAM 8 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV {c1}
  DISZ {t1}
  GLAS {g1} 0 0 1.5 4.0E+1 0 0 0 0 0 0
  DIAM 8 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV {c2}
  DISZ {t2}
  GLAS {g2} 0 0 1.5 4.0E+1 0 0 0 0 0 0
  DIAM 8 1 0 0 1 ""
SURF 4
  TYPE STANDARD
  CURV {c3}
  DISZ 80
  DIAM 8 1 0 0 1 ""
SURF 5
  TYPE STANDARD
  CURV 0.0
  DISZ 0
"""


def _triplet(tmp_path, glasses=CODES, name="triplet.zmx"):
    text = TRIPLET.format(**{f"c{i}": c for i, c in enumerate(CURVS)},
                          **{f"t{i}": t for i, t in enumerate(THICK)},
                          **{f"g{i}": g for i, g in enumerate(glasses)})
    f = tmp_path / name
    f.write_text(text)
    lines = [i for i, ln in enumerate(text.splitlines(), 1) if ln.startswith("  GLAS ")]
    return f, lines


def _zemax_warnings(call):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        out = call()
    return out, [w.message for w in rec if isinstance(w.message, ZemaxWarning)]


def _efl(indices):
    """The EFL of the cemented triplet in air by a paraxial y-nu trace written out here
    (refraction n'u' = nu - y (n' - n) c, transfer y' = y + t u')."""
    n = [1.0, *indices, 1.0]
    y, nu = 1.0, 0.0
    for i, c in enumerate(CURVS):
        nu -= y * (n[i + 1] - n[i]) * c
        if i < len(THICK):
            y += THICK[i] * nu / n[i + 1]
    return -1.0 / nu


def test_three_code_lines_give_one_warning_naming_all_three(tmp_path):
    f, lines = _triplet(tmp_path)
    lens, said = _zemax_warnings(lambda: read_zmx(f, glass_codes="model"))
    assert len(said) == 1, [str(w) for w in said]
    w = said[0]
    assert w.lines == tuple(lines) and w.line == lines[0] and w.feature == "GLAS"
    assert str(w).startswith(f"{f}:{lines[0]},{lines[1]},{lines[2]}: 3 glasses are read as "
                             f"six-digit n_d/V_d glass codes ('847238', '620603', '516641')")
    # the choice and the option that flips it
    assert "glass_codes='model'" in w.message and "glass_codes='refuse' (the default)" in w.message
    # the reading itself: n_d 1.NNN per code, the EFL of a y-nu trace written out here
    nds = [1.847, 1.620, 1.516]
    got = [float(lens.materials[i].n(torch.tensor(587.5618, dtype=torch.float64)))
           for i in (1, 2, 3)]
    assert got == pytest.approx(nds, abs=1e-12)
    assert float(paraxial(lens).efl) == pytest.approx(_efl(nds), rel=1e-12)


def test_one_code_keeps_its_own_values_in_the_message(tmp_path):
    f, lines = _triplet(tmp_path, glasses=("847238", "N-BK7", "N-SF5"))
    _, said = _zemax_warnings(lambda: read_zmx(f, glass_codes="model"))
    assert len(said) == 1 and said[0].lines == (lines[0],)
    assert said[0].message.startswith("glass '847238' is read as a six-digit n_d/V_d glass "
                                      "code: model glass n_d 1.847, V_d 23.8 "
                                      "(glass_codes='model')")


def test_the_same_code_on_two_lines_is_one_item(tmp_path):
    f, lines = _triplet(tmp_path, glasses=("847238", "620603", "847238"))
    _, said = _zemax_warnings(lambda: read_zmx(f, glass_codes="model"))
    assert len(said) == 1 and said[0].lines == tuple(lines)
    assert "2 glasses are read as six-digit n_d/V_d glass codes ('847238', '620603')" \
        in said[0].message


def test_two_causes_give_two_warnings(tmp_path):
    """Two codes and two glasses in no catalogue under the model-glass fallback: one warning
    each, naming its own lines, its choice and the option that flips it."""
    text, lines = _triplet(tmp_path, glasses=("847238", "ACME-1", "620603"))
    src = text.read_text().replace("GLAS ACME-1 0 0 1.5 4.0E+1", "GLAS ACME-1 0 0 1.6 50")
    src = src.replace("  DISZ 80\n", "  DISZ 80\n  GLAS ACME-2 0 0 1.7 45 0 0 0 0 0 0\n", 1)
    src = src.replace("SURF 5\n", "SURF 5\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 5\nSURF 6\n")
    text.write_text(src)
    acme = [i for i, ln in enumerate(src.splitlines(), 1) if "GLAS ACME" in ln]
    lens, said = _zemax_warnings(lambda: read_zmx(text, glass_codes="model",
                                                  glass_fallback="model"))
    assert len(said) == 2, [str(w) for w in said]
    codes = next(w for w in said if "six-digit" in w.message)
    model = next(w for w in said if "fallback" in w.message)
    assert codes.lines == (lines[0], lines[2])
    assert "2 glasses are read as six-digit n_d/V_d glass codes ('847238', '620603')" \
        in codes.message
    assert model.lines == tuple(acme)
    assert str(model).startswith(f"{text}:{acme[0]},{acme[1]}: 2 glasses ('ACME-1', 'ACME-2') "
                                 f"are not in the shipped SCHOTT catalogue; using each GLAS "
                                 f"line's model n_d/V_d (glass_fallback='model', without which "
                                 f"they are refused; ")
    assert "stale" in model.message and model.message.endswith("--glass-catalog")
    assert [lens.materials[i].nd for i in (2, 4)] == pytest.approx([1.6, 1.7], abs=1e-12)


def _notes(n, cause, path="f.zmx"):
    p = Locator(path)
    for k in range(n):
        p.note_each(10 + k, cause, f"'G{k}'", f"n_d 1.{k}")
    return p


CAUSE = Cause(one="glass {item} ({detail}): read as X (opt='x'; opt='y' refuses it)",
              many="{n} glasses ({items}): read as X (opt='x'; opt='y' refuses them)")


def test_a_cause_with_many_lines_names_four_items_and_six_lines():
    p = _notes(10, CAUSE)
    p.note(3, "something else")
    p.note(40, "something else")      # an equal note on another line: the same warning
    p.note(41, "a third thing")
    got = p.grouped_notes()
    assert got[0] == (list(range(10, 20)), "10 glasses ('G0', 'G1', 'G2', 'G3' and 6 more): read "
                                           "as X (opt='x'; opt='y' refuses them)")
    assert got[1:] == [([3, 40], "something else"), ([41], "a third thing")]
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        p.warn_notes(stacklevel=1)
    said = [w.message for w in rec]
    assert [str(w) for w in said][0].startswith("f.zmx:10,11,12,13,14,15 and 4 more: 10 glasses")
    assert said[0].lines == tuple(range(10, 20)) and said[0].line == 10
    assert str(said[1]) == "f.zmx:3,40: something else"
    # one item: its own detail
    assert _notes(1, CAUSE).grouped_notes() == [([10], "glass 'G0' (n_d 1.0): read as X "
                                                      "(opt='x'; opt='y' refuses it)")]


def test_listing_helpers():
    assert listed(["a", "b"]) == "a, b"
    assert listed([str(i) for i in range(6)]) == "0, 1, 2, 3 and 2 more"
    assert format_lines([5]) == "5" and format_lines(range(1, 8)) == "1,2,3,4,5,6 and 1 more"
    w = ZemaxWarning("m", source="f.zmx", line=7)    # the one-line form is unchanged
    assert str(w) == "f.zmx:7: m" and w.lines == (7,) and w.line == 7
    assert str(ZemaxWarning("m")) == "m" and ZemaxWarning("m").lines == ()


def test_a_surface_cause_on_two_surfaces_is_one_warning(tmp_path):
    """Two flat planes in air behind the triplet, each a fixed ``DIAM 1`` beside an ``OBSC``
    (OpticStudio's floating aperture is not applied there): one warning naming both surfaces
    and lines beside the one of the three code glasses."""
    f, glas = _triplet(tmp_path)
    src = f.read_text().replace("  DISZ 80\n", "  DISZ 40\n", 1)
    planes = "".join(f"SURF {k}\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 20\n  DIAM 1 1 0 0 1 \"\"\n"
                     f"  OBSC 0 {r}\n" for k, r in ((5, 0.5), (6, 0.3)))
    src = src.replace("SURF 5\n", planes + "SURF 7\n")
    f.write_text(src)
    diam = [i for i, ln in enumerate(src.splitlines(), 1) if ln.startswith("  DIAM 1 1")]
    _, said = _zemax_warnings(lambda: read_zmx(f, glass_codes="model"))
    assert len(said) == 2, [str(w) for w in said]
    w = next(w for w in said if "DIAM" in w.message)
    assert w.lines == tuple(diam) and w.feature == "DIAM"
    assert w.message.startswith("2 surfaces (SURF 5, SURF 6): a fixed DIAM beside an OBSC (a "
                                "surface aperture) does not clip rays in OpticStudio")
    assert next(w for w in said if "six-digit" in w.message).lines == tuple(glas)


def test_a_requested_fallback_on_two_glasses_is_one_warning_naming_the_option(tmp_path):
    f, lines = _triplet(tmp_path, glasses=("ACME-1", "N-BK7", "ACME-2"))
    lens, said = _zemax_warnings(lambda: read_zmx(f, glass_fallback="1.8/40"))
    assert len(said) == 1 and said[0].lines == (lines[0], lines[2])
    assert said[0].message.startswith("2 glasses ('ACME-1', 'ACME-2') are not in the shipped "
                                      "SCHOTT catalogue; using the requested fallback")
    assert "for each (glass_fallback, without which they are refused)" in said[0].message
    assert [lens.materials[i].nd for i in (1, 3)] == pytest.approx([1.8, 1.8], abs=1e-12)


def test_a_grouped_warning_keeps_each_items_numbers(tmp_path):
    """Two ``PARAX_XY`` surfaces of unequal x and y powers: one warning for the cause, and it
    still names each surface's two powers (the numbers a user checks), not only the surfaces."""
    from zmx_blocks import surf, zmx_file

    blocks = [surf(disz="INFINITY"), surf(stop=True, disz=5.0, diam=6.0),
              surf("PARAX_XY", parms=[0.01, 0.02], disz=10.0),
              surf("PARAX_XY", parms=[0.03, 0.005], disz=30.0), surf()]
    p = tmp_path / "parax_xy.zmx"
    p.write_text(zmx_file(blocks, "two PARAX_XY"))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        read_zmx(p)
    msgs = [str(x.message) for x in w if "PARAX_XY" in str(x.message)]
    assert len(msgs) == 1
    for power in ("0.01", "0.02", "0.03", "0.005"):
        assert power in msgs[0], (power, msgs[0])
