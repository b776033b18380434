"""Cramér-Rao bounds of calibration designs: the best accuracy the data allows.

Gravity-magnitude design (Qureshi & Golnaraghi III-A)
-----------------------------------------------------
Pose k holds the unit still with an unknown true gravity direction ``u_k`` (two angles: a
nuisance parameter per pose, since hand placement is never exact). Its mean raw reading is

    a_k = S (g u_k) + B + e_k,     e_k ~ N(0, Sigma_k),      S = M^-1,

with ``M`` upper triangular (the gauge of the 9-parameter model). The Fisher information of
``theta = (B, upper(M))`` and all ``u_k`` together is ``sum_k J_k^T Sigma_k^-1 J_k``; the bound
on ``theta`` is the corresponding block of its inverse (which accounts for the nuisance
directions through the Schur complement).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .gravity import _UPPER, triangular_and_rotation
from .labelled_model import (
    design_jacobian,
    jacobian,
    public_from_theta,
    theta_floor,
)


def _tangent_basis(u: np.ndarray) -> np.ndarray:
    """Two unit vectors perpendicular to ``u`` (3,), as columns of a (3, 2) array."""
    helper = np.eye(3)[np.argmin(np.abs(u))]
    t1 = np.cross(u, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(u, t1)
    return np.column_stack([t1, t2])


def gravity_crb(
    M: np.ndarray, B: np.ndarray, u: np.ndarray, g: float, cov_mean: np.ndarray
) -> np.ndarray:
    """Cramér-Rao bound of the 9-parameter gravity model for one design.

    Parameters
    ----------
    M : ndarray, shape (3, 3)
        True upper-triangular calibration matrix (m/s^2 per raw unit).
    B : ndarray, shape (3,)
        True bias, raw units (the bound does not depend on it; kept for clarity).
    u : ndarray, shape (N, 3)
        True gravity direction of each pose, unit vectors in the frame of ``M``.
    g : float
        Gravity, m/s^2.
    cov_mean : ndarray, shape (N, 3, 3)
        Covariance of each pose's mean reading, raw units^2.

    Returns
    -------
    ndarray, shape (9, 9)
        Lower bound on the covariance of any unbiased estimate of
        ``(b_x, b_y, b_z, k_x, k_y, k_z, k_xy, k_xz, k_yz)``.
    """
    del B
    S = np.linalg.inv(M)
    N = len(u)
    p = 9 + 2 * N
    F = np.zeros((p, p))
    for k in range(N):
        Jk = np.zeros((3, p))
        Jk[:, :3] = np.eye(3)  # d a / d B
        f = g * u[k]
        for c, (i, j) in enumerate(zip(*_UPPER, strict=True)):
            # d(M^-1) = -M^-1 dM M^-1  ->  d a / d M_ij = -S E_ij S f
            Jk[:, 3 + c] = -S[:, i] * (S[j] @ f)
        Jk[:, 9 + 2 * k : 11 + 2 * k] = g * S @ _tangent_basis(u[k])  # d a / d (angles of u_k)
        Wk = np.linalg.inv(cov_mean[k])
        F += Jk.T @ Wk @ Jk
    return np.linalg.inv(F)[:9, :9]


def factorization_crb(
    S: np.ndarray, b: np.ndarray, u: np.ndarray, sigma: float, samples: np.ndarray | int
) -> np.ndarray:
    """Cramér-Rao bound of an n-element unit calibrated from static orientations.

    Each orientation i gives ``samples`` readings ``z = S^T g_i + b + e`` with
    ``e ~ N(0, sigma^2 I_n)`` and ``g_i`` a unit vector (two nuisance angles each): the design
    of Hwangbo & Kanade's Table I (magnitude constraints only). The rotation of ``S`` is not
    identifiable, so the information matrix is singular along it; the pseudo-inverse gives the
    bound for every rotation-invariant function of the parameters (biases, gains, angles
    between axes).

    Parameters
    ----------
    S : ndarray, shape (3, n)
        True sensitivity axes (raw units per motion unit).
    b : ndarray, shape (n,)
    u : ndarray, shape (N, 3)
        True unit motion of each orientation.
    sigma : float
        Per-sample noise, raw units.
    samples : int or ndarray (N,)
        Readings per orientation.

    Returns
    -------
    ndarray, shape (n + 3n, n + 3n)
        Bound on the covariance of ``(b, vec(S))`` (row-major ``S``) in the gauge-free sense.
    """
    del b
    n = S.shape[1]
    N = len(u)
    counts = np.broadcast_to(np.asarray(samples, float), (N,))
    p = n + 3 * n + 2 * N
    F = np.zeros((p, p))
    for i in range(N):
        J = np.zeros((n, p))
        J[:, :n] = np.eye(n)  # d z / d b
        for r in range(3):  # d z_j / d S_rj = u_r
            J[np.arange(n), n + r * n + np.arange(n)] = u[i, r]
        J[:, 4 * n + 2 * i : 4 * n + 2 * i + 2] = S.T @ _tangent_basis(u[i])
        F += counts[i] * (J.T @ J) / sigma**2
    full = np.linalg.pinv(F, rcond=1e-12, hermitian=True)
    return full[: 4 * n, : 4 * n]


def invariant_summary(S: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation-invariant quantities of a unit: biases (n), gains (n), angles between every
    pair of axes (n(n-1)/2, degrees, row-major upper triangle)."""
    gains = np.linalg.norm(S, axis=0)
    s = S / gains
    iu = np.triu_indices(S.shape[1], 1)
    ang = np.degrees(np.arccos(np.clip((s.T @ s)[iu], -1, 1)))
    return np.concatenate([b, gains, ang])


