"""Checkpoint files: atomic writes, a SHA-256 beside each file, verified and safe loading.

``<name>.ckpt`` is written as ``<name>.ckpt.<unique>.tmp`` (a name no other process or thread
uses), flushed to disk and renamed over the old file, so a killed run leaves the old or the new checkpoint, never a half-written one.  Beside it,
``<name>.ckpt.sha256`` holds the SHA-256 of its bytes (one hex digest per line).  A write first
lists the new digest *and* the old one, then renames the checkpoint, then keeps only the new
digest: at every instant the file on disk matches a listed digest, so a kill between the two
renames does not make a good checkpoint look corrupt.

Loading checks the digest (a truncated, overwritten or randomly corrupted file is refused with
its path), then reads the file with ``torch.load(weights_only=True)``: tensors, numbers, strings
and containers only, never arbitrary pickled objects, whatever torch's own default.
:func:`check_compatible` then compares the checkpoint's parameters with the model it is loaded
into, so a checkpoint of another experiment says so instead of listing raw missing keys.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import shutil
import warnings
from pathlib import Path

import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO
from lightning.pytorch.utilities import rank_zero_info

from ..optics.io import atomic

__all__ = ["AtomicCheckpointIO", "CheckpointError", "check_compatible", "check_on_load",
           "checksum_path", "check_structure", "migrate_missing_buffers", "override_learning_rates",
           "read_checkpoint", "sha256_file", "temp_path", "write_checkpoint", "write_text_atomic"]

#: key under which :class:`AtomicCheckpointIO` records the file a loaded checkpoint came from
LOADED_FROM = "deeplens_loaded_from"


class CheckpointError(RuntimeError):
    """A checkpoint cannot be written, read or used; the message names the file."""


def checksum_path(path) -> Path:
    """The digest file beside checkpoint ``path``: ``<path>.sha256``."""
    path = Path(path)
    return path.with_name(path.name + ".sha256")


def sha256_file(path) -> str:
    """Hex SHA-256 of the file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _listed_digests(path) -> list[str]:
    """The digests listed beside ``path`` (hex, any case, as ``sha256sum`` or an editor may
    write them), lower-cased."""
    return _read_digests(path)[0]


def _read_digests(path) -> tuple[list[str], str]:
    """``(digests, why)``: the digests listed beside ``path`` (lower-cased), and when there
    are none, why (``"it is empty"``, ``"it cannot be read (...)"``, ``"it holds no 64-digit
    hex SHA-256 (...)"``)."""
    side = checksum_path(path)
    try:
        text = side.read_text()
    except (OSError, UnicodeDecodeError) as e:
        return [], f"it cannot be read ({type(e).__name__}: {e})"
    words = text.lower().split()
    found = [s for s in words if len(s) == 64 and all(c in "0123456789abcdef" for c in s)]
    if found:
        return found, ""
    if not words:
        return [], "it is empty"
    return [], f"it holds no 64-digit hex SHA-256 (it starts {text.strip()[:40]!r})"


def temp_path(path: Path) -> Path:
    """A new, empty temporary file beside ``path`` whose name no other writer uses
    (``<name>.<random>.tmp``): two runs or threads writing the same file never share one.
    Stale ones a killed writer left are removed first (:mod:`deeplens.optics.io.atomic`)."""
    return atomic.temp_path(path)


def _remove_quietly(tmp: Path | None) -> None:
    """Remove a temporary file; a failure here (a read-only folder) must not hide the error
    that made the write fail."""
    if tmp is not None:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


def _disk_full(e: BaseException, folder: Path) -> str | None:
    """``"disk full (N bytes free in folder)"`` when ``e`` is a full disk: ``ENOSPC``, or
    torch's zip writer's ``unexpected pos`` (its report of a short write)."""
    full = isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT)
    full |= isinstance(e, RuntimeError) and ("unexpected pos" in str(e)
                                             or "file write failed" in str(e))
    if not full:
        return None
    try:
        free = f"{shutil.disk_usage(folder).free:,} bytes free"
    except OSError:
        free = "free space unknown"
    first = str(e).splitlines()[0] if str(e) else ""
    return f"the disk is full ({free} in {folder}; {type(e).__name__}: {first})"


#: the largest file a FAT32 file system holds (bytes): 4 GiB - 1
FAT32_MAX_FILE_BYTES = 2 ** 32 - 1


