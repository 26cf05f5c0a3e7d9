"""Mutation run over the numeric core (issue 14, item 5): the share of wrong changes the tests catch.

Usage: ``.venv/bin/python -m bench.mutation [--per-module N] [--seed S[,S2...]] [--modules a,b]
[--jobs J] [--list]`` from the checkout; writes ``bench/results/mutation.md`` (one table per seed).
Not part of ``bench.run_all`` (it runs tests once per mutant). ``--list`` only prints the draw.

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

Only the tests that run the mutated statement are run: the clean run records, through the
pytest plugin ``bench/mutation_lines.py``, which test (or module-scoped fixture) executes which
line of the module. A site in a function body selects the tests that ran its statement; a site
executed at import (module constants, default arguments) or by a session-scoped fixture selects
all the module's tests, and so does a site in a numba-compiled function (its lines are machine
code, which the tracer never sees). A site that no test runs survives without a run ("not reached"): no
test can see it. The draw does not depend on this selection, so the score is the one of running
every test for every mutant (unless a test depended on another file's test having run the line
first, through a cache: none does), only faster: one seed of 64 mutants took 16 min with
``--jobs 1`` on the shared, loaded machine, against 36 min alone before. The traced clean run is
made once per module, whichever seeds follow. ``--jobs`` mutants run at once, each in its own
copy of the tree (the machine is shared: 2 at most, under ``nice``).

Sites of :data:`EQUIVALENT` (a documented list: module, keyword argument, mutation, reason) are
mutations without an observable effect, e.g. a BLAS thread limit of 1 changed to 2. When drawn
they are reported as "equivalent, excluded" and left out of the score's denominator; they are
never silently dropped from the draw.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import queue
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
OUT = HERE / "results" / "mutation.md"

# module -> the tests that should catch a wrong change in it (fast ones: no session campaign); the
# frozen-results check last (it only sees a dataclass made mutable, and imports every package)
FROZEN = "tests/test_frozen_results.py"
TARGETS = {
    "sindy_ekf/estimation/ekf.py": ["tests/sindy_ekf/estimation/test_ekf.py",
                                    "tests/sindy_ekf/estimation/test_measurements.py",
                                    "tests/sindy_ekf/estimation/test_ekf_lateral.py",
                                    "tests/sindy_ekf/estimation/test_ekf_gate_by_hand.py",
                                    "tests/sindy_ekf/estimation/test_ekf_runtime_share.py",
                                    "tests/sindy_ekf/estimation/test_ekf_grid_edges_by_hand.py",
                                    "tests/sindy_ekf/estimation/test_estimation_pieces_by_hand.py", FROZEN],
    "sindy_ekf/estimation/graph.py": ["tests/sindy_ekf/estimation/test_graph.py",
                                      "tests/sindy_ekf/estimation/test_measurements.py",
                                      "tests/sindy_ekf/estimation/test_isam2_linear.py",
                                      "tests/sindy_ekf/estimation/test_graph_last_fix.py",
                                      "tests/sindy_ekf/estimation/test_graph_by_hand.py",
                                      "tests/sindy_ekf/estimation/test_estimation_pieces_by_hand.py", FROZEN],
    "sindy_ekf/estimation/process_models.py": ["tests/sindy_ekf/estimation/test_process_models.py",
                                               "tests/sindy_ekf/estimation/test_process_noise_by_hand.py",
                                               "tests/sindy_ekf/estimation/test_saturation_by_hand.py",
                                               "tests/sindy_ekf/estimation/test_estimation_pieces_by_hand.py", FROZEN],
    "identification/sindy/evaluate.py": ["tests/identification/sindy/test_evaluate_by_hand.py",
                                         "tests/identification/sindy/test_evaluate.py",
                                         "tests/identification/sindy/test_windows_by_hand.py",
                                         "tests/identification/sindy/test_input_track_by_hand.py",
                                         "tests/identification/sindy/test_windows_and_tracks_edges_by_hand.py", FROZEN],
    # InputTrack, split out of evaluate.py (same code, same tests)
    "identification/sindy/input_track.py": ["tests/identification/sindy/test_evaluate_by_hand.py",
                                            "tests/identification/sindy/test_evaluate.py",
                                            "tests/identification/sindy/test_windows_by_hand.py",
                                            "tests/identification/sindy/test_input_track_by_hand.py",
                                            "tests/identification/sindy/test_input_track_far_ends_by_hand.py",
                                            # lagged_at: only the output-error sensitivities call it
                                            "tests/identification/sindy/test_sensitivity_rollout.py",
                                            "tests/identification/sindy/test_windows_and_tracks_edges_by_hand.py", FROZEN],
    "identification/sindy/stepwise.py": ["tests/identification/sindy/test_stepwise.py", FROZEN],
    "identification/sindy/regression.py": ["tests/identification/sindy/test_sindy.py",
                                           "tests/identification/sindy/test_stlsq_normalised.py",
                                           "tests/identification/sindy/test_regression_by_hand.py",
                                           "tests/identification/sindy/test_stlsq_small_columns.py",
                                           "tests/identification/sindy/test_constant_input_by_hand.py", FROZEN],
    "identification/preprocessing/clock_sync.py": ["tests/identification/preprocessing/test_sync.py",
                                                   "tests/identification/preprocessing/test_coarse_shift_origins.py",
                                                   "tests/identification/preprocessing/test_clock_fit_by_hand.py",
                                                   "tests/identification/preprocessing/test_clock_tolerance_by_hand.py",
                                                   FROZEN],
    "sindy_ekf/diagnose/rank.py": ["tests/sindy_ekf/diagnose/test_rank_order.py", FROZEN],
    "sindy_ekf/benchmark/health.py": ["tests/sindy_ekf/benchmark/test_health.py",
                                      "tests/sindy_ekf/benchmark/test_nis_alarm_by_hand.py",
                                      "tests/sindy_ekf/benchmark/test_health_recovery_diverges.py",
                                      "tests/sindy_ekf/benchmark/test_split_short_runs.py",
                                      "tests/sindy_ekf/benchmark/test_health_by_hand.py",
                                      "tests/sindy_ekf/benchmark/test_health_bookkeeping_by_hand.py", FROZEN],
    "sindy_ekf/benchmark/step_test.py": ["tests/sindy_ekf/benchmark/test_health.py",
                                         "tests/sindy_ekf/benchmark/test_health_by_hand.py",
                                         "tests/sindy_ekf/benchmark/test_step_test_bounds_by_hand.py", FROZEN],
}
# seeds whose surviving mutants tests were written against (the report says so: their score is
# not an unbiased measure of the tests; a fresh seed is)
WRITTEN_AGAINST = (5, 7, 14, 23, 31, 61, 149, 211, 701, 1001, 1002, 1003, 1004, 1005)
SWAP_BIN = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult, ast.Pow: ast.Mult}
SWAP_CMP = {ast.Lt: ast.GtE, ast.GtE: ast.Lt, ast.Gt: ast.LtE, ast.LtE: ast.Gt, ast.Eq: ast.NotEq,
            ast.NotEq: ast.Eq}
QUIET_CALLS = {"log", "logging", "warnings"}  # log.warning(...), warnings.warn(...): messages only


@dataclass(frozen=True)
class Site:
    """One mutation: the node's index in a walk of the tree, what changes and where.

    ``stmt_line`` is the first line of the innermost statement holding the node (a line event of
    the clean run there or at ``line`` means the mutated code ran); ``at_import`` is True for
    code that runs when the module is imported (module and class bodies, default arguments,
    decorators).
    """

    index: int
    line: int
    what: str
    stmt_line: int = 0
    at_import: bool = True
    keyword: str = ""  # "function.argument" when the node is (in) a keyword argument of a call


@dataclass(frozen=True)
class Equivalent:
    """A mutation site without observable effect: where (module, source regex), which mutation, why."""

    module: str  # path of the module, or "*" for every module
    keyword: str  # regular expression matched against Site.keyword ("function.argument")
    what: str  # regular expression matched against Site.what
    reason: str
    source: str = ""  # regular expression searched in the site's source line (empty: any line)

    def matches(self, module: str, site: Site, source_line: str = "") -> bool:
        """Return whether ``site`` of ``module`` (on ``source_line``) is this equivalent mutation."""
        return ((self.module == "*" or self.module == module) and re.fullmatch(self.keyword, site.keyword) is not None
                and re.fullmatch(self.what, site.what) is not None
                and (not self.source or re.search(self.source, source_line) is not None))


EQUIVALENT: list[Equivalent] = [
    Equivalent("*", r"threadpool_limits\.limits", r".*",
               "the number of BLAS threads: changes the speed of a factorisation, not its result"),
    Equivalent("*", r"njit\.cache", r".*",
               "numba's on-disk cache of a compiled function: whether compiling is saved for the next process, "
               "not what the function computes"),
    Equivalent("*", r"progress\.(total|desc|disable)", r".*",
               "the progress bar's display (its length, label): no result depends on it"),
    Equivalent("sindy_ekf/estimation/ekf.py", r"step_and_jac\.input_jacobian", r"False -> True",
               "the input Jacobian computed as well: this caller discards it (``x, F, _ = ...``)",
               source=r"x, F, _ = "),
    Equivalent("sindy_ekf/estimation/graph.py", r"", r".*",
               "counters of vectorised and single factor evaluations: only logged, no result reads them",
               source=r"self\.n_(batch|single) (=|\+=) "),
    Equivalent("identification/sindy/stepwise.py", r"", r"1 -> 2",
               "``reshape(-1)`` as ``reshape(-2)``: numpy takes any negative size as the one unknown dimension "
               "(``np.zeros((2, 3)).reshape(-2)`` has shape (6,)), so the array is the same",
               source=r"r, J = r\[ok\]\.reshape\(-1\), "),
    Equivalent("identification/sindy/stepwise.py", r"", r"1e-12 -> 2e-12",
               "the coefficient that makes a candidate term a parameter of the score's rollout: the score is a "
               "derivative at the fit, and a term of 1e-12 or 2e-12 moves the rollout by about 1e-12 of its "
               "feature, far below the round-off of the residuals it is projected on",
               source=r"_SEED = 1e-12"),
    Equivalent("identification/sindy/stepwise.py", r"", r"1e-300 -> 2e-300",
               "the zero-division guard of a term's score ``(Jn^T r)^2 / max(|Jn|^2, 1e-300)``: by Cauchy-Schwarz "
               "the numerator is at most ``|Jn|^2 |r|^2``, so where the guard binds the score is below "
               "``|r|^2`` times 1e-300 with either constant, zero for every ranking against a term that moves "
               "the residuals at all",
               source=r"np\.maximum\(np\.sum\(Jn\*\*2, axis=0\), 1e-300\)"),
    Equivalent("identification/sindy/regression.py", r"", r"1\.0 -> 2\.0",
               "the stand-in norm of an all-zero column or target (any positive value): a zero column "
               "divided by it stays zero and its coefficient zero, so the fit is the same",
               source=r"np\.where\((col|tgt) > 0, (col|tgt), 1\.0\)"),
    Equivalent("sindy_ekf/estimation/graph.py", r"", r"1e-300 -> 2e-300",
               "the zero-division guard of LM's relative decrease: it changes the decrease only when the "
               "error is below 2e-300, and then the accepted error (no larger) is below 1e-9, which ends "
               "the iterations whatever the decrease",
               source=r"max\(err, 1e-300\)"),
    Equivalent("*", r"", r"Add -> Sub",
               "the heading wrap ``(a + pi) % (2 pi) - pi`` with ``a - pi``: the two differ by exactly one "
               "period, so their remainders agree (up to the last bit of a float, 1e-15 rad)",
               source=r"\+ np\.pi\) % \(2(\.0)? \* np\.pi\) - np\.pi"),
    Equivalent("sindy_ekf/estimation/ekf.py", r"", r"1 -> 2",
               "the gate's bound at probability 1: chi2.ppf(1, dof) is inf, the value of the else branch, and a "
               "gate probability is in (0, 1] (config.py checks it), so ``< 2`` takes the same value",
               source=r"if gate_prob < 1 else np\.inf"),
    Equivalent("identification/sindy/input_track.py", r"", r"10000\.0 -> 20000\.0",
               "the held inputs' padding beyond the track's ends (the end values hold there): any padding longer "
               "than a query's distance from the track (a few seconds of dead time and window) gives the same "
               "averages, up to round-off of the padded integral (1e-12)",
               source=r"pad = 1e4"),
    Equivalent("identification/sindy/input_track.py", r"", r"0 -> 1",
               "the lower clip of a held input's index: ``held = vstack([u[:1], u])`` repeats the first sample, so "
               "rows 0 and 1 of ``held`` are equal and clipping the index to 1 instead of 0 reads the same value",
               source=r"k_(lo|hi) = np\.clip\(np\.searchsorted\(knots, "),
    Equivalent("sindy_ekf/estimation/ekf.py", r"", r"0 -> 1",
               "the EKF's test for the saturated step with the upper bound as the lower one: it only decides "
               "which of two calls steps the batch, and for states inside the bounds the saturated step is the "
               "plain one bit for bit (np.clip leaves them as they are, no row is held, the same step_and_jac "
               "call follows); states outside take the saturated step either way",
               source=r"outside_bounds\(x_k, bounds\[0\], bounds\[1\]\)"),
    Equivalent("sindy_ekf/estimation/ekf.py", r"", r"Add -> Sub",
               "one finiteness test of state and covariance together, ``isfinite(a + b)`` as ``isfinite(a - b)``: "
               "both are False exactly when a or b is inf or NaN (inf - inf and inf + -inf are NaN); they differ "
               "only when finite a and b of 1e308 overflow, a state 1e308 m off whose next prediction overflows "
               "(F P F^T) and raises the DivergenceError a step later",
               source=r"math\.isfinite\((ekf\.x\.sum\(\) \+ ekf\.P\.sum\(\)|x_next\.sum\(\) \+ P_max)\)"),
    Equivalent("identification/preprocessing/clock_sync.py", r"", r"Add -> Sub",
               "the clock offset's sign in the gap residuals whose spread sets the samples' matching tolerance: "
               "``- d`` for ``+ d`` adds 2 d to every residual, and the spread is their median absolute deviation "
               "about their median, which a common shift leaves unchanged",
               source=r"res_gap = gaps_rpi\[ig\] - \(k \* \(gaps_tr\[jt\] - tau\) \+ d\)"),
    Equivalent("identification/sindy/input_track.py", r"", r"2 -> 3",
               "the lag vector handed to first_order_lag one entry longer: first_order_lag reads only its first "
               "two entries (``np.asarray(lag_s).reshape(-1)[:2]``), ``one[i]`` sets entry 0 or 1 alike in both, "
               "and the third entry is never read",
               source=r"one = np\.zeros\(2\)"),
    Equivalent("sindy_ekf/benchmark/step_test.py", r"", r"0 -> 1",
               "the partition's fix count from the segment table's columns instead of its rows: the table is "
               "square, ``(n + 1, n + 1)`` (``_segment_rss`` builds it as ``c_w[None, :] - c_w[:, None]`` of one "
               "cumulative sum), in the one caller and in the tests alike",
               source=r"n = rss\.shape\[0\] - 1"),
    Equivalent("sindy_ekf/estimation/ekf.py", r"potrf\.(lower|clean)", r"(True -> False|False -> True)",
               "the positive-definiteness test's Cholesky factor, which is discarded (only LAPACK's info, ``[1]``, "
               "is read): ``clean`` only zeroes the factor's unused triangle; ``lower`` says which triangle is "
               "read of a matrix symmetrised bit for bit the line before (``0.5 (P + P^T)``: float addition "
               "commutes), so both factorise the same matrix. Their rounding differs (another "
               "order of the same sums), so they can disagree only for a P whose smallest eigenvalue is within "
               "round-off of zero: in 200 000 random 6 x 6 covariances with eigenvalues down to 1e-16, 6 "
               "disagreed, all with |lambda_min| < 4e-16 ||P||, where neither answer is more right and the "
               "repair moves P by at most min_eig = 1e-12",
               source=r"if potrf\(P, lower=True, clean=False\)\[1\] == 0:"),
    Equivalent("sindy_ekf/benchmark/step_test.py", r"", r"1 -> 2",
               "the floor of the levels' chi-square degrees of freedom, ``np.maximum(2 n - 2 k, 1)``, as 2: it never "
               "binds, since the levels are at most ``n // MIN_LEVEL_FIXES = n // 2`` and the test runs on n >= 8 "
               "fixes only (``if n < 8: return False`` above it), so 2 n - 2 k >= n >= 8",
               source=r"np\.maximum\(2 \* n - 2 \* levels, 1\)"),
    Equivalent("sindy_ekf/estimation/graph.py", r"", r"GtE -> Lt",
               "which sets of values trigger the dynamics factors' vectorised prediction of all steps: a cache "
               "keyed by the state, whose entry k a factor uses only if it was computed at that factor's own "
               "state bit for bit (``x0 == self._x[k]``), with step k's input and step (else it predicts alone); "
               "so every factor's prediction is step_and_jac at its own state either way, the same arithmetic "
               "row by row, and only the counts of vectorised and single calls (logged) change",
               source=r"if values\.size\(\) >= n_full:"),
    Equivalent("identification/sindy/evaluate.py", r"", r"1 -> 2",
               "the rollout's test for stacked dead times, ``delay.ndim > 1`` as ``> 2``: it differs only for a "
               "``(M, 2)`` stack, which then goes to ``inputs_for(delay)`` instead of ``inputs_for(delay.reshape(-1, "
               "2)).reshape((M,) + u_half.shape)``; the reshape leaves an ``(M, 2)`` array as it is and inputs_for "
               "returns ``(M, *u_half.shape)`` for it, so both give the same array",
               source=r"if delay\.ndim > 1 else windows\.inputs_for\(delay, lag_s=lag\)"),
    Equivalent("identification/preprocessing/clock_sync.py", r"", r"Add -> Sub",
               "the clock offset's sign in the samples' residuals that pick the outliers left out of the fit: "
               "``- d`` for ``+ d`` adds 2 d to every residual, and the residuals are only read about their "
               "median (their robust spread, ``|r - median(r)|`` against it), which a common shift leaves unchanged",
               source=r"r = y - \(k \* x \+ d\)"),
]


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


def _runtime_nodes(tree: ast.AST) -> dict[int, int]:
    """Return ``{id(node): first line of its innermost statement}`` for nodes in function bodies."""
    out: dict[int, int] = {}

    def visit_body(stmts):
        for stmt in stmts:
            for node in ast.walk(stmt):
                out[id(node)] = stmt.lineno
            for field in ("body", "orelse", "finalbody"):
                inner = getattr(stmt, field, None)
                if isinstance(inner, list):
                    visit_body(inner)
            for handler in getattr(stmt, "handlers", []):
                visit_body(handler.body)
            for case in getattr(stmt, "cases", []):
                visit_body(case.body)

    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not _compiled(node):
            visit_body(node.body)
    return out


def _compiled(func: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    """Return whether ``func`` is compiled by numba (``@numba.njit``, ``@njit(...)``, ``@jit``): the
    tracer of the clean run never sees its lines, so its sites select every test of the module."""
    for dec in func.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in ("njit", "jit"):
            return True
    return False


def _keyword_nodes(tree: ast.AST) -> dict[int, str]:
    """Return ``{id(node): "function.argument"}`` for nodes inside a keyword argument of a call."""
    out: dict[int, str] = {}
    for call in ast.walk(tree):
        if isinstance(call, ast.Call):
            func = call.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", "?")
            for kw in call.keywords:
                for node in ast.walk(kw.value):
                    out[id(node)] = f"{name}.{kw.arg}"  # walk is outer first: the innermost call wins
    return out


def sites(source: str) -> list[Site]:
    """Return every mutation site of a module's source (module docstring)."""
    tree = ast.parse(source)
    skip = _silent_nodes(tree)
    runtime = _runtime_nodes(tree)
    keywords = _keyword_nodes(tree)
    out = []
    for i, node in enumerate(ast.walk(tree)):
        what = None if id(node) in skip else _describe(node)
        if what is not None:
            line = getattr(node, "lineno", 0)
            out.append(Site(i, line, what, runtime.get(id(node), line), id(node) not in runtime,
                            keywords.get(id(node), "")))
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


