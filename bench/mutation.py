"""Mutation run over the numeric core (issue 14, item 5): the share of wrong changes the tests catch.

Usage: ``.venv/bin/python -m bench.mutation [--per-module N] [--seed S] [--modules a,b]`` from the
checkout; writes ``bench/results/mutation.md``. Not part of ``bench.run_all`` (it runs the tests
once per mutant: about 20 minutes for the default 8 mutants per module).

For each module of :data:`TARGETS` the script lists every mutation site of its code (not of
docstrings, log calls, error messages or f-strings, whose changes no numeric test should see):

- a sign or operator flipped: ``+`` and ``-``, ``*`` and ``/``, ``**`` to ``*``, a unary minus dropped;
- a comparison turned around: ``<`` and ``>=``, ``>`` and ``<=``, ``==`` and ``!=``;
- a constant changed: an integer ``n`` to ``n + 1``, a float ``c`` to ``2 c`` (``0.0`` to ``1.0``);
- ``and`` and ``or``, ``True`` and ``False``.

It draws ``--per-module`` sites at random (seeded), writes each mutant into a copy of the tree
(``ast.unparse`` of the mutated syntax tree; the unmutated unparse is run first and must pass),
and runs the module's tests there (``pytest -x``). A mutant is killed when the tests fail or run
longer than three times the clean run plus 30 s (a mutant that hangs the filter). The copy keeps
the checkout untouched whatever happens.
"""

from __future__ import annotations

import argparse
import ast
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
OUT = HERE / "results" / "mutation.md"

# module -> the tests that should catch a wrong change in it (fast ones: no session campaign)
TARGETS = {
    "sindy_ekf/estimation/ekf.py": ["tests/sindy_ekf/estimation/test_ekf.py",
                                    "tests/sindy_ekf/estimation/test_measurements.py",
                                    "tests/sindy_ekf/estimation/test_ekf_lateral.py"],
    "sindy_ekf/estimation/graph.py": ["tests/sindy_ekf/estimation/test_graph.py",
                                      "tests/sindy_ekf/estimation/test_measurements.py"],
    "sindy_ekf/estimation/process_models.py": ["tests/sindy_ekf/estimation/test_process_models.py"],
    "identification/sindy/evaluate.py": ["tests/identification/sindy/test_evaluate_by_hand.py",
                                         "tests/identification/sindy/test_evaluate.py"],
    "identification/sindy/regression.py": ["tests/identification/sindy/test_sindy.py"],
    "identification/preprocessing/clock_sync.py": ["tests/identification/preprocessing/test_sync.py"],
    "sindy_ekf/diagnose/rank.py": ["tests/sindy_ekf/diagnose/test_rank_order.py"],
    "sindy_ekf/benchmark/health.py": ["tests/sindy_ekf/benchmark/test_health.py"],
}
SWAP_BIN = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult, ast.Pow: ast.Mult}
SWAP_CMP = {ast.Lt: ast.GtE, ast.GtE: ast.Lt, ast.Gt: ast.LtE, ast.LtE: ast.Gt, ast.Eq: ast.NotEq,
            ast.NotEq: ast.Eq}
QUIET_CALLS = {"log", "logging", "warnings"}  # log.warning(...), warnings.warn(...): messages only


@dataclass(frozen=True)
class Site:
    """One mutation: the node's index in a walk of the tree, what changes and where."""

    index: int
    line: int
    what: str


def _silent_nodes(tree: ast.AST) -> set[int]:
    """Return ids of nodes whose mutation no test should see: docstrings, f-strings, messages."""
    skip: set[int] = set()

    def mark(node):
        skip.update(id(n) for n in ast.walk(node))

    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                mark(body[0])
        if isinstance(node, ast.JoinedStr) or isinstance(node, ast.Raise):
            mark(node)
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and isinstance(node.func.value, ast.Name) and node.func.value.id in QUIET_CALLS):
            mark(node)
        if isinstance(node, (ast.arg, ast.AnnAssign)) and getattr(node, "annotation", None) is not None:
            mark(node.annotation)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.returns is not None:
            mark(node.returns)
    return skip


def _describe(node: ast.AST) -> str | None:
    """Return what the mutation of ``node`` does, or None if it is no mutation site."""
    if isinstance(node, ast.BinOp) and type(node.op) in SWAP_BIN:
        return f"{type(node.op).__name__} -> {SWAP_BIN[type(node.op)].__name__}"
    if isinstance(node, ast.Compare) and len(node.ops) == 1 and type(node.ops[0]) in SWAP_CMP:
        return f"{type(node.ops[0]).__name__} -> {SWAP_CMP[type(node.ops[0])].__name__}"
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return "unary minus dropped"
    if isinstance(node, ast.BoolOp):
        return "and <-> or"
    if isinstance(node, ast.Constant) and isinstance(node.value, bool):
        return f"{node.value} -> {not node.value}"
    if isinstance(node, ast.Constant) and isinstance(node.value, int):
        return f"{node.value} -> {node.value + 1}"
    if isinstance(node, ast.Constant) and isinstance(node.value, float):
        return f"{node.value!r} -> {2 * node.value if node.value else 1.0!r}"
    return None


def sites(source: str) -> list[Site]:
    """Return every mutation site of a module's source (module docstring)."""
    tree = ast.parse(source)
    skip = _silent_nodes(tree)
    out = []
    for i, node in enumerate(ast.walk(tree)):
        what = None if id(node) in skip else _describe(node)
        if what is not None:
            out.append(Site(i, getattr(node, "lineno", 0), what))
    return out


