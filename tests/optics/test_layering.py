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


# ---------------------------------------------------------------- the whole package (issue 39)
#: the floors of the package, bottom to top: a module imports only from its own package (the
#: first name under ``deeplens``) and from packages on lower floors, never from a floor above
#: nor from another subpackage of its own floor (analysis and render do not know each other).
#: ``deeplens`` itself and its plain modules (``resources``, ``build_info``, ``extras``) are the
#: ground floor; ``deeplens.cli`` and ``deeplens.__main__`` the top (plain modules of one floor
#: may import each other: ``__main__`` runs ``cli``).
FLOORS = (
    ("deeplens", "deeplens.resources", "deeplens.build_info", "deeplens.extras"),
    ("deeplens.optics",),
    ("deeplens.analysis", "deeplens.render"),
    ("deeplens.design",),
    ("deeplens.nets", "deeplens.data"),
    ("deeplens.training",),
    ("deeplens.evaluation",),
    ("deeplens.cli", "deeplens.__main__"),
)
PACKAGE = ROOT / "deeplens"


def package_files():
    return sorted(PACKAGE.rglob("*.py"))


def room_of(module: str) -> str:
    """The package of ``module`` in :data:`FLOORS` (``deeplens.optics.io.zmx`` ->
    ``deeplens.optics``; ``deeplens`` -> ``deeplens``); ``KeyError`` if the table lacks it."""
    parts = module.split(".")
    room = ".".join(parts[:2])
    if room not in {r for floor in FLOORS for r in floor}:
        raise KeyError(f"{module}: its package {room} has no floor in FLOORS")
    return room


def floor_of(module: str) -> int:
    room = room_of(module)
    return next(k for k, floor in enumerate(FLOORS) if room in floor)


def _resolve(name: str, modules) -> str | None:
    """The module of the package that an imported name lives in (``deeplens.optics.io.load``
    for ``deeplens.optics.io.load.load_lens``), or ``None`` outside the package."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def _is_subpackage(room: str) -> bool:
    return room != "deeplens" and (ROOT / Path(*room.split(".")) / "__init__.py").is_file()


def package_graph(files=None, root=None) -> dict[str, list[str]]:
    """``{module: [modules of the package it imports]}`` over every module (module-level and
    function-level imports)."""
    files = package_files() if files is None else files
    modules = {module_name(p): p for p in files}
    return {n: sorted({r for _, m in imports_of(p)
                       if (r := _resolve(m, modules)) and r != n})
            for n, p in modules.items()}


def wrong_way(graph) -> list[str]:
    """Every import of ``graph`` that goes up a floor or across to another package of the
    same floor, as ``"a -> b (floor i -> j)"``."""
    bad = []
    for a, targets in graph.items():
        for b in targets:
            ra, rb = room_of(a), room_of(b)
            if ra == rb:
                continue
            fa, fb = floor_of(a), floor_of(b)
            if fb > fa or (fb == fa and _is_subpackage(ra) and _is_subpackage(rb)):
                bad.append(f"{a} -> {b} (floor {fa} -> {fb})")
    return bad


def test_every_package_has_a_floor():
    for p in package_files():
        floor_of(module_name(p))       # KeyError names a package the table lacks
    assert {"deeplens.training.train", "deeplens.evaluation.evaluate", "deeplens.cli",
            "deeplens.design.lensopt"} <= set(package_graph())


def test_no_import_goes_up_a_floor_or_across():
    bad = wrong_way(package_graph())
    assert not bad, "imports against the floors (tests/optics/test_layering.py FLOORS):\n" + \
        "\n".join(bad)


def test_the_package_has_no_import_cycle():
    cycle = find_cycle(package_graph())
    assert cycle is None, "import cycle in deeplens: " + " -> ".join(cycle)


def test_the_floor_checks_catch_a_planted_upward_import_and_cycle(tmp_path):
    """Planted in a copy of the package: training importing the evaluation inside a function
    (upward; the evaluation imports that module, so it is a cycle too), two training modules
    importing each other (a cycle within one floor), render importing analysis (across one
    floor)."""
    global ROOT
    copy = tmp_path / "deeplens"
    for p in package_files():
        q = copy / p.relative_to(PACKAGE)
        q.parent.mkdir(parents=True, exist_ok=True)
        q.write_text(p.read_text(encoding="utf-8"), encoding="utf-8")
    saved = ROOT
    ROOT = tmp_path
    try:
        files = sorted(copy.rglob("*.py"))
        assert not wrong_way(package_graph(files)) and find_cycle(package_graph(files)) is None
        machine = copy / "training" / "machine.py"
        machine.write_text(machine.read_text() + "\n\ndef _f():\n"
                           "    from ..evaluation.evaluate import seeds\n    return seeds\n")
        bad = wrong_way(package_graph(files))
        assert bad == ["deeplens.training.machine -> deeplens.evaluation.evaluate (floor 5 -> 6)"]
        # evaluate imports machine: the upward import closes a cycle too
        cycle = find_cycle(package_graph(files))
        assert cycle is not None and {"deeplens.training.machine",
                                      "deeplens.evaluation.evaluate"} <= set(cycle)
        machine.write_text(machine.read_text().rpartition("\n\ndef _f():")[0])
        assert not wrong_way(package_graph(files)) and find_cycle(package_graph(files)) is None
        # a cycle inside one floor (no wrong-way edge): checkpoint <-> train
        ckpt = copy / "training" / "checkpoint.py"
        ckpt.write_text(ckpt.read_text() + "\n\ndef _g():\n    from .train import train\n"
                        "    return train\n")
        assert not wrong_way(package_graph(files))
        cycle = find_cycle(package_graph(files))
        assert cycle is not None and {"deeplens.training.checkpoint",
                                      "deeplens.training.train"} <= set(cycle)
        render = copy / "render" / "sensor.py"
        render.write_text(render.read_text() + "\nfrom ..analysis import spot  # noqa\n")
        assert "deeplens.render.sensor -> deeplens.analysis.spot (floor 2 -> 2)" in \
            wrong_way(package_graph(files))
    finally:
        ROOT = saved
