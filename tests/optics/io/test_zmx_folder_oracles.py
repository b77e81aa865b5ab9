"""The unseen-file benchmark's oracles (``benchmarks/zmx_corpus.py FOLDER``): optiland's reading
of a file where optiland declines first-order data.

The benchmark measures how many real files load with numbers an independent reading confirms;
these tests check its oracle code on a synthetic file, so that a file is neither counted as
confirmed by an oracle that did not read it nor left unconfirmed by an oracle fault.
"""

import importlib.util
import warnings
from pathlib import Path

import pytest
import torch

from deeplens.optics.io.zmx import read_zmx

REPO = Path(__file__).resolve().parents[3]

# an Offner-like relay (three concentric-ish mirrors, the stop on the secondary, FLOA) whose
# field is decentred by a COORDBRK: optiland 0.6 declines paraxial data for it, even for the
# floating pupil the oracle asks it for
_DECENTRED_RELAY = """VERS 240000 3 0
MODE SEQ
UNIT MM X W X CM MR CPMM
FLOA
FTYP 0 0 1 1 0 0 0
WAVM 1 0.55 1
PWAV 1
XFLN 0
YFLN 0
SURF 0
  TYPE STANDARD
  CURV 0
  DISZ 10
SURF 1
  TYPE COORDBRK
  PARM 1 0
  PARM 2 -3
  PARM 3 0
  PARM 4 0
  PARM 5 0
  PARM 6 0
  DISZ 0
SURF 2
  TYPE STANDARD
  CURV -0.1
  DISZ -4.8
  GLAS MIRROR 0 0 0 0 0 0 0 0 0 0
  DIAM 5 0 0 0 1 ""
SURF 3
  STOP
  TYPE STANDARD
  CURV -0.19
  DISZ 4.8
  GLAS MIRROR 0 0 0 0 0 0 0 0 0 0
  DIAM 1 1 0 0 1 ""
SURF 4
  TYPE STANDARD
  CURV -0.1
  DISZ -10
  GLAS MIRROR 0 0 0 0 0 0 0 0 0 0
  DIAM 5 0 0 0 1 ""
SURF 5
  TYPE STANDARD
  CURV 0
  DISZ 0
"""


def _benchmark():
    spec = importlib.util.spec_from_file_location("zmx_corpus_benchmark",
                                                  REPO / "benchmarks" / "zmx_corpus.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_a_floating_pupil_optiland_declines_is_read_with_the_breaks_zeroed(tmp_path):
    """optiland raises ``UnsupportedParaxialGeometryError`` already where the oracle asks it for
    the floating pupil (``FLOA``) of the decentred file: the benchmark must then read the file
    with every break zeroed, as it does where the first-order numbers are declined (deeplens'
    paraxial data follow the local axes); before, the oracle counted as one that cannot read
    the file (OpticStudio's Offner relay sample in the fourth unseen set)."""
    pytest.importorskip("optiland")
    pytest.importorskip("rayoptics")
    f = tmp_path / "relay.zmx"
    f.write_text(_DECENTRED_RELAY)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = read_zmx(f)
        ok, why = _benchmark().folder_oracles(tmp_path)(f.name, lens)
    assert "optiland(breaks zeroed)" in ok, why


def test_a_lenslet_array_is_confirmed_through_its_on_axis_lenslet_stand_in(tmp_path):
    """Neither oracle reads ``US_ARRAY.DLL``: the benchmark gives both the file with the array
    as its on-axis lenslet (a ``STANDARD`` surface of its ``CURV``, the ``PARM`` lines dropped)
    and names that in the confirmation; a deeplens reading whose paraxial curvature were not the
    on-axis lenslet's (1 % off) is confirmed by neither."""
    pytest.importorskip("optiland")
    pytest.importorskip("rayoptics")
    from test_zmx_lenslet_array import uds1_file

    bench = _benchmark()
    text = uds1_file()
    stand_in = bench.lenslet_stand_in_text(text)
    assert "US_ARRAY" not in stand_in and "PARM" not in stand_in
    assert stand_in.count("TYPE STANDARD") == text.count("TYPE STANDARD") + 1
    assert "CURV 0.01" in stand_in
    f = tmp_path / "uds1.zmx"
    f.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lens = read_zmx(f)
        confirm = bench.folder_oracles(tmp_path)
        ok, why = confirm(f.name, lens)
        assert ok == ["optiland(on-axis lenslet stand-in)", "rayoptics(on-axis lenslet stand-in)"]
        with torch.no_grad():
            lens.surfaces[0].c.mul_(1.01)
        ok, why = confirm(f.name, lens)
    assert ok == [] and set(why) == {"optiland", "rayoptics"}, why
