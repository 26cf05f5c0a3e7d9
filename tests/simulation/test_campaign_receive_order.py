"""``simulate --receive-jitter`` and ``--clock-reset`` (issue 14): what the bags store, read back
with rosbags' own reader and counted here, against what the simulator says it injected."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from simulation.campaign import check_clock_resets, check_receive_jitter
from simulation.truth import read_truth
from tests.conftest import FIELD_RESETS
from tests.support.bag_order import HALF_PERIOD_S, backward_steps, stored_stamps


@pytest.fixture(scope="module")
def stored(field_campaign):
    return {d.name: stored_stamps(d) for d in sorted((field_campaign / "runs").iterdir())}


def test_every_message_its_own_latency_and_the_reorderings_equal_truth(field_campaign, stored):
    truth = read_truth(field_campaign, states=False)
    total = 0
    for run in truth.runs:
        assert run.bags["receive_jitter_s"] == [2e-3, 12e-3]
        for topic, (stamp, t_bag) in stored[run.name].items():
            assert np.all(np.diff(t_bag) >= 0)  # stored in receive order
            n_reordered, _ = backward_steps(stamp)
            assert n_reordered == run.bags["reordered"][topic], (run.name, topic)
            total += n_reordered
            if topic == "/at960/measurement":
                # a spurious pulse received before the real one next to it: at least the 1 ms
                # trigger dead time apart, at most the 10 ms spread of the latencies
                step = np.diff(stamp)
                inversion = -step[(step < 0) & (step >= -HALF_PERIOD_S)]
                assert np.all((inversion > 0.9e-3) & (inversion < 10e-3)), inversion
            if topic == "/joy_teleop/joy":  # UTC stamps: the latency itself is visible
                latency = t_bag - stamp
                assert latency.min() >= 2e-3 - 1e-6 and latency.max() <= 12e-3 + 1e-6
    assert total >= 4  # seed 4 of FIELD_SEED stores AT960 pulses out of order in five runs


def test_without_jitter_the_same_messages_in_stamp_order(field_campaign, field_twin, stored):
    for run_dir in sorted((field_twin / "runs").iterdir()):
        twin = stored_stamps(run_dir)
        for topic, (stamp, _) in twin.items():
            jittered = stored[run_dir.name][topic][0]
            assert backward_steps(stamp)[0] == 0, (run_dir.name, topic)
            np.testing.assert_array_equal(np.sort(jittered, kind="stable"), np.sort(stamp, kind="stable"))
    truth = read_truth(field_twin, states=False)
    assert all(r.bags["receive_jitter_s"] is None and not any(r.bags["reordered"].values()) for r in truth.runs)


def test_a_clock_reset_is_one_backward_jump_where_truth_says(field_campaign, stored):
    truth = read_truth(field_campaign, states=False)
    for run in truth.runs:
        reset = run.clock_reset
        if run.name not in FIELD_RESETS:
            assert reset is None
            continue
        tracker, fraction = FIELD_RESETS[run.name]
        stamp, t_bag = stored[run.name][f"/{tracker}/measurement"]
        assert backward_steps(stamp)[1] == 1
        i = reset["message"]
        assert stamp[i] - stamp[i - 1] == pytest.approx(reset["jump_s"], abs=1e-6)
        assert stamp[i] < stamp[i - 1] - 3600  # the controller had been up for hours
        # the new clock maps its stamps to UTC after the reset, at the fraction of the run asked
        after = reset["clock_after"]
        t_utc = after["k"] * stamp[i:] + after["d_s"]
        assert np.all(t_utc >= reset["t_utc_ns"] * 1e-9 - 1e-5)
        t0, t1 = run.t0_utc_ns * 1e-9, run.t0_utc_ns * 1e-9 + run.duration_s + 2.0
        assert t0 + fraction * run.duration_s < reset["t_utc_ns"] * 1e-9 < t1
        assert np.all(np.abs(t_bag[i:] - t_utc) < 12e-3 + 1e-4)  # received within the latency


@pytest.mark.parametrize("value, expected", [
    (True, (2e-3, 12e-3)), ("3,8", (3e-3, 8e-3)), ((0.0, 0.005), (0.0, 0.005)), (None, None),
    ("500,510", (0.5, 0.51))])
def test_receive_jitter_values(value, expected):
    got = check_receive_jitter(value)
    assert got is None if expected is None else got == pytest.approx(expected)


@pytest.mark.parametrize("value, culprit", [
    ("12,2", r"receive jitter \(12, 2\) ms"), ("2;12", r"receive jitter '2;12'"), ("-1,3", r"\(-1, 3\) ms"),
    # a spread of more than half a trigger period stores messages a period apart swapped: by the
    # data contract a clock reset, which preprocessing would cut every run at
    ("2,40", r"receive jitter \(2, 40\) ms: a spread of 38 ms .* at most 10 ms"), ("0,10.5", r"spread of 10\.5 ms")])
def test_bad_receive_jitter_is_named(value, culprit):
    with pytest.raises(InputError, match=culprit):
        check_receive_jitter(value)


def test_clock_reset_specs_and_bad_ones_named():
    assert check_clock_resets(["run_05", "run_02:ltd800:0.3"]) == {"run_05": ("at960", 0.5),
                                                                  "run_02": ("ltd800", 0.3)}
    for spec, culprit in (("run_99", "no run 'run_99'"), ("run_05:gps", "tracker 'gps'"),
                          ("run_05:at960:1.5", "fraction 1.5"), ("run_05:at960:x", "fraction 'x'"),
                          ("a:b:c:d", "expected RUN")):
        with pytest.raises(InputError, match=culprit):
            check_clock_resets([spec])
