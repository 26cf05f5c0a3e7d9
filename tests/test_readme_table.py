"""The README's results table and facts are generated from bench/results/*.md and the code, never typed.

The README must equal what ``python -m bench.readme_table`` writes; a number changed in a bench
result changes the table (so the test fails until the README is regenerated), and a result that
no longer holds what a row reads is an error naming the file.
"""

from __future__ import annotations

import re
import shutil

import pytest

from bench import readme_table
from bench.readme_table import README, RESULTS, ReadmeTableError, expected_readme, results_table
from identification.sindy.search import DEFAULT_GRID, QUICK_GRID


def test_readme_is_what_the_script_writes():
    assert README.read_text() == expected_readme(), "README.md is stale: run python -m bench.readme_table"
    assert readme_table.main(["--check"]) == 0


def test_the_table_follows_the_results_files(tmp_path):
    results = shutil.copytree(RESULTS, tmp_path / "results")
    text = (results / "preprocess.md").read_text()
    wall = re.search(r"\*\*Wall time: ([\d.]+) s\*\*", text).group(1)
    assert f"| {float(wall):g} s wall on 2 shared cores |" in results_table(results)
    (results / "preprocess.md").write_text(text.replace(f"**Wall time: {wall} s**", "**Wall time: 99.25 s**"))
    table = results_table(results)
    assert "| 99.25 s wall on 2 shared cores |" in table and table != results_table(RESULTS)
    assert expected_readme(README, results) != README.read_text()  # the check above would fail
    # a result that lost what a row reads: an error naming the file
    (results / "preprocess.md").write_text(text.replace("**Wall time:", "wall:"))
    with pytest.raises(ReadmeTableError, match=r"bench/results/preprocess\.md: no match"):
        results_table(results)
    (results / "preprocess.md").write_text(text)
    (results / "demo.md").unlink()
    with pytest.raises(ReadmeTableError, match=r"demo\.md: missing"):
        results_table(results)


def test_facts_are_the_code_s():
    facts = readme_table.facts()
    assert f"quick grid of {QUICK_GRID.size} points" in facts and f"full grid of {DEFAULT_GRID.size} points" in facts
    # the sizes are the products of the grid's axes
    assert QUICK_GRID.size == len(QUICK_GRID.s) * len(QUICK_GRID.tau) * len(QUICK_GRID.alpha) * len(QUICK_GRID.T)
