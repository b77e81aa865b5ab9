"""A checkpoint of the previous version of the code (issue 38 item 6): the surfaces' buffers
added since (``obscuration``, ``decenter``) are migrated with the defaults that version traced,
with one warning; what cannot be migrated is refused as a version difference, not as "another
experiment"."""

import warnings

import pytest
import torch

from deeplens.optics.io import load_lens
from deeplens.training.checkpoint import CheckpointError, check_compatible

NEW = ("obscuration", "decenter")


def model():
    m = torch.nn.Module()
    m.lens = load_lens("double_gauss")
    return m


def old_checkpoint(m):
    """What the previous version wrote for ``m``: no obscuration or decenter buffers."""
    return {"state_dict": {k: v.clone() for k, v in m.state_dict().items()
                           if not k.endswith(NEW)}}


def test_missing_new_buffers_are_migrated_with_one_warning():
    m = model()
    ck = old_checkpoint(m)
    n_missing = len(m.state_dict()) - len(ck["state_dict"])
    assert n_missing == 10
    with pytest.warns(UserWarning) as rec:
        check_compatible(ck, m, "old.ckpt")
    assert len(rec) == 1
    msg = str(rec[0].message)
    assert msg.startswith("checkpoint old.ckpt was written by an earlier deeplens version, "
                          "without 10 buffer(s) added since (lens: 10; e.g. ")
    assert "migrated with their defaults (no obscuration, a centred aperture" in msg
    fresh = model()
    fresh.load_state_dict(ck["state_dict"], strict=True)   # loads now
    for k, v in m.state_dict().items():
        assert torch.equal(fresh.state_dict()[k], v)


def test_a_current_checkpoint_migrates_nothing_and_warns_nothing():
    m = model()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_compatible({"state_dict": dict(m.state_dict())}, m, "new.ckpt")


def test_a_non_default_new_buffer_is_refused_as_a_version_difference():
    m = model()
    ck = old_checkpoint(m)
    with torch.no_grad():
        m.lens.surfaces[1].obscuration.fill_(0.5)   # this lens has one; the old code had none
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(CheckpointError, match=r"checkpoint old.ckpt comes from an earlier "
                                                  r"deeplens version \(a version difference, "
                                                  r"not another experiment\): it lacks 1 "
                                                  r"buffer\(s\) added since \(lens: 1; e.g. "
                                                  r"lens.surfaces.1.obscuration\)"):
            check_compatible(ck, m, "old.ckpt")


def test_another_experiment_is_still_named_as_such():
    m = model()
    ck = old_checkpoint(m)
    del ck["state_dict"]["lens.surfaces.2.c"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(CheckpointError, match=r"does not belong to this experiment .*"
                                                  r"lens.surfaces.2.c"):
            check_compatible(ck, m, "other.ckpt")
