"""Linear (algebraic) ellipsoid fit: the initial guess for unlabelled gravity sessions.

Static accelerometer means ``a_k`` of a calibrated-up-to-affine sensor lie on the ellipsoid
``|M (a - b)| = g``.  Writing the quadric as ``a^T A a + p^T a + c = 0`` makes the fit linear in
the ten coefficients, found as the null vector of the design matrix; ``b`` and an upper
triangular ``M`` follow from the centre and a Cholesky factor of the shape matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class EllipsoidFit:
    """Result of :func:`fit_ellipsoid`.

    Attributes
    ----------
    bias : ndarray, shape (3,)
        Centre of the ellipsoid, raw units.
    M : ndarray, shape (3, 3)
        Upper-triangular matrix with ``|M (a - bias)| = radius`` on the surface
        (raw units -> output units).
    kind : str
        ``"ellipsoid"`` or ``"sphere"`` (the fallback when the points cannot fix an ellipsoid).
    """

    bias: np.ndarray
    M: np.ndarray
    kind: str


def fit_ellipsoid(points: np.ndarray, radius: float) -> EllipsoidFit:
    """Fit ``|M (a - b)| = radius`` to points on (or near) an ellipsoid, algebraically.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Points in raw units, N >= 9 for an ellipsoid (N >= 4 for the sphere fallback).
    radius : float
        The surface's magnitude in output units (gravity, m/s^2).

    Returns
    -------
    EllipsoidFit
        Falls back to a sphere (isotropic M) when the general quadric is not an ellipsoid,
        which happens when the points cover too little of it.
    """
    points = np.asarray(points, dtype=float)
    # Normalise for conditioning: centre on the mean, scale to unit spread.
    centre0 = points.mean(axis=0)
    scale0 = np.sqrt(np.mean(np.sum((points - centre0) ** 2, axis=1)))
    if not np.isfinite(scale0) or scale0 <= 0:
        raise ValueError("points are all identical")
    p = (points - centre0) / scale0

    result = _general_quadric(p) if len(p) >= 9 else None
    kind = "ellipsoid"
    if result is None:
        result = _sphere(p)
        kind = "sphere"
    centre_n, U = result  # |U (p - centre_n)| = 1 in normalised coordinates
    bias = centre0 + scale0 * centre_n
    M = radius * U / scale0
    return EllipsoidFit(bias=bias, M=M, kind=kind)


def _general_quadric(p: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    x, y, z = p.T
    D = np.column_stack(
        [x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, x, y, z, np.ones_like(x)]
    )
    _, _, Vt = np.linalg.svd(D, full_matrices=False)
    v = Vt[-1]
    A = np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])
    lin, c = v[6:9], v[9]
    try:
        centre = -0.5 * np.linalg.solve(A, lin)
    except np.linalg.LinAlgError:
        return None
    k = centre @ A @ centre - c  # (p - centre)^T A (p - centre) = k
    if k == 0:
        return None
    Q = A / k
    try:
        L = np.linalg.cholesky(Q)  # Q = L L^T; positive definite only for an ellipsoid
    except np.linalg.LinAlgError:
        return None
    return centre, L.T  # Q = U^T U with U = L^T upper triangular


def _sphere(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # |p|^2 = 2 c.p + (r^2 - |c|^2): linear in (c, d).
    D = np.column_stack([2 * p, np.ones(len(p))])
    sol, *_ = np.linalg.lstsq(D, np.sum(p * p, axis=1), rcond=None)
    centre, d = sol[:3], sol[3]
    r2 = d + centre @ centre
    r = np.sqrt(r2) if r2 > 0 else 1.0
    return centre, np.eye(3) / r
