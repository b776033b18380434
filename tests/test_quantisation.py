"""A quantised gyro too quiet to dither its rounding (numerics/quantisation.py): the rounding
every still mean shares is in the stated bias std.

A modern gyro read at its widest range (an ICM-42688 at +-2000 deg/s: 16.4 LSB per deg/s,
0.0028 deg/s/sqrt(Hz)) has less noise per sample than half a count: each still period's
mean errs by the rounding of one true rate, the same in every period, which the fit's
residuals cannot show.  Without it the stated gyro bias std was 7x too small (qureshi18,
gyro noise 3e-4 rad/s against a 1.06e-3 rad/s count: coverage 5-20 %).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from imucal_cli.numerics.quantisation import (
    hold_rounding,
    noise_before_rounding,
    noise_from_codes,
    rounding_covariance,
    rounding_variance,
)


def _rounded_means(rng, sigma: float, n_inputs: int = 3000, n: int = 300):
    """Means and variances of ``n`` rounded samples of inputs uniform within a step (1)."""
    mu = rng.random(n_inputs)
    x = np.round(mu[:, None] + sigma * rng.standard_normal((n_inputs, n)))
    return x.mean(axis=1) - mu, x.var(axis=1, ddof=1)


@pytest.mark.parametrize("sigma", [0.0, 0.1, 0.28, 0.4])
def test_the_rounding_variance_is_what_the_means_show(sigma):
    """``v(sigma)`` is the variance of rounded means over inputs anywhere in a step (less
    their white part, ``s^2 / n``), and ``noise_before_rounding`` gives ``sigma`` back from
    the samples' variance; both within the Monte Carlo's own sampling error."""
    rng = np.random.default_rng(7)
    err, s2 = _rounded_means(rng, sigma)
    white = float(np.mean(s2)) / 300
    v_mc = float(np.mean(err**2)) - white
    se = float(np.std(err**2)) / np.sqrt(len(err))
    assert abs(v_mc - rounding_variance(sigma, 1.0)) < 4 * se + 1e-6
    assert rounding_variance(0.0, 2.0) == pytest.approx(4.0 / 12, rel=1e-4)
    assert rounding_variance(0.6, 1.0) < 1e-6 and rounding_variance(0.3, 0.0) == 0.0
    if sigma > 0:
        got = noise_before_rounding(float(np.mean(s2)), 1.0)
        assert got == pytest.approx(sigma, rel=0.03)


@pytest.mark.parametrize(("sigma", "rel"), [(0.2, 0.3), (0.28, 0.05), (0.4, 0.05), (1.0, 0.05)])
def test_the_noise_comes_from_the_codes_wherever_the_input_sits(sigma, rel):
    """18 holds of 200 samples, 3 channels, inputs anywhere in their steps: the codes give
    the noise within ``rel`` (over 20 draws: 0.28 within 2.5 %, std 0.8 %; 0.2 steps, where
    few holds sit near enough an edge to flip, 0.75-1.02), where one hold's variance depends
    on its place in the step (0.26-0.50 for 0.28 in a session)."""
    rng = np.random.default_rng(3)
    blocks = [np.round(rng.random(3) * 40 - 20 + sigma * rng.standard_normal((200, 3))) * 0.5
              + 0.25 for _ in range(18)]  # fmt: skip
    assert noise_from_codes(blocks, 0.5) == pytest.approx(0.5 * sigma, rel=rel)
    s = float(np.sqrt(np.mean([b.var(axis=0, ddof=1).mean() for b in blocks])))
    got, v = hold_rounding(blocks, 0.5, s)
    assert got == pytest.approx(0.5 * sigma, rel=rel)
    assert np.sqrt(v) == pytest.approx(np.sqrt(rounding_variance(got, 0.5)), rel=1e-9)
    assert hold_rounding(blocks, 0.0, s) == (s, 0.0)


@pytest.mark.parametrize("sigma", [0.0, 0.15, 0.3])
def test_the_rounding_errors_of_two_holds_covary_by_how_far_apart_they_sit(sigma):
    """Two holds whose inputs lie ``d`` apart (anywhere in a step): their rounded means' errors
    covary as ``rounding_covariance`` says: alike at 0 (and whole steps), opposite half a step
    apart, within the Monte Carlo's sampling error."""
    rng = np.random.default_rng(11)
    mu = rng.random(4000)
    for d in (0.0, 0.5, 0.25, 2.3):
        e1 = np.round(mu[:, None] + sigma * rng.standard_normal((4000, 100))).mean(1) - mu
        e2 = np.round(mu[:, None] + d + sigma * rng.standard_normal((4000, 100))).mean(1) - mu - d
        c = rounding_covariance(np.array([0.0, d]), sigma, 1.0)
        se = np.std(e1 * e2) / np.sqrt(len(mu))  # the two holds' noise draws are independent
        assert abs(np.mean(e1 * e2) - c[0, 1]) < 4 * se + 1e-4, (d, np.mean(e1 * e2), c)
    assert rounding_covariance(np.array([0.0, 1.0]), sigma, 0.0).sum() == 0.0