def _file_too_large(e: BaseException, folder: Path, written: int | None) -> str | None:
    """``"the file is too large (...)"`` when the write failed on a file-size limit (``EFBIG``:
    the process's ``ulimit -f`` (``RLIMIT_FSIZE``) or the file system's largest file, e.g.
    FAT32's 4 GiB), not a full disk.  torch's zip writer reports every short write as
    ``unexpected pos``; such a write is a size limit when the file stopped at the limit
    (``written`` bytes, the temporary file's size when the write failed)."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        soft = None if soft == resource.RLIM_INFINITY or soft < 0 else int(soft)
    except (ImportError, OSError, ValueError):   # no resource module (Windows)
        soft = None
    if isinstance(e, OSError):
        hit = e.errno == errno.EFBIG
    elif isinstance(e, RuntimeError) and ("unexpected pos" in str(e)
                                          or "file write failed" in str(e)):
        hit = written is not None and ((soft is not None and written >= soft)
                                       or written >= FAT32_MAX_FILE_BYTES)
    else:
        hit = False
    if not hit:
        return None
    if soft is not None:
        limit = f"the process's file-size limit of {soft:,} bytes (ulimit -f, RLIMIT_FSIZE)"
    else:
        limit = (f"the largest file the file system of {folder} holds (a FAT32 drive: "
                 f"{FAT32_MAX_FILE_BYTES:,} bytes)")
    try:
        free = f"{shutil.disk_usage(folder).free:,} bytes free"
    except OSError:
        free = "free space unknown"
    at = f" at {written:,} bytes" if written is not None else ""
    first = str(e).splitlines()[0] if str(e) else ""
    return (f"the file is too large: the write stopped{at} on {limit}, not on a full disk "
            f"({free}; EFBIG; {type(e).__name__}: {first}); raise the limit or write to "
            f"another file system")


def _size_or_none(p: Path | None) -> int | None:
    try:
        return None if p is None else p.stat().st_size
    except OSError:
        return None


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a fsynced temporary file and a rename (removed on
    failure)."""
    tmp = None
    try:
        tmp = temp_path(path)
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        atomic.replace(tmp, path)   # the umask's mode, not mkstemp's 0600
    except BaseException:
        _remove_quietly(tmp)
        raise


def write_checkpoint(checkpoint: dict, path) -> str:
    """Write ``checkpoint`` to ``path`` atomically with its digest file; returns the digest.

    Raises:
        CheckpointError: the write failed (disk full, permissions, ...); the message names the
            path, the temporary file is removed, and the previous checkpoint (if any) is left
            as it was and still verifies.
    """
    path = Path(path)
    tmp = None
    side = checksum_path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = temp_path(path)
        with open(tmp, "wb") as f:
            torch.save(checkpoint, f)
            f.flush()
            os.fsync(f.fileno())
        digest = sha256_file(tmp)
        old = _listed_digests(path)[:1] if path.exists() else []
        write_text_atomic(side, "\n".join([digest] + old) + "\n")  # both valid meanwhile
        atomic.replace(tmp, path)
        write_text_atomic(side, digest + "\n")
        return digest
    except BaseException as e:
        written = _size_or_none(tmp)
        _remove_quietly(tmp)
        if isinstance(e, Exception):
            why = (_file_too_large(e, path.parent, written) or _disk_full(e, path.parent)
                   or f"{type(e).__name__}: {e}")
            raise CheckpointError(f"could not write checkpoint {path}: {why} (the previous "
                                  f"checkpoint there, if any, is unchanged)") from e
        raise


