"""The optics layer's imports (issue 24): ``deeplens/optics`` sits at the bottom of the package.

It never imports the rooms above it (render, analysis, design, training, nets, data, the CLI)
nor Lightning or Hydra, at module level or inside a function, and its modules import each other
without a cycle (a cycle, even through a function-local import, is a sign that a concept sits in
the wrong module: the Zemax reader and the lens-file writer used to import each other).  The
imports are read from the source (``ast``), so the test needs no import of the package.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
OPTICS = ROOT / "deeplens" / "optics"
ABOVE = ("deeplens.render", "deeplens.analysis", "deeplens.design", "deeplens.training",
         "deeplens.nets", "deeplens.data", "deeplens.cli")
FORBIDDEN_LIBS = ("lightning", "pytorch_lightning", "hydra", "omegaconf")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(path: Path) -> list[tuple[int, str]]:
    """``(line, absolute module)`` of every import in ``path`` (module level and local); for
    ``from X import name`` both ``X`` and ``X.name`` (``name`` may be a submodule)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((node.lineno, mod))
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names]
    return out


def optics_files():
    return sorted(OPTICS.rglob("*.py"))


def test_there_are_optics_modules_to_check():
    names = {module_name(p) for p in optics_files()}
    assert {"deeplens.optics.lens", "deeplens.optics.tracer", "deeplens.optics.io.zmx"} <= names


@pytest.mark.parametrize("path", optics_files(), ids=lambda p: str(p.relative_to(OPTICS)))
def test_optics_imports_nothing_above_it(path):
    bad = [(line, mod) for line, mod in imports_of(path)
           if any(mod == a or mod.startswith(a + ".") for a in ABOVE)
           or mod.split(".")[0] in FORBIDDEN_LIBS]
    assert not bad, (f"{path.relative_to(ROOT)} imports from above the optics layer: "
                     + ", ".join(f"line {ln}: {m}" for ln, m in bad))


def _graph():
    modules = {module_name(p): p for p in optics_files()}
    graph = {}
    for name, path in modules.items():
        graph[name] = sorted({m for _, m in imports_of(path) if m in modules and m != name})
    return graph


def find_cycle(graph):
    """One cycle of ``graph`` (a list of nodes, first repeated last), or ``None``.  A package
    importing its own submodules (``surfaces/__init__`` -> ``surfaces.asphere``) is not an edge
    back: a submodule importing its package's ``__init__`` is how Python loads it anyway."""
    state, stack = {}, []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for m in graph.get(n, ()):
            if n.startswith(m + "."):  # a submodule and its own package
                continue
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_optics_modules_import_each_other_without_a_cycle():
    cycle = find_cycle(_graph())
    assert cycle is None, "import cycle in deeplens.optics: " + " -> ".join(cycle)


def test_the_checks_catch_what_they_look_for(tmp_path):
    """Planted: an upward import inside a function, and a two-module cycle."""
    bad = OPTICS / "io" / "_planted_for_test.py"
    assert not bad.exists()
    src = "def f():\n    from ...analysis.spot import spot_diagram\n    import hydra\n"
    p = tmp_path / "deeplens" / "optics" / "io" / "x.py"
    p.parent.mkdir(parents=True)
    p.write_text(src)
    global ROOT
    saved = ROOT
    ROOT = tmp_path
    try:
        mods = [m for _, m in imports_of(p)]
    finally:
        ROOT = saved
    assert "deeplens.analysis.spot" in mods and "hydra" in mods
    assert find_cycle({"a.x": ["a.y"], "a.y": ["a.x"]}) == ["a.x", "a.y", "a.x"]
    assert find_cycle({"a": ["a.x"], "a.x": ["a"]}) is None  # package and its submodule