def run_tests(work: Path, tests: list[str], timeout_s: float, lines_out: Path | None = None,
              target: str = "") -> tuple[bool, float]:
    """Return whether the tests pass in ``work`` and how long they took (a timeout fails them).

    With ``lines_out`` the run records which test runs which line of ``target`` (the clean run).
    """
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "PYTHONPATH": str(work)}
    cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider"]
    if lines_out is not None:
        env.update(MUTATION_TARGET=target, MUTATION_LINES_OUT=str(lines_out))
        cmd += ["-p", "bench.mutation_lines"]
    t0 = time.perf_counter()
    try:
        done = subprocess.run([*cmd, *tests], cwd=work, env=env, capture_output=True, text=True, timeout=timeout_s)
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
    for name in ("__init__.py", "mutation_lines.py"):
        shutil.copy2(HERE / name, dst / "bench" / name)
    for name in ("pyproject.toml", "conftest.py"):
        if (REPO / name).exists():
            shutil.copy2(REPO / name, dst / name)


def select_tests(site: Site, hits: dict[str, list[int]], tests: list[str]) -> list[str]:
    """Return the pytest arguments that run every test which ran ``site``'s code (lines of the control).

    Empty when no test ran it. Node ids and class ids inside a selected file are dropped.
    """
    lines = {site.line, site.stmt_line}
    keys = [k for k, v in hits.items() if lines & set(v)]
    if site.at_import or "*" in keys:  # run at import or by a session-scoped fixture: every test may see it
        return list(tests)
    files = [k for k in keys if "::" not in k]
    rest = [k for k in keys if "::" in k and not any(k.startswith(f + "::") for f in files)]
    classes = [k for k in rest if k.count("::") == 1 and "[" not in k and k.split("::")[1][:1].isupper()]
    rest = [k for k in rest if k in classes or not any(k.startswith(c + "::") for c in classes)]
    return files + rest


