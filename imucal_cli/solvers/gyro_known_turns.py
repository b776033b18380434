"""The turns between still periods in a known-angle fit (issue 24.5): their noise with the
accelerometer calibration's part, their whitening, and each turn's statistics
(:mod:`imucal_cli.solvers.gyro_known`).

The still periods' gravity directions come from the calibrated accelerometer, whose error
moves them all together: a turn's residual then carries it too, correlated over every turn
whose still periods it measures. :func:`accel_factor` is that part to first order, from the
accelerometer calibration's covariance as the pipeline gives it (``accel_dirs``: the still
periods' gravity vectors moved along each square-root direction of it).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular

from imucal_cli.solvers.gyro_full import _diagonal_blocks
from imucal_cli.solvers.gyro_model import Problem


class _DenseWhitener:
    """``L^-1 a`` for a dense covariance ``L L^T`` (the accelerometer calibration's part
    couples every turn whose still periods it measures)."""

    def __init__(self, cov: np.ndarray):
        n = len(cov)
        cov = cov + 1e-12 * np.trace(cov) / max(n, 1) * np.eye(n)
        self.L = np.linalg.cholesky(cov)

    def __call__(self, a: np.ndarray) -> np.ndarray:
        return solve_triangular(self.L, a, lower=True)


def accel_factor(gp: Problem, x: np.ndarray, accel_dirs: np.ndarray) -> np.ndarray:
    """(K, 2, m): each turn's residual change as the still periods' gravity vectors move by
    ``accel_dirs[:, :, j]`` (to first order: ``du = (I - u u^T) dg / |g|``, ``dp = R^T
    du_before``, ``dr = B_after^T (dp - du_after)``)."""
    g = gp.still.g
    norm = np.linalg.norm(g, axis=1)
    u = g / norm[:, None]
    proj = (np.eye(3)[None] - np.einsum("pi,pj->pij", u, u)) / norm[:, None, None]
    du = np.einsum("pij,pjm->pim", proj, accel_dirs)  # (P, 3, m)
    _, R = gp.predicted(x)
    i0, i1 = gp.rot.before, gp.rot.after
    dp = np.einsum("kji,kjm->kim", R, du[i0])  # R^T du_before
    return np.einsum("kia,kim->kam", gp.B[i1], dp - du[i1])


def accel_blocks(gp: Problem, x: np.ndarray, accel_dirs: np.ndarray | None) -> np.ndarray:
    """(K, 2, 2): each turn's residual covariance from the accelerometer calibration's error,
    which moves the measured gravity before and after it: ``F_k F_k^T`` with column j of
    ``F_k`` the residual's change as the still periods' gravity vectors move by
    ``accel_dirs[:, :, j]`` (to first order: ``du = (I - u u^T) dg / |g|``, ``dp = R^T
    du_before``, ``dr = B_after^T (dp - du_after)``). Zero without ``accel_dirs``."""
    if accel_dirs is None:
        return np.zeros((gp.K, 2, 2))
    F = accel_factor(gp, x, accel_dirs)
    return np.einsum("kam,kbm->kab", F, F)


def gravity_statistics(gp: Problem, x: np.ndarray, tau: float = 0.0,
                       accel_dirs: np.ndarray | None = None) -> dict:  # fmt: skip
    """Per gravity-referenced turn at ``x``: its residual angle and rotation angle (deg), its
    chi^2 (2 dof) in its noise with the excess ``tau`` (rad) and in the noise the model
    predicts (``gravity_chi2_stated``: the still periods' and the gyro's noise, and the
    accelerometer calibration's part, :func:`accel_blocks`), and its noise with the excess
    (deg, the root of the trace of its 2 x 2 covariance)."""
    K = gp.K
    p, R = gp.predicted(x)
    u1 = gp.u[gp.rot.after]
    resid = np.degrees(np.arccos(np.clip(np.sum(p * u1, axis=1), -1, 1)))
    angles = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    stated = _diagonal_blocks(gp.rotation_covariance(x), K) + accel_blocks(gp, x, accel_dirs)
    full = stated + tau**2 * np.eye(2)
    r = gp.raw_residuals(x)[: 2 * K].reshape(K, 2)

    def chi2(blocks):
        return np.einsum("ki,ki->k", r, np.linalg.solve(blocks, r[:, :, None])[:, :, 0])

    return {"gravity_chi2": chi2(full), "gravity_chi2_stated": chi2(stated),
            "gravity_residual_deg": resid, "gravity_angle_deg": angles,
            "gravity_sigma_deg": np.degrees(np.sqrt(np.trace(full, axis1=1, axis2=2)))}
