"""Simulator variants (issue 13, item 6): drawn deterministically from their index, different
across indices, every draw in its declared range, robots inside the envelope, round trip through
truth/, and variant 0 the simulator of main."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
import yaml

from groundfloor.errors import InputError
from simulation.driver import DrivingArea
from simulation.lateral import LATERAL_FORMS
from simulation.process_noise import NOISE_FORMS
from simulation.robot import simulate_run
from simulation.robot_params import RobotParams
from simulation.variant import Variant
from simulation.variants import DRIVER_STYLES, RANGES, check_envelope, check_variant, draw_variant

INDICES = tuple(range(1, 11))  # ten variants, never one simulator alone


@pytest.fixture(scope="module")
def variants() -> dict[int, Variant]:
    return {n: draw_variant(n) for n in INDICES}


def test_variant_zero_is_the_simulator_before_variants():
    assert draw_variant(0) == Variant() == check_variant(None) == check_variant(0)
    assert Variant().is_default and not draw_variant(1).is_default
    assert Variant().robot == RobotParams() and Variant().motor_lag_s == 0.0
    assert Variant().trackers()["at960"].noise_a_m == 3.75e-6  # table 3.2 read as 2 sigma


def test_same_index_same_variant_other_index_other_variant(variants):
    for n in (1, 7):
        assert draw_variant.__wrapped__(n) == variants[n]  # drawn again, not the cache
    for (n, a), (m, b) in itertools.combinations(variants.items(), 2):
        assert a.robot.terms_vx != b.robot.terms_vx, (n, m)
        assert a.motor_lag_s != b.motor_lag_s and a.driver.joy_rate_hz != b.driver.joy_rate_hz, (n, m)


def test_structural_choices_vary_across_ten_variants(variants):
    draws = [dict(v.draws) for v in variants.values()]
    assert len({d["lateral_form"] for d in draws}) >= 3
    assert len({d["noise_form"] for d in draws}) == len(NOISE_FORMS)
    assert {d["driver_style"] for d in draws} == set(DRIVER_STYLES)


def test_every_drawn_quantity_lies_in_its_range(variants):
    base = RobotParams()
    for n, v in variants.items():
        d = dict(v.draws)
        for key, (lo, hi) in RANGES.items():
            if key in d:
                assert lo <= d[key] <= hi, (n, key, d[key])
        assert d["lateral_form"] == v.lateral.form in LATERAL_FORMS
        shape = LATERAL_FORMS[v.lateral.form][0]
        if shape:
            assert RANGES[f"lateral_{shape}"][0] <= v.lateral.shape <= RANGES[f"lateral_{shape}"][1]
        assert RANGES["motor_lag_s"][0] <= v.motor_lag_s <= RANGES["motor_lag_s"][1]
        assert v.noise.form == d["noise_form"] in NOISE_FORMS
        if v.noise.form == "coloured":
            assert RANGES["noise_resonance_hz"][0] <= v.noise.resonance_hz <= RANGES["noise_resonance_hz"][1]
            assert RANGES["noise_damping_ratio"][0] <= v.noise.damping_ratio <= RANGES["noise_damping_ratio"][1]
        for k in v.tracker_noise_scale:
            assert RANGES["tracker_noise_scale"][0] <= k <= RANGES["tracker_noise_scale"][1]
        for s, s0 in zip(v.robot.accel_noise_std, base.accel_noise_std):
            assert RANGES["noise_std_factor"][0] <= s / s0 <= RANGES["noise_std_factor"][1]
        assert RANGES["joy_rate_hz"][0] <= v.driver.joy_rate_hz <= RANGES["joy_rate_hz"][1]
        # model B's coefficients: same terms, each changed by at most 30 %
        for mine, thesis in ((v.robot.terms_vx, base.terms_vx), (v.robot.terms_omega, base.terms_omega)):
            assert [t for t, _ in mine] == [t for t, _ in thesis]
            ratio = np.array([c / c0 for (_, c), (_, c0) in zip(mine, thesis)])
            assert np.all(np.abs(ratio - 1.0) <= 0.3 + 1e-12), n
        assert d["max_coefficient_change"] == pytest.approx(max(
            abs(c / c0 - 1.0) for (_, c), (_, c0) in zip(v.robot.terms_vx + v.robot.terms_omega,
                                                         base.terms_vx + base.terms_omega)))


def test_model_b_passes_the_envelope_check_and_a_folded_robot_does_not():
    ok = check_envelope(RobotParams(), Variant().lateral)
    assert ok.ok and ok.top_speed_m_s == pytest.approx(0.811, abs=2e-3)  # test_robot's steady states
    assert ok.peak_track_speed_m_s < 0.9 and ok.peak_omega_rad_s < 1.2
    # 3 % more throttle authority in model B removes the full-throttle steady state (its fold)
    p = RobotParams()
    terms = tuple((n, c * 1.03 if n == "u1" else c) for n, c in p.terms_vx)
    bad = check_envelope(replace(p, terms_vx=terms), Variant().lateral)
    assert not bad.ok and "fold" in bad.reason


def test_variant_runs_stay_sane(variants):
    """Every variant drives: inside the area, heading within limits, speeds below the limiters,
    its joystick at its rate; gentle drivers command less than aggressive ones on average."""
    area = DrivingArea()
    command = {"gentle": [], "aggressive": []}
    for n, v in variants.items():
        run = simulate_run(30.0, np.random.default_rng(n), variant=v, dt=0.004)
        command[v.driver.style].append(np.mean(np.abs(run.u_joy)))
        assert area.contains(run.x, run.y).all(), n
        assert np.degrees(np.abs(run.psi - run.psi[0])).max() < 150.0, n
        track = np.abs(run.vx) + v.robot.track_half_width_m * np.abs(run.omega)
        assert track.max() < v.robot.guard_track_speed_m_s + 0.05, n
        assert np.abs(run.vy).max() < 0.1, n
        gap = np.diff(run.t_joy)
        assert np.median(gap) == pytest.approx(1.0 / v.driver.joy_rate_hz, rel=0.1), n
    assert np.mean(command["gentle"]) < np.mean(command["aggressive"]) - 0.05


def test_variants_round_trip_through_truth_yaml(variants):
    for v in variants.values():
        text = yaml.safe_dump(v.to_dict(), sort_keys=False)
        assert Variant.from_dict(yaml.safe_load(text)) == v


@pytest.mark.parametrize("bad", [-1, True, 2.5, "3"])
def test_bad_variant_index_is_named(bad):
    with pytest.raises(InputError, match=f"variant={bad!r}"):
        check_variant(bad)


def test_default_variant_reproduces_main_float_for_float():
    """``variant=None`` and ``Variant()`` give the same run; both equal main's simulator (states
    after 8 s recorded from commit 638e139 for each default-form effect, to 1e-12)."""
    from simulation.effects import EFFECTS, Effect

    for name, expect in MAIN_STATES_AFTER_8_S.items():
        eff = Effect(name, EFFECTS[name].moderate) if name else None
        a = simulate_run(8.0, np.random.default_rng(11), effect=eff)
        b = simulate_run(8.0, np.random.default_rng(11), effect=eff, variant=Variant())
        np.testing.assert_array_equal(a.x, b.x)
        k = len(a.t) - 1
        got = [a.x[k], a.y[k], a.psi[k], a.vx[k], a.vy[k], a.omega[k], a.u_motor[k - 500, 0], a.u_motor[k - 500, 1],
               a.pitch[k]]
        np.testing.assert_allclose(got, expect, rtol=0, atol=1e-12, err_msg=str(name))


# x, y, psi, vx, vy, omega at 8 s, u_motor at 7 s, pitch at 8 s: simulate_run(8.0,
# default_rng(11), effect=moderate default form) on commit 638e139 (before variants and forms)
MAIN_STATES_AFTER_8_S = {
    None: (4.826852987146352, 2.9738767684790988, 3.2328420508965126, -0.458838142625597, -0.02184149784720666,
           -0.7517623935947613, -0.5374285972580483, 0.25356209692818643, -0.0008063468551456303),
    'input_delay': (4.433126483289493, 2.8904039737477256, 3.408700198644528, -0.547304820771529,
                    0.004402838065464853, 0.07345635099852242, -0.5374285972580483, 0.25356209692818643,
                    0.003198719224524653),
    'heading_dependence': (4.933741769368073, 3.0299345019941235, 3.1951167472324853, -0.5080607798937052,
                           -0.024314334443854727, -0.8011532025157171, -0.5374285972580483, 0.25356209692818643,
                           -0.02556627920968574),
    'position_dependence': (5.082042062404624, 2.7367018539494965, 2.6336730505655486, -0.2776810435265957,
                            -0.00999579286965252, -0.5456803560805326, -0.5172590266827513, 0.0,
                            0.00046205117748835973),
    'time_dependence': (4.82688968019515, 2.9729788106842854, 3.2319290771698186, -0.4585060190254121,
                        -0.02181525410339997, -0.7516142846082418, -0.5358610971827122, 0.2528225408121459,
                        -0.0007802802283827542),
    'asymmetry': (4.796545377371954, 2.91753661902622, 3.0981523468815975, -0.46399755399343207,
                  -0.023145128522922238, -0.7637248872619884, -0.5184114399884343, 0.2132549521338328,
                  3.110755342568278e-05),
    'deadband': (4.12558909321122, 2.9288840355170374, 2.58833504529895, 0.0007822777742999944,
                 1.2992615000326815e-05, -0.8255060382797736, 0.0, 0.0, 0.00041445499627481837),
    'lateral_slip': (4.660982955050744, 3.0475714420962907, 3.5482488047090284, -0.5405981470133588,
                     -0.008387408452751911, -0.23113052597500305, -0.5374285972580483, 0.25356209692818643,
                     0.0012692393296484614),
}


def test_process_noise_spectra():
    """White: per-step std sqrt(2 tau / dt) times the OU std (same low-frequency density);
    coloured: the given std with its power at the resonance; OU: lag-one correlation e^(-dt/tau)."""
    from simulation.process_noise import ProcessNoise, simulate_process_noise

    dt, std, tau, n = 0.002, np.array([0.06, 0.03, 0.15]), 0.05, 200_000
    rng = np.random.default_rng(0)
    white = simulate_process_noise(ProcessNoise("white"), n, dt, std, tau, rng)
    np.testing.assert_allclose(white.std(axis=0), std * np.sqrt(2 * tau / dt), rtol=0.02)
    ou = simulate_process_noise(ProcessNoise("ou"), n, dt, std, tau, rng)
    np.testing.assert_allclose(ou.std(axis=0), std, rtol=0.05)
    lag1 = np.mean(ou[1:, 0] * ou[:-1, 0]) / np.var(ou[:, 0])
    assert lag1 == pytest.approx(np.exp(-dt / tau), abs=0.01)
    col = simulate_process_noise(ProcessNoise("coloured", 6.0, 0.2), n, dt, std, tau, rng)
    np.testing.assert_allclose(col.std(axis=0), std, rtol=0.05)
    freq = np.fft.rfftfreq(n, dt)
    power = np.abs(np.fft.rfft(col[:, 0])) ** 2
    smooth = np.convolve(power, np.ones(200) / 200, mode="same")
    assert freq[np.argmax(smooth[freq < 50])] == pytest.approx(6.0, abs=0.6)

