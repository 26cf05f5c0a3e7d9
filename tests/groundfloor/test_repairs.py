"""Expected repairs are counted per run, once however often a run is read, and summed per kind."""

from __future__ import annotations

from groundfloor import repairs


def test_summary_counts_each_run_once():
    repairs.clear()
    repairs.note("pose gaps", "run_01", 2)
    repairs.note("pose gaps", "run_02", 1)
    repairs.note("pose gaps", "run_01", 2)  # the same campaign read again
    repairs.note("pose gaps", "run_03", 0)  # nothing repaired: not listed
    assert repairs.summary() == ["pose gaps: 3 in 2 runs (run_01 2, run_02 1)"]
    repairs.clear()
    assert repairs.summary() == []