def read_checkpoint(path, map_location="cpu", state_dict_only: bool = False,
                    resume: bool = False) -> dict:
    """Verify ``path`` against its digest file and load it with ``weights_only=True``.

    A checkpoint without a digest file (written by hand or by an older version) loads with a
    warning; one whose digest file exists but lists no digest (empty, unreadable or garbage) is
    refused.  With ``state_dict_only`` a bare module state dict (names to tensors) is accepted
    too: Lightning's spawn launcher (``trainer=ddp_cpu``) hands rank 0's weights back to the
    main process in such a file through the checkpoint I/O.

    The checkpoint's structure is checked (:func:`check_structure`): a file that passes its
    digest but is not what deeplens writes (a list where a dict belongs, a ``state_dict`` of
    other things than tensors; with ``resume``, no optimiser or loop state: a weights-only
    file) is refused naming the file, the field and what was expected, not with a
    ``KeyError`` or ``AttributeError`` from Lightning.

    Raises:
        FileNotFoundError: no file at ``path``.
        CheckpointError: the digest does not match (truncated or corrupted file), the digest
            file lists no digest (empty, unreadable or garbage: it says which), the file is
            not a readable checkpoint, or it holds objects that ``weights_only`` refuses; the
            message names the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    side = checksum_path(path)
    listed, why = _read_digests(path) if side.exists() else ([], "")
    if side.exists() and not listed:
        # deeplens writes the digest file atomically, so it is never empty or garbage: one
        # that is was damaged with the checkpoint, perhaps, and cannot vouch for it
        raise CheckpointError(
            f"checkpoint {path} cannot be verified: its digest file {side.name} lists no "
            f"SHA-256 ({why}); deeplens writes a 64-digit hex digest there, so the digest file "
            f"was damaged or replaced.  If you trust the checkpoint, delete {side} to load it "
            f"unverified (with a warning)")
    elif side.exists():
        digest = sha256_file(path)
        if digest not in listed:
            raise CheckpointError(
                f"checkpoint {path} is corrupt: its SHA-256 {digest[:16]}... does not match "
                f"{side.name} ({listed[0][:16] + '...' if listed else 'no valid digest'}); the "
                f"file was truncated or changed after it was written ({path.stat().st_size} "
                f"bytes)")
    else:
        warnings.warn(f"checkpoint {path} has no digest file {side.name}: loading it "
                      f"unverified", stacklevel=2)
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:
        raise CheckpointError(f"checkpoint {path} cannot be read: {type(e).__name__}: "
                              f"{str(e).splitlines()[0] if str(e) else ''}") from e
    if state_dict_only and isinstance(ckpt, dict) and ckpt and all(
            isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in ckpt.items()):
        return ckpt
    if not isinstance(ckpt, dict) or "state_dict" not in ckpt:
        bare = isinstance(ckpt, dict) and ckpt and all(torch.is_tensor(v) for v in ckpt.values())
        what = ("a bare state dict (parameter names to tensors, as torch.save(model."
                "state_dict()) writes): load it with module.load_state_dict(...); training "
                "resumes only from a checkpoint a training run wrote" if bare
                else f"no 'state_dict'; got {type(ckpt).__name__}")
        raise CheckpointError(f"{path} is not a training checkpoint ({what})")
    check_structure(ckpt, path, resume=resume)
    return ckpt


#: top-level checkpoint fields and the type Lightning writes for each, when present
_FIELD_TYPES = {"epoch": int, "global_step": int, "loops": dict, "optimizer_states": list,
                "lr_schedulers": list, "callbacks": dict, "hyper_parameters": dict,
                "pytorch-lightning_version": str}
_TYPE_WORDS = {int: "an integer", dict: "a dict", list: "a list", str: "a string"}
#: what a run resumes from (absent in a weights-only checkpoint)
_RESUME_FIELDS = ("epoch", "global_step", "loops", "optimizer_states")


def check_structure(ckpt: dict, path, resume: bool = False) -> None:
    """Raise :class:`CheckpointError` (naming ``path``, the field and what was expected) unless
    ``ckpt`` has the structure of a checkpoint deeplens (Lightning) writes: ``state_dict`` a
    dict of parameter names to tensors; ``epoch``, ``global_step`` integers, ``loops``,
    ``callbacks`` dicts, ``optimizer_states`` a list of dicts each with ``param_groups`` (a list
    of dicts) and, where present, ``state`` (a dict), ``lr_schedulers`` a list of dicts, where present; with
    ``resume``, the fields a run resumes from (``epoch``, ``global_step``, ``loops``,
    ``optimizer_states``) present."""
    def bad(field, expected, got):
        what = "missing" if got is None else f"a {type(got).__name__}"
        raise CheckpointError(f"checkpoint {path} is not one deeplens wrote: {field} is "
                              f"{what}, expected {expected}")

    sd = ckpt["state_dict"]
    if not isinstance(sd, dict):
        bad("state_dict", "a dict of parameter names to tensors", sd)
    for k, v in sd.items():
        if not isinstance(k, str) or not torch.is_tensor(v):
            bad(f"state_dict[{k!r}]", "a tensor (under a parameter name)", v)
    for field, typ in _FIELD_TYPES.items():
        if field in ckpt and not (isinstance(ckpt[field], typ)
                                  and not isinstance(ckpt[field], bool)):
            bad(field, _TYPE_WORDS[typ], ckpt[field])
    for i, opt in enumerate(ckpt.get("optimizer_states") or []):
        if not isinstance(opt, dict):
            bad(f"optimizer_states[{i}]", "a dict (an optimiser's state_dict)", opt)
        if "state" in opt and not isinstance(opt["state"], dict):
            bad(f"optimizer_states[{i}].state", "a dict", opt["state"])
        groups = opt.get("param_groups")
        if not isinstance(groups, list):
            bad(f"optimizer_states[{i}].param_groups", "a list of dicts", groups)
        for j, g in enumerate(groups):
            if not isinstance(g, dict):
                bad(f"optimizer_states[{i}].param_groups[{j}]", "a dict", g)
    for i, s in enumerate(ckpt.get("lr_schedulers") or []):
        if not isinstance(s, dict):
            bad(f"lr_schedulers[{i}]", "a dict (a scheduler's state_dict)", s)
    if resume:
        missing = [f for f in _RESUME_FIELDS if f not in ckpt]
        if missing:
            raise CheckpointError(
                f"checkpoint {path} holds no training state to resume from (no "
                f"{', '.join(missing)}): a weights-only file (ModelCheckpoint("
                f"save_weights_only=True), or written by hand); a run resumes only from a "
                f"checkpoint a training run wrote (last.ckpt); to score these weights, run "
                f"with train=false test=true ckpt_path=...")


def _summary(names, n: int = 3) -> str:
    """``"lens: 4, restorer: 80; e.g. lens.a, lens.b, ..."``: counts per sub-module, then names."""
    names = sorted(names)
    counts: dict[str, int] = {}
    for k in names:
        counts[k.split(".")[0]] = counts.get(k.split(".")[0], 0) + 1
    per = ", ".join(f"{m}: {c}" for m, c in counts.items())
    return f"{per}; e.g. " + ", ".join(names[:n]) + (", ..." if len(names) > n else "")


#: buffers added to surfaces after checkpoints of their lenses could be written, by their last
#: name, with the value that means what the older code traced: no obscuration (radius 0), a
#: centred aperture (decenter (0, 0))
MIGRATABLE_BUFFERS = {"obscuration": 0.0, "decenter": (0.0, 0.0)}


def migrate_missing_buffers(state_dict: dict, module, path=None) -> list[str]:
    """Add to ``state_dict`` the :data:`MIGRATABLE_BUFFERS` it lacks and ``module`` has, where
    ``module``'s value is that default (the checkpoint of an earlier deeplens version, whose
    lens had none); one warning names them.  Returns the names added; a missing buffer whose
    value in ``module`` is not the default is left missing (:func:`check_compatible` refuses
    it as a version difference)."""
    buffers = dict(module.named_buffers())
    done = []
    for k, v in module.state_dict().items():
        default = MIGRATABLE_BUFFERS.get(k.rsplit(".", 1)[-1])
        if k in state_dict or default is None or k not in buffers:
            continue
        if torch.equal(v.detach().cpu().double(), torch.tensor(default, dtype=torch.float64)):
            state_dict[k] = v.detach().clone()
            done.append(k)
    if done:
        warnings.warn(f"{f'checkpoint {path}' if path else 'the checkpoint'} was written by an "
                      f"earlier deeplens version, without {len(done)} buffer(s) added since "
                      f"({_summary(done)}): migrated with their defaults (no obscuration, a "
                      f"centred aperture: what that version traced)", stacklevel=2)
    return done


def check_on_load(checkpoint: dict, module, path, resume_groups=None) -> None:
    """A checkpoint being loaded into ``module`` checked (:func:`check_compatible`: another
    experiment's is refused, naming ``path``); when resuming (``resume_groups``: the run's
    ``[[optimiser param groups], ...]``, ``None`` when not fitting) this run's learning rates
    replace the checkpoint's (:func:`override_learning_rates`), which is said once."""
    groups = None if resume_groups is None else [g["name"] for g in resume_groups[0]]
    check_compatible(checkpoint, module, path, groups)
    if resume_groups is not None:
        changed = override_learning_rates(checkpoint, resume_groups)
        if changed:
            rank_zero_info(f"deeplens: resuming from {path or 'the checkpoint'} with this "
                           f"run's learning rates, not the checkpoint's ("
                           f"{'; '.join(changed)}); Adam's moment estimates are kept")


