"""The first day of a user (issue 35): a missing extra, a typo, a missing lens, ``--cfg job``,
the shipped lens names, the render summary: each is one clear line, checked before any work.
In-process (``deeplens.cli.main``) except where a separate interpreter is the point."""

import sys

import helpers as H
import pytest

run = H.run_cli


@pytest.fixture
def no_tracing(monkeypatch):
    """Fail the test if a lens file is loaded (the extra must be checked before any work)."""
    import deeplens.optics.io as io

    def boom(*a, **k):
        raise AssertionError("a lens was loaded before the extra was checked")

    monkeypatch.setattr(io, "load_lens", boom)


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_plot_without_matplotlib_names_the_plot_extra_before_tracing(monkeypatch, capsys,
                                                                     tmp_path, no_tracing):
    monkeypatch.setitem(sys.modules, "matplotlib", None)    # as if not installed
    out = tmp_path / "spot.png"
    code, _, err = run(["plot", "cooke_triplet", "--kind", "spot", "-o", str(out)], capsys)
    line = _one_line(err)
    assert code == 2 and not out.exists()
    assert "matplotlib" in line and 'pip install "deeplens-do[plot]"' in line


@pytest.mark.parametrize("cmd", ["train", "eval"])
def test_train_without_hydra_names_the_train_extra(monkeypatch, capsys, cmd):
    monkeypatch.setitem(sys.modules, "hydra", None)
    code, _, err = run([cmd, "experiment=doublet"], capsys)
    line = _one_line(err)
    assert code == 2
    assert line.startswith(f"deeplens {cmd}: error:") and "hydra" in line
    assert 'pip install "deeplens-do[train]"' in line


def test_train_py_entry_without_lightning_names_the_train_extra(monkeypatch, capsys):
    from deeplens.evaluation.entry import run as entry_run

    monkeypatch.setitem(sys.modules, "lightning", None)
    with pytest.raises(SystemExit) as e:
        entry_run("train", ["experiment=doublet"], prog="train.py")
    assert e.value.code == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("train.py: error:") and "lightning" in line and "[train]" in line


