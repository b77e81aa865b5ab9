"""``model.perceptual_weights`` files that are not VGG16 weights (issue 38 item 17): a pickle
that would run code is refused, without running it, by a one-line error naming the file and
what was expected, not torch's multi-paragraph ``UnpicklingError``; so is a file holding a list."""

import pytest
import torch

from deeplens.nets import PerceptualLoss


class _Payload:
    """Unpickling this would create ``marker`` (a stand-in for arbitrary code)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_a_malicious_pickle_is_refused_with_a_clear_error(tmp_path):
    marker = tmp_path / "ran"
    p = tmp_path / "vgg16.pth"
    torch.save({"features.0.weight": _Payload(marker)}, p)
    with pytest.raises(ValueError) as e:
        PerceptualLoss(weights_path=p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: cannot be read as VGG16 weights: torch.load(weights_only=True) "
                          f"refused it (UnpicklingError: ")
    assert "never arbitrary pickled objects: expected torchvision's VGG16 state dict" in msg
    assert "\n" not in msg and e.value.__cause__ is None and e.value.__suppress_context__
    assert not marker.exists()


def test_a_list_is_not_a_state_dict(tmp_path):
    p = tmp_path / "vgg16.pth"
    torch.save([torch.zeros(3)], p)
    with pytest.raises(ValueError, match=r"vgg16.pth is not a VGG16 state dict: it holds a list, "
                                         r"expected a dict of parameter names to tensors"):
        PerceptualLoss(weights_path=p)
