"""``deeplens train`` into a folder a live run holds (issue 38 item 1): refused *before* Hydra
writes into it, so the live run's ``.hydra/config.yaml`` and ``overrides.yaml`` stay as they
were (the lock used to be taken by the task, after Hydra had rewritten them)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from hydra.core.global_hydra import GlobalHydra

from deeplens.evaluation.entry import run
from deeplens.training.run_lock import LOCK_NAME, hold_output_folder

_spec = importlib.util.spec_from_file_location("_training_conftest",
                                               Path(__file__).with_name("conftest.py"))
_conf = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_conf)
TINY = _conf.TINY  # the shrunk training settings of tests/training/conftest.py


@pytest.fixture(autouse=True)
def _clear_hydra():
    yield
    GlobalHydra.instance().clear()


def test_a_second_train_leaves_the_live_runs_hydra_files_untouched(tmp_path):
    folder = tmp_path / "live"
    hydra_dir = folder / ".hydra"
    hydra_dir.mkdir(parents=True)
    records = {"config.yaml": "the live run's config\n", "overrides.yaml": "- live=1\n",
               "hydra.yaml": "the live run's hydra config\n"}
    for name, text in records.items():
        (hydra_dir / name).write_text(text)
    with hold_output_folder(folder):   # the live run
        with pytest.raises(SystemExit) as e:
            run("train", ["experiment=doublet", *TINY, f"hydra.run.dir={folder}", "train=false",
                          "test=false"])
    # status 1 with this message on stderr (what Python prints for SystemExit("..."))
    assert isinstance(e.value.code, str)
    assert e.value.code.startswith(f"error: output folder {folder} is in use by another live "
                                   f"run (pid ")
    for name, text in records.items():
        assert (hydra_dir / name).read_text() == text, name
    assert sorted(p.name for p in folder.iterdir()) == sorted([".hydra", LOCK_NAME])


def test_a_run_holds_its_folder_once(tmp_path):
    """The callback's lock and the task: the task does not lock the folder a second time (it
    would refuse itself), and the folder is free again when the run ends."""
    folder = tmp_path / "run"
    run("train", ["experiment=doublet", *TINY, f"hydra.run.dir={folder}", "train=false",
                  "test=false", "~logger"])
    assert (folder / ".hydra" / "config.yaml").is_file() and (folder / LOCK_NAME).is_file()
    with hold_output_folder(folder):   # released
        pass