class _Mutate(ast.NodeTransformer):
    """Apply the mutation at walk index ``target`` (indices of the unmutated tree)."""

    def __init__(self, target_node: ast.AST):
        self.target = target_node

    def visit(self, node):
        if node is not self.target:
            return self.generic_visit(node)
        if isinstance(node, ast.BinOp):
            node.op = SWAP_BIN[type(node.op)]()
        elif isinstance(node, ast.Compare):
            node.ops = [SWAP_CMP[type(node.ops[0])]()]
        elif isinstance(node, ast.UnaryOp):
            return node.operand
        elif isinstance(node, ast.BoolOp):
            node.op = ast.Or() if isinstance(node.op, ast.And) else ast.And()
        elif isinstance(node.value, bool):
            node.value = not node.value
        elif isinstance(node.value, int):
            node.value += 1
        else:
            node.value = 2 * node.value if node.value else 1.0
        return node


def mutant(source: str, site: Site | None) -> str:
    """Return the module's source with ``site`` mutated (None: unparsed unmutated, the control)."""
    tree = ast.parse(source)
    if site is not None:
        target = list(ast.walk(tree))[site.index]
        tree = _Mutate(target).visit(tree)
        ast.fix_missing_locations(tree)
    return ast.unparse(tree) + "\n"


def run_tests(work: Path, tests: list[str], timeout_s: float) -> tuple[bool, float]:
    """Return whether the tests pass in ``work`` and how long they took (a timeout fails them)."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "PYTHONPATH": str(work)}
    t0 = time.perf_counter()
    try:
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *tests],
                              cwd=work, env=env, capture_output=True, text=True, timeout=timeout_s)
        ok = done.returncode == 0
    except subprocess.TimeoutExpired:
        ok = False
    return ok, time.perf_counter() - t0


def copy_tree(dst: Path) -> None:
    """Copy the packages, tests and configuration into ``dst`` (no .git, no caches)."""
    for name in ("groundfloor", "simulation", "identification", "sindy_ekf", "tests"):
        shutil.copytree(REPO / name, dst / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    # the tests read recorded results (bench/results/diagnose_raw.json: the rank thresholds)
    shutil.copytree(REPO / "bench" / "results", dst / "bench" / "results")
    for name in ("pyproject.toml", "conftest.py"):
        if (REPO / name).exists():
            shutil.copy2(REPO / name, dst / name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-module", type=int, default=8, help="mutants drawn per module (default 8)")
    ap.add_argument("--seed", type=int, default=14, help="seed of the draw (default 14)")
    ap.add_argument("--modules", default=None, help="comma-separated subset of the modules (paths)")
    args = ap.parse_args(argv)
    targets = {m: t for m, t in TARGETS.items() if args.modules is None or m in args.modules.split(",")}
    rows, survivors, total_killed, total_run = [], [], 0, 0
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="mutation_") as tmp:
        work = Path(tmp)
        copy_tree(work)
        for module, tests in targets.items():
            source = (REPO / module).read_text()
            all_sites = sites(source)
            rng = random.Random(f"{args.seed}:{module}")  # the same draw whichever modules run
            drawn = sorted(rng.sample(all_sites, min(args.per_module, len(all_sites))), key=lambda s: s.line)
            (work / module).write_text(mutant(source, None))
            ok, clean_s = run_tests(work, tests, 900)
            if not ok:
                rows.append((module, len(all_sites), 0, 0, f"control run failed ({clean_s:.0f} s): skipped"))
                (work / module).write_text(source)
                continue
            killed = 0
            for site in drawn:
                (work / module).write_text(mutant(source, site))
                passed, secs = run_tests(work, tests, 3 * clean_s + 30)
                print(f"{module}:{site.line} {site.what}: {'survived' if passed else 'killed'} ({secs:.0f} s)",
                      flush=True)
                if passed:
                    survivors.append((module, site))
                else:
                    killed += 1
            (work / module).write_text(source)
            total_killed += killed
            total_run += len(drawn)
            rows.append((module, len(all_sites), len(drawn), killed, f"{clean_s:.0f} s clean"))
    minutes = (time.perf_counter() - t_start) / 60
    share = total_killed / max(total_run, 1)
    lines = ["## mutation: the share of wrong changes the tests catch (issue 14, item 5)", "",
             f"Command: `.venv/bin/python -m bench.mutation --per-module {args.per_module} --seed {args.seed}"
             + (f" --modules {args.modules}" if args.modules else "") + f"` ({minutes:.0f} min on the shared 2 cores)",
             "", f"**{total_killed} of {total_run} mutants killed: {100 * share:.0f} %** (target >= 90 %). "
             "Operators: sign/operator flips, comparisons turned around, constants changed, and/or, "
             "True/False; docstrings, log calls, error messages and f-strings excluded (bench/mutation.py).",
             "", "| module | mutation sites | drawn | killed | tests run |", "|---|---|---|---|---|"]
    for module, n_sites, n_drawn, n_killed, note in rows:
        tests = ", ".join(Path(t).name for t in targets[module])
        lines.append(f"| `{module}` | {n_sites} | {n_drawn} | {n_killed} | {tests} ({note}) |")
    lines += ["", "Surviving mutants (each a change the tests listed do not see):", ""]
    lines += [f"- `{m}` line {s.line}: {s.what}" for m, s in survivors] or ["- none"]
    OUT.write_text("\n".join(lines) + "\n")
    print(f"{total_killed}/{total_run} killed ({100 * share:.0f} %); written {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
