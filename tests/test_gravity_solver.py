"""The gravity-magnitude solver on synthetic pose means: exact recovery, honest uncertainty,
agreement with the Cramér-Rao bound, leave-one-out, and refusal of degenerate designs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal_cli.design.poses import count_distinct, coverage, spread_deg
from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.accel.crb import gravity_crb
from imucal_cli.estimators.accel.gravity import (
    fit_gravity,
    leave_one_out,
    leave_one_out_press,
    model_to_params,
)
from imucal_cli.estimators.ellipsoid import fit_ellipsoid

G = 9.80665
SENS = 8192 / G  # counts per m/s^2


def cube18() -> np.ndarray:
    faces = [s * e for e in np.eye(3) for s in (1, -1)]
    edges = []
    for i in range(3):
        for j in range(i + 1, 3):
            for si in (1, -1):
                for sj in (1, -1):
                    v = np.zeros(3)
                    v[i], v[j] = si, sj
                    edges.append(v / np.sqrt(2))
    return np.array(faces + edges)


def random_part(rng):
    """A general (non-triangular) sensitivity matrix S and bias b, counts."""
    S = np.diag(SENS * (1 + 0.03 * rng.uniform(-1, 1, 3))) @ (
        np.eye(3) + np.radians(0.5) * rng.standard_normal((3, 3))
    )
    b = 0.05 * G * SENS * rng.uniform(-1, 1, 3)
    return S, b


def gauge(T):
    Q, R = np.linalg.qr(T)
    D = np.diag(np.sign(np.diag(R)))
    return D @ R, Q @ D


def poses(rng, S, b, ups, sigma_counts=0.0, n=200, jitter_deg=0.0):
    rot = Rotation.from_rotvec(
        np.radians(jitter_deg / np.sqrt(3)) * rng.standard_normal((len(ups), 3))
    )
    u = rot.apply(ups)
    a = (G * u) @ S.T + b + sigma_counts / np.sqrt(n) * rng.standard_normal((len(ups), 3))
    cov = np.repeat((sigma_counts**2 / n * np.eye(3))[None], len(ups), axis=0)
    return a, cov, u


@pytest.mark.parametrize("init", ["updown", "ellipsoid", "auto"])
def test_exact_recovery_noise_free(init):
    rng = np.random.default_rng(1)
    S, b = random_part(rng)
    a, _, _ = poses(rng, S, b, cube18(), jitter_deg=3.0)
    res = fit_gravity(a, G, up=cube18(), init=init)
    M_true, _ = gauge(np.linalg.inv(S))
    np.testing.assert_allclose(res.bias, b, atol=1e-6 * SENS)
    np.testing.assert_allclose(res.matrix, M_true, rtol=0, atol=1e-9 / SENS)
    assert res.converged and np.max(np.abs(res.residuals)) < 1e-9
    assert np.allclose(np.tril(res.matrix, -1), 0) and np.all(np.diag(res.matrix) > 0)


def test_12_parameter_recovers_full_matrix_when_placement_is_exact():
    rng = np.random.default_rng(2)
    S, b = random_part(rng)
    a, _, _ = poses(rng, S, b, cube18())
    res = fit_gravity(a, G, up=cube18(), variant="12")
    np.testing.assert_allclose(res.matrix, np.linalg.inv(S), atol=1e-9 / SENS)
    assert res.param_names[3] == "m_xx" and len(res.params) == 12
    assert np.nanmax(res.up_angle_deg) < 1e-6


def test_unlabelled_poses_calibrate_from_the_ellipsoid_start():
    rng = np.random.default_rng(3)
    S, b = random_part(rng)
    ups = Rotation.random(30, random_state=4).apply([0, 0, 1])
    a, cov, _ = poses(rng, S, b, ups, sigma_counts=0.01 * SENS)
    res = fit_gravity(a, G, cov_mean=cov)
    assert res.init in ("ellipsoid", "sphere")
    M_true, _ = gauge(np.linalg.inv(S))
    x_true = model_to_params(b, M_true)
    assert np.all(np.abs(res.params - x_true) < 5 * res.std)


def test_ellipsoid_fit_is_exact_on_an_exact_ellipsoid():
    rng = np.random.default_rng(5)
    S, b = random_part(rng)
    ups = Rotation.random(12, random_state=6).apply([0, 0, 1])
    a = (G * ups) @ S.T + b
    fit = fit_ellipsoid(a, G)
    assert fit.kind == "ellipsoid"
    np.testing.assert_allclose(np.linalg.norm((a - fit.bias) @ fit.M.T, axis=1), G, rtol=1e-9)


def test_reported_covariance_equals_the_cramer_rao_bound_at_the_truth():
    """Two independent derivations (solver Jacobian, bound with nuisance directions) agree."""
    rng = np.random.default_rng(7)
    S, b = random_part(rng)
    sigma = 0.01 * SENS
    a, cov, u = poses(rng, S, b, cube18(), sigma_counts=sigma, jitter_deg=2.0)
    M_true, Q = gauge(np.linalg.inv(S))
    a_exact = (G * u) @ S.T + b  # noise-free means: the solver's Jacobian is evaluated at truth
    res = fit_gravity(a_exact, G, cov_mean=cov, up=cube18())
    crb = gravity_crb(M_true, b, u @ Q, G, cov)
    np.testing.assert_allclose(np.sqrt(np.diag(res.cov)), np.sqrt(np.diag(crb)), rtol=0.02)


def test_errors_are_at_the_bound_and_intervals_cover_95_percent():
    """Monte Carlo: RMS error / sqrt(CRB) near 1 and 95 % intervals covering ~95 %."""
    n_seeds, ups = 150, cube18()
    sigma = 0.01 * SENS
    err, std, crb = [], [], []
    for seed in range(n_seeds):
        rng = np.random.default_rng(100 + seed)
        S, b = random_part(rng)
        a, cov, u = poses(rng, S, b, ups, sigma_counts=sigma, jitter_deg=2.0)
        res = fit_gravity(a, G, cov_mean=cov, up=ups)
        M_true, Q = gauge(np.linalg.inv(S))
        err.append(res.params - model_to_params(b, M_true))
        std.append(res.std)
        crb.append(np.diag(gravity_crb(M_true, b, u @ Q, G, cov)))
    err, std, crb = map(np.array, (err, std, crb))
    ratio = np.sqrt(np.mean(err**2, 0) / np.mean(crb, 0))
    # Sampling error of an RMS over 150 seeds is about 1/sqrt(300) = 6 %: allow 3 sigma.
    assert np.all(ratio < 1.2) and np.all(ratio > 0.8), ratio
    covered = np.mean(np.abs(err) <= 1.96 * std)
    # 1350 (correlated) trials: binomial sd ~0.6 %; allow 2.5 points either way.
    assert 0.925 <= covered <= 0.975, covered


def test_noise_scale_inflates_when_residuals_exceed_the_noise():
    rng = np.random.default_rng(8)
    S, b = random_part(rng)
    a, cov, _ = poses(rng, S, b, cube18(), sigma_counts=0.01 * SENS)
    a = a + 0.05 * SENS * rng.standard_normal(a.shape)  # unmodelled disturbance, 70x the noise
    res = fit_gravity(a, G, cov_mean=cov, up=cube18())
    assert res.noise_scale > 100
    res_ok = fit_gravity(poses(rng, S, b, cube18(), 0.01 * SENS)[0], G, cov_mean=cov)
    assert res_ok.noise_scale < 10


def test_leave_one_out_matches_explicit_refits_and_press():
    rng = np.random.default_rng(9)
    S, b = random_part(rng)
    a, cov, _ = poses(rng, S, b, cube18(), sigma_counts=0.01 * SENS, jitter_deg=2.0)
    res = fit_gravity(a, G, cov_mean=cov, up=cube18())
    loo = leave_one_out(a, G, res, cov_mean=cov)
    for k in (0, 7, 17):
        keep = np.arange(18) != k
        sub = fit_gravity(a[keep], G, cov_mean=cov[keep])
        expected = np.linalg.norm(sub.matrix @ (a[k] - sub.bias)) - G
        assert loo[k] == pytest.approx(expected, abs=1e-4 * 0.01)
    press = leave_one_out_press(a, G, res, cov_mean=cov)
    np.testing.assert_allclose(press, loo, atol=0.1 * np.std(loo))
    # Held-out residuals are larger than fitted ones: the fit cannot see the pose it misses.
    assert np.sqrt(np.mean(loo**2)) > np.sqrt(np.mean(res.residuals**2))


def test_too_few_poses_are_refused_with_advice():
    rng = np.random.default_rng(10)
    S, b = random_part(rng)
    a, _, _ = poses(rng, S, b, cube18()[:8])
    with pytest.raises(DesignError, match="capture at least 9"):
        fit_gravity(a, G)


def test_poses_in_one_plane_are_refused():
    rng = np.random.default_rng(11)
    S, b = random_part(rng)
    phi = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    ups = np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])
    a, _, _ = poses(rng, S, b, ups)
    with pytest.raises(DesignError, match="undetermined"):
        fit_gravity(a, G, init="ellipsoid")


def test_no_convergence_is_a_solver_error():
    rng = np.random.default_rng(12)
    S, b = random_part(rng)
    a, cov, _ = poses(rng, S, b, cube18(), sigma_counts=0.01 * SENS)
    with pytest.raises(SolverError, match="did not converge"):
        fit_gravity(
            a + 2000 * rng.standard_normal(a.shape), G, init="updown", up=cube18(), max_iterations=1
        )


def test_12_parameter_needs_labels():
    rng = np.random.default_rng(13)
    S, b = random_part(rng)
    a, _, _ = poses(rng, S, b, cube18())
    with pytest.raises(DesignError, match="labelled"):
        fit_gravity(a, G, variant="12")


def test_pose_geometry():
    ups = cube18()
    assert count_distinct(ups) == 18
    assert count_distinct(np.vstack([ups, ups + 0.01])) == 18
    cov18 = coverage(ups)
    cov6 = coverage(ups[:6])
    assert cov18.fraction == pytest.approx(1.0)
    assert cov18.largest_gap_deg == pytest.approx(35.26, abs=1.5)  # cube corner to nearest edge
    assert cov6.largest_gap_deg == pytest.approx(54.74, abs=1.5)  # cube corner to nearest face
    assert cov6.fraction < cov18.fraction
    assert spread_deg(ups) == pytest.approx(180, abs=1)
    tilted = Rotation.from_rotvec(np.radians(10) * np.eye(3)).apply([0, 0, 1])
    assert spread_deg(tilted) < 20