def check_compatible(checkpoint: dict, module, path=None, optimizer_groups=None) -> None:
    """Raise :class:`CheckpointError` when ``checkpoint`` was not written for ``module``'s
    experiment: its parameter names or shapes differ, or (``optimizer_groups``: the parameter
    group names the module would optimise) its optimiser trained other parameters.

    Buffers added to deeplens since the checkpoint was written are first migrated
    (:func:`migrate_missing_buffers`, one warning); one that cannot be (this model's value is
    not the default) is refused as a version difference.  The message names the file and the
    first differing parameters on each side.
    """
    where = f"checkpoint {path}" if path else "the checkpoint"
    migrate_missing_buffers(checkpoint["state_dict"], module, path)
    saved = {k: tuple(v.shape) for k, v in checkpoint["state_dict"].items()
             if torch.is_tensor(v)}
    ours = {k: tuple(v.shape) for k, v in module.state_dict().items()}
    missing, extra = set(ours) - set(saved), set(saved) - set(ours)
    newer = {k for k in missing if k.rsplit(".", 1)[-1] in MIGRATABLE_BUFFERS}
    if newer and newer == missing and not extra:
        raise CheckpointError(
            f"{where} comes from an earlier deeplens version (a version difference, not another "
            f"experiment): it lacks {len(newer)} buffer(s) added since ({_summary(newer)}), "
            f"and this model's values of them are not the defaults that version traced "
            f"({MIGRATABLE_BUFFERS}), so it cannot be migrated: train this lens afresh, or "
            f"give it the defaults")
    shapes = [f"{k} {saved[k]} vs {ours[k]}" for k in sorted(set(ours) & set(saved))
              if saved[k] != ours[k]]
    problems = []
    if missing:
        problems.append(f"{len(missing)} of this model's parameters are not in it "
                        f"({_summary(missing)})")
    if extra:
        problems.append(f"it holds {len(extra)} parameters this model does not have "
                        f"({_summary(extra)})")
    if shapes:
        problems.append(f"{len(shapes)} parameters differ in shape ({_summary(shapes)})")
    if not problems and optimizer_groups is not None and checkpoint.get("optimizer_states"):
        groups = [g.get("name") for g in checkpoint["optimizer_states"][0]["param_groups"]]
        if groups != list(optimizer_groups):
            problems.append(f"its optimiser trained {groups}, this run trains "
                            f"{list(optimizer_groups)} (lens.trainable differs)")
    if problems:
        raise CheckpointError(f"{where} does not belong to this experiment (another lens, "
                              f"network or set of trainable parameters): " + "; ".join(problems))


