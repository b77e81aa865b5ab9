"""CI's guard against silent skips: ``--fail-on-skip`` (tests/conftest.py) fails the run on a
skip for a missing file (or anything but a missing GPU/CUDA device), and no test of this suite
reads outside the repository."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent


def test_fail_on_skip_fails_on_a_missing_file_but_not_on_a_missing_gpu(tmp_path):
    shutil.copy(TESTS / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "test_skips.py").write_text(
        "import pytest\n"
        "@pytest.mark.skipif(True, reason='no CUDA device')\n"
        "def test_gpu():\n    pass\n"
        "def test_needs_file():\n    pytest.skip('lens.txt not present')\n"
        "def test_runs():\n    pass\n")
    (tmp_path / "pytest.ini").write_text("[pytest]\n")  # not the repository's configuration
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-c",
           str(tmp_path / "pytest.ini"), str(tmp_path)]
    plain = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
    assert plain.returncode == 0, plain.stdout + plain.stderr
    strict = subprocess.run(cmd + ["--fail-on-skip"], cwd=tmp_path, capture_output=True,
                            text=True)
    assert strict.returncode == 1, strict.stdout + strict.stderr
    summary = strict.stdout.split("skips that fail the run")[1]
    assert "test_needs_file: Skipped: lens.txt not present" in summary
    assert "test_gpu" not in summary


def test_ci_runs_with_fail_on_skip():
    assert "--fail-on-skip" in (REPO / ".ci" / "run").read_text()


def test_no_test_reads_outside_the_repository():
    """No test names ../shared, an absolute /work path or the parent of the repository."""
    bad = re.compile(r"""(["']/work/|\.\./shared|parent\s*/\s*["']shared["']|ROOT\.parent|"""
                     r"""REPO\.parent)""")
    offenders = [f"{p.relative_to(REPO)}:{i}" for p in TESTS.rglob("*.py") if p != Path(__file__)
                 for i, line in enumerate(p.read_text().splitlines(), 1) if bad.search(line)]
    assert not offenders, offenders


def test_ci_reruns_the_rounding_sensitive_tests_on_the_scalar_kernels():
    """``.ci/run`` runs the ``numerics`` tests again under ``ATEN_CPU_CAPABILITY=default``, and
    every file or folder the marker is given by exists (a renamed file would silently drop out
    of the second run)."""
    import importlib.util

    # by path: several conftest modules exist, and whichever was imported first is `conftest`
    spec = importlib.util.spec_from_file_location("tests_root_conftest", TESTS / "conftest.py")
    root = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(root)
    NUMERICS = root.NUMERICS
    run = (REPO / ".ci" / "run").read_text()
    assert re.search(r"ATEN_CPU_CAPABILITY=default TORCHINDUCTOR_CACHE_DIR=\S+ .*\n.*"
                     r"-m \"numerics and not slow\"", run)
    missing = [p for p in NUMERICS if not (TESTS / p).exists()]
    assert not missing, missing
