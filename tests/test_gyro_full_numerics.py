"""The full gyro model's numerics (issue 14.3): vectorised integration over all rotations at
once, its sensitivity (the analytic Jacobian), and the sparse banded noise covariance.

Each check compares with an independent computation: scipy's Rotation composed over fine
sub-steps, finite differences, the dense covariance and its inverse."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from scipy.spatial.transform import Rotation

from imucal_cli.formats.config import config_from_dict
from imucal_cli.pipeline.calibrate import calibrate_accel, with_segments
from imucal_cli.pipeline.gyro import full_problem
from imucal_cli.simulate.rotations import simulate_gyro_rotations
from imucal_cli.solvers.banded import BandedWhitener
from imucal_cli.solvers.gyro_integration import (
    Stack,
    attitudes,
    end_sensitivity,
    integrate_rotations,
    matrix_rows,
)
from imucal_cli.solvers.gyro_model import Problem

CREATED = "2026-01-01T00:00:00Z"


def _hand_turn(rng, n, rate_hz=100.0):
    """A hand-like turn: smooth rates about a wandering axis (not a fixed-axis turn)."""
    t = np.arange(n) / rate_hz + rng.uniform(0, 5)
    tau = np.linspace(0, 1, n)
    w = np.column_stack([a * np.sin(np.pi * tau * f) for a, f in zip(
        rng.uniform(-3, 3, 3), rng.uniform(0.5, 2.0, 3), strict=True)])  # fmt: skip
    return t, w


def _reference(t, w, substeps=200):
    """Composition of many tiny fixed-axis steps of the linearly interpolated rate."""
    R = Rotation.identity()
    for i in range(len(t) - 1):
        s = np.linspace(0, 1, substeps + 1)
        mid = (s[:-1] + s[1:]) / 2
        h = (t[i + 1] - t[i]) / substeps
        for m in mid:
            R = R * Rotation.from_rotvec(((1 - m) * w[i] + m * w[i + 1]) * h)
    return R.as_matrix()


def test_integration_of_hand_turns_matches_a_fine_reference():
    rng = np.random.default_rng(4)
    turns = [_hand_turn(rng, n) for n in (40, 17, 90)]
    R = integrate_rotations([t for t, _ in turns], [w for _, w in turns])
    for (t, w), Rk in zip(turns, R, strict=True):
        ref = _reference(t, w, substeps=20)
        # Coning increment: error per step ~ h^4 |w|^2 |dw| / 96, far below 1e-6 rad here.
        err = Rotation.from_matrix(ref.T @ Rk).magnitude()
        assert err < 1e-6, err


def test_segments_are_independent_of_their_neighbours():
    rng = np.random.default_rng(5)
    turns = [_hand_turn(rng, n) for n in (3, 200, 16, 17, 33, 2)]
    together = integrate_rotations([t for t, _ in turns], [w for _, w in turns])
    for (t, w), Rk in zip(turns, together, strict=True):
        np.testing.assert_allclose(integrate_rotations([t], [w])[0], Rk, atol=1e-13)


def test_clock_scales_every_interval():
    rng = np.random.default_rng(6)
    t, w = _hand_turn(rng, 50)
    np.testing.assert_allclose(
        integrate_rotations([t], [w], clock=1.01)[0], integrate_rotations([1.01 * t], [w])[0],
        atol=1e-13,
    )


def test_end_sensitivity_is_the_derivative_of_the_end_attitude():
    """d phi = sum_i w_i E_i d omega_i: checked against re-integrating with a perturbed rate."""
    rng = np.random.default_rng(7)
    turns = [_hand_turn(rng, n) for n in (60, 25)]
    stack = Stack.of([t for t, _ in turns])
    w = np.concatenate([w for _, w in turns]).T.copy()
    v = rng.normal(size=w.shape)
    dA = rng.normal(size=(3, 3)) * 1e-6
    R9 = matrix_rows(attitudes(stack, w))
    S = end_sensitivity(stack, R9, v)
    end = stack.stop - 1

    def ends(rate):
        q = attitudes(stack, rate)
        return matrix_rows(q[:, end]).T.reshape(-1, 3, 3)

    R0, R1 = ends(w), ends(w + dA @ v)
    for k in range(len(turns)):
        dphi = Rotation.from_matrix(R0[k].T @ R1[k]).as_rotvec()  # small rotation at the end
        predicted = np.einsum("acj,cj->a", S[k], dA)
        # First order in the perturbation, trapezoid weights: agreement to a few percent.
        np.testing.assert_allclose(predicted, dphi, rtol=0.03, atol=1e-3 * np.abs(dphi).max())


@pytest.fixture(scope="module")
def problem():
    session, truth = simulate_gyro_rotations(plan="free:10", seed=8, created=CREATED)
    cfg = config_from_dict({"gyro": {"solver": "full"}})
    session, _ = with_segments(session)
    acc = calibrate_accel(session, cfg)
    rot, still, noise = full_problem(session, cfg, acc)
    return rot, still, noise, truth


def test_jacobian_matches_finite_differences(problem):
    rot, still, noise, truth = problem
    prob = Problem(rot, still, noise)
    x = np.r_[truth.gyro.bias, truth.gyro.matrix.ravel()] * (1 + 1e-3)
    r, J = prob.residuals_and_jacobian(x)
    np.testing.assert_allclose(prob.raw_residuals(x), r, atol=1e-12)
    for i in range(12):
        h = 1e-4 * max(abs(x[i]), 1e-9)
        e = np.zeros(12)
        e[i] = h
        num = (prob.raw_residuals(x + e) - prob.raw_residuals(x - e)) / (2 * h)
        scale = np.abs(J[:, i]).max()
        np.testing.assert_allclose(J[:, i], num, atol=0.02 * scale)


def test_whitening_equals_the_dense_inverse_covariance(problem):
    rot, still, noise, truth = problem
    prob = Problem(rot, still, noise)
    x = np.r_[truth.gyro.bias, truth.gyro.matrix.ravel()]
    cov = prob.rotation_covariance(x)
    W = BandedWhitener(cov, ridge=0.0)
    dense = cov.toarray()
    Wd = W(np.eye(len(dense)))
    np.testing.assert_allclose(Wd.T @ Wd, np.linalg.inv(dense), rtol=1e-8,
                               atol=1e-8 * np.abs(np.linalg.inv(dense)).max())  # fmt: skip
    # Consecutive rotations share one still period: a band of two rotations (2 x 2 blocks).
    assert W.bandwidth <= 3


def test_whitener_of_a_shuffled_sparse_covariance():
    """Rotations sharing still periods in any order: the reordering still finds a narrow band,
    and W^T W is the inverse covariance."""
    rng = np.random.default_rng(9)
    n_src, n = 60, 80
    C = sparse.hstack([sparse.random(n, n_src, density=0.03, random_state=rng),
                       sparse.identity(n) * 0.1])  # fmt: skip
    perm = rng.permutation(n)
    cov = (C @ C.T).tocsr()[perm][:, perm]
    W = BandedWhitener(cov, ridge=0.0)
    Wd = W(np.eye(n))
    np.testing.assert_allclose(Wd.T @ Wd @ cov.toarray(), np.eye(n), atol=1e-8)


def test_information_is_linear_in_the_number_of_turns_structure():
    """The whitener's band does not grow with the session: a long session costs the same per
    turn (time and memory linear in the number of turns; timings are in ``bench``)."""
    widths = []
    for n in (8, 64):
        session, truth = simulate_gyro_rotations(plan=f"free:{n}", seed=1, created=CREATED)
        cfg = config_from_dict({"gyro": {"solver": "full"}})
        session, _ = with_segments(session)
        rot, still, noise = full_problem(session, cfg, calibrate_accel(session, cfg))
        prob = Problem(rot, still, noise)
        x = np.r_[truth.gyro.bias, truth.gyro.matrix.ravel()]
        widths.append(BandedWhitener(prob.rotation_covariance(x)).bandwidth)
    assert widths[0] == widths[1] <= 3


def test_kept_jacobian_and_covariance_equal_fresh_ones(problem):
    """The residuals, Jacobian and noise covariance kept with an integration are what a fresh
    problem computes, read-only, and not handed to a problem with other still periods."""
    from dataclasses import replace

    rot, still, noise, truth = problem
    x = np.r_[truth.gyro.bias, truth.gyro.matrix.ravel()] * (1 + 1e-4)
    prob = Problem(rot, still, noise)
    r, J = prob.residuals_and_jacobian(x)
    assert prob.residuals_and_jacobian(x.copy())[1] is J  # kept
    assert not J.flags.writeable and not r.flags.writeable
    fresh_r, fresh_J = Problem(rot, still, noise).residuals_and_jacobian(x)
    np.testing.assert_array_equal(r, fresh_r)
    np.testing.assert_array_equal(J, fresh_J)
    C = prob.rotation_covariance(x)
    assert prob.rotation_covariance(x) is C
    np.testing.assert_array_equal(C.toarray(), Problem(rot, still, noise).rotation_covariance(x)
                                  .toarray())  # fmt: skip
    # With G = 0 the 21-parameter problem's covariance is the 12-parameter one's.
    with_g = Problem(rot, still, noise, g_sensitivity=True, like=prob)
    with_g.share_without_g(prob, x)
    x_g = np.r_[x, np.zeros(9)]
    assert with_g.rotation_covariance(x_g) is prob.rotation_covariance(x)
    assert with_g.residuals_and_jacobian(x_g)[1].shape == (len(r), 21)
    # Another still period's gravity: the same integration, its own residuals and covariance
    # (what it keeps replaces the first problem's: recomputed there when asked again).
    moved = prob.with_still(replace(still, g=still.g * 1.001 + 0.01))
    r2, J2 = moved.residuals_and_jacobian(x)
    assert J2 is not J
    np.testing.assert_array_equal(
        r2, Problem(rot, moved.still, noise).residuals_and_jacobian(x)[0])
    assert moved.rotation_covariance(x) is not C
    np.testing.assert_array_equal(prob.residuals_and_jacobian(x)[1], J)
    # Another noise level: its own covariance.
    other = Problem(rot, still, 2 * noise)
    other.share(prob)
    np.testing.assert_array_equal(other.rotation_covariance(x).toarray(),
                                  Problem(rot, still, 2 * noise).rotation_covariance(x).toarray())
