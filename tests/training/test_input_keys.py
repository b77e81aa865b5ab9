"""What a reused design or run is keyed on (issue 38 items 2 and 3): the content of the lens
file, not its path, for the classical variant's design; and, for a Zemax lens, the ``.agf``
catalogues its ``GCAT`` line loads from its folder."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import pytest

import deeplens.optics.io.zmx_glass as zmx_glass
import deeplens.evaluation.evaluate as ev
from deeplens.optics.io import read_zmx
from deeplens.optics.io.zmx_glass import catalogue_files
from deeplens.optics.materials import GLASS_TABLE
from deeplens.training.input_digest import input_digests

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------ item 2: the classical design

def test_a_lens_edited_in_place_is_designed_again(cfg_factory, tmp_path, capsys):
    """Before: the design's key held ``lens.path`` as text, so the edited lens (same path)
    reused the old design, and the classical run keyed on that design reused its run."""
    from deeplens.evaluation.classical import design_classical

    lens = tmp_path / "lens.json"
    shutil.copy(ROOT / "data" / "lenses" / "wide_doublet.json", lens)
    over = ("experiment=doublet", f"lens.path={lens}", "eval.classical.steps=1",
            "eval.classical.spot_sampling=hexapolar:2", "scene.psf_fields_deg=[0.0]",
            "eval.variants=[classical]")
    out = tmp_path / "classical"

    def design():
        cfg = cfg_factory(*over, config_name="eval.yaml")
        design_classical(cfg, out)
        run_key = ev._run_key(ev._variant_cfg(cfg, "classical", seed=0))
        return json.loads((out / "classical_design.json").read_text()), run_key

    first, key1 = design()
    assert first["key"]["inputs"]["lens.path"].startswith("sha256:")
    capsys.readouterr()
    again, key2 = design()
    assert "reusing the classical design" in capsys.readouterr().out and again == first
    assert key2 == key1
    d = json.loads(lens.read_text())
    d["surfaces"][2]["distance_mm"] += 0.2          # a thicker flint, same path
    lens.write_text(json.dumps(d))
    edited, key3 = design()
    assert "reusing the classical design" not in capsys.readouterr().out
    assert edited["key"]["inputs"] != first["key"]["inputs"]
    assert edited["merit_before"] != first["merit_before"]   # designed from the edited lens
    # the classical variant's run is keyed on the designed lens's content: trained again
    changed = [k for k in key3["inputs"] if key3["inputs"][k] != key1["inputs"].get(k)]
    assert "lens.path" in changed


# ------------------------------------------------------------ item 3: the .zmx's catalogues

def _singlet(gcat="GCAT OHARA"):
    return "\n".join([
        "VERS 170912 299 123456", "MODE SEQ", "NAME singlet", "UNIT MM X W X CM MR CPMM",
        "ENPD 10", gcat, "FTYP 0 0 1 1 0 0 0", "XFLN 0", "YFLN 0", "WAVM 1 0.55 1", "PWAV 1",
        "SURF 0", "  TYPE STANDARD", "  CURV 0.0", "  DISZ INFINITY",
        "SURF 1", "  STOP", "  TYPE STANDARD", "  CURV 0.02", "  DISZ 5",
        "  GLAS S-LAH66 0 0 1.7725 49.6 0 0 0 0 0 0", "  DIAM 8 1 0 0 1 \"\"",
        "SURF 2", "  TYPE STANDARD", "  CURV -0.005", "  DISZ 45", "  DIAM 8 1 0 0 1 \"\"",
        "SURF 3", "  TYPE STANDARD", "  CURV 0.0", "  DISZ 0", "  DIAM 6 1 0 0 1 \"\""]) + "\n"


def _agf(scale=1.0):
    b = list(GLASS_TABLE["N-BK7"].coefficients)
    b[0] *= scale
    return ("NM S-LAH66 2 0 1.5168 64.17 0 0 0\nCD " + " ".join(map(repr, b))
            + "\nLD 0.33 2.1\n")


@pytest.fixture
def zmx_with_agf(tmp_path):
    folder = tmp_path / "lens"
    folder.mkdir()
    (folder / "ohara.AGF").write_text(_agf())
    (folder / "schott.agf").write_text(_agf())     # not named on the GCAT line: never read
    zmx = folder / "singlet.zmx"
    zmx.write_text(_singlet())
    return zmx


def test_catalogue_files_are_those_the_reader_reads(zmx_with_agf, tmp_path, monkeypatch):
    read = []
    real = zmx_glass.read_agf
    monkeypatch.setattr(zmx_glass, "read_agf", lambda f, *a, **k: read.append(Path(f)) or
                        real(f, *a, **k))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        read_zmx(zmx_with_agf)
    assert read == catalogue_files(zmx_with_agf) == [zmx_with_agf.parent / "ohara.AGF"]
    # a catalogue passed for the name answers instead of the file next to the lens
    other = tmp_path / "OHARA.agf"
    other.write_text(_agf())
    read.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        read_zmx(zmx_with_agf, glass_catalogs=[other])
    assert read == catalogue_files(zmx_with_agf, [other]) == [other]
    # no GCAT name: no user catalogue is read
    zmx_with_agf.write_text(_singlet(gcat="GCAT"))
    assert catalogue_files(zmx_with_agf) == []


def test_an_edited_glass_changes_the_run_key(cfg_factory, zmx_with_agf, capsys):
    """Before: only the .zmx's own bytes were digested, so a run with the old index was reused
    after the glass was edited in its .agf."""
    cfg = cfg_factory("experiment=doublet", f"lens.path={zmx_with_agf}",
                      config_name="eval.yaml")
    vc = ev._variant_cfg(cfg, "frozen", seed=0)
    key = ev._run_key(vc)
    assert set(key["inputs"]) >= {"lens.path", "lens.path[GCAT OHARA]"}
    (zmx_with_agf.parent / "schott.agf").write_text(_agf(1.01))   # not read: same key
    assert ev._run_key(ev._variant_cfg(cfg, "frozen", seed=0)) == key
    (zmx_with_agf.parent / "ohara.AGF").write_text(_agf(1.01))    # the glass of the lens
    edited = ev._run_key(ev._variant_cfg(cfg, "frozen", seed=0))
    assert edited["inputs"]["lens.path"] == key["inputs"]["lens.path"]
    assert edited["inputs"]["lens.path[GCAT OHARA]"] != key["inputs"]["lens.path[GCAT OHARA]"]
    assert ev._same_run(edited) != ev._same_run(key)
    # a finished run recorded with the old glass is trained again, naming the catalogue
    folder = Path(vc.paths.output_dir)
    folder.mkdir(parents=True)
    (folder / ev.RUN_RECORD).write_text(json.dumps({"config": key, "metrics": {},
                                                    "tested": "best.ckpt"}))
    assert ev._reuse(vc) is None
    assert "(changed: lens.path[GCAT OHARA]): training again" in capsys.readouterr().out


def test_a_catalogue_passed_in_the_options_replaces_the_one_next_to_the_lens(zmx_with_agf,
                                                                           tmp_path):
    other = tmp_path / "OHARA.agf"
    other.write_text(_agf())
    tree = {"lens": {"path": str(zmx_with_agf),
                     "table_options": {"glass_catalogs": [str(other)]}}}
    d = input_digests(tree)
    assert "lens.path[GCAT OHARA]" in d and "lens.table_options.glass_catalogs[0]" in d
    assert d["lens.path[GCAT OHARA]"] == d["lens.table_options.glass_catalogs[0]"]
    (zmx_with_agf.parent / "ohara.AGF").write_text(_agf(1.01))   # not read: same digests
    assert input_digests(tree) == d
    # a .zmx that cannot be parsed brings no catalogue (reading the lens reports it)
    zmx_with_agf.write_text("SURF x\n")
    assert set(input_digests(tree)) == {"lens.path", "lens.table_options.glass_catalogs[0]"}
