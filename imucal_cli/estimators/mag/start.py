"""Starts of the magnetometer fit (:mod:`imucal_cli.estimators.mag.magnetometer`): the algebraic
ellipsoid, then the rotation onto the accelerometer frame from eq. (3) of that module,
``u_k . R n_k = s`` (``n_k`` the field direction of pose ``k`` in the magnetometer's frame,
``u_k`` its up direction in the accelerometer's).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import DesignError
from imucal_cli.estimators.ellipsoid import fit_ellipsoid

__all__ = [
    "cube_rotations",
    "ellipsoid_start",
    "polar",
    "refine_rotation",
    "rotation_candidates",
    "rotation_start",
]


def polar(W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polar decomposition ``W = R P``: rotation ``R`` (det +1) and symmetric ``P``.

    For a ``W`` with negative determinant (a left-handed sensor) ``R`` is a reflection.
    """
    U, sv, Vt = np.linalg.svd(W)
    R = U @ Vt
    P = Vt.T @ np.diag(sv) @ Vt
    return R, P


def ellipsoid_start(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """Centre and symmetric ``P`` with ``|P (m - c)| = 1`` from the algebraic fit."""
    try:
        ell = fit_ellipsoid(points, 1.0)
    except ValueError:
        raise DesignError(
            "every magnetometer reading is the same: the sensor is stuck or not connected"
        ) from None
    Q = ell.M.T @ ell.M
    lam, V = np.linalg.eigh(Q)
    P = V @ np.diag(np.sqrt(np.clip(lam, 1e-30, None))) @ V.T
    return ell.bias, P, ell.kind


def cube_rotations() -> list[np.ndarray]:
    """The 24 proper rotations that map the axes onto (signed) axes."""
    out = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for signs in np.ndindex(2, 2, 2):
            R = np.zeros((3, 3))
            for row, (col, sgn) in enumerate(zip(perm, signs, strict=True)):
                R[row, col] = 1.0 if sgn == 0 else -1.0
            if np.linalg.det(R) > 0:
                out.append(R)
    return out


def rotation_start(n: np.ndarray, up: np.ndarray, w: np.ndarray) -> list[tuple]:
    """Rotations ``R`` and ``s`` minimising ``sum w^2 (u . R n - s)^2`` (eq. 3), multi-start:
    the refined best few, ``(cost, R, s)``, lowest cost first (:func:`rotation_candidates`).

    ``n`` (K, 3) are the unit field directions in the magnetometer's frame, ``up`` (K, 3) the
    unit up directions in the accelerometer's frame.
    """
    starts = cube_rotations()
    if len(n) >= 9:
        # eq. (3) is linear in (vec R, s): the null vector of [kron(u, n), -1] rows.
        A = np.column_stack([np.einsum("ki,kj->kij", up, n).reshape(len(n), 9), -np.ones(len(n))])
        v = np.linalg.svd(A * w[:, None])[2][-1]
        for sign in (1.0, -1.0):
            R_lin, _ = polar(sign * v[:9].reshape(3, 3))
            if np.linalg.det(R_lin) > 0:
                starts.append(R_lin)

    return rotation_candidates(n, up, w, starts)


def rotation_candidates(n: np.ndarray, up: np.ndarray, w: np.ndarray,
                        starts: list[np.ndarray] | None = None) -> list[tuple]:  # fmt: skip
    """The best few ``starts`` (default the 24 axis permutations) by ``sum w^2 (u . R n -
    s)^2``, each refined by Gauss-Newton on ``R <- R Exp(delta)``: ``(cost, R, s)``, lowest
    cost first."""

    def cost(R):
        c = np.einsum("ki,ij,kj->k", up, R, n)
        s_opt = float(np.average(c, weights=w * w))
        return float(np.sum((w * (c - s_opt)) ** 2)), s_opt

    ranked = sorted(cube_rotations() if starts is None else starts,
                    key=lambda R: cost(R)[0])[:4]  # fmt: skip
    out = []
    for R in ranked:
        R, s_k = refine_rotation(R, cost(R)[1], n, up, w)
        out.append((cost(R)[0], R, float(np.clip(s_k, -1.0, 1.0))))
    return sorted(out, key=lambda c: c[0])


def refine_rotation(R, s, n, up, w, iterations: int = 30):
    """Gauss-Newton on ``w (u . R Exp(delta) n - s)`` over ``(delta, s)``."""
    for _ in range(iterations):
        Ru = up @ R  # rows R^T u
        r = w * (np.sum(Ru * n, axis=1) - s)
        J = np.column_stack([np.cross(n, Ru), -np.ones(len(n))]) * w[:, None]
        step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        R = R @ Rotation.from_rotvec(step[:3]).as_matrix()
        s += step[3]
        if np.linalg.norm(step) < 1e-12:
            break
    return R, s