def test_the_codes_ignore_a_stray_sample_nans_and_constant_holds():
    """One spike of 3 codes in two of 18 holds does not make the noise (it took 0.10 to
    0.26-0.32 steps); NaN rows are left out; holds whose codes never change say 0 (nothing
    tells the noise from none: the whole step's rounding, q^2/12)."""
    rng = np.random.default_rng(5)
    blocks = [np.round(rng.random(3) * 40 + 0.1 * rng.standard_normal((200, 3)))
              for _ in range(18)]  # fmt: skip
    clean = noise_from_codes(blocks, 1.0)
    blocks[0][5] += 3
    blocks[1][7] -= 3
    blocks[2][9] = np.nan
    assert noise_from_codes(blocks, 1.0) == pytest.approx(clean, rel=0.05)
    assert 0.08 < clean < 0.12
    assert noise_from_codes([np.full((50, 3), 7.0), np.full((20, 3), 2.0)], 1.0) == 0.0
    assert noise_from_codes([np.full((3, 1), np.nan)], 1.0) == 0.0
    assert hold_rounding([np.full((50, 1), 7.0)], 1.0, 0.0)[1] == pytest.approx(1 / 12, rel=1e-4)


def test_a_quiet_quantised_gyro_states_the_rounding_in_its_bias():
    """qureshi18 with gyro noise 3e-4 rad/s (0.28 counts): every bias std holds the shared
    rounding (at least 0.8 of sqrt(v)) and the intervals hold the truth (at most one miss in
    18 terms); before, std 0.007 counts against errors of 0.05."""
    from bench.live_grade import Graded, grade
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import Config
    from imucal_cli.simulate.triad import simulate

    sigma_counts = 3e-4 / np.radians(1 / 16.4)
    floor = 0.8 * np.sqrt(rounding_variance(sigma_counts, 1.0))
    misses = 0
    for seed in (103, 110, 112):  # seeds whose bias errs most (0.055-0.075 counts)
        session, truth = simulate(plan="qureshi18", seed=seed, gyro_noise=3e-4, hold_s=2.0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cal = calibrate_session(session, Config())
        gyro = grade(session, cal, truth)["gyro"]
        assert isinstance(gyro, Graded), gyro
        assert np.all(gyro.std[:3] >= floor), (gyro.std[:3], floor)
        misses += int(np.sum(~gyro.hits[:6]))
    assert misses <= 1


def test_a_quiet_quantised_accelerometer_states_the_rounding_in_its_pose_means():
    """qureshi18 with accelerometer noise 3e-4 m/s^2 (0.25 counts of 9.81/8192 m/s^2): each
    pose mean's covariance holds its own rounding (poses sit at other places within their
    counts, so pose by pose, not shared), at least 0.8 of ``v`` of the true noise; before,
    ``Sigma / n`` alone, and the 9 gravity terms' intervals held the truth 86 % of the time
    over 30 seeds (95 % with it)."""
    from imucal_cli.calibrate.common import static_poses
    from imucal_cli.simulate.triad import simulate

    session, _ = simulate(plan="qureshi18", seed=4, accel_noise=3e-4, hold_s=2.0)
    poses = static_poses(session)
    sigma_counts = 3e-4 / (9.80665 / 8192)
    v = rounding_variance(sigma_counts, 1.0)
    diag = np.diagonal(poses.cov_mean, axis1=1, axis2=2)
    assert np.all(diag >= 0.8 * v), (diag.min(), v)
    loud, _ = simulate(plan="qureshi18", seed=4, hold_s=2.0)  # 0.01 m/s^2: 8 counts, dithered
    lp = static_poses(loud)
    white = np.diagonal(lp.noise.cov)[None] / lp.samples[:, None]
    assert np.allclose(np.diagonal(lp.cov_mean, axis1=1, axis2=2), white, rtol=1e-9)
