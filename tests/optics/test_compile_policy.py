"""``TraceOptions(compile="default")``: eager until compiling has paid (the ski-rental rule of
:mod:`deeplens.optics.compile_policy`), per kernel signature, with an off switch; the ledger
round-trips through a checkpoint so that a resumed run switches at the same call."""

from __future__ import annotations

import math
import warnings

import pytest
import torch

import helpers as H

from deeplens.optics import compile_policy as P
from deeplens.optics import tracer
from deeplens.optics.io import load_lens
from deeplens.optics.options import TraceOptions
from deeplens.optics.rays import Rays


def _singlet():
    """The shipped double Gauss (a name kept short: any lens with compilable surfaces)."""
    return load_lens(H.LENS_DIR / "double_gauss.json").to(torch.float64)


N_FUSED = 11  # every surface of the double Gauss runs compiled (checked below)


def _rays(n, dtype=torch.float64):
    g = torch.Generator().manual_seed(0)
    xy = (torch.rand(n, 2, generator=g, dtype=dtype) - 0.5) * 4
    o = torch.cat([xy, torch.full((n, 1), -1.0, dtype=dtype)], -1)
    d = torch.tensor([0.0, 0.0, 1.0], dtype=dtype).expand(n, 3)
    return Rays(o, d, H.WAVELENGTH_D).to(dtype)


@pytest.fixture
def calls(monkeypatch):
    """Record which traces the scheduler sends to the compiled path (which then runs eager
    here: the rule is under test, not the kernels)."""
    seen = []

    def fake(lens, rays, order, n, z, reverse, options, step, propagate_to=None, mode=None):
        seen.append(mode)
        return tracer.trace(lens, rays, reverse=reverse, options=TraceOptions(compile=False),
                            propagate_to=propagate_to)

    monkeypatch.setattr(tracer, "trace_compiled", fake)
    monkeypatch.delenv("DEEPLENS_COMPILE", raising=False)
    return seen


def test_the_test_lens_is_compilable():
    lens = _singlet()
    assert sum(tracer.fused_kind(lens, i) is not None for i in range(len(lens.surfaces))) \
        == N_FUSED


def _cost_kinds(lens) -> list[str]:
    """Each surface's cost class read from its type and coefficients (not from ``fused_kind``):
    an aperture or a plane costs a plane, a sphere or conic a quadric, an asphere with
    coefficients a Newton surface."""
    out = []
    for s in lens.surfaces:
        name = type(s).__name__
        if name in ("Aperture", "Plane"):
            out.append("plane")
        elif name in ("Asphere", "Sphere"):
            out.append("newton" if len(s.a) else "quadric")
        else:
            raise AssertionError(f"the test lens has an unexpected surface {name}")
    return out


def _per_call(n_rays: int, grad: bool) -> float:
    """The modelled saving of one call of ``n_rays`` rays through the test lens, from the
    module's constants independently of the ledger's code."""
    return n_rays * sum(P.EAGER_S[k][grad] - P.COMPILED_S[k][grad]
                        for k in _cost_kinds(_singlet()))


def _switch_call(n_rays: int, grad: bool) -> int:
    """The 0-based index of the first compiled call under the ski-rental rule."""
    return math.ceil(P.COMPILE_COST_S / _per_call(n_rays, grad))


def test_every_fused_kind_has_a_cost_and_compiling_saves():
    from deeplens.optics import compiled as C

    for kind in [k for k in C.KINDS if k != "propagate"] + ["newton"]:
        for grad in (False, True):
            assert P.saving_per_ray_surface(kind, grad) > 0, (kind, grad)
    # the measured fact the per-kind model exists for: a Newton surface iterates its
    # intersection, so compiling it saves more than it saves on a sphere
    for grad in (False, True):
        assert P.saving_per_ray_surface("newton", grad) > P.saving_per_ray_surface("quadric", grad)
    assert P.saving_per_ray(("quadric", None, "newton"), False) == (
        P.saving_per_ray_surface("quadric", False) + P.saving_per_ray_surface("newton", False))


def test_the_ledger_charges_each_surface_by_its_kind():
    lens, opts = _singlet(), TraceOptions()
    n = 20_000
    with torch.no_grad():
        lens.trace(_rays(n), options=opts)
    (saved,) = opts.ledger.saved.values()
    assert saved == pytest.approx(_per_call(n, False), rel=1e-12)


def test_default_is_the_policy_and_false_switches_it_off():
    assert TraceOptions().compile == "default"
    assert TraceOptions(compile=False).compile is False


def test_eager_until_compiling_has_paid_then_compiled(calls, monkeypatch):
    monkeypatch.setattr(P, "COMPILE_COST_S", 0.1)  # a few calls of 2e4 rays
    lens, opts = _singlet(), TraceOptions()
    n = 20_000
    k = _switch_call(n, grad=False)
    assert 2 <= k <= 50
    with torch.no_grad():
        for i in range(k + 3):
            lens.trace(_rays(n), options=opts)
            assert len(calls) == max(0, i - k + 1), (i, k, calls)
    assert calls == ["auto"] * 3


