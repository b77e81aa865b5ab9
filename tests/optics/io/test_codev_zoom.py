"""CODE V zoom lenses (:mod:`deeplens.optics.io.codev_zoom`): each zoom position of
tests/data/codev/zoom/zoom3.seq against the same lens with that position's values typed in
(pos1.seq .. pos3.seq, which rayoptics also reads and confirms), the positions' shared surfaces
(as ``read_zmx_configs`` shares a ``.zmx`` file's configurations), ``load_lens(config=N)`` and
located refusals."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import torch

from deeplens.optics.errors import LensFileError
from deeplens.optics.io import load_lens
from deeplens.optics.io.codev import CodeVWarning, read_seq, read_seq_zooms

ZOOM = Path(__file__).resolve().parents[2] / "data" / "codev" / "zoom"


def _same(a, b):
    """The same prescription and system data: surfaces (every parameter, semi-diameters
    included), gaps, sensor, media, stop and spec."""
    assert [s.to_dict() for s in a.surfaces] == [s.to_dict() for s in b.surfaces]
    assert [float(x) for x in a.distances] == [float(x) for x in b.distances]
    assert float(a.d_sensor) == float(b.d_sensor) and a.stop_index == b.stop_index
    assert [m.name for m in a.materials] == [m.name for m in b.materials]
    assert a.spec.aperture_value == b.spec.aperture_value
    assert list(a.spec.fields_deg) == list(b.spec.fields_deg)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_each_zoom_position_is_the_file_with_its_values_typed_in(k):
    """``read_seq(zoom3.seq, zoom=k)`` is ``pos{k}.seq`` (the position's EPD, field, gaps and
    radius typed in), bit for bit; ``load_lens(..., config=k)`` the same."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # neither file warns when the position is given
        a = read_seq(ZOOM / "zoom3.seq", zoom=k)
        b = read_seq(ZOOM / f"pos{k}.seq")
    _same(a, b)
    _same(load_lens(ZOOM / "zoom3.seq", config=k), b)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_rayoptics_confirms_each_typed_in_position(k):
    """rayoptics (which does not read ``ZOO``) reads each single-position file to the EFL,
    entrance pupil and rear focal point deeplens gives zoom position ``k`` of the zoom file."""
    pytest.importorskip("rayoptics")
    from codev_oracle import agrees, numbers

    lens = read_seq(ZOOM / "zoom3.seq", zoom=k)
    for what, (dl, ro) in numbers(ZOOM / f"pos{k}.seq", lens).items():
        assert agrees(dl, ro), f"position {k}, {what}: deeplens {dl!r} vs rayoptics {ro!r}"


def test_the_positions_differ_where_the_zoo_lines_say():
    """The three positions' gaps, radius, EPD and field are the ZOO lines' (closed: the numbers
    of the file), and their EFLs differ."""
    from deeplens.optics.paraxial import paraxial

    lenses = read_seq_zooms(ZOOM / "zoom3.seq")
    assert len(lenses) == 3
    assert [float(L.distances[2]) for L in lenses] == [10.0, 20.0, 30.0]
    assert [float(L.d_sensor) for L in lenses] == [30.0, 25.0, 20.0]
    assert [1.0 / float(L.surfaces[2].c) for L in lenses] == pytest.approx([80.0, 84.0, 88.0],
                                                                          rel=1e-15)
    assert [L.spec.aperture_value for L in lenses] == [10.0, 8.0, 6.0]
    assert [list(L.spec.fields_deg) for L in lenses] == [[0.0, 5.0], [0.0, 3.0], [0.0, 2.0]]
    efl = [float(paraxial(L).efl) for L in lenses]
    assert len(set(efl)) == 3


