"""Which finished runs an evaluation reuses (issue 25 item 5, issue 20): the key holds the
content of every input file; a damaged record or a lost checkpoint means "train again" with a
message; ``eval.test_folder`` tests the same runs on a second test set without retraining them."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch

import deeplens.evaluation.evaluate as ev
from deeplens.evaluation.evaluate import evaluate

ROOT = Path(__file__).resolve().parents[2]
ARGS = ("experiment=edof", "scene.val_depths_mm=[4500.0,8000.0]", "eval.variants=[none]",
        "callbacks.image_logger=null", "eval.figures=false", "~logger",
        "trainer.enable_progress_bar=false")


class Retrained(Exception):
    pass


def _no_training(monkeypatch):
    def train(cfg):
        raise Retrained(cfg.paths.output_dir)

    monkeypatch.setattr(ev, "train", train)


def test_test_folder_reuses_the_runs_and_adds_a_block(cfg_factory, tmp_path, monkeypatch):
    from torchvision.io import write_png

    _, first = evaluate(cfg_factory(*ARGS, config_name="eval.yaml"))
    folder = tmp_path / "photos"
    folder.mkdir()
    g = torch.Generator().manual_seed(1)
    for k in range(2):
        write_png((torch.rand(3, 40, 48, generator=g) * 255).to(torch.uint8),
                  str(folder / f"p{k}.png"))
    _no_training(monkeypatch)
    table, again = evaluate(cfg_factory(*ARGS, f"eval.test_folder={folder}",
                                        config_name="eval.yaml"))
    assert again == first  # the same runs, not trained again, same texture results
    text = (tmp_path / "eval_table.md").read_text()
    assert "## Test set: 2 procedural textures" in text
    assert f"## Test set: the images of {folder} (centre crops)" in text
    assert text.count("| none | restored |") == 2 and f"images of {folder}" in table
    rec = json.loads((tmp_path / "eval_table.json").read_text())
    on_folder = rec["test_folder"]["variants"]["none"]["restored"]["4500"]["psnr"]
    assert rec["test_folder"]["path"] == str(folder) and rec["test_folder"]["digest"]
    assert on_folder != pytest.approx(first["none"]["restored"]["4500"]["psnr"], abs=1e-3)
    assert rec["machine"]["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert rec["machine"]["threads"] == torch.get_num_threads()
    assert f"{rec['machine']['threads']} thread(s)" in text


def test_reuse_is_keyed_on_the_lens_file_content(cfg_factory, tmp_path, monkeypatch, capsys):
    lens = tmp_path / "lens.json"
    shutil.copy(ROOT / "data" / "lenses" / "edof_achromat.json", lens)
    args = (*ARGS, f"lens.path={lens}")
    evaluate(cfg_factory(*args, config_name="eval.yaml"))
    _no_training(monkeypatch)
    evaluate(cfg_factory(*args, config_name="eval.yaml"))  # unchanged: reused
    d = json.loads(lens.read_text())
    d["name"] = d.get("name", "") + " (edited)"
    lens.write_text(json.dumps(d))  # same path, other content
    with pytest.raises(Retrained):
        evaluate(cfg_factory(*args, config_name="eval.yaml"))
    assert "a run of other input files (changed: lens.path): training again" in (
        capsys.readouterr().out)


@pytest.mark.parametrize("damage, why", [
    (lambda rec, run: rec.write_text("[1, 2]"), "is damaged"),
    (lambda rec, run: rec.write_text('{"config": '), r"is damaged \(JSONDecodeError"),
    (lambda rec, run: rec.write_text(json.dumps({**json.loads(rec.read_text()),
                                                 "metrics": [1]})), "is damaged"),
    (lambda rec, run: (run / "checkpoints" / "best.ckpt").unlink(),
     "names a tested checkpoint that cannot be loaded"),
    (lambda rec, run: (run / "checkpoints" / "best.ckpt").write_bytes(b"junk"),
     r"cannot be loaded \(checkpoint .* is corrupt"),
])
def test_broken_records_mean_train_again(cfg_factory, tmp_path, monkeypatch, capsys, damage,
                                         why):
    evaluate(cfg_factory(*ARGS, config_name="eval.yaml"))
    run = tmp_path / "none" / "seed0"
    damage(run / ev.RUN_RECORD, run)
    _no_training(monkeypatch)
    capsys.readouterr()
    with pytest.raises(Retrained):
        evaluate(cfg_factory(*ARGS, config_name="eval.yaml"))
    import re

    assert re.search(why + ".*training again", capsys.readouterr().out)
