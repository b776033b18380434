"""The labelled solver's fast paths (issue 14.3) against the straightforward computations
they replace: the same numbers, to rounding."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.calibrate.session import static_poses
from imucal_cli.estimators.accel import labelled, labelled_beyond
from imucal_cli.estimators.accel.labelled_model import (
    jacobian,
    public_from_theta,
    second_order,
)
from imucal_cli.simulate.triad import simulate

CREATED = "2026-01-01T00:00:00Z"
G0 = 9.80665


def _public_reference(t):
    """Bias, row norms of S = K^-1, angles between its rows minus 90 deg, the rotation."""
    K = np.zeros((3, 3))
    K[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]] = t[3:9]  # the diagonal, then xy, xz, yz
    S = np.linalg.inv(K)
    gains = np.linalg.norm(S, axis=1)
    n = S / gains[:, None]
    angles = [np.degrees(np.arccos(n[i] @ n[j])) - 90.0 for i, j in ((0, 1), (0, 2), (1, 2))]
    return np.concatenate([t[:3], gains, angles, t[9:]])


def test_public_from_theta_of_a_stack_is_that_of_each_row():
    rng = np.random.default_rng(2)
    theta = np.zeros((50, 12))
    theta[:, :3] = rng.normal(size=(50, 3)) * 100
    theta[:, 3:6] = 1e-3 * (1 + 0.05 * rng.normal(size=(50, 3)))  # K diagonal
    theta[:, 6:9] = 1e-5 * rng.normal(size=(50, 3))
    theta[:, 9:] = rng.normal(size=(50, 3))
    expected = np.array([_public_reference(t) for t in theta])
    stacked = public_from_theta(theta)
    np.testing.assert_allclose(stacked, expected, rtol=1e-12, atol=1e-10)
    assert np.array_equal(public_from_theta(theta[3]), stacked[3])


def test_batched_differences_equal_the_pointwise_ones():
    def f(x):
        return np.array([np.sin(x[0]) * x[1] ** 2, np.exp(x[0] * x[2]), x[1] / (1 + x[2] ** 2)])

    def f_many(X):
        return np.array([f(x) for x in X])

    x = np.array([0.3, 1.7, -0.4])
    cov = np.diag([1e-4, 2e-4, 3e-4]) + 1e-5
    np.testing.assert_array_equal(jacobian(f, x), jacobian(f_many, x, many=True))
    for a, b in zip(second_order(f, x, cov), second_order(f_many, x, cov, many=True), strict=True):
        np.testing.assert_array_equal(a, b)
    # against the analytic Hessian of the first output: d2/dx0^2 = -sin(x0) x1^2
    bias, _ = second_order(f, x, np.diag([1e-4, 0.0, 0.0]))
    assert bias[0] == pytest.approx(0.5 * 1e-4 * -np.sin(0.3) * 1.7**2, rel=1e-6)


def test_linear_refit_is_the_iterative_refit(monkeypatch):
    """Six faces (every direction labelled): each node's refit of (B, K, phi) by the linear
    solve equals Levenberg-Marquardt's from the node."""
    calls = []
    original = labelled_beyond._refit_linear

    def record(prob, X):
        calls.append((prob, X.copy()))
        return original(prob, X)

    monkeypatch.setattr(labelled_beyond, "_refit_linear", record)
    session, _ = simulate(plan="six", seed=2, created=CREATED)
    p = static_poses(session)
    res = labelled.fit_labelled(p.a_mean, p.up, G0, p.cov_mean, placement_deg=2.0)
    assert res.cov_parts["label_limited"] == 3 and len(calls) == 1
    prob, X = calls[0]
    assert len(X) == 2 * 3**2 + 1
    linear = original(prob, X)
    for x, lin in zip(X, linear, strict=True):
        iterative = labelled_beyond._refit_iterative(prob, x, np.arange(12))
        np.testing.assert_allclose(lin[:12], iterative[:12], rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(lin[12:], x[12:])  # the directions held


def test_values_are_the_predictions():
    session, _ = simulate(plan="qureshi18", seed=1, created=CREATED)
    p = static_poses(session)
    calls = []
    original = labelled._solve

    def record(prob, x0, max_iterations):
        calls.append(prob)
        return original(prob, x0, max_iterations)

    with pytest.MonkeyPatch.context() as m:
        m.setattr(labelled, "_solve", record)
        res = labelled.fit_labelled(p.a_mean, p.up, G0, p.cov_mean)
    prob = calls[0]
    x = np.concatenate([np.zeros(3), [1.0, 0.01, -0.02, 1.1, 0.03, 0.9], [0.1, -0.2, 0.3],
                        0.01 * np.arange(2 * prob.N)])  # fmt: skip
    f = prob.values(x).copy()
    np.testing.assert_array_equal(f, prob.predict(x)[0])
    assert res.converged


def test_deletion_of_groups_of_two_sizes_is_the_per_group_formula():
    """Labelled and unlabelled poses (5 and 3 rows) batched by size: the module formula."""
    from imucal_cli.design.outliers import deletion

    rng = np.random.default_rng(6)
    sizes = [5, 3, 5, 5, 3, 3, 5, 5, 3, 5]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    groups = [np.arange(a, a + n) for a, n in zip(starts, sizes, strict=False)]
    J, r = rng.normal(size=(starts[-1], 9)), rng.normal(size=starts[-1])
    P = np.linalg.inv(J.T @ J)
    d = deletion(J, r, groups, P)
    for k, rows in enumerate(groups):
        A = np.eye(len(rows)) - J[rows] @ P @ J[rows].T
        T = r[rows] @ np.linalg.solve(A, r[rows])
        dx = P @ J[rows].T @ np.linalg.solve(A, r[rows])
        assert d.T[k] == pytest.approx(T, rel=1e-9) and d.rank[k] == len(rows)
        np.testing.assert_allclose(d.dx[k], dx, rtol=1e-8, atol=1e-12)


def test_held_out_residuals_are_the_per_pose_formula():
    """``|M_(-k) (a_k - B_(-k))| - g`` with each pose's deletion step, pose by pose."""
    from scipy.spatial.transform import Rotation

    def R(phi):
        return Rotation.from_rotvec(phi).as_matrix()

    six, _ = simulate(plan="six", seed=6, created=CREATED)
    rnd, _ = simulate(plan="random:9", seed=6, created=CREATED)
    p6, pr = static_poses(six), static_poses(rnd)
    a = np.vstack([p6.a_mean, pr.a_mean])
    states = []
    original = labelled._held_out

    def record(prob, st, dele, offset, scale, a_mean, g):
        states.append((prob, st, dele, offset, scale))
        return original(prob, st, dele, offset, scale, a_mean, g)

    with pytest.MonkeyPatch.context() as m:
        m.setattr(labelled, "_held_out", record)
        res = labelled.fit_labelled(
            a, np.vstack([p6.up, pr.up]), G0, np.concatenate([p6.cov_mean, pr.cov_mean])
        )
    prob, st, dele, offset, scale = states[0]
    for k in range(len(a)):
        Bn, Kn, phi, _ = prob.split(st.sol.x + dele.dx[k])
        expected = np.linalg.norm(R(phi) @ Kn / scale @ (a[k] - offset - scale * Bn)) - G0
        assert res.residual_loo[k] == pytest.approx(expected, rel=1e-9, abs=1e-12)