def propagate(fun, x: np.ndarray, cov: np.ndarray, rel_step: float = 1e-7) -> np.ndarray:
    """Covariance of ``fun(x)`` by the delta method (central differences)."""
    f0 = np.asarray(fun(x))
    J = np.empty((len(f0), len(x)))
    for k in range(len(x)):
        h = rel_step * max(abs(x[k]), 1.0)
        dx = np.zeros_like(x)
        dx[k] = h
        J[:, k] = (np.asarray(fun(x + dx)) - np.asarray(fun(x - dx))) / (2 * h)
    return J @ cov @ J.T


def labelled_crb(
    M: np.ndarray,
    B: np.ndarray,
    u: np.ndarray,
    g: float,
    cov_mean: np.ndarray,
    placement_deg: float | np.ndarray,
) -> np.ndarray:
    """Cramér-Rao bound of the labelled-pose design with the labels as a prior.

    The derivation is in :mod:`.labelled` (eqs. L4-L5): each pose's direction is a nuisance
    parameter (two angles) with prior ``N(0, sigma_p^2 I)``, ``sigma_p = placement_deg /
    sqrt(2)``; the bound on ``theta = (B, K, r)`` (``M = R(r) K``, K upper triangular) is the
    Schur complement of the hybrid information, mapped to the solver's parameters.

    Parameters
    ----------
    M : ndarray, shape (3, 3)
        True calibration matrix (fixture frame), m/s^2 per raw unit.
    B : ndarray, shape (3,)
        True bias, raw units (the bound does not depend on it; kept for clarity).
    u : ndarray, shape (N, 3)
        True gravity direction of each pose (fixture frame).
    g : float
        Gravity, m/s^2.
    cov_mean : ndarray, shape (N, 3, 3)
        Covariance of each pose mean, raw units^2.
    placement_deg : float or ndarray, shape (N,)
        RMS angle between the true and the labelled up, degrees, for every pose or per pose
        (``inf``: no label, the pose's direction free: it adds one magnitude equation, as in
        the labelled solver's unlabelled poses).

    Returns
    -------
    ndarray, shape (12, 12)
        Bound on the covariance of the solver's parameters (:data:`.labelled.PARAM_NAMES`:
        bias, sensitivities, angles between the axes minus 90 deg, rotation r in degrees).
    """

    Gt, Gd = design_jacobian(M, u, g)
    placement = np.broadcast_to(np.asarray(placement_deg, float), (len(u),))
    finite = np.isfinite(placement)
    prior = np.zeros(len(u))
    prior[finite] = 2.0 / np.radians(placement[finite]) ** 2
    A = np.zeros((12, 12))
    for k in range(len(u)):
        Wk = np.linalg.inv(cov_mean[k])
        Dk = Gd[k].T @ Wk @ Gd[k] + prior[k] * np.eye(2)
        Ck = Gt[k].T @ Wk @ Gd[k]
        A += Gt[k].T @ Wk @ Gt[k] - Ck @ np.linalg.solve(Dk, Ck.T)  # Schur complement, (L5)
    diag = np.diag(A)
    d = 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0))  # equilibrate: decades apart
    cov = d[:, None] * np.linalg.pinv(d[:, None] * A * d, rcond=1e-13, hermitian=True) * d
    K, Q = triangular_and_rotation(M)
    theta = np.concatenate([B, K[_UPPER], np.degrees(Rotation.from_matrix(Q).as_rotvec())])
    T = jacobian(public_from_theta, theta, floor=theta_floor(theta))
    return T @ cov @ T.T
