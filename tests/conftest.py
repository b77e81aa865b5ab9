"""Test-wide set-up: a fixed global torch seed, and ``--fail-on-skip`` (used by ``.ci/run``).

``tests/`` and the repository root are on ``sys.path`` through ``pythonpath`` in
``pyproject.toml`` (for ``import helpers`` and this checkout's ``deeplens``).

``--fail-on-skip``: the run fails when any test is skipped for a reason other than a missing
GPU/CUDA device (a skip whose reason names ``cuda`` or ``gpu``).  Every file a test reads ships
with the repository (``tests/data/``, ``data/``), so on a clean clone nothing may skip for a
missing file, a missing optional package or anything else; the offending tests are listed in
the summary.

``numerics``: the tests whose outcome depends on floating-point rounding (float32 against
float64, gradients against finite differences, intersections at grazing incidence) carry this
marker, given here by file so that a new test in those files has it too (a single test
elsewhere carries ``@pytest.mark.numerics`` itself).  ``.ci/run`` runs them
a second time under ``ATEN_CPU_CAPABILITY=default`` (PyTorch's scalar kernels), so that a
tolerance tuned to one CPU's vector unit fails in CI instead of on a user's machine.
"""

from __future__ import annotations

import re

import pytest
import torch

ALLOWED_SKIP = re.compile(r"\b(cuda|gpu)\b", re.IGNORECASE)

NUMERICS = ("optics/test_gradients.py", "optics/test_intersect.py", "optics/test_refract.py",
            "optics/test_normalized.py", "optics/test_mirrors.py", "optics/test_limits.py",
            "optics/surfaces/", "analysis/test_far_object.py", "render/test_fftconv.py",
            "render/test_float32_plate_gradient.py", "render/test_diffraction.py",
            "render/test_diffraction_pixel.py",
            "render/test_camera_paths.py", "training/test_wiener_numerics.py")


def pytest_configure(config):
    """Under pytest-xdist the controller re-creates each warning a worker reports by importing
    the module of its class (``xdist.workermanage.unserialize_warning_message``), in the thread
    that reads that worker.  Two workers reporting optiland's warnings at once (its
    ``OptilandMaterialWarning``, ``ParaxialDomainWarning``) then import optiland from two
    threads, and optiland's circular imports (materials <-> optimization) fail in one of them
    with "partially initialized module", taking the worker down.  Importing the oracle once here,
    before any worker runs, makes those later imports no-ops.  Only the controller of a
    distributed run does it; optiland is a test-only oracle and may be absent."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    try:
        import optiland.materials.warnings  # noqa: F401
        import optiland.paraxial_path  # noqa: F401
    except ImportError:
        pass


def pytest_collection_modifyitems(config, items):
    for item in items:
        rel = item.path.as_posix().split("/tests/", 1)[-1]
        if rel.startswith(NUMERICS):
            item.add_marker(pytest.mark.numerics)


def pytest_addoption(parser):
    parser.addoption("--fail-on-skip", action="store_true", default=False,
                     help="fail the run when a test is skipped for any reason other than a "
                          "missing GPU/CUDA device (CI: no skip for a missing file)")


def _skip_reason(report) -> str:
    lr = report.longrepr
    if isinstance(lr, tuple) and len(lr) == 3:  # (path, line, "Skipped: reason")
        return str(lr[2])
    return str(lr)


def disallowed_skips(config) -> list[tuple[str, str]]:
    """``(node id, reason)`` of every skip not caused by a missing GPU/CUDA device."""
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    if reporter is None:
        return []
    out = []
    for rep in reporter.stats.get("skipped", []):
        reason = _skip_reason(rep)
        if not ALLOWED_SKIP.search(reason):
            out.append((rep.nodeid, reason))
    return out


def pytest_sessionfinish(session, exitstatus):
    if session.config.getoption("--fail-on-skip") and disallowed_skips(session.config):
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if not config.getoption("--fail-on-skip"):
        return
    bad = disallowed_skips(config)
    if bad:
        terminalreporter.section("skips that fail the run (--fail-on-skip)", red=True)
        for nodeid, reason in bad:
            terminalreporter.line(f"{nodeid or '<collection>'}: {reason}")
        terminalreporter.line(f"{len(bad)} test(s) skipped for a reason other than a missing "
                              f"GPU/CUDA device: ship the file under tests/data/ or install the "
                              f"[dev] extra")


@pytest.fixture(autouse=True)
def _seed_torch():
    """Every test starts from the same global torch seed (tests also pass their own generators)."""
    torch.manual_seed(0)
    yield
