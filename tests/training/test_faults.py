"""Faults found by hostile use (issue 25, items 1, 6, 7): every one gives a message naming the
key, the file or the cause, never a traceback from deep inside torch or Lightning."""

import errno
import warnings

import pytest
import torch

from deeplens.optics.limits import MemoryBudgetError
from deeplens.training import checkpoint as ck
from deeplens.training.checkpoint import (CheckpointError, checksum_path, read_checkpoint,
                                          write_checkpoint)
from deeplens.training.train import check_config


def _state(v=1.0):
    return {"state_dict": {"w": torch.full((4,), v)}, "global_step": 1}


@pytest.mark.parametrize("override, key", [
    ("seed=null", "^seed: expected int, got None$"),
    ("data.image_size=3", "^data.image_size: expected .*>= 4, got 3$"),
    ("sensor.resolution=[3,3]", r"^sensor.resolution: expected .*>= 6.*, got \[3, 3\]$"),
    ("trainer.max_epochs=abc", "^trainer.max_epochs: expected int, got 'abc'$"),
    ("+trainer.val_check_interval=often", "^trainer.val_check_interval: expected int or float, got 'often'$"),
])
def test_config_errors_name_the_key(cfg_factory, override, key):
    """These four failed deep inside the renderer, the texture generator, kornia's SSIM and
    Lightning's fit loop (a bare AssertionError) instead."""
    with pytest.raises(ValueError, match=key):
        check_config(cfg_factory(override))


def test_smallest_accepted_sizes_pass(cfg_factory):
    check_config(cfg_factory("data.image_size=4", "sensor.resolution=[6,6]"))


@pytest.mark.parametrize("override, key", [
    ("data.image_size=10000000", r"data\.image_size"),
    ("sensor.resolution=[1000000,1000000]", r"sensor\.resolution"),
    ("render.spp=100000000000", r"render\.spp"),
])
def test_sizes_beyond_memory_are_refused_with_the_bytes(cfg_factory, monkeypatch, override,
                                                        key):
    monkeypatch.setenv("DEEPLENS_MEMORY_BUDGET", "16G")
    with pytest.raises(MemoryBudgetError, match=key + r".*would need at least .*iB"):
        check_config(cfg_factory(override))


def test_uppercase_or_empty_digest_does_not_make_a_good_checkpoint_corrupt(tmp_path):
    p = tmp_path / "last.ckpt"
    write_checkpoint(_state(2.0), p)
    side = checksum_path(p)
    side.write_text(side.read_text().upper())  # as some tools write hex
    assert torch.equal(read_checkpoint(p)["state_dict"]["w"], torch.full((4,), 2.0))
    side.write_text("")   # deeplens never writes an empty one: refused, saying so (issue 38)
    with pytest.raises(CheckpointError, match=r"cannot be verified: its digest file "
                                              r"last.ckpt.sha256 lists no SHA-256 \(it is empty\)"):
        read_checkpoint(p)
    side.write_text("0" * 64 + "\n")  # a real mismatch is still refused
    with pytest.raises(CheckpointError, match="corrupt"):
        read_checkpoint(p)


