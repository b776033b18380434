"""The accelerometer calibration's error without the rotation of its frame.

An accelerometer calibration ``calibrated = A (raw - b)`` reports in a frame it estimates: the
labels' (the labelled-pose fit, up to a rotation the placements leave free, its ``frame``
std) or its own axes (Qureshi eq. 3's upper-triangular ``A``). An error ``dA`` of the matrix
turns that frame by the rotation in the antisymmetric part of ``dA A^-1`` (the rotation
vector ``phi``, ``dA = [phi]_x A`` for a pure turn), and bends the axes by the rest.

A gyroscope (or any sensor) calibrated against that accelerometer's gravity directions
reports in the same frame: a turn of it moves both calibrations together, and a rate
calibrated with them is off it by nothing. So the part of the accelerometer's error that the
gyro's own std carry is the bending only; the frame's rotation is stated once, in the
accelerometer's section (it is what the benches compare against: each truth turned into the
calibrated accelerometer's frame).
"""

from __future__ import annotations

import numpy as np


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def frame_split(A: np.ndarray, n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """The linear maps that split an error ``(db, dA row-major, ...)`` into the frame's turn
    and the rest.

    Parameters
    ----------
    A : ndarray, shape (3, 3)
        The calibration matrix.
    n : int
        Length of the error vector (>= 12: bias, matrix, then any further terms).

    Returns
    -------
    L : ndarray, shape (n, n)
        Removes the turn ``[phi]_x A`` from an error (the bending that remains).
    phi : ndarray, shape (3, n)
        The frame's rotation vector of an error (rad): the antisymmetric part of
        ``dA A^-1``; zero in the bias and further terms.
    """
    A = np.asarray(A, float)
    A_inv = np.linalg.inv(A)
    turn = np.zeros((12, 3))  # d(b, A) of a turn of the frame by phi
    for i in range(3):
        turn[3:, i] = (_skew(np.eye(3)[i]) @ A).ravel()
    phi = np.zeros((3, n))  # phi of an error d(b, A)
    for j in range(9):
        E = np.eye(9)[j].reshape(3, 3) @ A_inv
        S = (E - E.T) / 2
        phi[:, 3 + j] = (S[2, 1], S[0, 2], S[1, 0])
    L = np.eye(n)
    L[:12, :] -= turn @ phi[:, :]
    return L, phi


def frame_free(C: np.ndarray, A: np.ndarray) -> np.ndarray:
    """The covariance of ``(b, A row-major, ...)`` with the rotation of the frame taken out.

    Parameters
    ----------
    C : ndarray, shape (n, n), n >= 12
        Covariance of the bias (raw units), the matrix (row-major; calibrated units per raw
        unit) and any further terms (left as they are).
    A : ndarray, shape (3, 3)
        The calibration matrix.

    Returns
    -------
    ndarray, shape (n, n)
        ``L C L^T`` with ``L`` removing from each error ``(db, dA)`` the turn ``[phi]_x A``,
        ``phi`` the rotation vector of the antisymmetric part of ``dA A^-1`` (rad)
        (:func:`frame_split`).
    """
    C = np.asarray(C, float)
    L, _ = frame_split(A, len(C))
    return L @ C @ L.T
