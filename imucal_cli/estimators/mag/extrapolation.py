"""How well a magnetometer fit holds the field magnitude in directions it did not see.

MotionCal's *gaps* figure (:mod:`imucal_cli.design.sphere_quality`) asks for readings over
85 % of the sphere, because a sphere fitted to part of it may be wrong in the rest. A fit that
states its covariance says how wrong: the calibrated magnitude ``|W (m - b)|`` a field ``F d``
along a unit direction ``d`` (output frame) would read varies, to first order, by

    d|c| = d^T (dW x - W db),    x = m - b = W^-1 F d

(eq. (2) of :mod:`.magnetometer` linearised at the fit), so its variance is ``j^T C j`` with
``j`` that row of the Jacobian and ``C`` the covariance of ``b`` and ``W``. The inclination
``s`` does not enter; a rotation of ``W`` moves no magnitude.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from imucal_cli.estimators.mag.residuals import SYM_INDEX

if TYPE_CHECKING:
    from imucal_cli.estimators.mag.magnetometer import MagResult

__all__ = ["magnitude_std"]


def magnitude_std(res: MagResult, directions: np.ndarray) -> np.ndarray:
    """Standard deviation of the calibrated field magnitude along each direction, from the
    fit's covariance.

    Parameters
    ----------
    res : MagResult
        The fit (its ``bias``, ``matrix``, ``field``, ``aligned`` and ``cov``; ``cov`` is
        already scaled by the fit's noise scale).
    directions : ndarray, shape (K, 3)
        Directions of the field in the output frame; need not be unit length.

    Returns
    -------
    ndarray, shape (K,)
        One standard deviation of ``|c|``, in output units (uT, or 1 for the local field).
    """
    d = np.asarray(directions, float).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    W = np.asarray(res.matrix, float)
    x = res.field * np.linalg.solve(W, d.T).T  # (K, 3): m - b, raw units
    j_b = -d @ W  # d|c|/db
    if res.aligned:  # the 9 entries of W, row-major
        j_w = (d[:, :, None] * x[:, None, :]).reshape(len(d), 9)
    else:  # the 6 entries of a symmetric W (SYM_INDEX)
        j_w = np.stack([d[:, i] * x[:, j] + (d[:, j] * x[:, i] if i != j else 0.0)
                        for i, j in SYM_INDEX], axis=1)  # fmt: skip
    J = np.hstack([j_b, j_w])
    C = np.asarray(res.cov, float)[: J.shape[1], : J.shape[1]]
    return np.sqrt(np.clip(np.einsum("ki,ij,kj->k", J, C, J), 0, None))
