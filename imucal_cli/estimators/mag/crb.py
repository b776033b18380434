"""Cramér-Rao bound of a magnetometer calibration design (:mod:`.magnetometer`).

Each reading is ``m = W^-1 h + b + e``, ``e ~ N(0, Sigma)``, with ``h`` the field in the
output frame (eq. 1 of :mod:`.magnetometer`).  Unknown besides the parameters ``theta``:

- a motion sample: the direction of ``h`` (two angles);
- a static pose ``k``: the attitude (three small angles ``phi``), which moves both ``h_k`` and
  the up direction ``u_k``; the pose also observes ``u_k`` through the accelerometer (two
  tangent components, covariance ``C_k``), and ``h_k = F (s u_k + sqrt(1 - s^2) w_k)`` with
  ``w_k`` the horizontal field direction (eq. 3).

Each reading's nuisance angles are its own, so they are eliminated reading by reading (Schur
complement): reading ``i`` adds ``J_t^T (L - L J_n (J_n^T L J_n)^-1 J_n^T L) J_t`` to the
information of ``theta``, with ``L`` its inverse noise covariance and ``J_t``, ``J_n`` the
derivatives of its mean by ``theta`` and by its nuisance angles.  The bound is the inverse.

Parameters ``theta``: aligned ``(b, vec W (row-major), s)`` (13); not aligned ``(b, the 6
entries of a symmetric W)`` (9), for which poses count as magnitude readings only.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.estimators.mag.residuals import SYM_INDEX

__all__ = ["magnetometer_crb"]


def _tangent(u: np.ndarray) -> np.ndarray:
    helper = np.zeros_like(u)
    np.put_along_axis(helper, np.argmin(np.abs(u), axis=-1)[..., None], 1.0, axis=-1)
    t1 = np.cross(u, helper)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    return np.stack([t1, np.cross(u, t1)], axis=-1)


def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of rows ``v`` (n, 3) -> (n, 3, 3): ``[v]x a = v x a``."""
    z = np.zeros(len(v))
    return np.stack(
        [np.stack([z, -v[:, 2], v[:, 1]], -1), np.stack([v[:, 2], z, -v[:, 0]], -1),
         np.stack([-v[:, 1], v[:, 0], z], -1)], axis=1,
    )  # fmt: skip


def _d_mean_d_W(Winv: np.ndarray, d: np.ndarray, aligned: bool) -> np.ndarray:
    """d m / d (entries of W) for readings with ``m - b = d`` (n, 3) -> (n, 3, 9 or 6).

    ``d(W^-1) = -W^-1 dW W^-1``, so ``d m / d W_ij = -W^-1[:, i] d_j``.
    """
    full = -Winv[None, :, :, None] * d[:, None, None, :]  # (n, 3 rows of m, i, j)
    if aligned:
        return full.reshape(len(d), 3, 9)
    cols = [full[:, :, i, j] if i == j else full[:, :, i, j] + full[:, :, j, i]
            for i, j in SYM_INDEX]  # fmt: skip
    return np.stack(cols, axis=-1)


def _eliminate(Jt: np.ndarray, Jn: np.ndarray, L: np.ndarray) -> np.ndarray:
    """Sum over readings of ``Jt^T (L - L Jn (Jn^T L Jn)^-1 Jn^T L) Jt``."""
    LJt = L @ Jt
    LJn = L @ Jn
    A = np.swapaxes(Jn, 1, 2) @ LJn
    B = np.swapaxes(Jn, 1, 2) @ LJt
    info = np.swapaxes(Jt, 1, 2) @ LJt - np.swapaxes(B, 1, 2) @ np.linalg.solve(A, B)
    return info.sum(axis=0)


