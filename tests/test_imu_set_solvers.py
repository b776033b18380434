"""Issue 28.2: the set's estimators against their noise: the two-step rotation (eqs. R1-R2) on
synthetic vector pairs, the time offset (eq. T4) on a synthetic turn against its bound (T3), and
the two-step path of a simulated set (slow: its coverage)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal_cli.errors import DesignError
from imucal_cli.estimators.imu_set.rotation import (
    PairGroup,
    calibration_derivative,
    relative_rotation,
    tangent_weights,
)
from imucal_cli.estimators.imu_set.time_offset import (
    coarse_offset,
    fit_time_offset,
    fit_time_offset_gains,
    time_offset_bound,
)

R_TRUE = Rotation.from_rotvec([0.02, -0.05, 0.03]).as_matrix()


def _pairs(rng, directions, sigma, name="poses"):
    """Noisy pairs ``a = R b`` of unit vectors scaled by g, both sides noisy."""
    b_true = 9.8 * directions
    a = b_true @ R_TRUE.T + rng.normal(0, sigma, b_true.shape)
    b = b_true + rng.normal(0, sigma, b_true.shape)
    cov = np.broadcast_to(np.eye(3) * sigma**2, (len(a), 3, 3)).copy()
    return PairGroup(a, b, cov, cov.copy(), name=name)


def _coverage(make, n=400, seed=0) -> tuple[float, float]:
    rng = np.random.default_rng(seed)
    z = []
    for _ in range(n):
        fit = relative_rotation(make(rng))
        err = Rotation.from_matrix(fit.matrix @ R_TRUE.T).as_rotvec()
        z.append(err / np.sqrt(np.diag(fit.cov)))
    z = np.array(z)
    return float(np.mean(np.abs(z) < 1.96)), float(np.sqrt(np.mean(z**2)))


def test_two_step_rotation_std_matches_its_scatter():
    """Poses in many directions: 95 % intervals cover the truth 93-97 % of 1,200 values."""
    dirs = np.random.default_rng(5).normal(size=(12, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    cover, rms_z = _coverage(lambda rng: [_pairs(rng, dirs, 0.002)])
    assert 0.93 <= cover <= 0.97 and abs(rms_z - 1) < 0.08


def test_poses_of_one_direction_need_the_turns():
    """All poses one way: refused alone (the rotation about it is unknown); with turns about
    other axes determined, and the intervals cover."""
    up = np.tile([0.0, 0.0, 1.0], (6, 1))
    with pytest.raises(DesignError, match="all point one way"):
        relative_rotation([_pairs(np.random.default_rng(1), up, 0.002)])
    turns = np.array([[1.0, 0, 0], [0, 1.0, 0], [0.6, 0.8, 0], [0, 0, 1.0]])
    cover, rms_z = _coverage(lambda rng: [_pairs(rng, up, 0.002),
                                          _pairs(rng, turns / 9.8 * 1.5, 0.001, "turns")])
    assert 0.93 <= cover <= 0.97 and abs(rms_z - 1) < 0.08


def test_calibration_errors_are_propagated():
    """A calibration's error shared by every pair: its part of the covariance (eq. R2) makes
    the intervals cover what the pairs' noise alone would not."""
    dirs = np.random.default_rng(6).normal(size=(12, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    cal_std = 2e-4  # m/s^2 per raw unit on the matrix, 0.02 raw on the bias

    def make(rng, with_cal=True):
        g = _pairs(rng, dirs, 0.001)
        M = np.eye(3)
        dM = rng.normal(0, cal_std, (3, 3))
        g.imu = g.imu + g.imu @ dM.T  # the IMU's calibration matrix is off by dM
        cov = np.diag(np.r_[np.zeros(3), np.full(9, cal_std**2)])
        if with_cal:
            g.d_imu = calibration_derivative(M, g.imu)
            g.cal_imu = cov
        return [g]

    cover, _ = _coverage(make)
    assert 0.93 <= cover <= 0.97
    cover_without, _ = _coverage(lambda rng: make(rng, with_cal=False))
    assert cover_without < 0.85


def _turn(t, t0=1.0, dur=1.2, angle=1.5):
    tau = np.clip((t - t0) / dur, 0, 1)
    rate = angle * 30 * tau**2 * (1 - tau) ** 2 / dur
    return np.outer(rate, [0.6, 0.0, 0.8])


def test_pairs_fitted_by_their_calibrations_are_weighed_across_only():
    """Eq. R3's weights: the inverse of each pair's error covariance within the plane across
    ``a_p``, nothing along it. A pair whose calibrations put both vectors on the gravity sphere
    (six faces' labelled fits) has almost no first-order variance along ``a_p``; with the whole
    inverse, its part along ``a_p`` (second order in the errors: here 1e-6 of g) moved the
    rotation by the tangential errors it is correlated with, divided by that variance (tens of
    its std on six faces). Across only, it moves the rotation by nothing."""
    rng = np.random.default_rng(5)
    u = rng.normal(size=(6, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    a, b = 9.8 * u @ R_TRUE.T, 9.8 * u
    # covariances of 1e-3^2 across, nearly nothing along a_p, the two strongly correlated
    V = []
    for n in u @ R_TRUE.T:
        t = np.linalg.svd(n[:, None])[0][:, 1:]
        basis = np.column_stack([n, t])
        inner = np.array([[1e-12, 0.9e-9, 0.0], [0.9e-9, 1e-6, 0.0], [0.0, 0.0, 1e-6]])
        V.append(basis @ inner @ basis.T)
    V = np.array(V)
    W = tangent_weights(V, a)
    np.testing.assert_allclose(np.einsum("pij,pj->pi", W, a), 0.0, atol=1e-14 * 9.8 * 1e6)
    for p in range(len(a)):
        t = np.linalg.svd(a[p][:, None])[0][:, 1:]
        np.testing.assert_allclose(t.T @ W[p] @ t, np.linalg.inv(t.T @ V[p] @ t), rtol=1e-9,
                                   atol=1e-9 * 1e6)  # fmt: skip
    zero = np.zeros((len(a), 12, 3))

    def fit(ref):
        group = PairGroup(ref, b, V, np.zeros_like(V), cross_ref=zero, cross_imu=zero)
        return relative_rotation([group]).matrix

    radial = a * (1 + 1e-6 * rng.normal(size=(len(a), 1)))  # second-order errors along a_p
    moved = Rotation.from_matrix(fit(radial) @ fit(a).T).magnitude()
    assert moved < 1e-9  # rad; the whole inverse moved it by 4e-4


def test_time_offset_reaches_its_bound_and_covers():
    """Two IMUs at 100 and 250 Hz see the same turns; the offset's error scatter matches the
    reported std, which is the bound T3 (the signal smooth at both rates)."""
    rng = np.random.default_rng(2)
    delta, s_r, s_i = 0.0042, 0.005, 0.008
    t_r = np.arange(0, 4, 0.01)
    t_i = 0.0013 + np.arange(0, 4, 0.004)

    def signal(t):
        return _turn(t) + _turn(t, t0=2.4, dur=0.9, angle=-1.0)

    fine = np.linspace(0.9, 3.4, 20001)
    d = np.gradient(signal(fine), fine, axis=0)
    bound = time_offset_bound(np.trapezoid(d**2, fine, axis=0), s_r**2, 100.0, s_i**2, 250.0)
    errs, stds = [], []
    for _ in range(300):
        w_r = signal(t_r) + rng.normal(0, s_r, (len(t_r), 3))
        w_i = signal(t_i + delta) + rng.normal(0, s_i, (len(t_i), 3))
        start = coarse_offset(t_r, w_r, t_i, w_i)
        assert abs(start - delta) < 0.01
        fit = fit_time_offset(t_r, w_r, t_i, w_i, [(0.9, 2.3), (2.3, 3.4)], s_r**2, s_i**2,
                              start)  # fmt: skip
        errs.append(fit.value_s - delta)
        stds.append(fit.std_s)
    errs, stds = np.array(errs), np.array(stds)
    assert np.mean(np.abs(errs) < 1.96 * stds) == pytest.approx(0.95, abs=0.035)
    assert np.sqrt(np.mean(errs**2)) == pytest.approx(bound, rel=0.15)
    assert np.median(stds) == pytest.approx(bound, rel=0.1)


def test_time_offset_with_the_gyros_matrix_unknown_covers():
    """Eq. T5: the same turns (about three axes) read in raw counts by two gyros of unknown
    gains, misalignments and mounting (131 and 16.4 counts per deg/s, biases removed as the
    still periods give them): the offset fitted with the matrix between them covers the truth
    at 95 % with error/std RMS near 1, and costs little over T4 with the matrix known (its
    columns, the rate, nearly orthogonal to the offset's, its derivative: here within 0.1 %)."""
    rng = np.random.default_rng(3)
    delta = -0.0061
    t_r = np.arange(0, 6, 0.01)
    t_i = 0.0007 + np.arange(0, 6, 0.005)
    S_r = np.degrees(131.0) * Rotation.from_rotvec([0.01, -0.02, 0.015]).as_matrix()
    S_i = np.degrees(16.4) * np.diag([1.02, 0.97, 1.01]) @ R_TRUE.T
    n_r, n_i = 0.005 * np.degrees(131.0), 0.008 * np.degrees(16.4)  # counts
    windows = [(0.9, 2.3), (2.3, 3.4), (3.4, 5.0)]

    def signal(t):  # three turns about three axes (0.6, 0, 0.8), (0.8, 0.6, 0), (0, 0.8, 0.6)
        return (_turn(t) + np.roll(_turn(t, t0=2.4, dur=0.9, angle=-1.0), 1, axis=1)
                + np.roll(_turn(t, t0=3.6, dur=1.1, angle=1.2), 2, axis=1))  # fmt: skip

    z, ratio = [], []
    for _ in range(200):
        w_r = signal(t_r) @ S_r.T + rng.normal(0, n_r, (len(t_r), 3))
        w_i = signal(t_i + delta) @ S_i.T + rng.normal(0, n_i, (len(t_i), 3))
        start = coarse_offset(t_r, w_r, t_i, w_i)
        fit = fit_time_offset_gains(t_r, w_r, t_i, w_i, windows, np.full(3, n_r**2),
                                    np.full(3, n_i**2), start)  # fmt: skip
        known = fit_time_offset(t_r, w_r @ np.linalg.inv(S_r).T, t_i,
                                w_i @ np.linalg.inv(S_i).T, windows, 0.005**2, 0.008**2, start)
        z.append((fit.value_s - delta) / fit.std_s)
        ratio.append(fit.std_s / known.std_s)
    z = np.array(z)
    assert np.mean(np.abs(z) < 1.96) == pytest.approx(0.95, abs=0.045)  # 3 binomial se
    assert 0.85 <= float(np.sqrt(np.mean(z**2))) <= 1.15
    assert 0.95 <= float(np.median(ratio)) <= 1.2


@pytest.mark.slow
def test_two_step_path_of_a_simulated_set_covers(monkeypatch):
    """The two-step rotation (each IMU's own gravity fit, the shared poses) of 100 simulated
    sets of 3: its 95 % intervals cover the truth 93-97 % of the time."""
    import imucal_cli.calibrate.imu_set as imu_set
    from imucal_cli.formats.config import Config
    from imucal_cli.simulate.imu_set import gauge_rotation, simulate_set

    monkeypatch.setattr(imu_set, "_triads_of_gravity", lambda cals, kept: False)
    z = []
    for seed in range(100):
        session, truth = simulate_set(3, seed=700 + seed, created="2026-01-01T00:00:00Z")
        cal = imu_set.calibrate_set(session, Config(), name="x")
        q0 = gauge_rotation(np.array(truth.accel.matrix))
        for key, entry in cal.to_dict()["imus"].items():
            want = truth.to_dict()["imus"][key]
            r = q0.T @ np.array(want["rotation_to_reference"]) @ gauge_rotation(
                np.array(want["accel"]["matrix"]))  # fmt: skip
            err = Rotation.from_matrix(np.array(entry["rotation_to_reference"]) @ r.T)
            z.append(err.as_rotvec() / np.radians(entry["rotation_std_deg"]))
            assert entry["set"]["rotation_pairs"] == {"poses": 18}
    assert 0.93 <= np.mean(np.abs(np.array(z)) < 1.96) <= 0.97
