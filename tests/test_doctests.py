"""The ``>>>`` examples of the package's docstrings run (issue 39), so that an example that no
longer works fails a test instead of misleading a reader.

Every module whose source holds ``>>>`` is imported and its examples are run with
:mod:`doctest` (``ELLIPSIS`` and ``NORMALIZE_WHITESPACE``); an example marked
``# doctest: +SKIP`` is not run (the precheck's: it composes the Hydra config, ~2 s).
:data:`NOT_RUN` lists the modules whose examples are not run yet, with the reason.
"""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "deeplens"

#: modules whose examples are not run, with why (the lead clears an entry once its file is
#: free: deeplens/optics is being reworked on another branch this session)
NOT_RUN: dict[str, str] = {}


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules_with_examples() -> list[str]:
    return sorted(_module(p) for p in PACKAGE.rglob("*.py")
                  if ">>>" in p.read_text(encoding="utf-8"))


def test_every_listed_module_still_has_examples():
    assert set(NOT_RUN) <= set(modules_with_examples())
    assert len(modules_with_examples()) >= 10


@pytest.mark.parametrize("name", [m for m in modules_with_examples() if m not in NOT_RUN])
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in doctest.DocTestFinder().find(module, name):
        if test.examples:
            runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"