@dataclass(frozen=True)
class Outcome:
    """What became of one drawn site."""

    site: Site
    source_line: str
    status: str  # "killed", "survived", "not reached" (survived without a run), "equivalent"
    note: str = ""
    secs: float = 0.0


_CONTROL: dict[str, tuple[bool, float, dict]] = {}  # module -> (passed, seconds, lines run per test)


def run_module(module: str, tests: list[str], seed: int, per_module: int, works: "queue.Queue[Path]",
               jobs: int) -> tuple[int, list[Outcome], str]:
    """Return ``(n_sites, outcomes, note)`` of the draw of ``module`` for ``seed``."""
    source = (REPO / module).read_text()
    control = mutant(source, None)
    all_sites, control_sites = sites(source), sites(control)
    assert [s.what for s in all_sites] == [s.what for s in control_sites], f"{module}: unparse changed the tree"
    rng = random.Random(f"{seed}:{module}")  # the same draw whichever modules run
    drawn = sorted(rng.sample(range(len(all_sites)), min(per_module, len(all_sites))),
                   key=lambda i: all_sites[i].line)
    src_lines = source.splitlines()
    outcomes: dict[int, Outcome] = {}
    for i in drawn:
        site = all_sites[i]
        text = src_lines[site.line - 1].strip() if site.line else ""
        eq = next((e for e in EQUIVALENT if e.matches(module, site, text)), None)
        if eq is not None:
            outcomes[i] = Outcome(site, text, "equivalent", eq.reason)
    pending = [i for i in drawn if i not in outcomes]
    if not pending:
        return len(all_sites), [outcomes[i] for i in drawn], "all drawn equivalent"
    if module not in _CONTROL:  # one traced clean run per module, whichever seeds follow
        work = works.get()
        lines_out = work / "mutation_lines.json"
        try:
            (work / module).write_text(control)
            ok, clean_s = run_tests(work, tests, 1800, lines_out, module)
            _CONTROL[module] = ok, clean_s, json.loads(lines_out.read_text()) if ok else {}
        finally:
            (work / module).write_text(source)
            works.put(work)
    ok, clean_s, hits = _CONTROL[module]
    if not ok:
        return len(all_sites), [], f"control run failed ({clean_s:.0f} s): skipped"

    def one(i: int) -> Outcome:
        site, csite = all_sites[i], control_sites[i]
        text = src_lines[site.line - 1].strip()
        selected = select_tests(csite, hits, tests)
        if not selected:
            return Outcome(site, text, "not reached", "no test runs this line")
        work = works.get()
        try:
            (work / module).write_text(mutant(source, site))
            limit = 3 * clean_s + 30
            passed, secs = run_tests(work, selected, limit)
        finally:
            (work / module).write_text(source)
            works.put(work)
        n_sel = "all tests" if selected == list(tests) else f"{len(selected)} selected"
        # a mutant that runs past the limit counts as killed (an endless loop is a failure) but is
        # marked: on a loaded machine a slow survivor could time out, and the reader must see how many
        timed_out = not passed and secs >= limit
        out = Outcome(site, text, "survived" if passed else "killed", n_sel + (", timed out" if timed_out else ""), secs)
        print(f"  {module}:{site.line} {site.what}: {out.status} ({secs:.0f} s, {n_sel})", flush=True)
        return out

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        for i, out in zip(pending, pool.map(one, pending)):
            outcomes[i] = out
    return len(all_sites), [outcomes[i] for i in drawn], f"{clean_s:.0f} s clean, traced"


