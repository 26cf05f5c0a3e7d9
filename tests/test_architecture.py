"""The tree tells the pipeline: imports flow one way, modules stay small, plots stay apart.

Parses every module of the four packages with :mod:`ast` (nothing is imported), so a later change
cannot break the rules of ``docs/ARCHITECTURE.md`` silently:

- ``groundfloor`` imports nothing of the project;
- ``simulation`` and ``identification`` import only ``groundfloor`` (never ``sindy_ekf``, never
  each other);
- inside ``identification``, ``sindy`` reaches ``preprocessing`` only through
  :mod:`identification.sindy.data` (the one meeting point), and ``preprocessing`` never imports
  ``sindy``;
- no import cycle between modules;
- no module over 450 lines;
- matplotlib only in plot modules (``figures.py`` or a ``figures`` package), ``matplotlib.use``
  only in the command line and the report;
- project imports at the top of modules (an import inside a function hides a dependency),
  except a plot module imported where figures are asked for.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.support import REPO

PACKAGES = ("groundfloor", "simulation", "identification", "sindy_ekf")
MAX_LINES = 450
MEETING_POINT = "identification.sindy.data"
BACKEND_CHOOSERS = {"sindy_ekf.cli"}  # the command line picks the backend before a command runs


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            rel = path.relative_to(REPO).with_suffix("")
            parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> list[tuple[str, ast.AST, bool]]:
    """Return ``(imported module, node, at top level)`` of every import in the module."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    top_level = {id(n) for n in tree.body}
    for node in tree.body:  # imports under a top-level `if TYPE_CHECKING:` or try count as top
        if isinstance(node, (ast.If, ast.Try)):
            top_level |= {id(n) for n in ast.walk(node)}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node, id(node) in top_level) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((mod, node, id(node) in top_level))
            # `from pkg import module` imports the module too
            for a in node.names:
                sub = f"{mod}.{a.name}"
                if sub in MODULES:
                    out.append((sub, node, id(node) in top_level))
    return out


def _project(mod: str) -> str | None:
    """Return the project module ``mod`` names (longest known prefix), or None if external."""
    parts = mod.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in MODULES:
            return cand
    return None


GRAPH = {name: {p for m, _, _ in _imports(name, path) if (p := _project(m)) and p != name}
         for name, path in MODULES.items()}


def _top(name: str) -> str:
    return name.split(".")[0]


def test_every_package_is_parsed():
    assert {_top(m) for m in MODULES} == set(PACKAGES)
    assert MEETING_POINT in MODULES


@pytest.mark.parametrize("pkg, allowed", [("groundfloor", {"groundfloor"}),
                                          ("simulation", {"groundfloor", "simulation"}),
                                          ("identification", {"groundfloor", "identification"})])
def test_imports_flow_one_way(pkg, allowed):
    bad = sorted(f"{a} imports {b}" for a, deps in GRAPH.items() if _top(a) == pkg
                 for b in deps if _top(b) not in allowed)
    assert not bad, "\n".join(bad)


def test_sindy_reaches_preprocessing_only_through_its_meeting_point():
    bad = sorted(f"{a} imports {b}" for a, deps in GRAPH.items()
                 for b in deps
                 if (a.startswith("identification.sindy") and b.startswith("identification.preprocessing")
                     and a != MEETING_POINT)
                 or (a.startswith("identification.preprocessing") and b.startswith("identification.sindy")))
    assert not bad, "\n".join(bad)


def test_no_import_cycle():
    # Tarjan's strongly connected components; a component of more than one module is a cycle
    index, low, stack, on, comps, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            comps.append(comp)

    for v in GRAPH:
        if v not in index:
            visit(v)
    cycles = [sorted(c) for c in comps if len(c) > 1]
    assert not cycles, cycles


def test_no_module_over_450_lines():
    long = {name: n for name, path in MODULES.items() if (n := len(path.read_text().splitlines())) > MAX_LINES}
    assert not long, long


def _is_plot_module(name: str) -> bool:
    parts = name.split(".")
    return parts[-1] == "figures" or "figures" in parts[:-1]


def test_matplotlib_only_in_plot_modules():
    bad = sorted(f"{name} imports {m}" for name, path in MODULES.items()
                 if not _is_plot_module(name) and name not in BACKEND_CHOOSERS
                 for m, _, _ in _imports(name, path) if _top(m) == "matplotlib")
    assert not bad, "\n".join(bad)


def test_backend_chosen_only_by_the_command_line_and_the_report():
    bad = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "use"
                    and isinstance(node.func.value, ast.Name) and node.func.value.id == "matplotlib"
                    and name not in BACKEND_CHOOSERS):
                bad.append(f"{name}:{node.lineno}")
    assert not bad, bad


def test_project_imports_at_the_top():
    # the one exception: a plot module imported where figures are asked for, so that numeric
    # work never loads matplotlib (an optional heavy dependency)
    bad = sorted(f"{name}:{node.lineno} imports {m} inside a function"
                 for name, path in MODULES.items()
                 for m, node, top in _imports(name, path)
                 if not top and (p := _project(m)) and not _is_plot_module(p))
    assert not bad, "\n".join(bad)