def override_learning_rates(checkpoint: dict, optimizers: list[list[dict]]) -> list[str]:
    """Put this run's learning rates into ``checkpoint``'s optimiser states before Lightning
    restores them (it would bring the saved rates back and silently ignore changed
    ``model.*_lr`` settings); the moment estimates are kept.

    Args:
        optimizers: per optimiser, this run's parameter groups (``{"name", "lr"}``) in order.

    Returns:
        One line per changed group, ``"net: 0.001 -> 0.0001"``.
    """
    changed = []
    for state, groups in zip(checkpoint.get("optimizer_states") or [], optimizers):
        for saved, ours in zip(state.get("param_groups", []), groups):
            old, new = saved.get("lr"), float(ours["lr"])
            if old is not None and float(old) != new:
                changed.append(f"{ours.get('name', '?')}: {float(old):.6g} -> {new:.6g}")
                saved["lr"] = new
                if "initial_lr" in saved:
                    saved["initial_lr"] = new
    return changed


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning checkpoint I/O through :func:`write_checkpoint` / :func:`read_checkpoint`:
    atomic writes with a digest beside each file, verified loads, ``weights_only=True`` always
    (Lightning's ``weights_only=None`` would defer to torch's version-dependent default)."""

    def save_checkpoint(self, checkpoint, path, storage_options=None):
        if storage_options is not None:
            raise TypeError("AtomicCheckpointIO takes no storage_options")
        write_checkpoint(checkpoint, path)

    def load_checkpoint(self, path, map_location="cpu", weights_only=None):
        if weights_only is False:
            raise CheckpointError(f"checkpoint {path}: deeplens loads checkpoints with "
                                  f"weights_only=True only (no arbitrary pickled objects)")
        ckpt = read_checkpoint(path, map_location=map_location, state_dict_only=True)
        if "state_dict" in ckpt:  # a training checkpoint (not the spawn launcher's weights)
            ckpt[LOADED_FROM] = str(path)
        return ckpt

    def remove_checkpoint(self, path):
        super().remove_checkpoint(path)
        checksum_path(path).unlink(missing_ok=True)
