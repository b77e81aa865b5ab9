"""``BIRE__IN`` / ``BIRE_OUT`` (OpticStudio's Birefringent In and Out) and ``GRINSUR8`` (GRADIUM).

Birefringent In has the Standard surface's shape; the glass after it is the ordinary index, and an
ordinary ray "is refracted by n sin θ = n_o sin θ'", "just Snell's law" (M. Nicholson, "How to
design birefringent polarizers", Zemax knowledge base, 2005).  Its mode flag picks the ray:
0 and 2 the ordinary ray (of a beamsplitter, of a waveplate), 1 and 3 the extraordinary one
(Nicholson, "The Birefringent Mode Flag").  So an ordinary-ray file is the file with
``STANDARD`` there (checked against the thick-lens focal length and equal lens by lens), read
with one located warning naming that only the ordinary ray's path is traced; an extraordinary
one is refused at its mode line.  ``GRINSUR8`` is refused on its ``TYPE`` line in one line that
names the GRADIUM surface and the profile data it needs.
"""

from __future__ import annotations

import warnings

import pytest
from test_zmx import line_of, singlet, write

from deeplens.optics.errors import ZemaxWarning
from deeplens.optics.io import ZemaxFileError, lens_to_dict, read_zmx
from deeplens.optics.paraxial import paraxial

N, C1, C2, T = 1.5, 0.02, -0.005, 5.0
GLASS = f"GLAS ___BLANK 1 0 {N} 0 0 0 0 0 0 0"   # non-dispersive model glass, n = 1.5


def bire(mode=2, out_parm=()):
    """The test singlet with Birefringent In as its first face (mode ``mode``, the crystal axis
    along y) and Birefringent Out as its second."""
    text = singlet(s1_type="BIRE__IN", s1_extra=(f"PARM 1 {mode}", "PARM 2 0", "PARM 3 1",
                                                 "PARM 4 0", "PARM 5 1"),
                   curv1=C1, curv2=C2, k=0.0, glass=GLASS, t=T)
    return text.replace("SURF 3\n  TYPE STANDARD",
                        "SURF 3\n  TYPE BIRE_OUT" + "".join(f"\n  {x}" for x in out_parm))


def plain():
    return singlet(s1_extra=(), curv1=C1, curv2=C2, k=0.0, glass=GLASS, t=T,
                   s1_type="STANDARD")


@pytest.mark.parametrize("mode", [0, 2])
def test_ordinary_ray_modes_read_as_the_plain_lens(tmp_path, mode):
    text = bire(mode)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        lens = read_zmx(write(tmp_path, text))
    notes = [w.message for w in got if issubclass(w.category, ZemaxWarning)
             and "birefringent" in str(w.message)]
    assert len(notes) == 1 and notes[0].line == line_of(text, "TYPE BIRE__IN")
    kind = "beamsplitter" if mode == 0 else "waveplate"
    assert f"mode {mode}, the ordinary ray of a {kind}" in str(notes[0])
    assert "only the ordinary ray's path is traced" in str(notes[0])
    assert lens_to_dict(lens) == lens_to_dict(read_zmx(write(tmp_path, plain(), "p.zmx")))
    # the thick lens of index n_o in air: φ = (n − 1)(c1 − c2) + (n − 1)² t c1 c2 / n
    phi = (N - 1) * (C1 - C2) + (N - 1) ** 2 * T * C1 * C2 / N
    assert float(paraxial(lens).efl) == pytest.approx(1.0 / phi, rel=1e-12)


@pytest.mark.parametrize("mode,kind", [(1, "beamsplitter"), (3, "waveplate")])
def test_extraordinary_ray_modes_refused_at_the_mode(tmp_path, mode, kind):
    text = bire(mode)
    with pytest.raises(ZemaxFileError, match=(
            rf"SURF 2: a birefringent-in surface tracing the extraordinary ray \(mode {mode}, "
            rf"{kind}\): polarization ray tracing is not modelled")) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, f"PARM 1 {mode}")


@pytest.mark.parametrize("text_edit,needle,match", [
    (lambda: bire(5), "PARM 1 5", r"BIRE__IN mode \(PARM 1\) must be 0, 1, 2 or 3, got 5"),
    (lambda: bire(2, out_parm=("PARM 2 0.3",)), "PARM 2 0.3", r"SURF 3: BIRE_OUT PARM 2 = 0.3 is not read"),
])
def test_other_records_refused_at_their_line(tmp_path, text_edit, needle, match):
    text = text_edit()
    with pytest.raises(ZemaxFileError, match=match) as e:
        read_zmx(write(tmp_path, text))
    assert e.value.line == line_of(text, needle)


def test_gradium_refused_in_one_line_naming_its_data(tmp_path):
    text = singlet(s1_type="GRINSUR8", s1_extra=("PARM 1 0.25", "PARM 2 5.0"))
    with pytest.raises(ZemaxFileError) as e:
        read_zmx(write(tmp_path, text))
    msg = str(e.value)
    assert e.value.line == line_of(text, "TYPE GRINSUR8")
    assert "GRADIUM" in msg and "PROFILE.GRD" in msg and "deeplens reads" not in msg
    # one short line: the length of the message after its "file:line: " (the temporary
    # folder's path differs between machines and pytest workers)
    body = msg.split(".zmx:", 1)[1]
    assert len(msg.splitlines()) == 1 and len(body) < 250, body
