"""Poses too sparse for the integral windows get a one-line answer before the work starts.

The integral windows (eqs. 5.55 to 5.57) never cross a step longer than 200 ms, so a campaign of
poses every 500 ms (a real Warthog campaign with four poses of five left out, as a 2 Hz GNSS
ground truth would give) leaves no window: ``identify`` and ``diagnose`` used to fail deep in the
work with "only 0 integration windows" or "no run is longer than one 2 s integration window"
(the runs are minutes long) after warnings that the runs excite nothing. The rule is the median
step, worked out here by hand on stamps: 250 ms apart is refused, 150 ms is not.
"""

from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from groundfloor.errors import InputError
from groundfloor.types import BodyStates
from identification.sindy.regression import check_pose_spacing
from sindy_ekf.cli import main
from sindy_ekf.diagnose.data import split_from_states


def _states(step_s: float, n: int = 200) -> BodyStates:
    t = np.arange(n) * step_s
    v = np.sin(t)
    return BodyStates(t=t, vx=v, vy=0 * v, omega=np.cos(t), u1=v, u2=np.cos(t), x=t, y=0 * t, yaw=0 * t)


@pytest.mark.parametrize("step_s, refused", [(0.02, False), (0.15, False), (0.25, True), (0.5, True)])
def test_the_median_step_decides(step_s, refused):
    times = [np.arange(100) * step_s, 7.0 + np.arange(50) * step_s]
    if refused:
        with pytest.raises(InputError, match=f"train runs a, b: poses {1e3 * step_s:.0f} ms apart"):
            check_pose_spacing(times, ["a", "b"], "train runs")
    else:
        check_pose_spacing(times, ["a", "b"], "train runs")


def test_a_few_long_steps_among_short_ones_pass():
    # 10 Hz with every fourth step a 0.5 s hole: the median step is 0.1 s, windows remain between the holes
    t = np.cumsum(np.tile([0.1, 0.1, 0.1, 0.5], 50))
    check_pose_spacing([t], ["a"], "train runs")


def test_diagnose_windows_name_the_spacing_not_the_run_length():
    with pytest.raises(InputError, match="poses 500 ms apart"):
        split_from_states([_states(0.5)], ["r"], tau=2.0, what="test runs")
    split = split_from_states([_states(0.1)], ["r"], tau=2.0, what="test runs")
    assert len(split.start) > 0


def test_identify_on_a_real_campaign_thinned_to_2_hz_says_so_and_writes_nothing(shared_dir, tmp_path, capsys):
    root = tmp_path / "thin"
    shutil.copytree(shared_dir / "data" / "warthog-drive-wheels", root)
    for poses in (root / "runs").glob("*/poses.csv"):
        pd.read_csv(poses).iloc[::5].to_csv(poses, index=False)
    out = tmp_path / "model.json"
    assert main(["identify", str(root), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "poses 500 ms apart (median)" in err[-1] and "5 Hz or more" in err[-1]
    assert "excite" not in "\n".join(err)  # the warnings of a fit that cannot work do not come first
    assert not out.exists()
