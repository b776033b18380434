"""Issue 10: the accelerometer's uncertainty carried into the gyro's std beyond the first order.

The six faces' 5 moves, each near 180 degrees, are measured with an accelerometer that six
faces fix only to about 0.7 degree; forced with ``[gyro] solver = "full"``, seed 9 gave a gain
129 % off while its rates were stated to 36 % (a parameter 10.5 std off): the first-order
propagation of the accelerometer's covariance understated it. Now the accelerometer's part is
refitted at sigma points where the first order is doubtful (``estimators/gyro/sigma.py``), the
result states std that cover its error, and a warning names the nonlinearity; clean designs
keep the first order bit for bit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bench.gyro_table import COVERED, _compare, truth_in_frame
from imucal_cli.calibrate.session import calibrate_session, suspect_error
from imucal_cli.estimators.gyro.sigma import GATE, PRECHECK, envelope, propagate
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.simulate.play import simulate_plan
from imucal_cli.simulate.rotations import simulate_gyro_rotations

# --- the propagation on functions whose moments are known -----------------------------------


def _counting(fn):
    calls = []

    def refit(theta, x_start):
        calls.append(theta)
        return fn(theta)

    return refit, calls


def test_a_linear_dependence_keeps_the_first_order_exactly():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 3))
    C = np.diag([1.0, 4.0, 0.25])
    th0, x0 = np.zeros(3), rng.normal(size=4)
    refit, calls = _counting(lambda th: x0 + A @ th)
    out = propagate(x0, th0, C, A, 1e-4 * np.eye(4), refit)
    assert out.method == "first order" and calls  # checked by refits, then kept
    np.testing.assert_array_equal(out.cov, A @ C @ A.T)
    assert out.nonlinearity < 1e-9


def test_a_quadratic_dependence_gets_its_exact_second_moment():
    """x = e + b e^2 along one direction, e ~ N(0, s^2): E[(x - x_hat)^2] = s^2 + 3 b^2 s^4,
    what sigma points at sqrt(3) std give (the first order says s^2)."""
    s, b = 0.5, 1.5
    C = np.diag([s**2, 1e-6])
    A = np.eye(2)
    out = propagate(np.zeros(2), np.zeros(2), C, A, 1e-6 * np.eye(2),
                    lambda th, _: np.array([th[0] + b * th[0] ** 2, th[1]]))  # fmt: skip
    assert out.method == "sigma points"
    assert out.cov[0, 0] == pytest.approx(s**2 + 3 * b**2 * s**4, rel=1e-9)
    e = np.random.default_rng(1).normal(0, s, 400_000)
    assert np.mean((e + b * e**2) ** 2) == pytest.approx(out.cov[0, 0], rel=0.01)
    assert out.cov[1, 1] == pytest.approx(1e-6)  # below the gate: its first order


def test_a_step_that_finds_the_first_order_adequate_saves_the_refits():
    """The pre-check: one Gauss-Newton step per sigma point (here exact) that changes no std
    by more than PRECHECK keeps the first order without a refit."""
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 3))
    C = np.diag([1.0, 4.0, 0.25])
    x0 = rng.normal(size=4)
    refit, calls = _counting(lambda th: x0 + A @ th)
    step, steps = _counting(lambda th: x0 + A @ th + 1e-6 * th[0] ** 2)
    out = propagate(x0, np.zeros(3), C, A, 1e-4 * np.eye(4), refit, step)
    assert out.method == "first order" and not calls and steps and out.refits == 0
    assert out.nonlinearity <= PRECHECK and "no refit" in out.reason
    np.testing.assert_array_equal(out.cov, A @ C @ A.T)


def test_a_step_that_finds_a_nonlinearity_leaves_it_to_the_refits():
    """Above PRECHECK the refits decide, as without the pre-check (the same result)."""
    s, b = 0.5, 1.5
    C = np.diag([s**2, 1e-6])
    fn = lambda th, _: np.array([th[0] + b * th[0] ** 2, th[1]])  # noqa: E731
    without = propagate(np.zeros(2), np.zeros(2), C, np.eye(2), 1e-6 * np.eye(2), fn)
    out = propagate(np.zeros(2), np.zeros(2), C, np.eye(2), 1e-6 * np.eye(2), fn, fn)
    assert out.method == "sigma points" and out.refits == without.refits > 0
    np.testing.assert_array_equal(out.cov, without.cov)


def test_an_accelerometer_weaker_than_the_noise_is_not_refitted():
    refit, calls = _counting(lambda th: None)
    A, C = np.eye(2), np.diag([0.5 * GATE, 0.1]) ** 2
    out = propagate(np.zeros(2), np.zeros(2), C, A, np.eye(2), refit)
    assert out.method == "first order" and not calls and out.effect < GATE


def test_a_refit_that_fails_is_said_and_the_first_order_kept_for_it():
    out = propagate(np.zeros(2), np.zeros(2), np.eye(2), np.eye(2), 1e-4 * np.eye(2),
                    lambda th, _: None)  # fmt: skip
    assert out.method == "sigma points" and out.failed == out.refits == 4
    np.testing.assert_allclose(out.cov, np.eye(2))


def test_sigma_points_never_state_less_than_the_first_order():
    """Where the refits spread less than the first order (a saturating dependence), each
    combination keeps the larger variance."""
    out = propagate(np.zeros(2), np.zeros(2), np.eye(2), np.eye(2), 1e-4 * np.eye(2),
                    lambda th, _: np.tanh(th) * np.array([1.0, 3.0]))  # fmt: skip
    assert out.method == "sigma points"
    lo, hi = out.std_ratio
    assert lo < 0.9 and hi > 1.1  # x_0 saturates, x_1 grows faster than its slope
    total = 1e-4 * np.eye(2) + out.cov
    assert np.all(np.linalg.eigvalsh(total - (1e-4 * np.eye(2) + out.linear)) > -1e-12)
    assert out.cov[1, 1] > 1.5 * out.linear[1, 1]


def test_envelope_covers_both():
    rng = np.random.default_rng(2)
    X, Y = rng.normal(size=(2, 3, 3))
    a, b = X @ X.T + np.eye(3), Y @ Y.T + np.eye(3)
    e = envelope(a, b)
    assert np.all(np.linalg.eigvalsh(e - a) > -1e-9) and np.all(np.linalg.eigvalsh(e - b) > -1e-9)


# --- the calibrate step -----------------------------------------------------------------------

FULL = replace(Config(), gyro=replace(Config().gyro, solver="full"))


@pytest.fixture(scope="module")
def six_seed_9():
    """``imucal simulate --plan six --seed 9``, calibrated with the full model forced."""
    session, truth = simulate_plan("six", seed=9)
    return calibrate_session(session, FULL), truth


def test_six_faces_seed_9_forced_states_std_that_cover_its_error(six_seed_9):
    cal, truth = six_seed_9
    z, z_gains, rate_std, gain_error = _compare(cal.gyro, truth_in_frame(cal.accel, truth))
    assert gain_error > 1.0  # still a gain 129 % off: five near-180-degree turns
    assert z < COVERED and np.all(np.abs(z_gains) < COVERED), (z, z_gains)  # was 10.5
    assert rate_std > gain_error / COVERED  # stated 119 %; the first order said 36 %
    prop = cal.gyro.rate_std.accel_propagation
    assert prop.method == "sigma points" and prop.first_order_total < 0.4
    assert prop.refits <= 24  # only the accelerometer directions that move the gyro


def test_six_faces_seed_9_names_the_nonlinearity_and_is_not_saved_unasked(six_seed_9):
    cal, _ = six_seed_9
    nonlinear = [w for w in cal.gyro.warnings if "nonlinearly" in w]
    assert len(nonlinear) == 1 and "sigma points" in nonlinear[0], cal.gyro.warnings
    assert suspect_error(cal) is not None


def test_a_clean_design_keeps_the_first_order():
    """free:12: the accelerometer (13 poses) moves the gyro by more than its noise in one
    direction, so the sigma points check it: a Gauss-Newton step at each finds changes of
    3e-4 (the refits found the same), and the first order is kept without refits."""
    session, _ = simulate_gyro_rotations(plan="free:12", seed=3, created="x")
    cfg = config_from_dict({"accel": {"gravity": {"leave_one_out": False}},
                            "gyro": {"solver": "full", "full": {"g_sensitivity": "off"}}})
    g = calibrate_session(session, cfg).gyro
    prop = g.rate_std.accel_propagation
    assert prop.method == "first order" and prop.effect > GATE, prop
    assert prop.refits == 0 and "no refit" in prop.reason, prop
    assert prop.nonlinearity < 0.01
    assert not g.warnings
