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
        Standard deviations: the least-squares fit's (residual variance, on the shape of the
        turns' noise when it is given), the accelerometer calibration's part (``angle_cov``),
        which moves every measured angle together and does not show in the residuals, and the
        misalignment that eq. (15) leaves out of eq. (6) (``model_err``), beyond what the
        residuals already show of it.
    residuals_rad : ndarray, shape (K,)
        Measured minus predicted angle of each rotation, rad.
    approach : str
        ``"static"`` or ``"dynamic"``.
    k_ci95, b_ci95 : float
        Half-widths of the 95 % intervals: Student t on the parts' degrees of freedom, carried
        to the sum by Welch-Satterthwaite (the accelerometer's part known).
    k_misalignment_std : float
        The misalignment's share of ``k_std`` (rad/s per raw unit; 0 without ``model``).
    """

    k: float
    b: float
    k_std: float
    b_std: float
    residuals_rad: np.ndarray
    approach: str
    k_ci95: float = float("nan")
    b_ci95: float = float("nan")
    k_misalignment_std: float = 0.0


@dataclass
class TurnNoise:
    """What each turn's measured angle is noisy with, known from the still periods: the shape
    of the residuals' covariance (its scale is still estimated from the residuals).

    Attributes
    ----------
    x_var : ndarray, shape (K,)
        Variance of each turn's raw integral from the gyro's white noise, (raw units s)^2:
        ``sigma_z^2 dt T`` (it grows with the turn's duration: slow turns are noisier).
    angle_cov : ndarray, shape (K, K)
        Covariance of the angles from the accelerometer's noise in the still means, rad^2 (two
        turns that share a still period are anticorrelated).
    """

    x_var: np.ndarray
    angle_cov: np.ndarray

    def shape(self, k: float) -> np.ndarray:
        """The angles' noise covariance for scale ``k`` (rad per raw unit), rad^2."""
        return np.diag(k**2 * np.asarray(self.x_var, float)) + np.asarray(self.angle_cov, float)


@dataclass
class ModelErrors:
    """The angle errors (rad) that eq. (15) makes where the gyro follows eq. (6), per draw
    of the misalignment left out (:mod:`.axes_misalignment`).

    Attributes
    ----------
    errors : ndarray, shape (1 + C, N, K)
        Each turn's angle minus ``k`` times its integral, noise-free, at N draws of the
        misalignment at its measured RMS (first), then with the variance of each of its C
        components (rotation, non-orthogonality) raised by the fraction ``step``, the same
        draws (rad).
    step : float
        The fractional raise of a component's variance.
    dof : ndarray, shape (C,)
        Degrees of freedom of each component's measured variance.
    """

    errors: np.ndarray
    step: float
    dof: np.ndarray


def _ci95(parts: list[tuple[float, float]]) -> float:
    """95 % half-width of a sum of independent errors, each ``(variance, dof)`` (``inf``:
    known): Student t on Welch-Satterthwaite's effective degrees of freedom."""
    total = sum(v for v, _ in parts)
    if total <= 0:
        return 0.0
    denom = sum(v**2 / n for v, n in parts if v > 0 and np.isfinite(n))
    nu = total**2 / denom if denom > 0 else np.inf
    q = stdtrit(min(nu, 1e6), 0.975) if np.isfinite(nu) else 1.959964
    return float(q * np.sqrt(total))


@dataclass
class _LeastSquares:
    sol: np.ndarray
    res: np.ndarray
    cov_noise: np.ndarray  # residual scale on the noise's shape, P W P^T
    dof: float  # of the scale: tr(R W)^2 / tr(R W R W), R = I - H (K - p when W = I)
    P: np.ndarray  # pinv(A): the estimate's response to the angles
    H_res: np.ndarray  # I - A P: the residuals' response
    W: np.ndarray  # noise shape
    trace: float  # tr((I - H) W): E(residual sum of squares) per unit scale


def _least_squares(A: np.ndarray, angle: np.ndarray, noise: TurnNoise | None) -> _LeastSquares:
    """Ordinary least squares (eq. 20-21), its covariance on the noise's shape ``W``: the
    scale ``s^2 = |r|^2 / tr((I - H) W)`` (unbiased when the noise is ``s^2 W``: slow turns
    integrate more gyro noise, so equal weights understate the long turns' share) times
    ``P W P^T`` (the sandwich). ``W = I`` without ``noise``: the textbook ``s^2 (A^T A)^-1``."""
    P = np.linalg.pinv(A)
    sol = P @ angle
    res = angle - A @ sol
    H_res = np.eye(len(angle)) - A @ P
    W = np.eye(len(angle)) if noise is None else noise.shape(float(sol[0]))
    RW = H_res @ W
    trace = float(np.trace(RW))
    s2 = float(res @ res) / trace
    # |r|^2 of noise s^2 W has mean s^2 tr(RW) and variance 2 s^4 tr(RWRW): Satterthwaite
    dof = trace**2 / max(float(np.sum(RW * RW.T)), 1e-300)
    return _LeastSquares(sol, res, s2 * P @ W @ P.T, dof, P, H_res, W, trace)


def _model_part(ls: _LeastSquares, model: ModelErrors | None, J: np.ndarray) -> tuple[float, float]:
    """Variance (and its dof) that the misalignment left out adds to ``J @ sol``: the mean
    square of its error over the draws, less what the residual scale already credits it with
    (its residuals, scaled as in :func:`_least_squares`); zero when that is larger.

    The dof: each component's variance ``sigma_c^2`` is measured on ``nu_c`` dof, so
    ``Var(ln V) = sum_c 2 e_c^2 / nu_c`` with ``e_c = d ln V / d ln sigma_c^2`` (finite
    difference over ``step``): ``nu_V = 1 / sum_c (e_c^2 / nu_c)`` (``nu_c`` for one linear
    component, ``nu_c / 4`` for a purely quadratic one)."""
    if model is None:
        return 0.0, np.inf
    gain = ls.P.T @ J  # (K,): the estimate's response to each angle
    credit = float(J @ ls.P @ ls.W @ ls.P.T @ J) / ls.trace
    E = np.asarray(model.errors, float)
    err = np.mean((E @ gain) ** 2, axis=1)
    res = np.mean(np.sum((E @ ls.H_res.T) ** 2, axis=2), axis=1)
    V = err - credit * res  # (1 + C,)
    if V[0] <= 0:
        return 0.0, np.inf
    e = (V[1:] - V[0]) / (V[0] * model.step)
    denom = float(np.sum(e**2 / np.asarray(model.dof, float)))
    return float(V[0]), (1 / denom if denom > 0 else np.inf)


def fit_axis_static(
    x: np.ndarray, T: np.ndarray, angle: np.ndarray, b: float, b_std: float = 0.0,
    angle_cov: np.ndarray | None = None, noise: TurnNoise | None = None,
    model: ModelErrors | None = None,
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
    noise : TurnNoise, optional
        The turns' noise shape (default: equal and independent).
    model : ModelErrors, optional
        Angle errors of the misalignment eq. (15) leaves out (default: none).
    """
    x, T, angle = map(np.asarray, (x, T, angle))
    if len(x) < 2:
        raise DesignError("the static-bias approach needs at least 2 rotations per axis")
    d = x - b * T  # eq. (17) with b known
    ls = _least_squares(d[:, None], angle, noise)
    k = float(ls.sol[0])
    noise_var = float(ls.cov_noise[0, 0])
    known = (k * b_std) ** 2 * float((T @ d) ** 2) / float(d @ d) ** 2
    if angle_cov is not None:  # dk = d . d(angle) / (d . d)
        known += float(d @ angle_cov @ d) / float(d @ d) ** 2
    mis, mis_dof = _model_part(ls, model, np.array([1.0]))
    return AxisFit(k, b, float(np.sqrt(noise_var + known + mis)), b_std, ls.res, "static",
                   _ci95([(noise_var, ls.dof), (known, np.inf), (mis, mis_dof)]),
                   1.959964 * b_std, float(np.sqrt(mis)))  # fmt: skip


def fit_axis_dynamic(x: np.ndarray, T: np.ndarray, angle: np.ndarray,
                     angle_cov: np.ndarray | None = None, noise: TurnNoise | None = None,
                     model: ModelErrors | None = None) -> AxisFit:  # fmt: skip
    """Dynamic approach: ``k`` and ``k b`` together by least squares (eqs. 19-21).

    Parameters as for :func:`fit_axis_static`; needs rotations of different durations or
    different angles (else ``k`` and ``b`` are not separable).
    """
    x, T, angle = map(np.asarray, (x, T, angle))
    if len(x) < 3:
        raise DesignError("the dynamic approach needs at least 3 rotations per axis")
    A = np.column_stack([x, -T])  # eq. (19): A [k, k b]^T = Delta theta
    ls = _least_squares(A, angle, noise)  # eqs. (20)-(21)
    k, kb = ls.sol
    cov_known = np.zeros((2, 2)) if angle_cov is None else ls.P @ angle_cov @ ls.P.T
    b = kb / k
    J = np.array([-kb / k**2, 1 / k])  # delta method for b = (k b) / k
    k_noise, k_known = float(ls.cov_noise[0, 0]), float(cov_known[0, 0])
    b_noise, b_known = float(J @ ls.cov_noise @ J), float(J @ cov_known @ J)
    k_mis, k_dof = _model_part(ls, model, np.array([1.0, 0.0]))
    b_mis, b_dof = _model_part(ls, model, J)
    return AxisFit(
        float(k), float(b), float(np.sqrt(k_noise + k_known + k_mis)),
        float(np.sqrt(b_noise + b_known + b_mis)), ls.res, "dynamic",
        _ci95([(k_noise, ls.dof), (k_known, np.inf), (k_mis, k_dof)]),
        _ci95([(b_noise, ls.dof), (b_known, np.inf), (b_mis, b_dof)]), float(np.sqrt(k_mis)),
    )  # fmt: skip
