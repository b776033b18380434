"""What the magnetometer fit sees of a session's static poses (:func:`pose_data`): each
pose's mean reading and its noise, and the up direction its alignment uses (eq. 3 of
:mod:`imucal_cli.estimators.mag.magnetometer`) from the accelerometer calibrated in the same
run, with the covariance the pose's own noise gives it and the error all the poses share, the
accelerometer calibration's.

That shared error does not average out over the poses.  Where the accelerometer is known only
from six faces (the labelled solver, each face's placement a nuisance: its axes' angles to
about a degree) it bends the up directions by far more than their noise, and an alignment that
took them as exact pulled the hard iron by several of its stated standard deviations.  It is
carried as a factor (:attr:`.MagData.up_shared`) that the joint fit weighs eq. (3) with.

The part of it that rotates every up direction together is left out: the magnetometer is
calibrated into *the accelerometer's calibrated frame*, and a rotation of that frame (stated in
the accelerometer's own section) turns the magnetometer's output with it, fitting just as well.
What is kept is the part that bends the directions against each other: the accelerometer's
scale factors, axis angles and bias.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.estimators.mag.magnetometer import MagData
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import SensorCalibration

__all__ = ["accel_factor", "changed_rows", "factor_dof", "pose_data", "up_direction"]

#: The accelerometer calibration's ``(bias, matrix row-major)``: the terms its covariance has.
N_ACCEL_TERMS = 12


def changed_rows(rows: np.ndarray, mag: np.ndarray) -> np.ndarray:
    """Of the session rows ``rows`` (in order), those that differ from the previous one."""
    if len(rows) == 0:
        return rows
    block = mag[rows]
    keep = np.r_[True, np.any(block[1:] != block[:-1], axis=1)]
    return rows[keep]


def pose_data(session: Session, mag: np.ndarray, rows_used: tuple, held: bool,
               accel: SensorCalibration | None, factor: np.ndarray | None):
    """What the solver sees: the ``motion`` rows, and each static segment's mean over its
    ``usable`` rows (``rows_used = (motion, usable)``; ``held``: repeats of a held reading left
    out), with the noise pooled over the segments, the accelerometer's up direction and the
    error all of them share (its calibration's, ``factor`` of :func:`accel_factor`).

    Returns
    -------
    data : MagData
        ``sample_cov`` (raw units^2) pooled where the segments give at least 10 degrees of
        freedom, else None (and no ``pose_cov``); ``up`` only with ``accel``.
    segments : list of Segment
        The static segments with at least 3 usable rows, in order.
    counts : ndarray of int, shape (K,)
        Rows averaged in each.
    """
    motion, usable = rows_used
    segments, means, covs, counts, ups, up_covs, up_jacs = [], [], [], [], [], [], []
    pooled, pooled_dof = np.zeros((3, 3)), 0
    for seg in session.static_segments():
        rows = np.flatnonzero(usable[seg.start : seg.stop]) + seg.start
        rows = changed_rows(rows, mag) if held else rows
        if len(rows) < 3:
            continue
        block = mag[rows]
        cov = np.cov(block, rowvar=False)
        pooled += cov * (len(rows) - 1)
        pooled_dof += len(rows) - 1
        segments.append(seg)
        means.append(block.mean(axis=0))
        covs.append(cov / len(rows))
        counts.append(len(rows))
        up, up_cov, up_jac = up_direction(session, seg, accel)
        ups.append(up)
        up_covs.append(up_cov)
        up_jacs.append(up_jac)
    sample_cov = pooled / pooled_dof if pooled_dof >= 10 else None
    K = len(segments)
    data = MagData(
        samples=mag[motion],
        pose_mean=np.array(means).reshape(K, 3),
        sample_cov=sample_cov,
        pose_cov=np.array(covs).reshape(K, 3, 3) if sample_cov is not None else None,
        up=np.array(ups).reshape(K, 3) if accel is not None else None,
        up_cov=np.array(up_covs).reshape(K, 3, 3) if accel is not None else None,
        up_shared=None if factor is None else np.array(up_jacs).reshape(K, 3, -1) @ factor,
        up_shared_dof=factor_dof(accel),
    )
    return data, segments, np.array(counts, int)


def up_direction(session: Session, seg, accel: SensorCalibration | None):
    """Calibrated up direction of a static segment, its covariance from the segment's noise
    (rad^2) and its Jacobian by the accelerometer's ``(bias, matrix row-major)`` (3, 12); NaN
    without an accelerometer or fewer than 2 finite rows."""
    nan = (np.full(3, np.nan), np.full((3, 3), np.nan), np.full((3, N_ACCEL_TERMS), np.nan))
    if accel is None or session.accel is None:
        return nan
    block = session.accel[seg.start : seg.stop]
    block = block[np.isfinite(block).all(axis=1)]
    if len(block) < 2:
        return nan
    M, d = np.asarray(accel.matrix, float), block.mean(axis=0) - np.asarray(accel.bias, float)
    h = M @ d
    norm = np.linalg.norm(h)
    u = h / norm
    across = (np.eye(3) - np.outer(u, u)) / norm  # du = across dh
    J = across @ M
    dh = np.zeros((3, N_ACCEL_TERMS))  # dh by (bias, matrix): -M, then d in row i's entries
    dh[:, :3] = -M
    for i in range(3):
        dh[i, 3 + 3 * i : 6 + 3 * i] = d
    return u, J @ (np.cov(block, rowvar=False) / len(block)) @ J.T, across @ dh


def _without_rotation(M: np.ndarray) -> np.ndarray:
    """(12, 12): the accelerometer's ``(bias, matrix)`` error less its rotation part, to first
    order: ``dM -> sym(dM M^-1) M`` (the antisymmetric part of ``dM M^-1`` turns the frame)."""
    T = np.eye(N_ACCEL_TERMS)
    Minv = np.linalg.inv(M)
    for j in range(9):
        dM = np.zeros(9)
        dM[j] = 1.0
        X = dM.reshape(3, 3) @ Minv
        T[3:, 3 + j] = (0.5 * (X + X.T) @ M).ravel()
    return T


def accel_factor(accel: SensorCalibration | None, notes: list[str]) -> np.ndarray | None:
    """(12, m): a square root of the accelerometer calibration's covariance, its rotation
    part left out (module docstring): its error is ``F @ z``, ``z`` standard normal; None
    (a note says why) when the section states no covariance of its 12 terms."""
    if accel is None:
        return None
    cov = None if accel.covariance is None else accel.covariance.values
    M = np.asarray(accel.matrix, float)
    if cov is None or np.shape(cov) != (N_ACCEL_TERMS, N_ACCEL_TERMS) or M.shape != (3, 3):
        notes.append("the accelerometer calibration states no covariance: the alignment takes "
                     "its up directions as exact, and the magnetometer's std leave out its "
                     "uncertainty")  # fmt: skip
        return None
    T = _without_rotation(M)
    C = np.asarray(cov, float)
    C = T @ (0.5 * (C + C.T)) @ T.T
    scale = np.sqrt(np.clip(np.diag(C), 0, None))  # bias in raw units, matrix entries ~1e-3
    scale[scale == 0] = 1.0
    lam, V = np.linalg.eigh(C / np.outer(scale, scale))
    keep = lam > 1e-12 * max(lam[-1], 1e-300)
    return scale[:, None] * V[:, keep] * np.sqrt(lam[keep])


def factor_dof(accel: SensorCalibration | None) -> float:
    """Degrees of freedom of the accelerometer covariance's variance: a labelled fit's
    placement estimated from the poses rests on its redundancy (six faces: 6), as its own t
    intervals do; inf otherwise (the noise, many samples)."""
    placement = getattr(accel, "placement", None)
    if placement is None or placement.source != "estimated" or placement.dof is None:
        return np.inf
    return max(float(placement.dof), 1.0)
