"""Checkpoint files: digests beside each file, refused corruption, failed writes, safe loading."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from deeplens.training import checkpoint as ck
from deeplens.training.checkpoint import (
    CheckpointError,
    check_compatible,
    checksum_path,
    read_checkpoint,
    write_checkpoint,
)


def _state(v: float = 1.0) -> dict:
    # > 64 KiB of tensor data, so that corrupting 4 KiB in the middle hits tensor bytes
    return {"state_dict": {"w": torch.full((20_000,), v), "b": torch.arange(5.0)},
            "global_step": int(v), "loops": {"fit_loop": {"epoch": 1}}}


def _equal(a: dict, b: dict) -> bool:
    return (a["global_step"] == b["global_step"]
            and all(torch.equal(a["state_dict"][k], b["state_dict"][k]) for k in a["state_dict"]))


def test_write_then_read_round_trips_with_a_digest_beside_the_file(tmp_path):
    p = tmp_path / "last.ckpt"
    digest = write_checkpoint(_state(2.0), p)
    assert checksum_path(p).read_text().split() == [digest] == [ck.sha256_file(p)]
    assert _equal(read_checkpoint(p), _state(2.0))
    assert sorted(f.name for f in tmp_path.iterdir()) == ["last.ckpt", "last.ckpt.sha256"]


def test_random_bytes_are_refused_naming_the_file(tmp_path):
    p = tmp_path / "last.ckpt"
    write_checkpoint(_state(), p)
    p.write_bytes(os.urandom(5000))
    with pytest.raises(CheckpointError, match=rf"{p}.*corrupt.*SHA-256"):
        read_checkpoint(p)
    # without a digest file the reader still names the file (no bare IndexError)
    q = tmp_path / "other.ckpt"
    q.write_bytes(os.urandom(5000))
    with pytest.warns(UserWarning, match="no digest file"), \
            pytest.raises(CheckpointError, match=rf"{q} cannot be read"):
        read_checkpoint(q)


def test_truncated_checkpoint_is_refused_naming_the_file(tmp_path):
    p = tmp_path / "best.ckpt"
    write_checkpoint(_state(), p)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(CheckpointError, match=rf"{p} is corrupt.*truncated"):
        read_checkpoint(p)


def test_corruption_in_the_middle_is_detected(tmp_path):
    """4 KiB overwritten inside the tensor data: torch.load would read it silently."""
    p = tmp_path / "last.ckpt"
    write_checkpoint(_state(), p)
    data = bytearray(p.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 4096] = os.urandom(4096)
    p.write_bytes(bytes(data))
    assert torch.load(p, weights_only=True)["global_step"] == 1  # loads without the digest
    with pytest.raises(CheckpointError, match=rf"{p} is corrupt"):
        read_checkpoint(p)


def test_a_write_failing_half_way_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    """Disk full in the middle of torch.save: the error names the path, no .tmp is left
    behind, and the previous checkpoint still verifies and loads unchanged."""
    p = tmp_path / "last.ckpt"
    write_checkpoint(_state(1.0), p)
    real_save = torch.save

    def half_then_enospc(obj, f):
        real_save(obj, f)
        f.seek(f.tell() // 2)
        f.truncate()
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(ck.torch, "save", half_then_enospc)
    with pytest.raises(CheckpointError, match=rf"could not write checkpoint {p}.*No space"):
        write_checkpoint(_state(7.0), p)
    monkeypatch.undo()
    assert sorted(f.name for f in tmp_path.iterdir()) == ["last.ckpt", "last.ckpt.sha256"]
    assert _equal(read_checkpoint(p), _state(1.0))


@pytest.mark.parametrize("fail", ["checkpoint rename", "final digest rename"])
def test_an_interrupted_write_leaves_a_checkpoint_that_verifies(tmp_path, monkeypatch, fail):
    """The checkpoint and its digest file are two renames; whichever of them does not happen
    (a kill, an I/O error), the file on disk must still match a listed digest: the old
    checkpoint if its rename failed, the new one if only the digest's last update failed."""
    p = tmp_path / "last.ckpt"
    side = checksum_path(p)
    write_checkpoint(_state(1.0), p)
    real_replace = os.replace
    calls = []

    def replace(src, dst):
        calls.append(str(dst))
        if fail == "checkpoint rename" and str(dst) == str(p):
            raise OSError(5, "Input/output error")
        if fail == "final digest rename" and calls.count(str(side)) == 2:
            raise OSError(5, "Input/output error")
        real_replace(src, dst)

    monkeypatch.setattr(ck.os, "replace", replace)
    with pytest.raises(CheckpointError, match=str(p)):
        write_checkpoint(_state(3.0), p)
    monkeypatch.undo()
    expected = _state(1.0) if fail == "checkpoint rename" else _state(3.0)
    assert _equal(read_checkpoint(p), expected)
    assert not list(tmp_path.glob("*.tmp"))


class _Payload:
    def __reduce__(self):
        return (os.getcwd, ())


def test_pickled_objects_are_refused_not_executed(tmp_path):
    p = tmp_path / "evil.ckpt"
    write_checkpoint({"state_dict": {}, "x": _Payload()}, p)  # digest is valid
    with pytest.raises(CheckpointError, match=rf"{p} cannot be read.*Weights only"):
        read_checkpoint(p)