def test_small_calls_and_one_off_calls_stay_eager(calls, monkeypatch):
    monkeypatch.setattr(P, "COMPILE_COST_S", 1e-12)
    lens, opts = _singlet(), TraceOptions()
    with torch.no_grad():
        for _ in range(5):   # below MIN_RAYS: never compiled, never charged
            lens.trace(_rays(P.MIN_RAYS - 1), options=opts)
        assert calls == [] and opts.ledger.saved == {}
        lens.trace(_rays(P.MIN_RAYS), options=opts)   # the first large call: eager, charged
        assert calls == [] and len(opts.ledger.saved) == 1
        lens.trace(_rays(P.MIN_RAYS))                 # no options object, no ledger: eager
        assert calls == []
        lens.trace(_rays(P.MIN_RAYS), options=opts)
        assert calls == ["auto"]


def test_signatures_are_charged_separately(calls, monkeypatch):
    """With and without gradients are different kernels: each pays for its own compile."""
    lens, opts = _singlet(), TraceOptions()
    n = 20_000
    monkeypatch.setattr(P, "COMPILE_COST_S", _per_call(n, True) * 1.5)
    lens.d_sensor.requires_grad_(True)
    for _ in range(2):
        lens.trace(_rays(n), options=opts)   # with gradients: 1.5 calls' worth, then compiled
    assert calls == []
    with torch.no_grad():
        lens.trace(_rays(n), options=opts)   # another signature: charged from zero
    assert calls == [] and len(opts.ledger.saved) == 2
    lens.trace(_rays(n), options=opts)
    assert calls == ["auto"]


@pytest.mark.parametrize("switch", ["env", "false"])
def test_off_switch(calls, monkeypatch, switch):
    monkeypatch.setattr(P, "COMPILE_COST_S", 1e-12)
    opts = TraceOptions(compile=False) if switch == "false" else TraceOptions()
    if switch == "env":
        monkeypatch.setenv("DEEPLENS_COMPILE", "0")
    lens = _singlet()
    with torch.no_grad():
        for _ in range(4):
            lens.trace(_rays(P.MIN_RAYS), options=opts)
    assert calls == []


def test_no_compiler_warns_once_and_stays_eager(calls, monkeypatch):
    monkeypatch.setattr(P, "COMPILE_COST_S", 1e-12)
    monkeypatch.setattr(P, "compiler_available", lambda device: (False, "no g++ here"))
    lens, opts = _singlet(), TraceOptions()
    with warnings.catch_warnings(record=True) as w, torch.no_grad():
        warnings.simplefilter("always")
        for _ in range(4):
            lens.trace(_rays(P.MIN_RAYS), options=opts)
    assert calls == []
    assert len([x for x in w if "no g++ here" in str(x.message)]) == 1


def test_ledger_round_trip_switches_at_the_same_call(calls, monkeypatch):
    """A run resumed from a stored ledger switches where the uninterrupted run did."""
    monkeypatch.setattr(P, "COMPILE_COST_S", 0.1)
    lens, n = _singlet(), 20_000
    k = _switch_call(n, grad=False)
    a = TraceOptions()
    with torch.no_grad():
        for _ in range(k - 1):
            lens.trace(_rays(n), options=a)
        state = a.ledger.state_dict()
        b = TraceOptions()
        b.ledger.load_state_dict(state)
        lens.trace(_rays(n), options=b)   # call k - 1: still eager
        assert calls == []
        lens.trace(_rays(n), options=b)   # call k: compiled, as in the uninterrupted run
        assert calls == ["auto"]
    assert TraceOptions().ledger.saved == {}
    assert a.replace(tol=1e-9).ledger is not a.ledger


@pytest.mark.slow
def test_switched_trace_equals_the_forced_compiled_one(monkeypatch):
    """After the switch, ``"default"`` runs the very kernels of ``compile=True`` (bitwise);
    before it, the eager trace (bitwise).  Slow: it compiles the double Gauss (about 1 min on
    an idle core, 5 under load); the kernels themselves are tested in ``test_compiled.py``."""
    monkeypatch.delenv("DEEPLENS_COMPILE", raising=False)
    monkeypatch.setattr(P, "COMPILE_COST_S", 1e-12)
    lens, rays = _singlet(), _rays(P.MIN_RAYS)
    opts = TraceOptions()
    with torch.no_grad():
        eager = lens.trace(rays, options=TraceOptions(compile=False))
        first = lens.trace(rays, options=opts)      # charged: eager
        forced = lens.trace(rays, options=TraceOptions(compile=True))
        second = lens.trace(rays, options=opts)     # compiled
    assert torch.equal(first.o, eager.o) and torch.equal(first.d, eager.d)
    assert torch.equal(second.o, forced.o) and torch.equal(second.valid, forced.valid)
    v = eager.valid
    assert float((second.o - eager.o)[v].abs().max()) < 1e-12
