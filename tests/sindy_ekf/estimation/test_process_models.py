"""Process models: exact RK4 Jacobians against numerical derivatives, integration against scipy,
process noise and lag-model gains recovered from data generated with known values."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from groundfloor.dynamics import Dynamics
from identification.sindy.baselines import (
    ConstantVelocityModel,
    LagModel,
    UnicycleModel,
)
from identification.sindy.model import model_from_terms
from simulation.robot import RobotParams, TrueDynamics
from sindy_ekf.estimation.process_models import (
    ProcessModel,
    StateSeries,
    body_states_from_state_series,
    fit_mean_reversion,
    fit_process_noise,
    state_series_from_body_states,
    unmodelled_states,
)
from tests.support.estimation_helpers import LinearDynamics


class PolyBody(Dynamics):
    """A small polynomial body model with hand-written Jacobians."""

    name = "poly_body"

    @staticmethod
    def f(x, u):
        vx, vy, w = x[..., 0], x[..., 1], x[..., 2]
        u1, u2 = u[..., 0], u[..., 1]
        return np.stack([2.0 * u1 - 3.0 * vx + 0.4 * w * vy - 0.2 * vx * u2 ** 2,
                         -5.0 * vy - 0.3 * vx * w,
                         1.5 * u2 - 2.5 * w + 0.1 * vx * u2], axis=-1)

    @staticmethod
    def J_f_x(x, u):
        vx, vy, w = x[..., 0], x[..., 1], x[..., 2]
        u2 = u[..., 1]
        z = np.zeros_like(vx)
        return np.stack([np.stack([-3.0 - 0.2 * u2 ** 2, 0.4 * w, 0.4 * vy], -1),
                         np.stack([-0.3 * w, -5.0 + z, -0.3 * vx], -1),
                         np.stack([0.1 * u2, z, -2.5 + z], -1)], axis=-2)

    @staticmethod
    def J_f_u(x, u):
        vx = x[..., 0]
        u1, u2 = u[..., 0], u[..., 1]
        z = np.zeros_like(vx)
        return np.stack([np.stack([2.0 + z, -0.4 * vx * u2], -1),
                         np.stack([z, z], -1),
                         np.stack([z, 1.5 + 0.1 * vx], -1)], axis=-2)

    def accel_and_jacobians(self, x6, u, t=0.0):
        x3 = x6[..., 3:]
        J_x = np.zeros(x6.shape[:-1] + (3, 6))
        J_x[..., 3:] = self.J_f_x(x3, u)
        return self.f(x3, u), J_x, self.J_f_u(x3, u)


class PoseTimeDynamics(PolyBody):
    """Stand-in for simulation.robot.TrueDynamics: depends on pose and time as effects may."""

    name = "pose_time"

    def accel_and_jacobians(self, x, u, t=0.0):
        a, J, J_u = super().accel_and_jacobians(x, u, t)
        a[..., 0] += 0.3 * np.sin(x[..., 2]) + 0.05 * x[..., 0] * np.cos(0.5 * t)
        a[..., 2] += 0.02 * x[..., 1] ** 2
        J[..., 0, 2] = 0.3 * np.cos(x[..., 2])
        J[..., 0, 0] = 0.05 * np.cos(0.5 * t)
        J[..., 2, 1] = 0.04 * x[..., 1]
        return a, J, J_u


def test_the_derivative_without_a_time_is_the_one_at_the_run_start():
    # by hand: vx' of PoseTimeDynamics carries 0.05 x cos(0.5 t), 0.05 x at t = 0
    x = np.array([2.0, -1.0, 0.4, 0.5, 0.1, -0.2])
    u = np.array([0.3, -0.1])
    model = ProcessModel(PoseTimeDynamics())
    vx, vy, w, u1, u2 = 0.5, 0.1, -0.2, 0.3, -0.1
    vx_dot = 2.0 * u1 - 3.0 * vx + 0.4 * w * vy - 0.2 * vx * u2 ** 2 + 0.3 * np.sin(0.4) + 0.05 * 2.0
    assert model.f(x, u)[3] == pytest.approx(vx_dot, rel=1e-12)
    assert model.f(x, u, 2.0)[3] == pytest.approx(vx_dot - 0.05 * 2.0 * (1.0 - np.cos(1.0)), rel=1e-12)


def _models():
    A = np.random.default_rng(3).normal(size=(6, 6)) * 0.5
    B = np.random.default_rng(4).normal(size=(6, 2))
    sindy = model_from_terms({"vx": {"u1": 2.0, "vx": -3.0, "omega vy": 0.4, "u2^2 vx": -0.2},
                              "vy": {"vy": -5.0, "omega vx": -0.3},
                              "omega": {"u2": 1.5, "omega": -2.5, "u2 vx": 0.1}})
    return [ProcessModel(PolyBody()), ProcessModel(PoseTimeDynamics()), ProcessModel(ConstantVelocityModel(), "cv"),
            ProcessModel(LagModel(0.9, 0.3, 0.7, 0.15)), ProcessModel(UnicycleModel(0.9, 1.2)),
            ProcessModel(LinearDynamics(A, B)), ProcessModel(sindy, name="sindy_model"),
            ProcessModel(TrueDynamics(RobotParams()), name="real_oracle")]


def _numerical_jacobian(fun, x, eps=1e-6):
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((fun(x + d) - fun(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("model", _models(), ids=lambda m: m.name)
def test_step_jacobians_match_numerical_derivatives(model):
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = np.concatenate([rng.normal(size=2) * 3, rng.uniform(-3, 3, 1), rng.normal(size=3) * 0.7])
        u = rng.uniform(-1, 1, 2)
        t, dt = 1.3, 0.05
        _, F, G = model.step_and_jac(x, u, t, dt)
        F_num = _numerical_jacobian(lambda xx: model.step(xx, u, t, dt), x)
        G_num = _numerical_jacobian(lambda uu: model.step(x, uu, t, dt), u)
        np.testing.assert_allclose(F, F_num, atol=1e-7, rtol=1e-6)
        np.testing.assert_allclose(G, G_num, atol=1e-7, rtol=1e-6)
        # the continuous Jacobian too (the chain through the stages builds on it)
        _, Jx, Ju = model.dynamics.derivative_and_jacobians(x, u, t)
        np.testing.assert_allclose(Jx, _numerical_jacobian(lambda xx: model.f(xx, u, t), x), atol=1e-6)
        np.testing.assert_allclose(Ju, _numerical_jacobian(lambda uu: model.f(x, uu, t), u), atol=1e-6)


def test_vectorised_step_equals_single_steps():
    model = ProcessModel(PoseTimeDynamics())
    rng = np.random.default_rng(1)
    x = rng.normal(size=(7, 6))
    u = rng.uniform(-1, 1, (7, 2))
    t = rng.uniform(0, 5, 7)
    dt = rng.uniform(0.01, 0.05, 7)
    xn, F, G = model.step_and_jac(x, u, t, dt)
    for i in range(7):
        xi, Fi, Gi = model.step_and_jac(x[i], u[i], t[i], dt[i])
        np.testing.assert_allclose(xn[i], xi, rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(F[i], Fi, rtol=1e-14, atol=1e-14)


def test_rk4_propagation_matches_scipy_dop853():
    model = ProcessModel(PolyBody())
    t = np.arange(0.0, 5.0 + 1e-9, 0.02)
    u = np.column_stack([0.8 * np.ones_like(t), 0.5 * np.ones_like(t)])
    x0 = np.array([1.0, -2.0, 0.3, 0.1, 0.0, 0.0])
    x_rk4 = model.propagate(x0, u, t)
    ref = solve_ivp(lambda tt, xx: model.f(xx, u[0], tt), (0, 5), x0, t_eval=t, method="DOP853",
                    rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(x_rk4, ref.y.T, atol=1e-7)


def _simulate_series(model, Q_rate, rng, n=4000, dt=0.02):
    t = np.arange(n) * dt
    u = np.column_stack([np.sin(0.3 * t) * 0.8, np.sign(np.sin(0.11 * t)) * 0.6])
    x = np.zeros((n, 6))
    L = np.linalg.cholesky(Q_rate * dt)
    for k in range(n - 1):
        x[k + 1] = model.step(x[k], u[k], t[k], dt) + L @ rng.standard_normal(6)
    return StateSeries("sim", t, x, u)


def test_process_noise_recovers_the_generating_density():
    rng = np.random.default_rng(7)
    Q_rate = np.diag([1e-4, 2e-4, 5e-5, 4e-3, 1e-3, 2e-3])
    model = ProcessModel(LagModel(1.0, 0.25, 0.8, 0.2))
    series = [_simulate_series(model, Q_rate, rng) for _ in range(2)]
    fit_process_noise(model, series, floor_std=0.0)
    # 8000 samples: relative standard error of a variance is sqrt(2/8000) = 1.6 %
    np.testing.assert_allclose(np.diag(model.Q_rate_), np.diag(Q_rate), rtol=0.06)
    assert np.all(np.linalg.eigvalsh(model.Q_rate_) > 0)
    # the one-step residual std is that of the noise added per 0.02 s step
    np.testing.assert_allclose(model.residual_std_, np.sqrt(np.diag(Q_rate) * 0.02), rtol=0.03)


def test_state_series_and_body_states_convert_column_by_column():
    t = np.array([0.0, 0.1, 0.2])
    x6 = np.arange(18.0).reshape(3, 6)  # columns x, y, psi, vx, vy, omega
    u = np.array([[0.1, -0.2], [0.3, -0.4], [0.5, -0.6]])
    st = body_states_from_state_series(StateSeries("s", t, x6, u))
    for name, column in (("x", 0), ("y", 1), ("yaw", 2), ("vx", 3), ("vy", 4), ("omega", 5)):
        np.testing.assert_array_equal(getattr(st, name), x6[:, column])
    np.testing.assert_array_equal(st.u1, u[:, 0])
    np.testing.assert_array_equal(st.u2, u[:, 1])
    back = state_series_from_body_states(st, "s")
    np.testing.assert_array_equal(back.x6, x6)
    np.testing.assert_array_equal(back.u, u)


def test_lag_fit_recovers_known_gains():
    rng = np.random.default_rng(8)
    truth = ProcessModel(LagModel(1.2, 0.3, 0.9, 0.12))
    series = [_simulate_series(truth, np.diag([1e-8] * 3 + [1e-6] * 3), rng, n=3000)]
    fit = LagModel().fit([body_states_from_state_series(s) for s in series])
    assert fit.k_v_ == pytest.approx(1.2, rel=0.03)
    assert fit.tau_v_ == pytest.approx(0.3, rel=0.05)
    assert fit.k_w_ == pytest.approx(0.9, rel=0.03)
    assert fit.tau_w_ == pytest.approx(0.12, rel=0.08)


def test_missing_process_noise_is_named():
    with pytest.raises(Exception, match="'cv'.*fit_process_noise"):
        ProcessModel(ConstantVelocityModel(), "cv").Q(0.02)


def test_non_increasing_state_times_name_the_run():
    s = StateSeries("run_07", np.array([0.0, 0.02, 0.02, 0.04]), np.zeros((4, 6)), np.zeros((4, 2)))
    with pytest.raises(Exception, match="run_07"):
        fit_process_noise(ProcessModel(ConstantVelocityModel()), [s])


def test_envelope_flags_states_outside_the_training_range():
    envelope = {"vx": [-0.5, 1.0], "vy": [-0.1, 0.1], "omega": [-1.0, 1.0], "u1": [-1, 1], "u2": [-1, 1]}
    model = ProcessModel(model_from_terms({"vx": {"vx": -1.0}}, envelope=envelope))
    x = np.zeros((3, 6))
    x[1, 3] = 1.2  # beyond 1.0 + 10 % of the 1.5 m/s width = 1.15
    x[2, 3] = 1.1  # inside the widened envelope
    np.testing.assert_array_equal(model.in_envelope(x, np.zeros(2)), [True, False, True])


# -- unmodelled states: Gauss-Markov instead of a random walk -----------------------------------

class ZeroLateral(PolyBody):
    """The identified model of the real cmd runs in miniature: dvy/dt = 0, vy in the yaw equation."""

    name = "zero_lateral"

    @staticmethod
    def f(x, u):
        f = PolyBody.f(x, u)
        f[..., 1] = 0.0
        f[..., 2] += 0.8 * x[..., 1]
        return f

    @staticmethod
    def J_f_x(x, u):
        J = PolyBody.J_f_x(x, u)
        J[..., 1, :] = 0.0
        J[..., 2, 1] += 0.8
        return J

    @staticmethod
    def J_f_u(x, u):
        J = PolyBody.J_f_u(x, u)
        J[..., 1, :] = 0.0
        return J


def _gm_series(tau_s: float, std: float, n: int = 20000, dt: float = 0.02, seed: int = 0) -> StateSeries:
    """A run whose vy is an exact sampled first-order Gauss-Markov process (the reference)."""
    rng = np.random.default_rng(seed)
    phi = np.exp(-dt / tau_s)
    vy = np.empty(n)
    vy[0] = rng.normal(0, std)
    e = rng.normal(0, std * np.sqrt(1 - phi ** 2), n)
    for k in range(1, n):
        vy[k] = phi * vy[k - 1] + e[k]
    x6 = np.zeros((n, 6))
    x6[:, 4] = vy
    return StateSeries("gm", np.arange(n) * dt, x6, np.zeros((n, 2)))


def test_unmodelled_states_are_the_zero_equations_another_one_depends_on():
    series = [_gm_series(0.5, 0.05, n=500)]
    assert unmodelled_states(ProcessModel(ZeroLateral()), series) == [4]
    assert unmodelled_states(ProcessModel(PolyBody()), series) == []


class _HandAccel(Dynamics):
    """Accelerations written out by hand, ``accel(vx, vy, omega, u1)``, with their Jacobians by
    central differences (the rule needs only which entries are zero)."""

    def __init__(self, accel):
        self._accel = accel

    def accel_and_jacobians(self, x6, u, t=0.0):
        x6, u = np.asarray(x6, float), np.asarray(u, float)
        a = self._accel(x6[..., 3], x6[..., 4], x6[..., 5], u[..., 0])
        J_x, J_u = np.zeros(a.shape + (6,)), np.zeros(a.shape + (2,))
        for j in range(3):
            e = np.zeros(6)
            e[3 + j] = 1e-6
            J_x[..., 3 + j] = (self._accel(*(x6 + e)[..., 3:].T, u[..., 0]) -
                               self._accel(*(x6 - e)[..., 3:].T, u[..., 0])) / 2e-6
        J_u[..., 0] = (self._accel(*x6[..., 3:].T, u[..., 0] + 1e-6) - self._accel(*x6[..., 3:].T, u[..., 0] - 1e-6)) / 2e-6
        return a, J_x, J_u


def _accel(vx_dot, vy_dot, omega_dot):
    return lambda vx, vy, w, u1: np.stack(np.broadcast_arrays(vx_dot(vx, vy, w, u1), vy_dot(vx, vy, w, u1),
                                                              omega_dot(vx, vy, w, u1)), axis=-1)


@pytest.mark.parametrize("name, accel, expected", [
    # dvy/dt = 0 and the yaw rate depends on vy everywhere: the random walk of the cmd runs
    ("coupled", _accel(lambda vx, vy, w, u1: u1 - vx, lambda *a: 0.0, lambda vx, vy, w, u1: 0.8 * vy - w), [4]),
    # dvy/dt = 0 but no other equation depends on vy: vy does not matter, nothing to model
    ("uncoupled", _accel(lambda vx, vy, w, u1: u1 - vx, lambda *a: 0.0, lambda vx, vy, w, u1: -w), []),
    # zero on every sample by chance (u1 = 0 there), not identically: its input Jacobian is vy
    ("zero by chance, input", _accel(lambda vx, vy, w, u1: -vx, lambda vx, vy, w, u1: u1 * vy,
                                     lambda vx, vy, w, u1: 0.8 * vy - w), []),
    # zero on every sample by chance (vx = 0 there): its Jacobian in vx is vy
    ("zero by chance, state", _accel(lambda vx, vy, w, u1: -vx, lambda vx, vy, w, u1: vx * vy,
                                     lambda vx, vy, w, u1: 0.8 * vy - w), []),
    # dvx/dt = 0, the lateral equation depends on vx: vx is the unmodelled state
    ("forward", _accel(lambda *a: 0.0, lambda vx, vy, w, u1: 0.5 * vx - vy, lambda vx, vy, w, u1: -w), [3]),
])
def test_unmodelled_states_by_hand(name, accel, expected):
    # samples with vx = 0 and u1 = 0 (the chance zeros), vy and omega nonzero
    series = [_gm_series(0.5, 0.05, n=200)]
    series[0].x6[:, 5] = 0.1
    assert unmodelled_states(ProcessModel(_HandAccel(accel)), series) == expected, name


def test_mean_reversion_time_constant_and_noise_match_the_gauss_markov_reference():
    tau, std = 0.8, 0.05
    series = [_gm_series(tau, std, seed=s) for s in range(3)]
    assert fit_mean_reversion(series, 4) == pytest.approx(tau, rel=0.1)
    model = fit_process_noise(ProcessModel(ZeroLateral()), series)
    assert model.mean_reverting_[4] == pytest.approx(tau, rel=0.1)
    # textbook first-order Gauss-Markov: noise density 2 std^2 / tau (Gelb 1974, table 3.8-1)
    assert model.Q_rate_[4, 4] == pytest.approx(2 * std ** 2 / tau, rel=0.1)
    # the step decays vy by exp(-dt / tau) and its row of F is that factor on vy alone (by hand)
    x = np.array([0.0, 0.0, 0.0, 0.5, 0.2, 0.1])
    x_next, F, G = model.step_and_jac(x, np.zeros(2), 0.0, 0.02)
    phi = np.exp(-0.02 / model.mean_reverting_[4])
    assert x_next[4] == pytest.approx(0.2 * phi, rel=1e-12)
    np.testing.assert_allclose(F[4], phi * np.eye(6)[4], atol=1e-15)
    np.testing.assert_allclose(G[4], 0.0, atol=1e-15)
    assert model.step(x, np.zeros(2), 0.0, 0.02)[4] == pytest.approx(0.2 * phi, rel=1e-12)


def test_dead_reckoned_vy_variance_stays_at_the_stationary_one():
    # propagating only the covariance for 30 s: a Gauss-Markov vy levels off at its stationary
    # variance std^2 (the reference); the random walk (mean_reverting=False) grows as Q t
    tau, std = 0.8, 0.05
    series = [_gm_series(tau, std, seed=s) for s in range(3)]
    gm = fit_process_noise(ProcessModel(ZeroLateral()), series)
    rw = fit_process_noise(ProcessModel(ZeroLateral()), series, mean_reverting=False)
    assert rw.mean_reverting_ == {}
    out = {}
    for name, m in (("gm", gm), ("rw", rw)):
        x, P = np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.0]), np.diag([1e-4] * 6)
        for _ in range(1500):
            x, F, _ = m.step_and_jac(x, np.zeros(2), 0.0, 0.02)
            P = F @ P @ F.T + m.Q(0.02)
        out[name] = P[4, 4]
    assert out["gm"] == pytest.approx(std ** 2, rel=0.15)
    assert out["rw"] > 10 * std ** 2
