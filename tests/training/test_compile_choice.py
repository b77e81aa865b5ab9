"""``render.compile=default`` in training (:mod:`deeplens.training.compile_choice`): the run
decides after its first step whether compiling pays for the steps left, stores the choice in
its checkpoints, and a resumed run traces as the uninterrupted one did from its first step."""

from __future__ import annotations

import math

import pytest

from deeplens.optics import compile_policy as P
from deeplens.optics import tracer
from deeplens.optics.options import TraceOptions
from deeplens.training import compile_choice
from deeplens.training.checkpoint import read_checkpoint
from deeplens.training.module import EndToEndModule
from deeplens.training.train import train

FAST = ("experiment=doublet", "callbacks.image_logger=null", "~logger",
        "trainer.enable_progress_bar=false", "test=false")


def test_decide_pays_when_the_steps_left_repay_each_compile():
    c = P.COMPILE_COST_S
    assert compile_choice.decide({"a": c / 10, "b": c / 10}, 0, 10)[0] == "auto"   # 2c vs 2c
    assert compile_choice.decide({"a": c / 10, "b": c / 10}, 0, 9)[0] is False     # 1.8c < 2c
    assert compile_choice.decide({"a": c / 10, "b": 0.0}, 0, 10)[0] == "auto"      # c vs c
    assert compile_choice.decide({"a": 1e-9}, 0, math.inf)[0] == "auto"
    assert compile_choice.decide({}, 0, 10**9)[0] is False
    assert compile_choice.decide({}, 1, 0)[0] == "auto"     # already compiled: keep it


def test_default_config_compiles_by_the_policy(cfg_factory):
    assert cfg_factory(*FAST).render.compile == "default"


@pytest.fixture
def dispatched(monkeypatch):
    """Per training batch, how many traces the scheduler sent to the compiled path (which
    runs eager here: the choice is under test, not the kernels)."""
    calls, per_batch = [], []

    def fake(lens, rays, order, n, z, reverse, options, step, propagate_to=None, mode=None):
        calls.append(mode)
        return tracer.trace(lens, rays, reverse=reverse, options=TraceOptions(compile=False),
                            propagate_to=propagate_to)

    orig = EndToEndModule.on_train_batch_end

    def on_batch_end(self, *a):
        per_batch.append(len(calls))
        calls.clear()
        return orig(self, *a)

    monkeypatch.setattr(tracer, "trace_compiled", fake)
    monkeypatch.setattr(EndToEndModule, "on_train_batch_end", on_batch_end)
    monkeypatch.delenv("DEEPLENS_COMPILE", raising=False)
    return per_batch


@pytest.mark.parametrize("pays", [True, False])
def test_choice_is_made_once_stored_and_resumed(cfg_factory, tmp_path, dispatched,
                                                monkeypatch, pays):
    seen = []
    real = compile_choice.decide

    def decide(delta, already, left):
        seen.append((dict(delta), already, left))
        return ("auto" if pays else False), "test"

    monkeypatch.setattr(compile_choice, "decide", decide)
    _, a = train(cfg_factory(*FAST, "trainer.max_epochs=2", out=tmp_path / "a"))
    # decided once, after the first step, from that step's ledger growth, 3 steps left
    assert len(seen) == 1 and seen[0][2] == 3
    assert seen[0][0] and real(seen[0][0], 0, 3)[0] in ("auto", False)
    assert a["module"].camera.options.compile == ("auto" if pays else False)
    uninterrupted = list(dispatched)
    assert uninterrupted[0] == 0                                # the first step: eager
    assert all((k > 0) == pays for k in uninterrupted[1:])      # then as decided
    dispatched.clear()
    train(cfg_factory(*FAST, "trainer.max_epochs=1", out=tmp_path / "b"))
    ckpt = tmp_path / "b" / "checkpoints" / "last.ckpt"
    assert read_checkpoint(ckpt)[compile_choice.CHOICE_KEY] == ("auto" if pays else False)
    dispatched.clear()
    seen.clear()
    _, c = train(cfg_factory(*FAST, "trainer.max_epochs=2", f"ckpt_path={ckpt}",
                             out=tmp_path / "c"))
    assert seen == []                                  # not decided again
    # traced as the uninterrupted run did from the first step on (a new process's first step
    # traces a few more times: the renderer's cached pixel plan, its image-circle traces, is
    # built again; values are unchanged, test_resume.py)
    assert len(dispatched) == 2 and all((k > 0) == pays for k in dispatched)
    assert c["module"].camera.options.compile == ("auto" if pays else False)


def test_explicit_setting_is_kept(cfg_factory, tmp_path, dispatched):
    _, a = train(cfg_factory(*FAST, "render.compile=false", "trainer.max_epochs=1",
                             out=tmp_path / "a"))
    assert a["module"].camera.options.compile is False
    assert dispatched == [0, 0]
    assert read_checkpoint(tmp_path / "a" / "checkpoints" / "last.ckpt")[
        compile_choice.CHOICE_KEY] is None
