"""Every code block of the README and the documentation site (docs/**/*.md) runs.

- Every fenced block names its language (```python, ```bash, ```text, ```yaml, ```json, ```toml).
- ```python blocks run in this interpreter (default suite), each in a fresh namespace.
- ```bash blocks run in ``bash -euo pipefail`` with ``deeplens`` and ``python`` on PATH meaning
  this interpreter and this checkout; they start processes, so they are ``slow`` tests.
- ```yaml / ```json blocks must parse.
- A python or bash block that cannot run in a test (a training of minutes, an install, the test
  suite itself) starts with the visible comment ``# not run by the docs test: <reason>`` and is
  not collected; ``test_skipped_blocks_say_why`` checks every such marker gives a reason.

Blocks run from a scratch folder that links the checkout's top-level folders (``data``,
``tests``, ``configs``, ...), so relative paths of the docs work and outputs stay out of the
checkout.

As a user with the wheel (``slow``, ``test_block_runs_from_the_installed_wheel``): every python
and bash block runs again from an empty folder with only the installed wheel on the path (no
checkout on ``sys.path``, no linked folders), so a snippet that reads ``data/lenses/...`` or
``tests/...`` fails there.  A block that needs the checkout itself (``python train.py``,
``bash dev.sh``, the benchmarks) starts with ``# needs the checkout: <reason>`` and is run only
by the checkout tests.
"""

from __future__ import annotations

import json
import os
import re
import stat
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
LANGUAGES = {"python", "bash", "text", "yaml", "json", "toml"}
SKIP = re.compile(r"^#\s*not run by the docs test:\s*(.*)$")
CHECKOUT = re.compile(r"^#\s*needs the checkout:\s*(.*)$", re.MULTILINE)
FENCE = re.compile(r"^(\s*)(`{3,})\s*([\w+-]*)\s*$")


@dataclass
class Block:
    path: Path
    line: int       # 1-based line of the opening fence
    lang: str
    code: str

    @property
    def id(self) -> str:
        return f"{self.path.relative_to(REPO)}:{self.line}"

    @property
    def skip_reason(self) -> str | None:
        first = self.code.lstrip("\n").split("\n", 1)[0].strip()
        m = SKIP.match(first)
        return None if m is None else m.group(1).strip()

    @property
    def checkout_reason(self) -> str | None:
        m = CHECKOUT.search(self.code)
        return None if m is None else m.group(1).strip()


def blocks(path: Path) -> list[Block]:
    """The fenced code blocks of a markdown file (indented fences in lists included)."""
    out, lines, i = [], path.read_text().split("\n"), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        indent, ticks, lang = len(m.group(1)), m.group(2), m.group(3)
        body, j = [], i + 1
        while j < len(lines) and not re.match(rf"^\s*{ticks}\s*$", lines[j]):
            body.append(lines[j][indent:] if lines[j][:indent].strip() == "" else lines[j])
            j += 1
        if j == len(lines):
            raise AssertionError(f"{path.relative_to(REPO)}:{i + 1}: unclosed code fence")
        out.append(Block(path, i + 1, lang, "\n".join(body) + "\n"))
        i = j + 1
    return out


ALL = [b for p in DOCS for b in blocks(p)]
RUN = [b for b in ALL if b.lang in ("python", "bash") and b.skip_reason is None]


def test_the_docs_have_runnable_blocks():
    """The collection itself works: the README's quick start is among the python blocks."""
    assert any(b.path.name == "README.md" and b.lang == "python" for b in RUN)
    assert any(b.lang == "bash" for b in RUN)


def test_every_code_block_names_its_language():
    bad = [f"{b.id} ({b.lang or 'no language'})" for b in ALL if b.lang not in LANGUAGES]
    assert not bad, f"tag these fences with one of {sorted(LANGUAGES)}: {bad}"


