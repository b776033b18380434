"""Gyroscope scale and bias per axis from hand rotations (Qureshi & Golnaraghi, III-B).

Model (eq. 15): ``omega = k (omega_s - b)`` per axis. A rotation k about axis i, between two
still periods, turns the unit by ``Delta theta_ik``, which the already calibrated accelerometer
measures from the gravity directions before and after it. With ``x_k = integral of omega_s``
over the rotation (the paper's mean rate times the duration, eq. 16) and ``T_k`` its duration:

    Delta theta_ik = k_i (x_k - b_i T_k)                                             (17)

* static-bias approach: ``b_i`` from still data, then ``k_i`` by least squares over the
  rotations (eq. 18 for one rotation);
* dynamic approach: ``k_i`` and ``k_i b_i`` together from the linear system of eq. (19),
  solved by least squares (eqs. 20-21).

The angle is measured exactly for any orientation: the signed angle, about the rotation axis,
between the projections of the gravity directions before and after onto the plane normal to
the axis (instead of the appendix's tilt formulas, eqs. 22-28, which hold for small
combinations of tilts only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import stdtrit

from imucal_cli.errors import DesignError


def rotation_angle_about_axis(
    g_before: np.ndarray, g_after: np.ndarray, axis: np.ndarray
) -> tuple[float, float]:
    """Signed angle (rad) by which the unit turned about a body ``axis``, from gravity.

    A body turning by ``theta`` about body axis ``a`` sees the gravity direction turn by
    ``-theta`` about ``a``; the angle is read in the plane normal to ``a``.

    Parameters
    ----------
    g_before, g_after : ndarray, shape (3,)
        Calibrated accelerometer means of the still periods before and after (any units).
    axis : ndarray, shape (3,)
        The rotation axis in the body frame.

    Returns
    -------
    angle : float
        Right-handed about ``axis``, in (-pi, pi].
    leverage : float
        ``|p_before| |p_after|`` of the unit gravity directions projected on the plane: the
        sine-squared of the tilt between gravity and the axis. Near 0 (axis near vertical)
        the accelerometer cannot see the turn.
    """
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    u0 = np.asarray(g_before, float) / np.linalg.norm(g_before)
    u1 = np.asarray(g_after, float) / np.linalg.norm(g_after)
    p0, p1 = u0 - (u0 @ a) * a, u1 - (u1 @ a) * a
    angle = -np.arctan2(a @ np.cross(p0, p1), p0 @ p1)
    return float(angle), float(np.linalg.norm(p0) * np.linalg.norm(p1))


@dataclass
class AxisFit:
    """Scale and bias of one gyro axis.

    Attributes
    ----------
    k : float
        Scale, rad per raw unit (eq. 15).
    b : float
        Bias, raw units.
    k_std, b_std : float
        Standard deviations: the least-squares fit's (residual variance) and the
        accelerometer calibration's part (``angle_cov``), which moves every measured angle
        together and does not show in the residuals.
    residuals_rad : ndarray, shape (K,)
        Measured minus predicted angle of each rotation, rad.
    approach : str
        ``"static"`` or ``"dynamic"``.
    k_ci95, b_ci95 : float
        Half-widths of the 95 % intervals: Student t on the residual variance's degrees of
        freedom, carried to the sum by Welch-Satterthwaite (the accelerometer's part known).
    """

    k: float
    b: float
    k_std: float
    b_std: float
    residuals_rad: np.ndarray
    approach: str
    k_ci95: float = float("nan")
    b_ci95: float = float("nan")


def _ci95(noise_var: float, known_var: float, dof: int) -> float:
    """95 % half-width of an error with a variance estimated on ``dof`` degrees of freedom
    plus one known (Welch-Satterthwaite's effective degrees of freedom)."""
    total = noise_var + known_var
    if total <= 0:
        return 0.0
    nu = dof * total**2 / noise_var**2 if noise_var > 0 else np.inf
    q = stdtrit(min(nu, 1e6), 0.975) if np.isfinite(nu) else 1.959964
    return float(q * np.sqrt(total))


def fit_axis_static(
    x: np.ndarray, T: np.ndarray, angle: np.ndarray, b: float, b_std: float = 0.0,
    angle_cov: np.ndarray | None = None,
) -> AxisFit:  # fmt: skip
    """Static-bias approach: scale by least squares over the rotations (eq. 18 generalised).

    Parameters
    ----------
    x : ndarray, shape (K,)
        Integral of the raw axis reading over each rotation (raw units x s).
    T : ndarray, shape (K,)
        Duration of each rotation, s.
    angle : ndarray, shape (K,)
        Measured angle of each rotation (from the accelerometer), rad.
    b, b_std : float
        Bias from still data and its standard deviation, raw units.
    angle_cov : ndarray, shape (K, K), optional
        Covariance of the measured angles from the accelerometer calibration's error, rad^2.
    """
    x, T, angle = map(np.asarray, (x, T, angle))
    if len(x) < 2:
        raise DesignError("the static-bias approach needs at least 2 rotations per axis")
    d = x - b * T  # eq. (17) with b known
    k = float(d @ angle / (d @ d))
    res = angle - k * d
    dof = len(x) - 1
    s2 = float(res @ res) / dof
    noise = s2 / float(d @ d)
    known = (k * b_std) ** 2 * float((T @ d) ** 2) / float(d @ d) ** 2
    if angle_cov is not None:  # dk = d . d(angle) / (d . d)
        known += float(d @ angle_cov @ d) / float(d @ d) ** 2
    return AxisFit(k, b, float(np.sqrt(noise + known)), b_std, res, "static",
                   _ci95(noise, known, dof), 1.959964 * b_std)  # fmt: skip


def fit_axis_dynamic(x: np.ndarray, T: np.ndarray, angle: np.ndarray,
                     angle_cov: np.ndarray | None = None) -> AxisFit:  # fmt: skip
    """Dynamic approach: ``k`` and ``k b`` together by least squares (eqs. 19-21).

    Parameters as for :func:`fit_axis_static`; needs rotations of different durations or
    different angles (else ``k`` and ``b`` are not separable).
    """
    x, T, angle = map(np.asarray, (x, T, angle))
    if len(x) < 3:
        raise DesignError("the dynamic approach needs at least 3 rotations per axis")
    A = np.column_stack([x, -T])  # eq. (19): A [k, k b]^T = Delta theta
    sol, *_ = np.linalg.lstsq(A, angle, rcond=None)  # eqs. (20)-(21)
    k, kb = sol
    res = angle - A @ sol
    dof = len(x) - 2
    s2 = float(res @ res) / dof
    pinv = np.linalg.pinv(A)
    cov_noise = s2 * np.linalg.inv(A.T @ A)
    cov_known = np.zeros((2, 2)) if angle_cov is None else pinv @ angle_cov @ pinv.T
    b = kb / k
    J = np.array([-kb / k**2, 1 / k])  # delta method for b = (k b) / k
    b_noise, b_known = float(J @ cov_noise @ J), float(J @ cov_known @ J)
    return AxisFit(
        float(k), float(b), float(np.sqrt(cov_noise[0, 0] + cov_known[0, 0])),
        float(np.sqrt(b_noise + b_known)), res, "dynamic",
        _ci95(float(cov_noise[0, 0]), float(cov_known[0, 0]), dof),
        _ci95(b_noise, b_known, dof),
    )  # fmt: skip
