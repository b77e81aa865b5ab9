"""``SCBD`` records (surface tilt/decenter data and the coordinate return, by what real files
show: ``deeplens.optics.io.zmx_parse._surface_tilt_decenter_ignored``): not applied, each with a
located note that says so; the note no longer calls them scattering."""

from __future__ import annotations

import warnings

from test_zmx import line_of, singlet, write

from deeplens.optics.io import ZemaxWarning, lens_to_dict, read_zmx


def _notes(path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lens = read_zmx(path)
    return lens, [str(w.message) for w in caught if issubclass(w.category, ZemaxWarning)]


def test_scbd_notes_say_what_is_not_applied(tmp_path):
    """A non-zero tilt before the lens's rear face is named as not applied (the geometry is not
    OpticStudio's), the all-zero after-data as ignored; the lens is the same as without them."""
    rec = ("SCBD 1 0 0 0 0 1.5E+1 0 0", "SCBD 2 1 2 -0 -0 -0 -0 -0")
    text = singlet(extra_s2=rec)
    lens, notes = _notes(write(tmp_path, text))
    ln1, ln2 = line_of(text, "SCBD 1"), line_of(text, "SCBD 2")
    tilt = [m for m in notes if f"t.zmx:{ln1}:" in m]
    zero = [m for m in notes if f"t.zmx:{ln2}:" in m]
    assert len(tilt) == 1 and "SCBD on SURF 3: a surface tilt/decenter before the surface" in \
        tilt[0] and "is NOT applied" in tilt[0] and "0 0 1.5E+1 0 0" in tilt[0]
    assert len(zero) == 1 and "all 0: ignored" in zero[0]
    assert not any("scattering" in m for m in notes)
    bare = read_zmx(write(tmp_path, singlet(), "bare.zmx"))
    assert lens_to_dict(lens) == {**lens_to_dict(bare), "name": lens_to_dict(lens)["name"]}


def test_scbd_coordinate_return_note(tmp_path):
    """``SCBD 3 3 N`` (a coordinate return on a break): noted as not applied, the break's PARM
    values read as written."""
    text = singlet(extra_s2=("SCBD 3 3 1",))
    _, notes = _notes(write(tmp_path, text))
    ln = line_of(text, "SCBD")
    assert [m for m in notes if f"t.zmx:{ln}:" in m] == [
        f"{tmp_path / 't.zmx'}:{ln}: SCBD on SURF 3: a coordinate return (to SURF 1) is not "
        f"applied; the coordinate break's PARM values are read as written"]
