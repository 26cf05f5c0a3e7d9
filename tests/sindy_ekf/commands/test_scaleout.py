"""Scale-out (issue 16 item 4): identify on a Dask LocalCluster gives the model of the local run."""

from __future__ import annotations

import json

import pytest

from groundfloor.parallel import Workers, parallel_map
from sindy_ekf.cli import main
from tests.groundfloor.test_parallel import TASKS, noisy_sum


@pytest.fixture(scope="module")
def cluster():
    """A 2-worker Dask cluster of separate processes on this machine, as a real cluster's workers are."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        yield c.scheduler_address


def test_tasks_on_the_cluster_equal_the_serial_map(cluster):
    assert parallel_map(noisy_sum, TASKS, Workers(dask=cluster)) == [noisy_sum(t) for t in TASKS]


def test_identify_on_a_local_cluster_equals_the_local_run(cluster, small_trajectory, tmp_path):
    """The identify end-to-end test's campaign and quick grid, through jobs=1, jobs=2 and the cluster. The
    linear library only: the same tasks, folds and candidates reach the workers as with poly3, in 24 s
    a run instead of 53 s (the search's arithmetic does not depend on the library's degree)."""
    models = {}
    for label, flags in (("jobs1", ["--jobs", "1"]), ("jobs2", ["--jobs", "2"]), ("dask", ["--dask", cluster])):
        out = tmp_path / f"{label}.json"
        assert main(["identify", str(small_trajectory), "--out", str(out), "--quick", "--library", "poly1", "--quiet",
                     *flags]) == 0
        models[label] = json.loads(out.read_text())
    local = models.pop("jobs1")
    assert any(any(row) for row in local["coefficients"].values())
    for label, model in models.items():
        assert model == local, label  # every key, coefficients exactly equal


RUNS = (("run_a", 30.0, "train"), ("run_b", 30.0, "train"), ("run_c", 25.0, "test"), ("run_d", 25.0, "test"))


def test_benchmark_runs_in_two_processes_and_on_the_cluster_equal_one_process(cluster, tmp_path):
    """The smoothers' runs are the benchmark's parallel tasks: the estimates do not depend on where they ran."""
    import numpy as np

    from groundfloor.parallel import Workers
    from identification.preprocessing.trajectory import read_trajectory_campaign
    from identification.sindy.model import model_from_terms
    from simulation.robot import RobotParams
    from sindy_ekf.benchmark.run import benchmark_campaign
    from tests.support.trajectory_synth import write_mini_campaign

    campaign = read_trajectory_campaign(write_mini_campaign(tmp_path / "mini", seed=5, runs=RUNS))
    model = model_from_terms(RobotParams().terms())
    results = {str(w): benchmark_campaign(campaign, model, "dgnss", seed=3, estimators=("sindy_ekf", "sindy_graph"),
                                          outage_warmup_s=10.0, outage_recovery_s=12.0, workers=w)
               for w in (1, 2, Workers(dask=cluster))}
    one = results.pop("1")
    assert set(one.estimates["sindy_graph"]) == {"run_c", "run_d"}
    for label, other in results.items():
        for name, runs in one.estimates.items():
            for run, est in runs.items():
                np.testing.assert_array_equal(other.estimates[name][run].x, est.x, err_msg=f"{label} {name} {run}")
                np.testing.assert_array_equal(other.estimates[name][run].P, est.P, err_msg=f"{label} {name} {run}")
        assert {k: s.ate_pos_m for k, s in other.scores.items()} == {k: s.ate_pos_m for k, s in one.scores.items()}