def magnetometer_crb(
    W: np.ndarray,
    field: float,
    sample_dirs: np.ndarray,
    sample_cov: np.ndarray,
    *,
    pose_up: np.ndarray | None = None,
    pose_dirs: np.ndarray | None = None,
    pose_cov: np.ndarray | None = None,
    up_cov: np.ndarray | None = None,
    aligned: bool = True,
) -> np.ndarray:
    """Cramér-Rao bound on the magnetometer parameters for one design.

    Parameters
    ----------
    W : ndarray, shape (3, 3)
        True soft-iron matrix (output units per raw unit); symmetric when not ``aligned``.
    field : float
        ``F``, output units.
    sample_dirs : ndarray, shape (N, 3)
        True unit field direction of each motion sample, output frame.
    sample_cov : ndarray, shape (3, 3)
        Noise covariance of one sample, raw units^2.
    pose_up : ndarray, shape (K, 3), optional
        True up direction of each static pose, output frame.
    pose_dirs : ndarray, shape (K, 3), optional
        True unit field direction of each pose (its angle to ``pose_up`` is the same for all).
    pose_cov : ndarray, shape (K, 3, 3), optional
        Covariance of each pose's mean magnetometer reading, raw units^2.
    up_cov : ndarray, shape (K, 3, 3), optional
        Covariance of each pose's measured up direction (rad^2, perpendicular to it); default
        nearly exact (1e-12).
    aligned : bool
        The 13-parameter model with eq. (3) (needs the poses) or the 9-parameter symmetric one.

    Returns
    -------
    ndarray, shape (13, 13) or (9, 9)
        Lower bound on the covariance of ``(b, W, s)`` or ``(b, sym W)``.
    """
    W = np.asarray(W, float)
    Winv = np.linalg.inv(W)
    n_w = 9 if aligned else 6
    p = 3 + n_w + (1 if aligned else 0)
    info = np.zeros((p, p))
    dirs = np.asarray(sample_dirs, float).reshape(-1, 3)
    K = 0 if pose_dirs is None else len(pose_dirs)
    if not aligned and K:
        dirs = np.concatenate([dirs, np.asarray(pose_dirs, float)])
    # ---- magnitude readings: nuisance = direction of h (2 angles)
    if len(dirs):
        n = len(dirs)
        d = (field * dirs) @ Winv.T
        Jt = np.zeros((n, 3, p))
        Jt[:, :, :3] = np.eye(3)
        Jt[:, :, 3 : 3 + n_w] = _d_mean_d_W(Winv, d, aligned)
        Jn = field * (Winv[None] @ _tangent(dirs))
        covs = np.broadcast_to(np.asarray(sample_cov, float), (n, 3, 3)).copy()
        if not aligned and K:
            covs[len(sample_dirs):] = pose_cov
        info += _eliminate(Jt, Jn, np.linalg.inv(covs))
    if aligned and K:
        info += _pose_information(W, Winv, field, pose_up, pose_dirs, pose_cov, up_cov, p)
    return np.linalg.inv(info)


def _pose_information(W, Winv, field, up, dirs, pose_cov, up_cov, p):
    """Information of the static poses: magnetometer mean and accelerometer direction, with
    the attitude (3 angles) eliminated."""
    up = np.asarray(up, float)
    dirs = np.asarray(dirs, float)
    K = len(up)
    s = float(np.mean(np.sum(up * dirs, axis=1)))
    c = np.sqrt(max(1.0 - s * s, 1e-12))
    h = field * dirs
    d = h @ Winv.T
    w = (dirs - s * up) / c  # horizontal unit direction of the field
    Jt = np.zeros((K, 5, p))
    Jt[:, :3, :3] = np.eye(3)
    Jt[:, :3, 3:12] = _d_mean_d_W(Winv, d, True)
    Jt[:, :3, 12] = field * (up - (s / c) * w) @ Winv.T  # dh/ds
    T = _tangent(up)  # (K, 3, 2)
    Jn = np.zeros((K, 5, 3))
    Jn[:, :3, :] = -Winv[None] @ _skew(h)  # d h = phi x h
    Jn[:, 3:, :] = -np.swapaxes(T, 1, 2) @ _skew(up)  # d u = phi x u, tangent components
    L = np.zeros((K, 5, 5))
    L[:, :3, :3] = np.linalg.inv(np.asarray(pose_cov, float))
    if up_cov is None:
        C = np.broadcast_to(1e-12 * np.eye(2), (K, 2, 2))
    else:
        C = np.swapaxes(T, 1, 2) @ np.asarray(up_cov, float) @ T + 1e-15 * np.eye(2)
    L[:, 3:, 3:] = np.linalg.inv(C)
    return _eliminate(Jt, Jn, L)