def report(seed_runs, args, minutes: float, targets: dict[str, list[str]]) -> list[str]:
    """Return the markdown lines of the result (one table per seed, then the excluded patterns)."""
    cmd = (f"`.venv/bin/python -m bench.mutation --per-module {args.per_module} --seed {args.seed} --jobs {args.jobs}"
           + (f" --modules {args.modules}" if args.modules else "")
           + (f" --out {args.out.resolve().relative_to(REPO)}" if args.out.resolve() != OUT.resolve() else "") + "`")
    lines = ["## mutation: the share of wrong changes the tests catch (issue 14, item 5)", "",
             f"Command: {cmd} ({minutes:.0f} min on the shared 2 cores). Operators: sign/operator flips, "
             "comparisons turned around, constants changed, and/or, True/False; docstrings, log calls, error "
             "messages and f-strings excluded. Each mutant runs the tests (of the module's test files) that ran "
             "the mutated statement in the clean run; a line no test runs is a survivor without a run "
             "(\"not reached\"). Drawn sites on the documented list of equivalent mutations (below) are "
             "counted apart, not in the score (bench/mutation.py).", ""]
    for seed, rows in seed_runs:
        outs = [o for _, _, oc, _ in rows for o in oc]
        killed = sum(o.status == "killed" for o in outs)
        equiv = sum(o.status == "equivalent" for o in outs)
        timed_out = sum(o.status == "killed" and o.note.endswith("timed out") for o in outs)
        scored = len(outs) - equiv
        how = ("the draw whose survivors the tests were written against" if seed in WRITTEN_AGAINST
               else "a fresh draw: no test was written against it")
        lines += [f"### seed {seed} ({how}): **{killed} of {scored} mutants killed: {100 * killed / max(scored, 1):.0f} %** "
                  f"(target >= 90 %; {equiv} drawn equivalent, excluded; {timed_out} of the killed by the time limit "
                  "of 3 x the clean run + 30 s)", "",
                  "| module | mutation sites | drawn | equivalent, excluded | killed | survived (not reached) | tests |",
                  "|---|---|---|---|---|---|---|"]
        for module, n_sites, oc, note in rows:
            k = sum(o.status == "killed" for o in oc)
            e = sum(o.status == "equivalent" for o in oc)
            s = sum(o.status in ("survived", "not reached") for o in oc)
            nr = sum(o.status == "not reached" for o in oc)
            names = ", ".join(Path(t).name for t in targets[module])
            lines.append(f"| `{module}` | {n_sites} | {len(oc)} | {e} | {k} | {s} ({nr}) | {names} ({note}) |")
        lines += ["", "Surviving mutants (a change the tests do not see):", ""]
        lines += [f"- `{m}:{o.site.line}` {o.site.what} in `{o.source_line}`"
                  + (" (not reached: no test runs this line)" if o.status == "not reached" else "")
                  for m, _, oc, _ in rows for o in oc if o.status in ("survived", "not reached")] or ["- none"]
        eq = [f"- `{m}:{o.site.line}` {o.site.what} in `{o.source_line}`: {o.note}"
              for m, _, oc, _ in rows for o in oc if o.status == "equivalent"]
        lines += ["", "Drawn and excluded as equivalent:", ""] + (eq or ["- none"]) + [""]
    lines += ["Equivalent mutations excluded (`EQUIVALENT` in bench/mutation.py: module, source pattern, "
              "mutation, why no test can see it):", ""]
    lines += [f"- module `{e.module}`" + (f", inside keyword argument `{e.keyword}`" if e.keyword else "")
              + (f", on a line matching `{e.source}`" if e.source else "") + f", mutation `{e.what}`: {e.reason}"
              for e in EQUIVALENT]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-module", type=int, default=8, help="mutants drawn per module (default 8)")
    ap.add_argument("--seed", default="23", help="seed(s) of the draw, comma-separated (default 23)")
    ap.add_argument("--modules", default=None, help="comma-separated subset of the modules (paths)")
    ap.add_argument("--jobs", type=int, default=1, help="mutants run at once, each in its own copy (default 1)")
    ap.add_argument("--list", action="store_true", help="only print the drawn sites")
    ap.add_argument("--out", type=Path, default=OUT, help="the results page (default bench/results/mutation.md)")
    args = ap.parse_args(argv)
    targets = {m: t for m, t in TARGETS.items() if args.modules is None or m in args.modules.split(",")}
    seeds = [int(s) for s in args.seed.split(",")]
    if args.list:
        for seed in seeds:
            for module in targets:
                source = (REPO / module).read_text()
                all_sites = sites(source)
                rng = random.Random(f"{seed}:{module}")
                for i in sorted(rng.sample(range(len(all_sites)), min(args.per_module, len(all_sites))),
                                key=lambda i: all_sites[i].line):
                    s = all_sites[i]
                    print(f"{seed} {module}:{s.line} {s.what}: {source.splitlines()[s.line - 1].strip()}")
        return 0
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))  # stopped: the copies are removed all the same
    t_start = time.perf_counter()
    seed_runs = []
    with tempfile.TemporaryDirectory(prefix="mutation_") as tmp:
        works: queue.Queue[Path] = queue.Queue()
        for j in range(max(args.jobs, 1)):
            copy_tree(Path(tmp) / str(j))
            works.put(Path(tmp) / str(j))
        for seed in seeds:
            rows = []
            for module, tests in targets.items():
                print(f"seed {seed}: {module}", flush=True)
                n_sites, outcomes, note = run_module(module, tests, seed, args.per_module, works, args.jobs)
                rows.append((module, n_sites, outcomes, note))
            seed_runs.append((seed, rows))
            # written after each seed: a run stopped later still leaves the seeds it finished
            lines = report(seed_runs, args, (time.perf_counter() - t_start) / 60, targets)
            args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
