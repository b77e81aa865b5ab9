"""The host reads a surface's opening and a misalignment's identity test depend on (an
obscuration's ``> 0``, a clear radius's finiteness, a decenter's zero) are made once per change
of their tensors (:func:`~deeplens.optics.surfaces.base.host_flags`), not at every trace: every
kind of change is seen (in place, a new tensor, ``.to()``, ``load_state_dict``, a drawn lens's
substituted values, ``requires_grad``), and the reads are cached otherwise."""

from __future__ import annotations

import copy

import torch

from deeplens.optics.misalignment import Misalignment
from deeplens.optics.openings import Circle, Difference
from deeplens.optics.surfaces import Aperture, Asphere
from deeplens.optics.surfaces.base import host_flags


def test_host_flags_reads_again_after_each_kind_of_change():
    m = torch.nn.Module()
    t = torch.zeros(())
    reads = []

    def read(x):
        reads.append(1)
        return float(x)

    assert host_flags(m, "_f", (t,), read) == 0.0
    assert host_flags(m, "_f", (t,), read) == 0.0 and len(reads) == 1   # cached
    t.fill_(2.0)                                                       # in place
    assert host_flags(m, "_f", (t,), read) == 2.0 and len(reads) == 2
    u = torch.full((), 2.0)                                             # another tensor
    assert host_flags(m, "_f", (u,), read) == 2.0 and len(reads) == 3
    with torch.inference_mode():                                        # no version counter
        w = torch.full((), 5.0)
    assert host_flags(m, "_f", (w,), read) == 5.0
    assert host_flags(m, "_f", (w,), read) == 5.0 and len(reads) == 5


def test_an_asphere_opening_follows_its_obscuration():
    s = Asphere(1 / 40, 5.0)
    assert isinstance(s.opening, Circle) and s.closed_form
    with torch.no_grad():
        s.obscuration.fill_(1.0)
    assert isinstance(s.opening, Difference) and not s.closed_form
    s.load_state_dict({**s.state_dict(), "obscuration": torch.tensor(0.0, dtype=torch.float64)})
    assert isinstance(s.opening, Circle)
    t = copy.deepcopy(s)
    with torch.no_grad():
        t.obscuration.fill_(2.0)
    assert isinstance(t.opening, Difference) and isinstance(s.opening, Circle)
    s = s.float()                                                        # new buffers
    assert isinstance(s.opening, Circle) and s.opening.radius is s.semi_diameter
    with torch.no_grad():
        s.clear_radius.fill_(4.0)
    assert s.opening.kernel_clip is None and not s.closed_form
    assert s.in_aperture(torch.tensor([4.5, 3.5]), torch.tensor([0.0, 0.0])).tolist() == \
        [False, True]


def test_an_aperture_opening_follows_its_decenter():
    a = Aperture(3.0)
    assert a.opening.kernel_clip is not None
    with torch.no_grad():
        a.decenter[0] = 0.5
    assert a.opening.kernel_clip is None and a.fused is None
    assert a.in_aperture(torch.tensor([3.2]), torch.tensor([0.0])).tolist() == [True]


def test_a_misalignment_identity_follows_its_values():
    m = Misalignment()
    assert m.is_identity()
    with torch.no_grad():
        m.dx.fill_(0.01)
    assert not m.is_identity()
    m.load_state_dict({k: torch.zeros_like(v) for k, v in m.state_dict().items()})
    assert m.is_identity()
    m.tilt_y.requires_grad_(True)
    assert not m.is_identity()
    m.tilt_y.requires_grad_(False)
    assert m.is_identity()
    m.dy = torch.nn.Parameter(torch.tensor(0.2, dtype=torch.float64), requires_grad=False)
    assert not m.is_identity()