def test_a_garbage_digest_file_does_not_let_a_damaged_checkpoint_load(tmp_path):
    """A flipped byte in the checkpoint and garbage in its .sha256 (issue 38): refused, saying
    the digest file is garbage and how to load the checkpoint anyway; once the digest file is
    deleted it loads unverified with a warning (and fails or not on its own bytes)."""
    p = tmp_path / "last.ckpt"
    write_checkpoint(_state(2.0), p)
    raw = bytearray(p.read_bytes())
    raw[len(raw) // 2] ^= 0x01
    p.write_bytes(bytes(raw))
    side = checksum_path(p)
    side.write_text("not a digest: garbage\n")
    with pytest.raises(CheckpointError, match=r"last.ckpt cannot be verified: its digest file "
                                              r"last.ckpt.sha256 lists no SHA-256 \(it holds no "
                                              r"64-digit hex SHA-256 \(it starts 'not a digest"
                                              r".*delete .*last.ckpt.sha256 to load it unverified"):
        read_checkpoint(p)
    side.write_bytes(b"\xff\xfe\x00garbage")   # not UTF-8
    with pytest.raises(CheckpointError, match=r"lists no SHA-256 \(it cannot be read "
                                              r"\(UnicodeDecodeError"):
        read_checkpoint(p)


def test_disk_full_is_named_not_torchs_unexpected_pos(tmp_path, monkeypatch):
    p = tmp_path / "last.ckpt"

    def short_write(obj, f):
        f.write(b"PK")
        raise RuntimeError("[enforce fail at inline_container.cc:664] . unexpected pos 1088 "
                           "vs 1024")

    monkeypatch.setattr(ck.torch, "save", short_write)
    with pytest.raises(CheckpointError, match=rf"{p}: the disk is full \([\d,]+ bytes free"):
        write_checkpoint(_state(), p)
    monkeypatch.setattr(ck.torch, "save", lambda obj, f: (_ for _ in ()).throw(
        OSError(28, "No space left on device")))
    with pytest.raises(CheckpointError, match="the disk is full"):
        write_checkpoint(_state(), p)
    assert not list(tmp_path.glob("*.tmp"))


def test_read_only_folder_reports_the_write_error_not_the_cleanup(tmp_path, monkeypatch):
    """In a read-only folder the temporary file cannot be removed either; that second error
    (PermissionError from the cleanup) used to replace the first."""
    p = tmp_path / "last.ckpt"

    def read_only(*a, **k):
        raise PermissionError(13, "Permission denied")

    def save_fails(obj, f):
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(ck.torch, "save", save_fails)
    monkeypatch.setattr(ck.Path, "unlink", read_only)
    with pytest.raises(CheckpointError, match="Read-only file system"):
        write_checkpoint(_state(), p)


def test_temporary_files_have_unique_names(tmp_path):
    p = tmp_path / "last.ckpt"
    a, b = ck.temp_path(p), ck.temp_path(p)
    assert a != b and a.parent == b.parent == tmp_path and a.name.startswith("last.ckpt.")
    assert a.name.endswith(".tmp")


def test_bare_state_dict_is_named_as_such(tmp_path):
    p = tmp_path / "weights.pt"
    torch.save({"restorer.w": torch.zeros(2)}, p)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(CheckpointError, match="bare state dict.*load_state_dict"):
            read_checkpoint(p)


def test_a_file_size_limit_is_named_not_a_full_disk(tmp_path, monkeypatch):
    """``ulimit -f`` (a real RLIMIT_FSIZE, raised back at once) and EFBIG from a FAT32 drive
    (issue 38): named as a file-size limit; torch's short write said "the disk is full"."""
    resource = pytest.importorskip("resource")
    p = tmp_path / "last.ckpt"
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    limit = 65536
    if hard != resource.RLIM_INFINITY and hard < limit:
        pytest.skip("the hard file-size limit is below the test's")
    big = {"state_dict": {"w": torch.zeros(100_000)}}   # 400 kB
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    try:
        with pytest.raises(CheckpointError) as e:
            write_checkpoint(big, p)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    msg = str(e.value)
    assert (f"could not write checkpoint {p}: the file is too large: the write stopped at "
            f"65,536 bytes on the process's file-size limit of 65,536 bytes (ulimit -f, "
            f"RLIMIT_FSIZE), not on a full disk") in msg
    assert "the disk is full" not in msg and not list(tmp_path.glob("*.tmp"))
    if soft != resource.RLIM_INFINITY:
        return   # the FAT32 wording is for processes without a file-size limit
    monkeypatch.setattr(ck.torch, "save", lambda obj, f: (_ for _ in ()).throw(
        OSError(errno.EFBIG, "File too large")))
    with pytest.raises(CheckpointError, match=r"the file is too large: the write stopped at 0 "
                                              r"bytes on the largest file the file system of .* "
                                              r"holds \(a FAT32 drive: 4,294,967,295 bytes\)"):
        write_checkpoint(_state(), p)


@pytest.mark.parametrize("ckpt,match", [
    ({"state_dict": [torch.zeros(2)]},
     r"state_dict is a list, expected a dict of parameter names to tensors"),
    ({"state_dict": {"w": 3.0}}, r"state_dict\['w'\] is a float, expected a tensor"),
    ({"state_dict": {"w": torch.zeros(2)}, "epoch": "3"}, r"epoch is a str, expected an integer"),
    ({"state_dict": {"w": torch.zeros(2)}, "optimizer_states": [[1, 2]]},
     r"optimizer_states\[0\] is a list, expected a dict \(an optimiser's state_dict\)"),
    ({"state_dict": {"w": torch.zeros(2)}, "optimizer_states": [{"state": {}}]},
     r"optimizer_states\[0\].param_groups is missing, expected a list of dicts"),
    ({"state_dict": {"w": torch.zeros(2)}, "loops": [1]}, r"loops is a list, expected a dict"),
])
def test_a_checkpoint_deeplens_did_not_write_is_named_not_a_key_error(tmp_path, ckpt, match):
    """It passes its digest (written through write_checkpoint), but a list stands where a dict
    belongs (issue 38 item 7): Lightning's KeyError / AttributeError came from deep inside."""
    p = tmp_path / "odd.ckpt"
    write_checkpoint(ckpt, p)
    with pytest.raises(CheckpointError, match=rf"checkpoint {p} is not one deeplens wrote: "
                                              + match):
        read_checkpoint(p)


def test_weights_only_checkpoint_cannot_be_resumed_and_says_so(tmp_path):
    p = tmp_path / "weights.ckpt"
    write_checkpoint({"state_dict": {"w": torch.zeros(2)}, "epoch": 3}, p)
    assert read_checkpoint(p)["epoch"] == 3        # testing it is fine
    with pytest.raises(CheckpointError, match=r"weights.ckpt holds no training state to resume "
                                              r"from \(no global_step, loops, optimizer_states\)"
                                              r": a weights-only file"):
        read_checkpoint(p, resume=True)
