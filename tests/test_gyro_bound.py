"""The full gyro model against its Cramér-Rao bound (issue 10, gyro side).

The stated std are the bound of the design: the gyro's own, with the accelerometer
calibration's covariance propagated through the turns (``full_bound``, what ``bench gyro``
measures errors against), from noise pooled over the still periods that is the simulator's
true noise. And ``bench gyro``'s error/bound states its own sampling error: with 20 seeds an
estimator exactly at the bound shows one of 12 parameters above 1.2 more often than not
(issue 10's "m_yz 1.31" at 20 seeds was 1.02 at 100).
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.gyro import MIN_SEEDS, error_over_bound
from bench.gyro_table import truth_in_frame
from imucal_cli.calibrate.gyro.rotations import full_bound, full_problem
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.formats.config import config_from_dict
from imucal_cli.simulate.rotations import simulate_gyro_rotations

CFG = config_from_dict({"accel": {"gravity": {"leave_one_out": False}},
                        "gyro": {"solver": "full", "full": {"g_sensitivity": "off"}}})  # fmt: skip


@pytest.fixture(scope="module")
def fitted():
    session, truth = simulate_gyro_rotations(plan="free:12", seed=3, created="x")
    cal = calibrate_session(session, CFG)
    return session, truth, cal, truth_in_frame(cal.accel, truth)


def test_stated_std_is_the_bound_with_the_accelerometer_propagated(fitted):
    session, _, cal, x = fitted
    g = cal.gyro
    assert g.fit.noise_scale == 1.0  # residuals within the noise: no inflation
    std = np.array([p.std for p in g.parameters])
    crb, total = (np.sqrt(np.diag(c)) for c in full_bound(session, CFG, cal.accel, x))
    # The accelerometer's share: none in the bias, up to 1.2 times the gyro's own bound in the
    # matrix here (13 poses calibrate the accelerometer; without it the std fell below). Its
    # frame's rotation is not in it (the gyro turns with that frame; errors are measured in
    # it): with it the share was 1.5 times.
    assert np.all(total >= crb) and np.all(total[3:] > 1.004 * crb[3:])
    assert 1.1 < np.max(total / crb) < 1.35
    # std at the estimate, bound at the truth: the same to first order.
    np.testing.assert_allclose(std, total, rtol=0.01)
    assert np.all(np.abs(np.r_[g.bias, g.matrix.ravel()] - x) < 4.5 * total)


def test_the_bound_uses_the_simulator_s_true_noise(fitted):
    """Pooled over the still periods, the gyro noise is the truth's (input-referred rad/s
    through the sensitivities, per raw channel)."""
    session, truth, cal, _ = fitted
    _, _, noise = full_problem(session, CFG, cal.accel)
    S = np.linalg.inv(truth.gyro.matrix)
    true_raw = truth.gyro.noise * np.sqrt(np.trace(S @ S.T) / 3)
    assert abs(noise / true_raw - 1) < 0.02


def test_error_over_bound_states_its_sampling_error():
    rng = np.random.default_rng(0)
    n, p = 400, 12
    crb = np.full((n, p), 4.0)
    err = 2.0 * 1.1 * rng.standard_normal((n, p))  # an estimator 10 % above its bound
    s = error_over_bound(err, crb)
    assert np.all(np.abs(s["ratio"] - 1.1) < 4 * s["se"])
    np.testing.assert_allclose(s["se"], 1.1 / np.sqrt(2 * n), rtol=0.25)  # Gaussian: r/sqrt(2N)
    assert np.all((s["lo"] < s["ratio"]) & (s["ratio"] < s["hi"]))
    # How often an estimator exactly at the bound shows some parameter above 1.2:
    at_bound = [error_over_bound(rng.standard_normal((k, p)), np.ones((k, p)))["p_any_above"]
                for k in (20, MIN_SEEDS)]  # fmt: skip
    assert at_bound[0] > 0.5 and at_bound[1] < 0.05
