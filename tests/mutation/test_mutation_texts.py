"""Every planted bug of ``run_mutations.py`` still applies to the code it names.

The runner replaces a mutation's ``old`` text by its ``new`` text in one file; when the code is
later rewritten and the text is gone, the runner can only report the mutation as not applied,
and nothing in the default suite notices.  This test does: each ``old`` text is in its file, the
replacement changes the file, the tests it runs exist, and the names are unique.
"""

from __future__ import annotations

import importlib.util
import sys
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _mutations():
    name = "deeplens_tests_run_mutations"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name(
            "run_mutations.py"))
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod   # dataclasses look the module up while the class is built
        spec.loader.exec_module(mod)
    return sys.modules[name].MUTATIONS


MUTATIONS = _mutations()


def test_names_are_unique():
    repeated = [n for n, k in Counter(m.name for m in MUTATIONS).items() if k > 1]
    assert not repeated, f"mutation names used more than once: {repeated}"


@pytest.mark.parametrize("m", MUTATIONS, ids=[m.name for m in MUTATIONS])
def test_mutation_still_applies(m):
    path = ROOT / m.file
    assert path.is_file(), f"{m.name}: {m.file} does not exist"
    text = path.read_text()
    assert m.old in text, (f"{m.name}: its text is no longer in {m.file} (the code was "
                           f"rewritten): update the mutation to the current code")
    assert text.replace(m.old, m.new) != text, f"{m.name}: the replacement changes nothing"
    for t in m.tests:
        assert (ROOT / t.split("::")[0]).exists(), f"{m.name}: test {t} does not exist"
