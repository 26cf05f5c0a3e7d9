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
    """The identify end-to-end test's campaign and quick grid, through jobs=1, jobs=2 and the cluster."""
    models = {}
    for label, flags in (("jobs1", ["--jobs", "1"]), ("jobs2", ["--jobs", "2"]), ("dask", ["--dask", cluster])):
        out = tmp_path / f"{label}.json"
        assert main(["identify", str(small_trajectory), "--out", str(out), "--quick", "--quiet", *flags]) == 0
        models[label] = json.loads(out.read_text())
    local = models.pop("jobs1")
    assert any(any(row) for row in local["coefficients"].values())
    for label, model in models.items():
        assert model == local, label  # every key, coefficients exactly equal
