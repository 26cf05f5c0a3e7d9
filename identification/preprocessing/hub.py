"""Turning-hub eccentricity model of the prism-to-prism baseline length (thesis 5.2.3, eq. 5.25).

Each prism sits in a motorised hub (thesis 3.1.7, 4.3) that turns it towards its tracker. The
prism reference point is off the hub axis by a radius ``r_i`` (table 7.5: about 0.21 mm front,
0.12 mm rear), so it moves on a circle in the body's horizontal plane as the hub turns. The
commanded azimuth (eqs. 4.1 to 4.6) is the angle from the horizontal baseline direction (fixed
in the body) to the prism-to-tracker direction, measured *clockwise* seen from above: eq. 4.4
projects the prism-to-tracker vector ``-x`` on the baseline but eq. 4.5 projects the
tracker-to-prism vector ``+x`` on the counter-clockwise normal. So up to a per-run phase the
azimuth is minus the hub's angle in the body frame. Eq. 5.25 models the baseline length as

.. math:: l(t_i) + \\epsilon_i = c + r_1 \\cos(\\varphi_1 + \\Phi_1) + r_2 \\cos(\\varphi_2 + \\Phi_2)

which is linear in ``c`` and ``(a_i, b_i) = (r_i cos Phi_i, -r_i sin Phi_i)``:
``l = c + a_1 cos(phi_1) + b_1 sin(phi_1) + a_2 cos(phi_2) + b_2 sin(phi_2)``. The thesis fitted
it with ``scipy.optimize.curve_fit`` per run; here the same least squares is solved linearly
(no start values, no local minima) and radii and phases follow by error propagation.

What the model can and cannot correct
-------------------------------------
The baseline observes only the component of each eccentricity vector along the baseline:
``r_i cos(phi_i + Phi_i)``. That component is estimated directly. The perpendicular component
``r_i sin(phi_i + Phi_i)`` (which tilts the baseline and so biases the yaw by up to
``(r_1 + r_2) / c``, about 0.025 deg) follows only from the sense in which the hub turns: a
hub that keeps its prism facing the tracker turns clockwise as the azimuth of eq. 4.6 grows
(``sense=-1``, the default); ``sense=+1`` flips the perpendicular part for a hub mounted the
other way. Nothing in the baseline tells where the prism was when the lever arms were
surveyed (thesis 5.2.3): :meth:`HubModel.eccentricity_body` and :meth:`HubModel.correct`
remove the whole circular motion, i.e. refer the prisms to the hub axes, which is right when
the lever arms are the hub axes (as in the simulator) and leaves a constant body-frame offset
of at most ``r_i`` per prism otherwise. The fitted ``r_i`` is the amplitude along the 3D baseline;
the horizontal radius is ``r_i / cos(elevation)`` with the baseline's elevation in the body
(about 10 deg for table 7.1, i.e. 1.6 %), which :meth:`HubModel.radius_horizontal` applies.

Per run or pooled
-----------------
Both azimuths follow the robot's heading, so within a run they move almost together
(correlation about 0.98 on simulated runs) and only their slowly varying difference separates
the two circles. Runs of several minutes do that well (simulated default campaign: radii
within 2 um per run), runs of half a minute do not (up to 0.1 mm off). :func:`fit_hub_model_joint`
shares the radii across runs, as thesis 5.2.3 proposes, and recovers them within a few um even
from nine 30 s runs (``bench/results/poses.md``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from groundfloor.errors import InputError

log = logging.getLogger(__name__)

#: condition number of the scaled normal matrix above which the model is not identifiable
MAX_CONDITION = 1e8


@dataclass(frozen=True)
class HubModel:
    """Fitted eq. 5.25 for one run: constant baseline, two hub eccentricities, uncertainties.

    ``params`` is ``[c, a_front, b_front, a_rear, b_rear]`` (metres) with covariance ``cov``
    (a posteriori: scaled by the variance factor ``s0_m**2`` of the fit, as the thesis did;
    the residuals are correlated in time, so these are lower bounds).
    """

    params: np.ndarray  # (5,) [c, a_f, b_f, a_r, b_r], m
    cov: np.ndarray  # (5, 5) a posteriori covariance of params, m^2
    s0_m: float  # a posteriori standard deviation of one baseline length, m
    rms_before_m: float  # RMS of the baseline length about its mean, m
    rms_after_m: float  # RMS of the residual after the model, m
    n: int  # samples used
    t: np.ndarray  # (n,) sample times (for plotting), s
    baseline_length_m: np.ndarray  # (n,) the fitted baseline lengths, m
    azimuth_front: np.ndarray  # (n,) rad
    azimuth_rear: np.ndarray  # (n,) rad

    @property
    def c_m(self) -> float:
        """Constant prism-to-prism distance c of eq. 5.25, m."""
        return float(self.params[0])

    @property
    def c_std_m(self) -> float:
        """Standard deviation of c, m."""
        return float(np.sqrt(self.cov[0, 0]))

    @property
    def radius_m(self) -> np.ndarray:
        """(2,) eccentricity amplitudes along the baseline [front, rear] (r_1, r_2 of eq. 5.25), m."""
        ab = self.params[1:].reshape(2, 2)
        return np.hypot(ab[:, 0], ab[:, 1])

    @property
    def phase_rad(self) -> np.ndarray:
        """(2,) phases [front, rear] (Phi_1, Phi_2 of eq. 5.25), rad in (-pi, pi]."""
        ab = self.params[1:].reshape(2, 2)
        return np.arctan2(-ab[:, 1], ab[:, 0])

    def _J_polar_ab(self) -> np.ndarray:
        """Return (2, 2, 2) Jacobians d[r, Phi]/d[a, b] per hub (error propagation)."""
        ab = self.params[1:].reshape(2, 2)
        a, b = ab[:, 0], ab[:, 1]
        r2 = np.maximum(a**2 + b**2, 1e-30)
        r = np.sqrt(r2)
        return np.stack([np.stack([a / r, b / r], -1), np.stack([b / r2, -a / r2], -1)], 1)

    @property
    def radius_std_m(self) -> np.ndarray:
        """(2,) standard deviations of the radii by first-order error propagation, m."""
        return np.sqrt(self._polar_cov()[:, 0, 0])

    @property
    def phase_std_rad(self) -> np.ndarray:
        """(2,) standard deviations of the phases by first-order error propagation, rad."""
        return np.sqrt(self._polar_cov()[:, 1, 1])

    def _polar_cov(self) -> np.ndarray:
        """Return (2, 2, 2) covariances of [r, Phi] per hub."""
        J = self._J_polar_ab()
        C = np.stack([self.cov[1:3, 1:3], self.cov[3:5, 3:5]])
        return J @ C @ np.swapaxes(J, 1, 2)

    def radius_horizontal(self, lever_front_body, lever_rear_body) -> np.ndarray:
        """Return (2,) physical (horizontal) hub radii [front, rear], m.

        The eccentricity circle lies in the body's horizontal plane; the baseline sees it
        foreshortened by the cosine of the baseline's elevation in the body frame.
        """
        d = np.asarray(lever_front_body, float) - np.asarray(lever_rear_body, float)
        return self.radius_m * np.linalg.norm(d) / np.linalg.norm(d[:2])

    def predict(self, azimuth_front, azimuth_rear) -> np.ndarray:
        """Return the modelled baseline length (eq. 5.25) at the given azimuths, m."""
        return _design(np.asarray(azimuth_front, float), np.asarray(azimuth_rear, float)) @ self.params

    def residual(self) -> np.ndarray:
        """Return the fit residual ``l - model`` at the fitted samples, m."""
        return self.baseline_length_m - self.predict(self.azimuth_front, self.azimuth_rear)

    def eccentricity_body(self, azimuth_front, azimuth_rear, lever_front_body, lever_rear_body,
                          sense: int = -1) -> tuple[np.ndarray, np.ndarray]:
        """Return the (n, 3) body-frame offsets of the front and rear prisms from their hub axes, m.

        ``e_i = R_i (cos(phi_i + Phi_i) d_i + sense * sin(phi_i + Phi_i) z x d_i)`` with ``d_i``
        the horizontal unit vector from the other prism to prism ``i`` (so the along-baseline
        part reproduces eq. 5.25 exactly), ``R_i`` the horizontal radius and ``sense = -1``
        for the clockwise azimuth of eq. 4.6 (see the module docstring). Add them to the
        lever arms to get time-varying lever arms for :func:`identification.preprocessing.poses.fit_poses`,
        or subtract them in the body frame to refer measurements to the hub axes.
        """
        if sense not in (1, -1):
            raise InputError(f"sense: must be +1 or -1, got {sense!r}")
        lf = np.asarray(lever_front_body, float)
        lr = np.asarray(lever_rear_body, float)
        d = np.array([lf[0] - lr[0], lf[1] - lr[1], 0.0])
        if np.linalg.norm(d) < 1e-6:
            raise InputError("lever_front_body: lever arms have no horizontal separation")
        d /= np.linalg.norm(d)
        radius = self.radius_horizontal(lf, lr)
        out = []
        for i, (az, sign) in enumerate(((azimuth_front, 1.0), (azimuth_rear, -1.0))):
            theta = np.asarray(az, float) + self.phase_rad[i]
            d_i = sign * d
            m_i = np.array([-d_i[1], d_i[0], 0.0])  # z x d_i
            out.append(radius[i] * (np.cos(theta)[:, None] * d_i + sense * np.sin(theta)[:, None] * m_i))
        return out[0], out[1]

    def correct(self, p_front_local, p_rear_local, azimuth_front, azimuth_rear,
                sense: int = -1) -> tuple[np.ndarray, np.ndarray]:
        """Return the (n, 3) prism positions referred to the hub axes, local frame, m.

        Works in the local frame without a pose: ``d_i`` is the measured horizontal baseline
        direction, so this is :meth:`eccentricity_body` rotated by the instantaneous heading of
        the baseline (pitch neglected: below 1e-4 relative). The along-baseline part is what
        eq. 5.25 observes; the perpendicular part rests on ``sense`` (see the module docstring).
        The corrected baseline length varies by the fit residual only.
        """
        if sense not in (1, -1):
            raise InputError(f"sense: must be +1 or -1, got {sense!r}")
        pf = np.asarray(p_front_local, float)
        pr = np.asarray(p_rear_local, float)
        d3 = pf - pr
        length = np.linalg.norm(d3, axis=1)
        d = d3.copy()
        d[:, 2] = 0.0
        horiz = np.linalg.norm(d, axis=1)
        d /= horiz[:, None]
        radius_scale = (length / horiz)[:, None]  # along-3D amplitude -> horizontal radius
        out = []
        for i, (p, az, sign) in enumerate(((pf, azimuth_front, 1.0), (pr, azimuth_rear, -1.0))):
            theta = np.asarray(az, float) + self.phase_rad[i]
            d_i = sign * d
            m_i = np.column_stack([-d_i[:, 1], d_i[:, 0], np.zeros(len(d_i))])
            e = self.radius_m[i] * radius_scale * (np.cos(theta)[:, None] * d_i
                                                   + sense * np.sin(theta)[:, None] * m_i)
            out.append(p - e)
        return out[0], out[1]


def _design(azimuth_front: np.ndarray, azimuth_rear: np.ndarray) -> np.ndarray:
    """Return the (n, 5) design matrix of eq. 5.25 in its linear form."""
    return np.column_stack([np.ones_like(azimuth_front), np.cos(azimuth_front), np.sin(azimuth_front),
                            np.cos(azimuth_rear), np.sin(azimuth_rear)])


def fit_hub_model(t, baseline_length_m, azimuth_front, azimuth_rear) -> HubModel:
    """Return the least-squares turning-hub eccentricity model of one run.

    Implements eq. 5.25 (thesis 5.2.3) in linear form, with the a posteriori covariance of
    eqs. 2.25 and 2.26 and radii/phases by error propagation.

    Parameters
    ----------
    t : (n,) sample times, s (only carried for plots).
    baseline_length_m : (n,) prism-to-prism distances ``|p_front - p_rear|``, m.
    azimuth_front, azimuth_rear : (n,) commanded hub azimuths at the same times, rad (the
        ``/turning_hub/azimuth`` set points interpolated at the trigger times by the caller).

    Samples with a non-finite value in any input are left out.

    Raises
    ------
    InputError
        Mismatched lengths, fewer than 10 usable samples, or an azimuth that does not vary
        enough to separate the eccentricity from the constant (the argument is named).
    """
    arrays = {"t": t, "baseline_length_m": baseline_length_m, "azimuth_front": azimuth_front,
              "azimuth_rear": azimuth_rear}
    arrays = {k: np.asarray(v, dtype=float).ravel() for k, v in arrays.items()}
    n_all = arrays["baseline_length_m"].size
    for key, val in arrays.items():
        if val.size != n_all:
            raise InputError(f"{key}: {val.size} samples, baseline_length_m has {n_all}")
    ok = np.logical_and.reduce([np.isfinite(v) for v in arrays.values()])
    if ok.sum() < 10:
        raise InputError(f"baseline_length_m: only {int(ok.sum())} usable samples (need 10)")
    tt, l, az_f, az_r = (arrays[k][ok] for k in arrays)
    A = _design(az_f, az_r)
    # column scaling so that the condition number measures identifiability, not units
    scale = np.linalg.norm(A, axis=0)
    for key, cols in (("azimuth_front", [1, 2]), ("azimuth_rear", [3, 4])):
        sub = A[:, [0, *cols]] / scale[[0, *cols]]
        sv = np.linalg.svd(sub, compute_uv=False)
        if sv[-1] < sv[0] / MAX_CONDITION**0.5:
            raise InputError(f"{key}: azimuth does not vary enough to fit the hub eccentricity "
                             f"(span {np.ptp(np.unwrap(arrays[key][ok])):.3g} rad)")
    As = A / scale
    sv = np.linalg.svd(As, compute_uv=False)
    if sv[-1] < sv[0] / MAX_CONDITION**0.5:
        raise InputError("azimuth_rear: moves in lockstep with azimuth_front, the two hubs cannot be "
                         "separated in this run (fit_hub_model_joint pools runs)")
    params_s, *_ = np.linalg.lstsq(As, l, rcond=None)
    params = params_s / scale
    v = l - A @ params
    dof = l.size - 5
    s0_sq = float(v @ v) / dof if dof > 0 else np.nan
    Q = np.linalg.inv(As.T @ As) / np.outer(scale, scale)
    cov = s0_sq * Q
    model = HubModel(params=params, cov=0.5 * (cov + cov.T), s0_m=float(np.sqrt(s0_sq)),
                     rms_before_m=float(np.std(l)), rms_after_m=float(np.sqrt(np.mean(v**2))),
                     n=int(l.size), t=tt, baseline_length_m=l, azimuth_front=az_f, azimuth_rear=az_r)
    log.debug("hub model: c=%.6f m, r=%s mm, rms %.3f -> %.3f mm", model.c_m, model.radius_m * 1e3,
              model.rms_before_m * 1e3, model.rms_after_m * 1e3)
    return model


def fit_hub_model_joint(runs) -> tuple[HubModel, ...]:
    """Return one HubModel per run with the two radii shared by all runs.

    Implements the improvement thesis 5.2.3 proposes: the radii are properties of the hubs and
    the same in every run, while the constant ``c_j`` and the phases ``Phi_1j``, ``Phi_2j``
    (how the prisms were seated) are per run. Within one run the two azimuths follow the
    robot's heading almost together (correlation ~0.98), so a short run separates the two
    circles poorly; pooling the runs, whose phase differences differ, fixes that. Solved as a
    nonlinear least-squares problem (``scipy.optimize.least_squares``, analytic Jacobian)
    started from the per-run linear fits; the covariance is ``s0^2 (J^T J)^-1`` with one
    pooled variance factor, propagated to each run's ``[c, a_1, b_1, a_2, b_2]``.

    Parameters
    ----------
    runs : sequence of ``(t, baseline_length_m, azimuth_front, azimuth_rear)`` tuples, as the
        arguments of :func:`fit_hub_model`. Each run must be fittable on its own (its linear
        fit gives the start values); :class:`InputError` otherwise, naming the argument.
    """
    singles = [fit_hub_model(*run) for run in runs]
    if not singles:
        raise InputError("runs: no runs to fit")
    k = len(singles)
    l_all = np.concatenate([m.baseline_length_m for m in singles])
    az1 = np.concatenate([m.azimuth_front for m in singles])
    az2 = np.concatenate([m.azimuth_rear for m in singles])
    run_of = np.repeat(np.arange(k), [m.n for m in singles])
    n_par = 2 + 3 * k

    def unpack(p):
        c, ph1, ph2 = p[2::3], p[3::3], p[4::3]
        return p[0], p[1], c[run_of], az1 + ph1[run_of], az2 + ph2[run_of]

    def residual(p):
        r1, r2, c, th1, th2 = unpack(p)
        return c + r1 * np.cos(th1) + r2 * np.cos(th2) - l_all

    def jacobian(p):
        r1, r2, _, th1, th2 = unpack(p)
        J = np.zeros((l_all.size, n_par))
        J[:, 0], J[:, 1] = np.cos(th1), np.cos(th2)
        rows = np.arange(l_all.size)
        J[rows, 2 + 3 * run_of] = 1.0
        J[rows, 3 + 3 * run_of] = -r1 * np.sin(th1)
        J[rows, 4 + 3 * run_of] = -r2 * np.sin(th2)
        return J

    x0 = np.zeros(n_par)
    x0[0], x0[1] = (np.median([m.radius_m[i] for m in singles]) for i in (0, 1))
    for j, m in enumerate(singles):
        x0[2 + 3 * j], x0[3 + 3 * j], x0[4 + 3 * j] = m.c_m, *m.phase_rad
    sol = least_squares(residual, x0, jac=jacobian, method="lm", x_scale="jac")
    p = sol.x.copy()
    if p[0] < 0:  # a negative radius is the same circle half a turn on
        p[0], p[3::3] = -p[0], p[3::3] + np.pi
    if p[1] < 0:
        p[1], p[4::3] = -p[1], p[4::3] + np.pi
    v = residual(p)
    J = jacobian(p)
    s0_sq = float(v @ v) / max(l_all.size - n_par, 1)
    cov_p = s0_sq * np.linalg.inv(J.T @ J)
    out = []
    for j, m in enumerate(singles):
        idx = [0, 1, 2 + 3 * j, 3 + 3 * j, 4 + 3 * j]  # r1, r2, c, Phi1, Phi2
        r1, r2, c, ph1, ph2 = p[idx]
        params = np.array([c, r1 * np.cos(ph1), -r1 * np.sin(ph1), r2 * np.cos(ph2), -r2 * np.sin(ph2)])
        G = np.zeros((5, 5))  # d[c, a1, b1, a2, b2] / d[r1, r2, c, Phi1, Phi2]
        G[0, 2] = 1.0
        G[1, 0], G[1, 3] = np.cos(ph1), -r1 * np.sin(ph1)
        G[2, 0], G[2, 3] = -np.sin(ph1), -r1 * np.cos(ph1)
        G[3, 1], G[3, 4] = np.cos(ph2), -r2 * np.sin(ph2)
        G[4, 1], G[4, 4] = -np.sin(ph2), -r2 * np.cos(ph2)
        cov = G @ cov_p[np.ix_(idx, idx)] @ G.T
        vj = v[run_of == j]
        out.append(HubModel(params=params, cov=0.5 * (cov + cov.T), s0_m=float(np.sqrt(s0_sq)),
                            rms_before_m=m.rms_before_m, rms_after_m=float(np.sqrt(np.mean(vj**2))), n=m.n,
                            t=m.t, baseline_length_m=m.baseline_length_m, azimuth_front=m.azimuth_front,
                            azimuth_rear=m.azimuth_rear))
    log.info("joint hub model over %d runs: r = %.4f, %.4f mm", k, p[0] * 1e3, p[1] * 1e3)
    return tuple(out)
