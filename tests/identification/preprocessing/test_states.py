"""Body-frame states from poses (eqs. 5.64 to 5.68) against analytic truth."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from groundfloor.errors import InputError
from groundfloor.types import InputSeries, PoseTrack
from identification.preprocessing.figures import plot_body_states
from identification.preprocessing.smoothing_spline import noise_std_from_data
from identification.preprocessing.states import (
    body_states_from_poses,
    body_states_segments,
)
from tests.support.pose_synth import trajectory

log = logging.getLogger(__name__)

STD_XY_M = 10e-6
STD_YAW_RAD = 2e-5
SMOOTHING = (0.0, 0.0005, 0.01, 1.0, 10.0)


def _poses(t, seed, with_std=True, wrap=False):
    """Return (PoseTrack with noise, analytic truth) along tests.support.pose_synth.trajectory."""
    rng = np.random.default_rng(seed)
    tr = trajectory(t, seed)
    n = t.size
    nan = np.full(n, np.nan)
    yaw = tr.yaw + rng.normal(0, STD_YAW_RAD, n)
    if wrap:
        yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    std = (lambda v: np.full(n, v)) if with_std else (lambda v: nan)  # noqa: E731
    track = PoseTrack(t=t, x=tr.x + rng.normal(0, STD_XY_M, n), y=tr.y + rng.normal(0, STD_XY_M, n), z=nan,
                      pitch=nan, yaw=yaw, x_std=std(STD_XY_M), y_std=std(STD_XY_M), z_std=nan, pitch_std=nan,
                      yaw_std=std(STD_YAW_RAD))
    return track, tr


def _inputs(t_end):
    t = np.arange(0.0, t_end, 0.05)
    return InputSeries(t=t, u1=np.sin(t), u2=np.cos(t))


def _rms(states, tr, sel=slice(None)):
    err = np.column_stack([states.vx - tr.vx, states.vy - tr.vy, states.omega - tr.omega])[sel]
    return np.sqrt(np.nanmean(err**2, axis=0))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_body_velocities_vs_analytic_derivatives(seed):
    t = np.arange(0.0, 60.0, 0.02)
    track, tr = _poses(t, seed)
    inner = slice(150, -150)  # natural end conditions bend the derivative in the last seconds
    rms = {s: _rms(body_states_from_poses(track, _inputs(61.0), s), tr) for s in SMOOTHING}
    rms_in = {s: _rms(body_states_from_poses(track, _inputs(61.0), s), tr, inner) for s in SMOOTHING}
    for s in SMOOTHING:
        log.info("seed %d s=%g: velocity RMS vx vy omega %s (inner %s)", seed, s, rms[s], rms_in[s])
    # interpolation passes the tracker noise on: sigma * sqrt(2)/dt * ~0.8 (cubic spline)
    floor = np.sqrt(2) * STD_XY_M / 0.02
    assert 0.5 * floor < rms[0.0][0] < 1.2 * floor
    # noise-level smoothing (s = 1) is far better than the thesis's near-interpolating values
    assert np.all(rms[1.0] < 0.3 * rms[0.0005])
    assert np.all(rms_in[10.0] < rms_in[1.0])
    assert rms[0.0005][0] <= rms[0.0][0] and rms[0.01][0] <= rms[0.0005][0]
    assert np.all(rms[1.0][:2] < 2e-4) and rms[1.0][2] < 3e-4


@pytest.mark.parametrize("seed", [0, 3])
def test_padded_ends_remove_the_natural_end_bias(seed):
    t = np.arange(0.0, 40.0, 0.02)
    track, tr = _poses(t, seed)
    ends = np.r_[0:150, t.size - 150:t.size]
    inner = slice(250, -250)
    plain = body_states_from_poses(track, _inputs(41.0), 10.0, pad_ends=False)
    padded = body_states_from_poses(track, _inputs(41.0), 10.0)
    assert np.all(_rms(padded, tr, ends) < 0.3 * _rms(plain, tr, ends))
    np.testing.assert_allclose(_rms(padded, tr, inner), _rms(plain, tr, inner), rtol=0.2)


def test_body_frame_rotation_and_smoothed_pose():
    t = np.arange(0.0, 30.0, 0.02)
    track, tr = _poses(t, 4)
    st = body_states_from_poses(track, _inputs(31.0), 1.0)
    # eqs. 5.64-5.66 checked from the local-frame derivative of the truth
    x_dot = np.cos(st.yaw) * st.vx - np.sin(st.yaw) * st.vy
    y_dot = np.sin(st.yaw) * st.vx + np.cos(st.yaw) * st.vy
    assert np.sqrt(np.mean((x_dot - tr.x_dot) ** 2)) < 2e-4
    assert np.sqrt(np.mean((y_dot - tr.y_dot) ** 2)) < 2e-4
    assert np.sqrt(np.mean((st.x - tr.x) ** 2)) < STD_XY_M  # smoothed, so better than the noise
    assert np.sqrt(np.mean((st.yaw - tr.yaw) ** 2)) < STD_YAW_RAD


def test_wrapped_yaw_gives_the_same_states():
    t = np.arange(0.0, 40.0, 0.02)
    unwrapped, _ = _poses(t, 5)
    wrapped, _ = _poses(t, 5, wrap=True)
    a = body_states_from_poses(unwrapped, _inputs(41.0), 1.0)
    b = body_states_from_poses(wrapped, _inputs(41.0), 1.0)
    assert np.ptp(np.abs(np.diff(b.yaw))) < 0.1  # output yaw is unwrapped
    np.testing.assert_allclose(b.omega, a.omega, atol=1e-9)
    np.testing.assert_allclose(b.vx, a.vx, atol=1e-9)


def test_missing_std_estimated_from_data():
    t = np.arange(0.0, 60.0, 0.02)
    with_std, tr = _poses(t, 6)
    without, _ = _poses(t, 6, with_std=False)
    assert noise_std_from_data(with_std.x) == pytest.approx(STD_XY_M, rel=0.2)
    assert noise_std_from_data(with_std.yaw) == pytest.approx(STD_YAW_RAD, rel=0.2)
    a = _rms(body_states_from_poses(with_std, _inputs(61.0), 1.0), tr)
    b = _rms(body_states_from_poses(without, _inputs(61.0), 1.0), tr)
    np.testing.assert_allclose(b, a, rtol=0.5)


def test_non_uniform_rate():
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.01, 0.03, 3000))
    t = t[rng.uniform(size=t.size) > 0.05]  # lost poses
    track, tr = _poses(t, 7)
    rms = _rms(body_states_from_poses(track, _inputs(t[-1] + 1), 1.0), tr)
    assert np.all(rms < 3e-4)


def test_gap_is_not_bridged():
    t = np.arange(0.0, 40.0, 0.02)
    keep = (t < 15.0) | (t > 25.0)  # a 10 s hole
    full, tr = _poses(t, 8)
    holed = PoseTrack(**{k: getattr(full, k)[keep] for k in full.__dataclass_fields__})
    st = body_states_from_poses(holed, _inputs(41.0), 1.0, t_eval=t)
    gap = ~keep
    assert np.all(np.isnan(st.vx[gap])) and np.all(np.isnan(st.x[gap]))
    assert np.all(np.isfinite(st.u1[gap]))  # inputs are still defined
    assert np.all(np.isfinite(st.vx[~gap]))
    segs = body_states_segments(holed, _inputs(41.0), 1.0)
    assert [s.t.size for s in segs] == [np.sum(t < 15.0), np.sum(t > 25.0)]
    # each side is as good as without the hole, away from its new ends
    sel = (t > 2.0) & (t < 13.0)
    err = st.vx[sel] - tr.vx[sel]
    assert np.sqrt(np.mean(err**2)) < 1e-4
    # a NaN pose inside a segment stays a hole at the pose times
    nan_pose = PoseTrack(**{k: getattr(full, k).copy() for k in full.__dataclass_fields__})
    nan_pose.x[500] = np.nan
    st2 = body_states_from_poses(nan_pose, _inputs(41.0), 1.0)
    assert np.isnan(st2.vx[500]) and np.isfinite(st2.vx[499])


def test_input_hold_zoh_and_linear():
    t = np.arange(0.0, 10.0, 0.02)
    track, _ = _poses(t, 9)
    inputs = InputSeries(t=np.array([0.0, 1.0, 3.0]), u1=np.array([0.0, 1.0, -1.0]), u2=np.array([0.5, 0.5, 0.0]))
    t_eval = np.array([0.5, 1.0, 2.0, 2.99, 5.0])
    zoh = body_states_from_poses(track, inputs, 0.0, t_eval=t_eval)
    lin = body_states_from_poses(track, inputs, 0.0, t_eval=t_eval, input_hold="linear")
    np.testing.assert_array_equal(zoh.u1, [0.0, 1.0, 1.0, 1.0, -1.0])  # the last message received
    np.testing.assert_allclose(lin.u1, [0.5, 1.0, 0.0, -0.99, -1.0])  # thesis: linear interpolation
    np.testing.assert_allclose(lin.u2, [0.5, 0.5, 0.25, 0.0025, 0.0])


def test_plot_body_states(tmp_path):
    t = np.arange(0.0, 10.0, 0.02)
    track, _ = _poses(t, 1)
    fig = plot_body_states({s: body_states_from_poses(track, _inputs(11.0), s) for s in (0.0, 1.0)},
                           tmp_path / "states.png")
    assert len(fig.axes) == 3 and len(fig.axes[0].lines) == 2 and (tmp_path / "states.png").exists()


# ------------------------------------------------------------------------------- bad inputs

@pytest.fixture(scope="module")
def small():
    t = np.arange(0.0, 2.0, 0.02)
    return _poses(t, 0)[0], _inputs(3.0)


def test_bad_smoothing(small):
    with pytest.raises(InputError, match="smoothing"):
        body_states_from_poses(*small, -0.1)


def test_bad_input_hold(small):
    with pytest.raises(InputError, match="input_hold"):
        body_states_from_poses(*small, 0.0, input_hold="cubic")


def test_bad_empty_inputs(small):
    empty = InputSeries(t=np.array([]), u1=np.array([]), u2=np.array([]))
    with pytest.raises(InputError, match="inputs"):
        body_states_from_poses(small[0], empty, 0.0)


def test_bad_pose_time_order(small):
    track, inputs = small
    t = track.t.copy()
    t[5] = t[3]
    bad = PoseTrack(**{**{k: getattr(track, k) for k in track.__dataclass_fields__}, "t": t})
    with pytest.raises(InputError, match="poses.t"):
        body_states_from_poses(bad, inputs, 0.0)


def test_bad_too_few_poses(small):
    track, inputs = small
    x = np.full(track.t.size, np.nan)
    x[:2] = 0.0
    bad = PoseTrack(**{**{k: getattr(track, k) for k in track.__dataclass_fields__}, "x": x})
    with pytest.raises(InputError, match="poses: only 2 finite"):
        body_states_from_poses(bad, inputs, 0.0)


# ------------------------------------------------------------------------ simulated campaign

def _nearest(t_ref, t):
    i = np.clip(np.searchsorted(t_ref, t), 1, t_ref.size - 1)
    return i - (np.abs(t_ref[i - 1] - t) < np.abs(t_ref[i] - t))


def test_simulated_campaign_poses_and_states_vs_truth(small_campaign, small_trajectory):
    """Preprocessed small campaign (poses from this module's stages) against truth/runs/*/states.csv."""
    from identification.preprocessing.trajectory import read_trajectory_campaign
    from simulation.truth import read_truth

    truth = read_truth(small_campaign)
    camp = read_trajectory_campaign(small_trajectory)
    assert len(camp.runs) == len(truth.runs)
    err_pose, err_vel = [], {s: [] for s in (0.0, 0.0005, 0.01, 1.0)}
    for run in camp.runs:
        st = truth.run(run.name).states
        i = _nearest(st.t_utc_ns * 1e-9, run.poses.t)
        assert np.max(np.abs(st.t_utc_ns[i] * 1e-9 - run.poses.t)) < 1e-6  # poses at trigger times
        d_yaw = (run.poses.yaw - st.psi[i] + np.pi) % (2 * np.pi) - np.pi
        err_pose.append(np.column_stack([run.poses.x - st.x[i], run.poses.y - st.y[i], d_yaw]))
        for s in err_vel:
            b = body_states_from_poses(run.poses, run.inputs, s)
            err_vel[s].append(np.column_stack([b.vx - st.vx[i], b.vy - st.vy[i], b.omega - st.omega[i]]))
    e = np.concatenate(err_pose)
    pos_rms = np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))
    yaw_rms_deg = np.degrees(np.sqrt(np.mean(e[:, 2] ** 2)))
    log.info("simulated: position RMS %.4f mm, yaw RMS %.5f deg", pos_rms * 1e3, yaw_rms_deg)
    assert pos_rms < 0.5e-3 and yaw_rms_deg < 0.01
    rms = {s: np.sqrt(np.nanmean(np.concatenate(v) ** 2, axis=0)) for s, v in err_vel.items()}
    for s, r in rms.items():
        log.info("simulated: s=%g velocity RMS vx %.2e m/s, vy %.2e m/s, omega %.2e rad/s", s, *r)
        assert r[0] < 5e-3 and r[1] < 5e-3 and r[2] < np.radians(0.5)
    assert rms[1.0][1] < rms[0.0][1]  # noise-level smoothing helps the noisy lateral velocity
