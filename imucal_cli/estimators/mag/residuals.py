"""The magnetometer model's residuals (:mod:`.magnetometer`, eqs. (2) and (3)), their
Jacobians and their noise, in normalised coordinates: :class:`Problem` (the whitened residuals
the fit minimises), the standard deviation and the mean the noise gives each eq.-(2) residual
(:func:`residual_sigmas`: a fit's), the covariance of a pose's pair of residuals, the weights;
the symmetric soft-iron parameterisation (:data:`SYM_INDEX`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import least_squares

if TYPE_CHECKING:
    from imucal_cli.estimators.mag.magnetometer import MagData, MagResult

#: Symmetric soft iron: (row, column) of the 6 free entries, in parameter order.
SYM_INDEX = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


# --------------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------------


def sym(w: np.ndarray) -> np.ndarray:
    W = np.empty((3, 3))
    for value, (i, j) in zip(w, SYM_INDEX, strict=True):
        W[i, j] = W[j, i] = value
    return W


def sym_params(W: np.ndarray) -> np.ndarray:
    return np.array([W[i, j] for i, j in SYM_INDEX])


def conditioning(J: np.ndarray) -> float:
    """Smallest over largest singular value of ``J`` with unit columns (cheap for tall J)."""
    norms = np.linalg.norm(J, axis=0)
    Jn = J / np.where(norms > 0, norms, 1.0)
    lam = np.linalg.eigvalsh(Jn.T @ Jn)
    return float(np.sqrt(max(lam[0], 0.0) / lam[-1])) if lam[-1] > 0 else 0.0


# --------------------------------------------------------------------------------------------
# Residuals of eqs. (2) and (3) and their Jacobians, in normalised coordinates
# --------------------------------------------------------------------------------------------


class Problem:
    """Whitened residuals of eq. (2) over ``points`` and of eqs. (2) and (3) over the poses.

    Coordinates are normalised: raw ``m`` -> ``(m - c0) / rho`` and the field to 1, so that
    every parameter is of order one.  ``aligned`` selects the 9-entry ``W`` plus ``s``;
    otherwise ``W`` is symmetric (6 entries) and there are no poses.  Each pose gives the pair
    (eq. 2, eq. 3); the pairs, stacked ``(eq. 2, eq. 3)`` pose after pose, are whitened by
    ``white`` (2K, 2K): both residuals of a pose come from the same mean reading, and the
    accelerometer calibration's error moves every pose's eq. (3) together (:func:`pose_cov`).
    """

    def __init__(self, points, w_mag, poses=None, up=None, white=None, shift=None,
                 pose_shift=None, covs=None, shared=None):  # fmt: skip
        self.points, self.w_mag, self.covs = points, w_mag, covs
        # (2K, m): the poses' whitened residuals moved by the error the up directions share
        self.shared = shared
        self.aligned = poses is not None
        self.poses, self.up, self.white = poses, up, white
        self.n_w = 9 if self.aligned else 6
        # the mean the noise adds to each eq.-(2) residual (second order), held fixed
        self.shift = np.zeros(len(points)) if shift is None else shift
        self.pose_shift = (np.zeros(0 if poses is None else len(poses)) if pose_shift is None
                           else pose_shift)  # fmt: skip

    def unpack(self, x):
        b = x[:3]
        if self.aligned:
            return b, x[3:12].reshape(3, 3), float(x[12])
        return b, sym(x[3:9]), None

    def pack(self, b, W, s=None):
        if self.aligned:
            return np.concatenate([b, W.ravel(), [s]])
        return np.concatenate([b, sym_params(W)])

    def _dW(self, a, d):
        """d(a . W d)/d(params of W) for rows a (n, 3), d (n, 3): ``a_i d_j`` per entry."""
        full = a[:, :, None] * d[:, None, :]  # (n, 3, 3)
        if self.aligned:
            return full.reshape(len(a), 9)
        cols = [
            full[:, i, j] if i == j else full[:, i, j] + full[:, j, i] for i, j in SYM_INDEX
        ]
        return np.column_stack(cols)

    def _magnitude(self, pts, b, W, n_par):
        d = pts - b
        h = d @ W.T
        r = np.linalg.norm(h, axis=1)
        hu = h / r[:, None]
        J = np.zeros((len(d), n_par))
        J[:, :3] = -(hu @ W)
        J[:, 3 : 3 + self.n_w] = self._dW(hu, d)
        return r - 1.0, J, d, h, r, hu

    def evaluate(self, x):
        b, W, s = self.unpack(x)
        n_par = len(x)
        r, J1, *_ = self._magnitude(self.points, b, W, n_par)
        res = [(r - self.shift) * self.w_mag]
        jac = [J1 * self.w_mag[:, None]]
        if self.aligned and len(self.poses):
            rm, Jm, dk, _, rk, hku = self._magnitude(self.poses, b, W, n_par)
            c = np.sum(self.up * hku, axis=1)
            g = (self.up - c[:, None] * hku) / rk[:, None]  # d(u . h/|h|)/dh
            Jd = np.zeros((len(dk), n_par))
            Jd[:, :3] = -(g @ W)
            Jd[:, 3:12] = self._dW(g, dk)
            Jd[:, 12] = -1.0
            pair = np.stack([rm - self.pose_shift, c - s], axis=1)  # (K, 2)
            Jpair = np.stack([Jm, Jd], axis=1)  # (K, 2, p)
            res.append(self.white @ pair.ravel())
            jac.append(self.white @ Jpair.reshape(-1, n_par))
        return np.concatenate(res), np.concatenate(jac)

    def solve(self, x0, max_nfev):
        cache = {}

        def both(x):
            key = x.tobytes()
            if key not in cache:
                cache.clear()
                cache[key] = self.evaluate(x)
            return cache[key]

        return least_squares(
            lambda x: both(x)[0], x0, jac=lambda x: both(x)[1], method="lm", x_scale="jac",
            xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev,
        )  # fmt: skip


def magnitude_sigma(points, covs, b, W):
    """Standard deviation of each point's eq.-(2) residual, normalised units."""
    h = (points - b) @ W.T
    r = np.linalg.norm(h, axis=1)
    v = (h / r[:, None]) @ W
    return np.sqrt(np.clip(np.einsum("ni,nij,nj->n", v, covs, v), 0, None))


