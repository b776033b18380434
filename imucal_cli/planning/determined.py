"""Which parameters, or combinations of them, a design determines (issue 27 point 3, the
estimation's first half): the null space of its Fisher information.

A log recorded for another reason (a vehicle's few still periods on flat ground, a robot
pitching about one axis) cannot fix the whole model, yet it determines part of it: every still
period the gyro's bias, the poses part of the accelerometer.  For a design and a fit
(:mod:`.design_information`), :func:`determination` splits the model's parameters into

- **determined**: the parameter's own direction carries information (it is orthogonal to every
  direction of no information): it has a finite std, whatever the others are held at;
- **undetermined**: it moves along a direction of no information; among these, the
  **combinations** the design still determines (an estimable function of several of them,
  e.g. ``b_z - 0.1 s_z`` when every pose has the same face up) are listed.

Each parameter is scaled by a typical size (the spread of a consumer part, as the proposals'
prior) before the eigenvalues are judged: a direction is of no information when it would be
known to worse than :data:`UNKNOWN_FACTOR` times that spread.

The accelerometer's parameters are the report's: bias ``b_*`` (raw units), sensitivities
``s_*`` (raw units per m/s^2), the angles between its axes ``a_*`` (degrees) and the frame's
rotation ``r_*`` (degrees: known only from labels); the gyroscope's are the full model's ``b_*``
and ``m_*``, the accelerometer taken as known (a calibration given with ``--accel``, or the
nominal one).

The fits that use it (the determined parameters measured, the others held at nominal values
or at an earlier calibration, each marked measured or assumed in the calibration JSON) are
``calibrate/accel/partial.py`` and ``calibrate/gyro/partial.py``.  A parameter counts as
determined here only when it is free of every null direction (to 1e-6): one tied to them only
weakly shows as a determined combination whose other coefficients are small (``1 b_x``, the
others under 0.1, in the bench's table).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal_cli.estimators.accel.labelled_model import public_from_theta

from .information import Fit, Noise, Pose, Turn, accel_information, gyro_information

__all__ = [
    "ACCEL_NAMES",
    "GYRO_NAMES",
    "Determination",
    "accel_determination",
    "determination",
    "gyro_determination",
]

UNKNOWN_FACTOR = 1e3
"""A direction known to worse than this many times a part's spread is not determined."""

ACCEL_NAMES = ("b_x", "b_y", "b_z", "s_x", "s_y", "s_z", "a_xy", "a_xz", "a_yz", "r_x", "r_y",
               "r_z")  # fmt: skip
GYRO_NAMES = ("b_x", "b_y", "b_z", *(f"m_{r}{c}" for r in "xyz" for c in "xyz"))


@dataclass(frozen=True)
class Determination:
    """What a design determines of a model.

    Attributes
    ----------
    names : tuple of str
        The parameters, in order.
    determined, undetermined : tuple of str
        Parameters with a finite std, and the others.
    std : dict
        Each determined parameter's std (its unit: the parameter's).
    combinations : tuple of dict
        Determined combinations of the undetermined parameters: ``{name: coefficient}``, the
        largest coefficient 1 (in the parameters' scaled units, see the module notes).
    """

    names: tuple[str, ...]
    determined: tuple[str, ...]
    undetermined: tuple[str, ...]
    std: dict[str, float]
    combinations: tuple[dict[str, float], ...]

    @property
    def complete(self) -> bool:
        return not self.undetermined


def determination(info: np.ndarray, names: tuple[str, ...], scale: np.ndarray
                  ) -> Determination:  # fmt: skip
    """Split the parameters of an information matrix (p x p, in the parameters' units) by what
    it determines; ``scale`` (p,) a typical size of each (a part's spread)."""
    scale = np.asarray(scale, float)
    E = scale[:, None] * info * scale  # information in units of the spread
    w, V = np.linalg.eigh((E + E.T) / 2)
    null = V[:, w < UNKNOWN_FACTOR**-2]
    touched = np.linalg.norm(null, axis=1) > 1e-6 if null.size else np.zeros(len(names), bool)
    cov = np.linalg.pinv(E, rcond=1e-12, hermitian=True)
    determined = tuple(n for n, t in zip(names, touched, strict=True) if not t)
    undetermined = tuple(n for n, t in zip(names, touched, strict=True) if t)
    std = {n: float(np.sqrt(max(cov[i, i], 0.0)) * scale[i])
           for i, n in enumerate(names) if not touched[i]}  # fmt: skip
    combos = []
    idx = np.flatnonzero(touched)
    if idx.size:
        # c (supported on the undetermined) with c . N = 0: the left null space of N_U, in
        # reduced row echelon form (each combination led by a parameter of its own)
        U, sv, _ = np.linalg.svd(null[idx], full_matrices=True)
        rank = int(np.sum(sv > 1e-9))
        for c in _echelon(U[:, rank:].T):
            combos.append({names[idx[k]]: round(float(v), 4) for k, v in enumerate(c)
                           if abs(v) > 1e-3})  # fmt: skip
    return Determination(tuple(names), determined, undetermined, std, tuple(combos))


def _echelon(rows: np.ndarray) -> np.ndarray:
    """Reduced row echelon form of a few rows by Gauss-Jordan with full pivoting (the
    largest coefficient left leads the next row): the same span, each row led by a
    coefficient 1 of its own and no other coefficient above 1 in size, rows in the order of
    their leading parameter."""
    A = np.array(rows, float)
    free = np.ones(A.shape[1], bool)
    pivots = []
    for r in range(len(A)):
        sub = np.abs(A[r:, :]) * free
        i, col = np.unravel_index(np.argmax(sub), sub.shape)
        if sub[i, col] < 1e-9:
            return A[:r][np.argsort(pivots)]
        A[[r, r + i]] = A[[r + i, r]]
        A[r] /= A[r, col]
        others = np.arange(len(A)) != r
        A[others] -= np.outer(A[others, col], A[r])
        free[col] = False
        pivots.append(col)
    return A[np.argsort(pivots)]


def accel_determination(fit: Fit, poses: list[Pose], noise: Noise) -> Determination:
    """What still poses determine of the accelerometer (its report's parameters)."""
    theta = fit.theta()
    T = fit.public_jacobian()  # d public / d theta, invertible at a fit
    Ti = np.linalg.inv(T)
    info = Ti.T @ accel_information(fit, poses, noise) @ Ti
    public = public_from_theta(theta)
    gains = np.abs(public[3:6])
    scale = np.r_[0.05 * fit.gravity * gains, 0.03 * gains, np.ones(3), 2.0 * np.ones(3)]
    return determination(info, ACCEL_NAMES, scale)


def gyro_determination(fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise
                       ) -> Determination:  # fmt: skip
    """What still periods and turns determine of the gyroscope's full model, the
    accelerometer known (its uncertainty not counted)."""
    info, _ = gyro_information(fit, poses, turns, noise)
    M = np.asarray(fit.gyro_matrix, float)
    size = float(np.mean(np.abs(np.diag(M))))
    scale = np.r_[np.full(3, np.radians(3.0) / size),
                  np.where(np.eye(3).ravel() > 0, 0.03 * size, np.radians(1.0) * size)]
    return determination(info, GYRO_NAMES, scale)
