"""Plots live apart from the numbers: only plot modules import matplotlib, and only the command
line and the report choose its backend.

A plot module is a file named ``figures.py`` or a module inside a ``figures/`` package (this
includes the shared helper :mod:`groundfloor.figures`). Every other module of the packages, the
examples and the benchmarks computes numbers only, so that importing it never loads matplotlib;
the exceptions are the modules that choose the backend, ``sindy_ekf/cli.py`` and the report
(``sindy_ekf/report/``), and no other module switches a notebook user's backend.
"""

from __future__ import annotations

import ast
from pathlib import Path

from tests.support import REPO

SOURCE_DIRS = ("groundfloor", "simulation", "identification", "sindy_ekf", "examples", "bench")
# the only places allowed to choose the backend: the command line (once, before a command runs)
# and the report builder, which renders figures without a display
BACKEND_CHOOSERS = ("sindy_ekf/cli.py", "sindy_ekf/report/")


def _modules() -> list[Path]:
    return sorted(p for d in SOURCE_DIRS for p in (REPO / d).rglob("*.py"))


def _rel(path: Path) -> str:
    return path.relative_to(REPO).as_posix()


def chooses_backend(path: Path) -> bool:
    """Return whether ``path`` may choose matplotlib's backend (and import matplotlib for it)."""
    rel = _rel(path)
    return any(rel == c or (c.endswith("/") and rel.startswith(c)) for c in BACKEND_CHOOSERS)


def is_plot_module(path: Path) -> bool:
    """Return whether ``path`` is a plot module: ``figures.py`` or inside a ``figures/`` package."""
    return path.name == "figures.py" or "figures" in path.relative_to(REPO).parts[:-1]


def matplotlib_imports(tree: ast.AST) -> list[int]:
    """Return the line numbers of every import of matplotlib (top level or local)."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        if any(n == "matplotlib" or n.startswith("matplotlib.") for n in names):
            lines.append(node.lineno)
    return lines


def backend_switches(tree: ast.AST) -> list[int]:
    """Return the line numbers of calls of ``matplotlib.use`` or ``pyplot.switch_backend``
    (under any name they were imported as)."""
    aliases = {"use": set(), "switch_backend": set()}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in ("matplotlib", "matplotlib.pyplot"):
            for a in node.names:
                if a.name in aliases:
                    aliases[a.name].add(a.asname or a.name)
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Attribute) and f.attr in ("use", "switch_backend") and \
                isinstance(f.value, ast.Name) and f.value.id in ("matplotlib", "mpl", "plt", "pyplot"):
            lines.append(node.lineno)
        elif isinstance(f, ast.Name) and any(f.id in names for names in aliases.values()):
            lines.append(node.lineno)
    return lines


def test_the_rule_sees_the_plot_modules_and_the_imports():
    """The checks below would catch what they are for (guards against a rule that sees nothing)."""
    plot_modules = {_rel(p) for p in _modules() if is_plot_module(p)}
    assert {"groundfloor/figures.py", "simulation/figures.py", "identification/preprocessing/figures.py",
            "identification/sindy/figures.py", "sindy_ekf/benchmark/figures.py",
            "sindy_ekf/diagnose/figures.py", "sindy_ekf/report/figures.py"} <= plot_modules
    assert matplotlib_imports(ast.parse("import matplotlib.pyplot as plt\nfrom matplotlib import cm\n"
                                        "def f():\n    from matplotlib.figure import Figure\n")) == [1, 2, 4]
    assert backend_switches(ast.parse("import matplotlib\nmatplotlib.use('Agg')\n"
                                      "from matplotlib import use as u\nu('Agg')\n")) == [2, 4]


def test_only_plot_modules_import_matplotlib():
    offenders = [f"{_rel(p)}:{line}" for p in _modules() if not (is_plot_module(p) or chooses_backend(p))
                 for line in matplotlib_imports(ast.parse(p.read_text(), str(p)))]
    assert not offenders, "matplotlib imported outside the plot modules (move the plot to a figures module): " \
        + ", ".join(offenders)


def test_only_the_command_line_and_the_report_choose_the_backend():
    offenders = [f"{_rel(p)}:{line}" for p in _modules() if not chooses_backend(p)
                 for line in backend_switches(ast.parse(p.read_text(), str(p)))]
    assert not offenders, "matplotlib backend chosen outside sindy_ekf/cli.py and sindy_ekf/report/: " \
        + ", ".join(offenders)
