"""The rotation of a magnetometer calibration onto the accelerometer frame (eq. 3 of
:mod:`.magnetometer`, ``u_k . W (m_k - b) / |W (m_k - b)| = s``): whether the static poses can
fix it (enough poses with an up direction, not all parallel), the joint fit of eqs. (2) and
(3) from the symmetric magnitude-only solution, and what an aligned fit says of the rotation
and the dip (each pose's dip residual, the inclination, the rotation's uncertainty).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.special import stdtrit

from imucal_cli.estimators.mag.residuals import (
    Problem,
    conditioning,
    magnitude_shift,
    magnitude_sigma,
    noise_weights,
    pose_cov,
    pose_pair_cov,
    shared_dip,
    shared_rows,
    whiten,
)
from imucal_cli.estimators.mag.start import polar, rotation_start

if TYPE_CHECKING:
    from imucal_cli.estimators.mag.magnetometer import MagData

__all__ = [
    "MIN_ALIGN_POSES",
    "MIN_UP_SPREAD_DEG",
    "alignment_figures",
    "can_align",
    "fit_aligned",
    "t_intervals",
]

#: Fewest static poses with an up direction that can fix the rotation and the dip (4 unknowns).
MIN_ALIGN_POSES = 4
#: Up directions all within this angle of each other leave the rotation about them free.
MIN_UP_SPREAD_DEG = 15.0


def _max_angle_deg(u: np.ndarray) -> float:
    """Largest angle between any two unit vectors (rows), degrees."""
    if len(u) < 2:
        return 0.0
    return float(np.degrees(np.arccos(np.clip((u @ u.T).min(), -1.0, 1.0))))


def can_align(data: MagData, notes: list[str]) -> bool:
    """Whether the poses can fix the rotation by eq. (3): at least :data:`MIN_ALIGN_POSES`
    with an up direction, not all parallel; else a note says why not."""
    labelled = data.labelled()
    if labelled.sum() < MIN_ALIGN_POSES:
        notes.append(
            f"not aligned to the accelerometer: {int(labelled.sum())} static poses with an "
            f"accelerometer direction, at least {MIN_ALIGN_POSES} needed"
        )
        return False
    if _max_angle_deg(np.asarray(data.up, float)[labelled]) < MIN_UP_SPREAD_DEG:
        notes.append(
            "not aligned to the accelerometer: the static poses share one gravity direction "
            "(the rotation about it is free); hold the unit with different faces up"
        )
        return False
    return True


def fit_aligned(data: MagData, pts_n, covs_n, rho, b1, W1, max_iterations, notes):
    """The joint fit of eqs. (2) and (3) in normalised coordinates, started from the symmetric
    solution ``(b1, W1)``: ``(problem, solution)``, or None (a note says why not).

    Parameters
    ----------
    data : MagData
        The readings, their noise and the up directions (raw units).
    pts_n : ndarray, shape (N + K, 3)
        :attr:`.MagData.points` normalised, ``(m - c) / rho``.
    covs_n : ndarray, shape (N + K, 3, 3), or None
        Their covariances, normalised (``/ rho^2``); None: equal weights.
    rho : float
        The normalisation's radius, raw units.
    b1, W1 : ndarray, shapes (3,), (3, 3)
        The symmetric magnitude-only solution, normalised.
    max_iterations : int
        Function evaluations of each Levenberg-Marquardt run.
    notes : list of str
        Appended to where the poses cannot align.
    """
    if not can_align(data, notes):
        return None
    labelled = data.labelled()
    n = len(data.samples)
    rest = np.r_[np.ones(n, bool), ~labelled]  # magnitude-only readings
    pose_covs_n = (
        None if covs_n is None or data.pose_cov is None
        else np.asarray(data.pose_cov, float)[labelled] / rho**2
    )  # fmt: skip
    up_cov = None if data.up_cov is None else np.asarray(data.up_cov, float)[labelled]
    up_shared = (None if covs_n is None or data.up_shared is None
                 else np.asarray(data.up_shared, float)[labelled])  # fmt: skip
    fit = _joint_fit(
        pts_n[rest], None if covs_n is None else covs_n[rest], pts_n[n:][labelled],
        pose_covs_n, np.asarray(data.up, float)[labelled], (up_cov, up_shared), b1, W1,
        max_iterations,
    )  # fmt: skip
    if isinstance(fit, str):
        notes.append(fit)
        return None
    return fit


def _joint_fit(pts_n, covs_n, poses_n, pose_covs_n, up, up_errors, b1, W1, max_iter):
    """Joint fit of eqs. (2) and (3): ``(problem, solution)``, or why it could not align.
    ``up_errors``: ``(up_cov, up_shared)`` of the up directions (:class:`.MagData`)."""
    up_cov, up_shared = up_errors

    def problem(b, W):
        w = np.ones(len(pts_n)) if covs_n is None else noise_weights(
            magnitude_sigma(pts_n, covs_n, b, W))
        C = pose_pair_cov(poses_n, pose_covs_n, up, up_cov, b, W)
        shared = shared_dip(poses_n, up, up_shared, b, W)
        white = whiten(pose_cov(C, shared))
        rows = shared_rows(shared, len(C))
        shifts = (magnitude_shift(pts_n, covs_n, b, W),
                  magnitude_shift(poses_n, pose_covs_n, b, W))  # fmt: skip
        return Problem(pts_n, w, poses_n, up, white, *shifts, covs=covs_n,
                       shared=None if rows is None else white @ rows), C  # fmt: skip

    h = (poses_n - b1) @ W1.T
    n_dir = h / np.linalg.norm(h, axis=1, keepdims=True)
    prob, C = problem(b1, W1)
    starts = rotation_start(n_dir, up, 1.0 / np.sqrt(C[:, 1, 1]))
    fits = [_run(problem, prob, b1, W1, starts[0][1:], max_iter, covs_n is not None)]
    if isinstance(fits[0], str):
        return fits[0]
    # rivals only where eq. (3) is weighed with the accelerometer's error: taking the up
    # directions as exact, a wrong rotation can fit its bent directions better
    for start in _rivals(starts) if up_shared is not None else []:
        fit = _run(problem, prob, b1, W1, start[1:], max_iter, covs_n is not None)
        if not isinstance(fit, str):
            fits.append(fit)
    fits.sort(key=lambda f: f[2])
    prob, sol, _ = fits[0]
    _, J = prob.evaluate(sol.x)
    if conditioning(J[:, 3:]) <= 1e-6:
        return (
            "not aligned to the accelerometer: the static poses leave the rotation undetermined; "
            "hold the unit with different faces up"
        )
    return prob, sol, _ambiguity(prob, fits)


#: Another start of the rotation is tried when its cost (eq. 3 alone) is within this factor
#: of the best's, plus :data:`RIVAL_COST_FLOOR`, and it is at least :data:`RIVAL_MIN_DEG` away.
RIVAL_COST_FACTOR = 4.0
RIVAL_COST_FLOOR = 50.0
RIVAL_MIN_DEG = 10.0
#: Two solutions this far apart whose chi2 differ by less than this: the poses cannot tell them
#: apart (a likelihood ratio within 3 sigma).
AMBIGUOUS_CHI2 = 9.0


def _angle_deg(A: np.ndarray, B: np.ndarray) -> float:
    """Angle of the rotation between the rotation parts of ``A`` and ``B``, degrees."""
    Ra, Rb = polar(A)[0], polar(B)[0]
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(Ra @ Rb.T).as_rotvec())))


def _rivals(starts: list[tuple]) -> list[tuple]:
    """The starts beside the best whose eq.-(3) cost is near it and whose rotation is not."""
    limit = RIVAL_COST_FACTOR * starts[0][0] + RIVAL_COST_FLOOR
    out: list[tuple] = []
    for start in starts[1:]:
        if start[0] <= limit and all(_angle_deg(start[1], k[1]) > RIVAL_MIN_DEG
                                     for k in [starts[0], *out]):  # fmt: skip
            out.append(start)
    return out


def _run(problem, prob, b1, W1, start, max_iter: int, weighted: bool):
    """The joint fit from the rotation ``start = (R, s)``: ``(problem, solution, chi2)``, or
    why it did not converge (a second pass with the weights at the solution)."""
    R0, s0 = start
    sol = prob.solve(prob.pack(b1, R0 @ W1, s0), max_iter)
    if sol.status <= 0:
        return (
            f"not aligned to the accelerometer: the joint fit with the static poses did not "
            f"converge in {max_iter} iterations ({sol.message})"
        )
    if weighted:
        b, W, _ = prob.unpack(sol.x)
        prob, _ = problem(b, W)
        sol2 = prob.solve(sol.x, max_iter)
        sol = sol2 if sol2.status > 0 else sol
    r, _ = prob.evaluate(sol.x)
    return prob, sol, float(r @ r)


def _ambiguity(prob, fits: list[tuple]) -> str | None:
    """Words for a second solution as good as the first (``fits`` by chi2), else None."""
    _, W0, s0 = prob.unpack(fits[0][1].x)
    for other, sol, chi2 in fits[1:]:
        _, W, s = other.unpack(sol.x)
        angle = _angle_deg(W, W0)
        if angle > RIVAL_MIN_DEG and chi2 - fits[0][2] < AMBIGUOUS_CHI2:
            inc0, inc = (float(np.degrees(np.arcsin(np.clip(-v, -1, 1)))) for v in (s0, s))
            return (
                f"the static poses leave the rotation onto the accelerometer ambiguous: "
                f"another rotation {angle:.0f} deg away fits as well (chi2 {chi2:.1f} against "
                f"{fits[0][2]:.1f}; inclination {inc:.1f} deg against {inc0:.1f}), and the "
                "stated std hold only near the one given. Hold the unit in more poses (the 12 "
                "edges of plan qureshi18), or check the inclination against the local field's "
                "(a geomagnetic model such as the WMM)"
            )
    return None


def alignment_figures(data: MagData, bias, matrix, s: float, cov: np.ndarray):
    """What an aligned fit says of the rotation and the dip, in raw and output units.

    Parameters
    ----------
    data : MagData
    bias : ndarray, shape (3,)
        ``b``, raw units.
    matrix : ndarray, shape (3, 3)
        ``W``, output units per raw unit.
    s : float
        ``-sin I``, eq. (3).
    cov : ndarray, shape (13, 13)
        Covariance of ``(b, vec W, s)``.

    Returns
    -------
    dip : ndarray, shape (K,)
        Angle of each pose's field to gravity minus the fitted one, degrees (NaN unlabelled).
    inc, inc_std : float
        Inclination ``I`` and its std, degrees.
    R : ndarray, shape (3, 3)
        Rotation of the polar decomposition ``W = R P``.
    rot_std : float
        RMS one-sigma of ``R``'s small-angle components, degrees.
    """
    dip = np.full(len(data.pose_mean), np.nan)
    labelled = data.labelled()
    h = (data.pose_mean[labelled] - bias) @ matrix.T
    up = np.asarray(data.up, float)[labelled]
    ang = np.degrees(np.arccos(np.clip(np.sum(up * h, axis=1) / np.linalg.norm(h, axis=1),
                                       -1, 1)))  # fmt: skip
    dip[labelled] = ang - np.degrees(np.arccos(np.clip(s, -1, 1)))
    inc = float(np.degrees(np.arcsin(np.clip(-s, -1, 1))))
    inc_std = float(np.degrees(np.sqrt(cov[-1, -1]) / max(np.sqrt(1 - s * s), 1e-9)))
    R, _ = polar(matrix)
    rot_std = _rotation_std_deg(matrix, cov[3:12, 3:12])
    return dip, inc, inc_std, R, rot_std


def _rotation_std_deg(W: np.ndarray, cov_W: np.ndarray) -> float:
    """RMS one-sigma of the small-angle rotation of ``R`` in ``W = R P`` (delta method)."""
    R0, _ = polar(W)
    J = np.empty((3, 9))
    eps = 1e-7 * max(np.abs(W).max(), 1e-300)
    for k in range(9):
        dW = np.zeros(9)
        dW[k] = eps
        Rp, _ = polar(W + dW.reshape(3, 3))
        Rm, _ = polar(W - dW.reshape(3, 3))
        J[:, k] = (Rotation.from_matrix(Rp @ R0.T).as_rotvec()
                   - Rotation.from_matrix(Rm @ R0.T).as_rotvec()) / (2 * eps)  # fmt: skip
    cov_phi = J @ cov_W @ J.T
    return float(np.degrees(np.sqrt(max(np.trace(cov_phi), 0.0) / 3)))


def t_intervals(cov: np.ndarray, cov_shared: np.ndarray | None, shared_dof: float,
                noise_dof: float) -> np.ndarray:  # fmt: skip
    """Half-widths of the 95 % intervals of the parameters: Student t on the degrees of
    freedom of each one's variance (Satterthwaite), its part from the up directions' shared
    error resting on ``shared_dof`` (an accelerometer placement estimated from six faces: 6),
    the rest on ``noise_dof``; 1.96 std where both are many."""
    v = np.clip(np.diag(cov), 0, None)
    v_a = np.zeros_like(v) if cov_shared is None else np.clip(np.diag(cov_shared), 0, v)
    v_n = v - v_a
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = v**2 / (v_a**2 / shared_dof + v_n**2 / max(noise_dof, 1))
    dof = np.where(np.isfinite(dof), np.maximum(dof, 1.0), 1e6)
    return stdtrit(np.minimum(dof, 1e6), 0.975) * np.sqrt(v)