def magnitude_shift(points, covs, b, W) -> np.ndarray:
    """Mean of each point's eq.-(2) residual from its noise alone, to second order:
    ``tr(P W Sigma W^T) / (2 |h|)`` with ``P`` the projection across ``h``."""
    if covs is None:
        return np.zeros(len(points))
    h = (points - b) @ W.T
    r = np.linalg.norm(h, axis=1)
    hu = h / r[:, None]
    C = W[None] @ covs @ W.T[None]  # (n, 3, 3) output covariance
    across = np.trace(C, axis1=1, axis2=2) - np.einsum("ni,nij,nj->n", hu, C, hu)
    return across / (2.0 * r)


def pose_pair_cov(poses, covs, up, up_cov, b, W):
    """Covariance (K, 2, 2) of each pose's residual pair (eq. 2, eq. 3).

    Covariance of the pair: the mean reading's noise through both gradients (correlated), plus
    the accelerometer direction's noise on eq. (3).  ``covs`` None: unit variance, no
    correlation (equal weighting).
    """
    K = len(poses)
    if covs is None:
        return np.broadcast_to(np.eye(2), (K, 2, 2)).copy()
    h = (poses - b) @ W.T
    r = np.linalg.norm(h, axis=1)
    hu = h / r[:, None]
    c = np.sum(up * hu, axis=1)
    g = (up - c[:, None] * hu) / r[:, None]
    G = np.stack([hu @ W, g @ W], axis=1)  # (K, 2, 3) gradients by the raw mean
    C = G @ covs @ np.swapaxes(G, 1, 2)
    if up_cov is not None:
        q = hu - c[:, None] * up  # d(u . h/|h|)/du along the sphere of u
        C[:, 1, 1] += np.einsum("ni,nij,nj->n", q, up_cov, q)
    # floor: a pose whose readings never changed would get an infinite weight
    scale = np.median(np.trace(C, axis1=1, axis2=2)) if K else 1.0
    return C + 1e-6 * max(scale, 1e-300) * np.eye(2)


def shared_dip(poses, up, up_shared, b, W) -> np.ndarray | None:
    """(K, m): how each pose's eq.-(3) residual moves with the error all the up directions
    share (``u_k`` moves by ``up_shared[k] @ z``, ``z`` standard normal; the accelerometer
    calibration's), to first order ``(h^ - c u)^T du``; None without ``up_shared``."""
    if up_shared is None:
        return None
    h = (poses - b) @ W.T
    hu = h / np.linalg.norm(h, axis=1, keepdims=True)
    q = hu - np.sum(up * hu, axis=1, keepdims=True) * up  # d(u . h^)/du along the sphere of u
    return np.einsum("ki,kim->km", q, up_shared)


def shared_rows(shared: np.ndarray | None, K: int) -> np.ndarray | None:
    """(2K, m): :func:`shared_dip`'s rows on the eq.-(3) residuals of the stacked pairs."""
    if shared is None:
        return None
    out = np.zeros((2 * K, shared.shape[1]))
    out[1::2] = shared
    return out


def pose_cov(blocks: np.ndarray, shared: np.ndarray | None) -> np.ndarray:
    """Covariance (2K, 2K) of the poses' residual pairs stacked ``(eq. 2, eq. 3)`` pose after
    pose: each pose's own block (:func:`pose_pair_cov`) plus ``shared shared^T`` on the eq.-(3)
    rows (``shared`` (K, m) from :func:`shared_dip`, or None)."""
    K = len(blocks)
    C = np.zeros((2 * K, 2 * K))
    for k in range(K):
        C[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = blocks[k]
    if shared is not None:
        C[1::2, 1::2] += shared @ shared.T
    return C


def whiten(C: np.ndarray) -> np.ndarray:
    """``L^-1`` with ``C = L L^T`` (one matrix, or a stack of them)."""
    return np.linalg.inv(np.linalg.cholesky(C))


def noise_weights(sig: np.ndarray) -> np.ndarray:
    # A reading whose noise is zero would get an infinite weight: floor each sigma at a
    # thousandth of the median.
    positive = sig[sig > 0]
    floor = 1e-3 * np.median(positive) if len(positive) else 1.0
    return 1.0 / np.maximum(sig, floor)


def residual_sigmas(result: MagResult, data: MagData) -> np.ndarray:
    """Standard deviation the noise alone gives each reading's eq.-(2) residual, output units.

    Shape (N + K,) in the order of :attr:`MagData.points`; NaN without a noise model.
    """
    covs = data.point_covs()
    if covs is None:
        return np.full(len(data.points), np.nan)
    return magnitude_sigma(data.points, covs, result.bias, result.matrix)