def test_read_seq_zooms_shares_the_unchanged_surfaces():
    """As ``read_zmx_configs``: a surface no position changes is one object in every lens (the
    positive lens's rear and the negative lens's rear surface), its semi-diameter the largest of
    the positions'; the stop (its radius is each position's pupil) and the zoomed radius are
    each position's own."""
    lenses = read_seq_zooms(ZOOM / "zoom3.seq")
    single = [read_seq(ZOOM / f"pos{k}.seq") for k in (1, 2, 3)]
    for i in range(len(lenses[0].surfaces)):
        same = all(L.surfaces[i] is lenses[0].surfaces[i] for L in lenses[1:])
        assert same == (i in (1, 3)), i
        if same:
            assert float(lenses[0].surfaces[i].semi_diameter) == max(
                float(L.surfaces[i].semi_diameter) for L in single)
    with torch.no_grad():
        lenses[0].surfaces[1].c.mul_(1.01)   # an optimiser step on a shared surface
    assert float(lenses[2].surfaces[1].c) == float(lenses[0].surfaces[1].c)


def test_without_a_position_the_first_is_read_with_a_warning():
    with pytest.warns(CodeVWarning, match=r"zoom lens with 3 positions: position 1 read; "
                                          r"read_seq\(path, zoom=N\)"):
        a = read_seq(ZOOM / "zoom3.seq")
    _same(a, read_seq(ZOOM / "pos1.seq"))


HEAD = "RDM Y\nDIM M\nWL 587.56\nEPD 10\nYAN 0 5\n"
BODY = "SO 0 1e20\nS 60 5 517000.642000\n  STO\nS -60 10\nSI 0 0\n"


@pytest.mark.parametrize("zoo,line,match", [
    ("ZOO 2\nZOO GLA S1 517000.642000 517000.642000\n", 7, "zooming GLA is not supported"),
    ("ZOO 2\nZOO THI S2 10 20 30\n", 7, "3 values for the 2 zoom positions"),
    ("ZOO 2\nZOO THI S7 10 20\n", 7, "surface S7 does not exist"),
    ("ZOO THI S2 10 20\n", 6, "ZOO values with no 'ZOO n' line"),
    ("ZOO 2\nZOO FNO 4 5\n", 7, "the file's aperture is EPD"),
    ("ZOO 2\nZOO YAN 3 4\n", 7, "without Fk: the file has 2 fields"),
    ("ZOO 2\nZOO YAN F3 3 4\n", 7, r"F3: the file has 2 fields"),
    ("ZOO 2\nZOO THI 10 20\n", 7, "expected a surface"),
    ("ZOO 2\nZOO 3\n", 7, "already 2"),
])
def test_refusals_name_the_line(tmp_path, zoo, line, match):
    p = tmp_path / "z.seq"
    p.write_text(HEAD + zoo + BODY)
    with pytest.raises(LensFileError, match=match) as e:
        read_seq(p, zoom=1)
    assert e.value.source == str(p) and e.value.line == line


def test_a_position_beyond_the_file_is_refused():
    with pytest.raises(LensFileError, match=r"zoom position 4 requested: the file has 3") as e:
        read_seq(ZOOM / "zoom3.seq", zoom=4)
    assert e.value.line == 10


def test_cli_report_config_reads_a_zoom_position(capsys):
    """``deeplens report zoom3.seq --config N`` reports zoom position ``N``: its EFL and fields
    are those of ``read_seq(..., zoom=N)``."""
    import json

    import helpers as H

    from deeplens.optics.paraxial import paraxial

    for k in (2, 3):
        code, out, err = H.run_cli(["report", str(ZOOM / "zoom3.seq"), "--config", str(k),
                                    "--json", "--sampling", "hexapolar:2"], capsys)
        assert code == 0, err
        rep = json.loads(out)
        lens = read_seq(ZOOM / "zoom3.seq", zoom=k)
        assert rep["efl_mm"] == pytest.approx(float(paraxial(lens).efl), rel=1e-12)
        assert sorted({f["field_deg"] for f in rep["fields"]}) == list(lens.spec.fields_deg)
    code, out, err = H.run_cli(["report", str(ZOOM / "zoom3.seq"), "--config", "4"], capsys)
    assert code == 2 and "zoom position 4 requested: the file has 3" in err