def test_skipped_blocks_say_why():
    skipped = [b for b in ALL if b.skip_reason is not None]
    assert all(b.lang in ("python", "bash") for b in skipped), [b.id for b in skipped]
    assert all(len(b.skip_reason) >= 10 for b in skipped), \
        [b.id for b in skipped if len(b.skip_reason) < 10]


@pytest.mark.parametrize("block", [b for b in ALL if b.lang in ("yaml", "json")],
                         ids=lambda b: b.id)
def test_data_block_parses(block):
    if block.lang == "json":
        json.loads(block.code)
    else:
        import yaml

        yaml.safe_load(block.code)


@pytest.fixture
def scratch(tmp_path, monkeypatch):
    """A folder outside the checkout that links its top-level entries; the cwd of a block."""
    for entry in REPO.iterdir():
        if entry.name not in (".git", ".venv", "outputs", "site") and \
                not entry.name.startswith("."):
            (tmp_path / entry.name).symlink_to(entry)
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("block", [b for b in RUN if b.lang == "python"], ids=lambda b: b.id)
def test_python_block_runs(block, scratch):
    code = compile(block.code, block.id, "exec")
    exec(code, {"__name__": "__docs_example__"})


def _shims(folder: Path) -> dict:
    """PATH with ``deeplens`` and ``python`` meaning this interpreter and this checkout."""
    folder.mkdir()
    for name, line in (("deeplens", f'exec "{sys.executable}" -m deeplens "$@"'),
                       ("python", f'exec "{sys.executable}" "$@"')):
        p = folder / name
        p.write_text(f"#!/usr/bin/env bash\n{line}\n")
        p.chmod(p.stat().st_mode | stat.S_IXUSR)
    env = {k: v for k, v in os.environ.items() if k != "DEEPLENS_DATA_DIR"}
    env.update(PATH=f"{folder}{os.pathsep}{env.get('PATH', '')}", PYTHONPATH=str(REPO),
               OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    return env


@pytest.mark.slow
@pytest.mark.parametrize("block", [b for b in RUN if b.lang == "bash"], ids=lambda b: b.id)
def test_bash_block_runs(block, scratch):
    env = _shims(scratch / ".shims")
    r = subprocess.run(["bash", "-euo", "pipefail", "-c", block.code], cwd=scratch, env=env,
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, f"{block.id}:\n{block.code}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"


@pytest.fixture(scope="session")
def wheel_venv(tmp_path_factory):
    """A venv with the wheel built from this checkout (tests/test_packaging.py's helpers)."""
    from test_packaging import _venv_with_wheel, build_wheel

    root = tmp_path_factory.mktemp("docs-wheel")
    return _venv_with_wheel(root, build_wheel(root / "dist"))


@pytest.mark.slow
@pytest.mark.parametrize("block", [b for b in RUN if b.checkout_reason is None],
                         ids=lambda b: b.id)
def test_block_runs_from_the_installed_wheel(block, wheel_venv, tmp_path):
    """The block as a user with the wheel runs it: an empty folder, the venv's ``deeplens`` and
    ``python`` first on PATH, nothing of the checkout importable."""
    work = tmp_path / "user"
    work.mkdir()
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "DEEPLENS_DATA_DIR", "VIRTUAL_ENV")}
    env.update(PATH=f"{wheel_venv / 'bin'}{os.pathsep}{env.get('PATH', '')}",
               OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    if block.lang == "python":
        script = work / "block.py"
        script.write_text(block.code)
        cmd = [str(wheel_venv / "bin" / "python"), str(script)]
    else:
        cmd = ["bash", "-euo", "pipefail", "-c", block.code]
    r = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, f"{block.id}:\n{block.code}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"


def test_checkout_markers_say_why():
    marked = [b for b in RUN if b.checkout_reason is not None]
    assert all(len(b.checkout_reason) >= 10 for b in marked), \
        [b.id for b in marked if len(b.checkout_reason) < 10]