def test_checkpoint_of_another_model_names_what_differs(tmp_path):
    a = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2))
    b = torch.nn.Sequential(torch.nn.Linear(3, 5), torch.nn.Linear(5, 2), torch.nn.ReLU())
    c = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2), torch.nn.Linear(2, 2))
    ckpt = {"state_dict": a.state_dict(),
            "optimizer_states": [{"param_groups": [{"name": "net"}, {"name": "lens.d_sensor"}]}]}
    check_compatible(ckpt, a, "x.ckpt", ["net", "lens.d_sensor"])
    with pytest.raises(CheckpointError, match=r"x\.ckpt does not belong.*differ in shape.*"
                                              r"0\.weight \(4, 3\) vs \(5, 3\)"):
        check_compatible(ckpt, b, "x.ckpt")
    with pytest.raises(CheckpointError, match=r"2 of this model's parameters are not in it "
                                              r"\(2: 2; e.g. 2\.bias, 2\.weight\)"):
        check_compatible(ckpt, c, "x.ckpt")
    with pytest.raises(CheckpointError, match=r"trained \['net', 'lens.d_sensor'\], this run "
                                              r"trains \['net'\]"):
        check_compatible(ckpt, a, "x.ckpt", ["net"])


def test_lightning_loads_through_the_verified_reader(tmp_path):
    """The trainer's I/O plugin refuses a corrupt checkpoint by path and always loads with
    weights_only=True, whatever the caller asks."""
    io = ck.AtomicCheckpointIO()
    p = tmp_path / "last.ckpt"
    io.save_checkpoint(_state(4.0), p)
    got = io.load_checkpoint(p)
    assert got.pop(ck.LOADED_FROM) == str(p) and _equal(got, _state(4.0))
    with pytest.raises(CheckpointError, match="weights_only=True only"):
        io.load_checkpoint(p, weights_only=False)
    p.write_bytes(p.read_bytes()[:100])
    with pytest.raises(CheckpointError, match=rf"{p} is corrupt"):
        io.load_checkpoint(p)
    io.remove_checkpoint(p)
    assert not list(tmp_path.iterdir())


def test_trainer_refuses_a_checkpoint_of_the_other_experiment(cfg_factory, tmp_path):
    """An EDOF checkpoint given to the doublet experiment (test), or one trained with other
    lens.trainable (resume), stops before anything runs, naming the file and what differs."""
    from deeplens.training.train import build_objects

    edof = build_objects(cfg_factory("experiment=edof", "~logger", "callbacks.image_logger=null"))
    groups = [g["name"] for g in edof["module"]._param_groups()]
    p = tmp_path / "edof.ckpt"
    import lightning

    write_checkpoint({"pytorch-lightning_version": lightning.__version__,
                      "state_dict": edof["module"].state_dict(),
                      "optimizer_states": [{"param_groups": [{"name": n} for n in groups]}]}, p)
    doublet = build_objects(cfg_factory("experiment=doublet", "~logger",
                                        "callbacks.image_logger=null"))
    with pytest.raises(CheckpointError, match=rf"checkpoint {p} does not belong to this "
                                              r"experiment.*not in it \(lens: \d+.*restorer: \d+"):
        doublet["trainer"].test(doublet["module"], datamodule=doublet["datamodule"],
                                ckpt_path=str(p), verbose=False)
    other = build_objects(cfg_factory("experiment=edof", "~logger", "callbacks.image_logger=null",
                                      "lens.trainable=[surfaces.4.a.6]"))
    with pytest.raises(CheckpointError, match=rf"{p} does not belong.*lens\.trainable differs"):
        other["trainer"].fit(other["module"], datamodule=other["datamodule"], ckpt_path=str(p))


def test_a_failed_lens_export_names_the_file_and_leaves_no_tmp(tmp_path, monkeypatch):
    """The lens written beside a checkpoint (``last.lens.json``) fails like a checkpoint write:
    the error names the file and its ``.tmp`` is removed."""
    from types import SimpleNamespace

    from deeplens.optics.io import load_lens
    from deeplens.training import callbacks

    lens = load_lens(Path(__file__).resolve().parents[2] / "data" / "lenses" / "wide_doublet.json")
    trainer = SimpleNamespace(is_global_zero=True, global_step=3, loggers=[],
                              lightning_module=SimpleNamespace(lens=lens),
                              save_checkpoint=lambda path, weights_only=False: None)
    cb = callbacks.LensCheckpoint(dirpath=tmp_path)
    cb._save_checkpoint(trainer, str(tmp_path / "last.ckpt"))
    assert (tmp_path / "last.lens.json").exists()
    from deeplens.optics.io import lensfile

    def full_disk(obj, f, **kw):  # the disk fills half-way through the temporary file
        f.write("{half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(lensfile.json, "dump", full_disk)
    out = tmp_path / "best.lens.json"
    with pytest.raises(CheckpointError, match=rf"could not write the lens file {out}.*No space"):
        cb._save_checkpoint(trainer, str(tmp_path / "best.ckpt"))
    assert not list(tmp_path.glob("*.tmp"))


def test_checkpoint_io_hands_back_a_bare_state_dict_for_the_spawn_launcher(tmp_path):
    """Lightning's spawn launcher (trainer=ddp_cpu) saves rank 0's ``module.state_dict()``
    through the checkpoint I/O and loads it back in the main process: that round trip works
    (the file is still written atomically with its digest), while ``read_checkpoint`` alone,
    what resuming uses, still refuses a file that is not a training checkpoint."""
    from deeplens.training.checkpoint import (AtomicCheckpointIO, CheckpointError,
                                              checksum_path, read_checkpoint)

    sd = torch.nn.Linear(3, 2).state_dict()
    io = AtomicCheckpointIO()
    path = tmp_path / ".temp.ckpt"
    io.save_checkpoint(sd, path)
    assert checksum_path(path).exists()
    back = io.load_checkpoint(path)
    assert set(back) == set(sd) and all(torch.equal(back[k], sd[k]) for k in sd)
    with pytest.raises(CheckpointError, match="not a training checkpoint"):
        read_checkpoint(path)