def test_design_without_matplotlib_writes_nothing_and_says_so(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    out = tmp_path / "sens"
    code, stdout, err = run(["design", "sensitivity", "--out", str(out)], capsys)
    line = _one_line(err)
    assert code == 2 and not out.exists() and "figures in" not in stdout
    assert 'pip install "deeplens-do[plot]"' in line


def test_tolerance_needs_matplotlib_only_for_its_figure(monkeypatch, capsys, tmp_path,
                                                        no_tracing):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    code, _, err = run(["tolerance", "cooke_triplet", "--monte-carlo", "2",
                        "--out", str(tmp_path / "t")], capsys)
    assert code == 2 and "[plot]" in _one_line(err)


def test_render_without_pillow_names_the_plot_extra(monkeypatch, capsys, tmp_path, no_tracing):
    monkeypatch.setitem(sys.modules, "PIL", None)
    code, _, err = run(["render", "cooke_triplet", str(tmp_path / "a.png"), "--depth", "2000",
                        "-o", str(tmp_path / "b.png")], capsys)
    line = _one_line(err)
    assert code == 2 and "PIL" in line and "[plot]" in line


@pytest.fixture
def clean_hydra():
    """Hydra's global state cleared, and the root logger's handlers (Hydra's run configures
    them onto this test's captured stderr) put back afterwards."""
    import logging

    from hydra.core.global_hydra import GlobalHydra

    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    GlobalHydra.instance().clear()
    yield
    GlobalHydra.instance().clear()
    root.handlers[:] = handlers
    root.setLevel(level)


@pytest.mark.parametrize("kind", ["train", "eval"])
def test_cfg_job_after_overrides_prints_the_composed_config(kind, capsys, clean_hydra):
    """``deeplens train experiment=doublet --cfg job``: the first thing a Hydra user types."""
    from deeplens.evaluation.entry import run as entry_run

    entry_run(kind, ["experiment=doublet", "trainer.max_epochs=3", "--cfg", "job"])
    out = capsys.readouterr().out
    assert f"task_name: {'doublet' if kind == 'train' else 'eval'}" in out
    assert "max_epochs: 3" in out
    assert "wide_doublet.json" in out


def test_cfg_hydra_names_the_job_after_the_command(capsys, clean_hydra):
    from deeplens.evaluation.entry import run as entry_run

    entry_run("eval", ["experiment=doublet", "--cfg", "hydra"])
    out = capsys.readouterr().out
    job = out[out.index("\n  job:\n"):]
    assert job.split("\n")[2].strip() == "name: eval"


def test_info_after_overrides_works(capsys, clean_hydra):
    from deeplens.evaluation.entry import run as entry_run

    entry_run("train", ["experiment=doublet", "--info", "defaults"])
    out = capsys.readouterr().out
    assert "experiment/doublet" in out


@pytest.mark.parametrize("argv, expected", [
    (["trainer.max_epoch=3"], "did you mean trainer.max_epochs"),
    (["experiment=doublet", "model.net_lrr=1"], "did you mean model.net_lr"),
    (["-m", "seeed=0,1"], "did you mean seed"),                  # a swept key
])
def test_config_typo_suggests_the_key_before_any_folder(argv, expected, capsys, monkeypatch,
                                                        tmp_path, clean_hydra):
    from deeplens.evaluation.entry import run as entry_run

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        entry_run("train", argv)
    line = _one_line(capsys.readouterr().err)
    assert e.value.code == 2 and expected in line and "To append" not in line
    bad = next(a for a in argv if a.split("=")[0] in line).split("=")[0]
    assert f"+{bad}=VALUE" in line                          # how to add a key on purpose
    assert list(tmp_path.iterdir()) == []                   # no output folder


def test_missing_lens_is_one_line_before_any_folder(capsys, monkeypatch, tmp_path, clean_hydra):
    from deeplens.evaluation.entry import run as entry_run

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        entry_run("eval", ["experiment=doublet", "lens.path=my_lens.zmx"])
    line = _one_line(capsys.readouterr().err)
    assert e.value.code == 2
    assert line.startswith("deeplens eval: error: lens.path: no lens file my_lens.zmx")
    assert "cooke_triplet" in line                          # the shipped names
    assert list(tmp_path.iterdir()) == []


def test_suggest_keys_prefers_the_same_parent():
    from deeplens.training.precheck import suggest_keys

    keys = ["trainer", "trainer.max_epochs", "trainer.max_steps", "data.max_epochs", "seed"]
    assert suggest_keys("trainer.max_epoch", keys)[0] == "trainer.max_epochs"
    assert suggest_keys("sed", keys) == ["seed"]
    assert suggest_keys("zzz.qqq", keys) == []


@pytest.mark.parametrize("cmd, func", [("report", "_report"), ("plot", "_plot"),
                                       ("optimize", "_optimize"), ("tolerance", "_tolerance")])
def test_one_default_sampling_shown_in_help(cmd, func, capsys, monkeypatch):
    """report, plot, optimize and tolerance sample the pupil alike by default (one lens, one
    on-axis RMS), and their --help says so."""
    import deeplens.cli as cli
    from deeplens.optics.sampling import DEFAULT_SAMPLING

    code, out, _ = run([cmd, "-h"], capsys)
    assert code == 0
    assert f"(default {DEFAULT_SAMPLING}" in " ".join(out.split())
    seen = {}
    monkeypatch.setattr(cli, func, lambda args: seen.setdefault("s", args.sampling) and 0)
    extra = {"plot": ["--kind", "spot", "-o", "x.png"], "optimize": ["--vary", "x",
                                                                    "--out", "x.json"]}
    run([cmd, "cooke_triplet", *extra.get(cmd, [])], capsys)
    assert seen["s"] == DEFAULT_SAMPLING


def _blur(out: str) -> float:
    import re

    return float(re.search(r"RMS spot diameter ([0-9.e+]+) um", out).group(1))


def test_render_focuses_at_the_object_and_says_what_it_did(capsys, tmp_path):
    import numpy as np
    from PIL import Image

    src = tmp_path / "photo.png"
    Image.fromarray(np.full((12, 16, 3), 100, dtype=np.uint8)).save(src)
    base = ["render", "cooke_triplet", str(src), "--depth", "2000", "--spp", "1",
            "-o", str(tmp_path / "out.png")]
    code, out, err = run(base, capsys)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == str(tmp_path / "out.png")
    # 16 x 12 pixels on the file's 21.5 mm semi-diagonal: 43 mm / 20 px = 2.15 mm
    assert "16 x 12 pixels" in out and "pixel pitch 2150 um" in out
    assert "focus: at 2000 mm (the object depth" in out
    sharp = _blur(out)
    code, out, err = run(base + ["--focus", "file"], capsys)
    assert code == 0 and "as in the lens file" in out
    blurred = _blur(out)
    # the triplet's file focuses far away; at 2 m, ~f^2/u = 5 mm of defocus at F/3.5: ~1 mm
    assert blurred > 20 * sharp and 500 < blurred < 2000
    code, _, err = run(base + ["--focus", "near"], capsys)
    assert code == 2 and "--focus must be depth, file, inf or a distance" in err


def test_lenses_lists_every_shipped_lens_with_its_numbers(capsys):
    import json
    from pathlib import Path

    from deeplens.optics.paraxial import paraxial
    from deeplens.optics.io import load_lens

    code, out, err = run(["lenses", "--json"], capsys)
    assert code == 0, err
    rows = {r["name"]: r for r in json.loads(out)}
    shipped = Path(__file__).resolve().parents[1] / "data" / "lenses"
    assert set(rows) == {p.stem for p in shipped.glob("*.json")}
    p = paraxial(load_lens("cooke_triplet").double())
    assert rows["cooke_triplet"]["efl_mm"] == pytest.approx(float(p.efl), rel=1e-12)
    assert rows["cooke_triplet"]["fno"] == pytest.approx(float(p.fno), rel=1e-12)
    # elements: the triplet's three singlets, the cemented doublet's two glasses, the
    # double Gauss's six (two cemented pairs and two singlets)
    assert [rows[n]["elements"] for n in ("cooke_triplet", "wide_doublet", "double_gauss",
                                          "thorlabs_la1131")] == [3, 2, 6, 1]
    code, table, _ = run(["lenses"], capsys)
    assert code == 0 and len(table.splitlines()) == len(rows) + 2
    assert "101.18" in table.splitlines()[1 + sorted(rows).index("cooke_triplet")]


def test_help_names_the_shipped_lenses(capsys):
    code, out, _ = run(["-h"], capsys)
    flat = " ".join(out.split())
    assert code == 0 and "cooke_triplet, double_gauss" in flat and "deeplens lenses" in flat
    code, out, _ = run(["report", "-h"], capsys)
    assert "wide_doublet" in out


def test_readme_extras_table_matches_pyproject():
    """Every distribution of an extra in pyproject.toml is named in that extra's README row."""
    import re
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    text = (root / "README.md").read_text()
    table = text[text.index("| extra |"):].split("\n\n")[0].splitlines()[2:]
    rows = {}
    for line in table:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        rows[cells[0].split("`")[1] if "`" in cells[0] else ""] = cells[1]

    def names(specs):
        return [re.split(r"[<>=\[ ;]", s, maxsplit=1)[0].lower() for s in specs]

    extras = {"": names(project["dependencies"]),
              **{k: names(v) for k, v in project["optional-dependencies"].items()}}
    assert set(rows) == set(extras) - {"design"}, rows.keys()
    for extra, dists in extras.items():
        if extra == "design":
            continue
        for d in dists:
            if d == "deeplens-do":      # an extra that includes others names them in backticks
                continue
            assert re.search(rf"(?<![\w-]){re.escape(d)}(?![\w-])", rows[extra].lower()), \
                (extra, d, rows[extra])


def test_cli_hides_torchs_own_deprecation_but_not_other_warnings(monkeypatch, capsys):
    import warnings

    import deeplens.cli as cli

    def noisy(args):
        warnings.warn("`torch.jit.script` is deprecated. Please switch to `torch.compile`",
                      FutureWarning)
        warnings.warn("something about the user's lens")
        return 0

    monkeypatch.setattr(cli, "_report", noisy)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        assert run(["report", "cooke_triplet"], capsys)[0] == 0
    assert [str(w.message) for w in got] == ["something about the user's lens"]
