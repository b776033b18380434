"""The time offset between two IMUs of a rigid set from their gyro signals (issue 28).

Model (``docs/imu-set.md``, "Time offset"): the body turns at ``s(t)`` (rad/s, reference
frame, true time = the reference's clock).  The reference reads ``w_r(t_j) = s(t_j) + e_r``,
the other IMU, rotated into the reference's frame, ``w_i(tau_k) = s(tau_k + delta) + e_i``:
``delta`` (the spec's ``time_offset_s``) is the time to add to its stamps ``tau``.  White noise
of variance ``var_r``, ``var_i`` per axis per sample.

- :func:`coarse_offset`: the peak of the cross-correlation of the two rate magnitudes
  (bias removed, each scaled by its own spread: raw units will do) on a common grid, refined by
  a parabola through the peak: a start within a grid step.
- :func:`fit_time_offset`: least squares of ``w_i(tau_k) - w_r(tau_k + delta)`` over the
  samples of the turns, the reference interpolated linearly at ``tau_k + delta`` (no sample of
  either IMU is changed), Gauss-Newton with the derivative of the reference's rate
  (Savitzky-Golay); its variance from the noise of both (the reference's through the
  interpolation weights): at high signal-to-noise it reaches the bound below.
- :func:`time_offset_bound`: the Cramér-Rao bound with the signal ``s`` a nuisance
  (derivation in ``docs/imu-set.md``)::

      var(delta) >= 1 / sum_a [ int s_a'(t)^2 dt / (var_r,a / f_r + var_i,a / f_i) ]

  for white noise of densities ``var / f`` (``f`` the sample rates).
- :func:`fit_time_offset_gains`: the same fit where a gyro is not calibrated in full (eq.
  T5): each IMU's raw rate, its bias from the still periods removed, and the matrix ``A``
  that maps the reference's into the other's (gains, misalignment, rotation, units) fitted
  jointly with ``delta``; the offset's variance holds what ``A``'s uncertainty adds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import DesignError

__all__ = ["TimeOffset", "coarse_offset", "fit_time_offset", "fit_time_offset_gains",
           "rate_derivative", "time_offset_bound"]  # fmt: skip

MAX_OFFSET_S = 1.0
"""The largest time offset :func:`coarse_offset` looks for, s."""


def _speed(time: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """The rate's magnitude, bias (median) removed, scaled by its spread."""
    x = np.linalg.norm(rate - np.median(rate, axis=0), axis=1)
    x = x - np.mean(x)
    spread = np.std(x)
    return x / spread if spread > 0 else x


def coarse_offset(t_ref: np.ndarray, w_ref: np.ndarray, t_imu: np.ndarray, w_imu: np.ndarray,
                  max_offset_s: float = MAX_OFFSET_S) -> float:  # fmt: skip
    """The offset (s, to add to ``t_imu``) that best lines up the two gyro signals' magnitudes.

    Parameters
    ----------
    t_ref, t_imu : ndarray, shape (N,), (M,)
        Sample times, s.
    w_ref, w_imu : ndarray, shape (N, 3), (M, 3)
        Gyro samples, raw or calibrated (each IMU in its own units and frame).
    max_offset_s : float
        The search range, +-s.

    Raises
    ------
    DesignError
        The signals do not overlap, or do not move (no turn to line up).
    """
    h = 0.5 / max(1.0 / np.median(np.diff(t_ref)), 1.0 / np.median(np.diff(t_imu)))
    lo, hi = max(t_ref[0], t_imu[0]), min(t_ref[-1], t_imu[-1])
    if hi - lo <= 4 * max_offset_s:
        max_offset_s = max((hi - lo) / 4, 2 * h)
    if hi - lo <= 8 * h:
        raise DesignError("the IMUs' recordings do not overlap in time")
    grid = np.arange(lo, hi, h)
    x_r = np.interp(grid, t_ref, _speed(t_ref, w_ref))
    x_i = np.interp(grid, t_imu, _speed(t_imu, w_imu))
    if not (np.std(x_r) > 0 and np.std(x_i) > 0):
        raise DesignError("a gyro does not move: no turn to line the IMUs' clocks up with")
    from scipy.signal import correlate, correlation_lags  # start-up: see DEVELOPERS.md

    c = correlate(x_r, x_i, mode="full", method="fft")  # c[L] = sum_l x_r[l] x_i[l - L]
    lags = correlation_lags(len(x_r), len(x_i), mode="full")
    inside = np.abs(lags) <= max_offset_s / h
    c, lags = c[inside], lags[inside]
    k = int(np.argmax(c))
    frac = 0.0
    if 0 < k < len(c) - 1:
        den = c[k - 1] - 2 * c[k] + c[k + 1]
        frac = 0.5 * (c[k - 1] - c[k + 1]) / den if den < 0 else 0.0
    return float((lags[k] + frac) * h)


def rate_derivative(time: np.ndarray, rate: np.ndarray, window_s: float = 0.05) -> np.ndarray:
    """``d rate / dt`` (N, 3), rad/s^2: a Savitzky-Golay derivative (cubic, ``window_s`` wide,
    at least 5 samples) of uniformly sampled data (the median step)."""
    dt = float(np.median(np.diff(time)))
    n = max(5, int(round(window_s / dt)) | 1)
    if n > len(time):
        return np.gradient(rate, time, axis=0)
    from scipy.signal import savgol_filter  # start-up: see DEVELOPERS.md

    return savgol_filter(rate, n, 3, deriv=1, delta=dt, axis=0)


@dataclass
class TimeOffset:
    """A fitted time offset (:func:`fit_time_offset`).

    Attributes
    ----------
    value_s, std_s : float
        ``delta`` (add to the IMU's stamps) and its standard deviation, s.
    start_s : float
        Where the fit started (:func:`coarse_offset`), s.
    samples : int
        The IMU's samples in the turns the fit used.
    rms, rms_expected : float
        The residual RMS per axis and what the noise predicts, ``units``.
    iterations : int
    method : str or None
        How it was found, in words; None: both gyros calibrated (eq. T4, the calibrated
        rates, the IMU's rotated into the reference's frame).
    units : str
        The units of ``rms``: rad/s (calibrated rates), or the IMU's raw gyro units.
    """

    value_s: float
    std_s: float
    start_s: float
    samples: int
    rms: float
    rms_expected: float
    iterations: int
    method: str | None = None
    units: str = "rad/s"


def _interp_weights(t_ref: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation at ``t``: left indices ``j`` and weights ``a`` (value =
    ``(1 - a) x[j] + a x[j + 1]``)."""
    j = np.clip(np.searchsorted(t_ref, t, side="right") - 1, 0, len(t_ref) - 2)
    a = np.clip((t - t_ref[j]) / (t_ref[j + 1] - t_ref[j]), 0.0, 1.0)
    return j, a


def fit_time_offset(
    t_ref: np.ndarray, w_ref: np.ndarray, t_imu: np.ndarray, w_imu: np.ndarray,
    windows: list[tuple[float, float]], var_ref: float, var_imu: float, start_s: float,
    max_iterations: int = 20,
) -> TimeOffset:  # fmt: skip
    """Fit ``delta`` (module notes) over the IMU's samples within ``windows``.

    Parameters
    ----------
    t_ref, w_ref : ndarray, shape (N,), (N, 3)
        The reference's times (s) and calibrated rate (rad/s).
    t_imu, w_imu : ndarray, shape (M,), (M, 3)
        The IMU's times (its own stamps, s) and calibrated rate rotated into the reference's
        frame (rad/s).
    windows : list of (float, float)
        The turns, reference time, s.
    var_ref, var_imu : float
        White noise variance per axis per sample of each, (rad/s)^2.
    start_s : float
        The starting value (:func:`coarse_offset`), s.

    Raises
    ------
    DesignError
        No sample of the IMU in a turn, or a signal without a derivative to fit.
    """
    d_ref = rate_derivative(t_ref, w_ref)
    delta, iterations = float(start_s), 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (reported)
        k = _inside(t_imu + delta, windows, t_ref)
        if k.size < 3:
            raise DesignError("no samples of the IMU inside the turns: no time offset")
        j, a = _interp_weights(t_ref, t_imu[k] + delta)
        model = (1 - a)[:, None] * w_ref[j] + a[:, None] * w_ref[j + 1]
        g = (1 - a)[:, None] * d_ref[j] + a[:, None] * d_ref[j + 1]
        r = w_imu[k] - model
        info = float(np.sum(g * g))
        if not info > 0:
            raise DesignError("the turns do not change the rate: no time offset")
        step = float(np.sum(g * r)) / info
        delta += step
        if abs(step) < 1e-9:
            break
    k = _inside(t_imu + delta, windows, t_ref)
    j, a = _interp_weights(t_ref, t_imu[k] + delta)
    g = (1 - a)[:, None] * d_ref[j] + a[:, None] * d_ref[j + 1]
    r = w_imu[k] - ((1 - a)[:, None] * w_ref[j] + a[:, None] * w_ref[j + 1])
    info = float(np.sum(g * g))
    # the reference's noise reaches the fit through the interpolation weights (eq. T4)
    back = np.zeros((len(t_ref), 3))
    np.add.at(back, j, (1 - a)[:, None] * g)
    np.add.at(back, j + 1, a[:, None] * g)
    var = (var_imu * info + var_ref * float(np.sum(back * back))) / info**2
    expected = np.sqrt(var_imu + var_ref * float(np.mean((1 - a) ** 2 + a**2)))
    return TimeOffset(value_s=delta, std_s=float(np.sqrt(var)), start_s=float(start_s),
                      samples=int(k.size), rms=float(np.sqrt(np.mean(r * r))),
                      rms_expected=float(expected), iterations=iterations)  # fmt: skip


#: The method of :func:`fit_time_offset_gains`, in words.
GAINS_METHOD = ("a gyro not calibrated in full: raw rates, biases from the still periods, the "
                "matrix between the gyros fitted with the offset (docs/imu-set.md, eq. T5)")


def fit_time_offset_gains(
    t_ref: np.ndarray, w_ref: np.ndarray, t_imu: np.ndarray, w_imu: np.ndarray,
    windows: list[tuple[float, float]], var_ref: np.ndarray, var_imu: np.ndarray,
    start_s: float, max_iterations: int = 30,
) -> TimeOffset:  # fmt: skip
    """Fit ``delta`` jointly with the matrix ``A`` of (T5) ``w_imu(tau_k) = A w_ref(tau_k +
    delta) + e`` over the IMU's samples within ``windows`` (Gauss-Newton on the 9 terms of
    ``A`` and ``delta``, the IMU's channels weighed by their noise).  Its covariance is the
    sandwich of both IMUs' noise (the reference's through the interpolation weights, as T4),
    so ``delta``'s variance holds what the unknown ``A`` adds to it.

    Parameters
    ----------
    t_ref, w_ref : ndarray, shape (N,), (N, 3)
        The reference's times (s) and bias-free rate (any units, any frame).
    t_imu, w_imu : ndarray, shape (M,), (M, 3)
        The IMU's times (its own stamps, s) and bias-free rate (any units, any frame).
    windows : list of (float, float)
        The turns, reference time, s.
    var_ref, var_imu : ndarray, shape (3,)
        White noise variance per channel per sample of each, its units squared.
    start_s : float
        The starting value (:func:`coarse_offset`), s.

    Raises
    ------
    DesignError
        No sample of the IMU in a turn, or turns that do not determine the offset.
    """
    sig = np.sqrt(np.asarray(var_imu, float))
    var_ref = np.asarray(var_ref, float)
    if not (np.all(sig > 0) and np.all(np.isfinite(sig)) and np.all(np.isfinite(var_ref))):
        raise DesignError("the gyros' noise is not measured (no still period): no time offset")
    d_ref = rate_derivative(t_ref, w_ref)
    delta, A, iterations = float(start_s), None, 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (reported)
        k, j, a, m, g = _at(t_ref, w_ref, d_ref, t_imu + delta, windows)
        if A is None:
            A = np.linalg.lstsq(m, w_imu[k], rcond=None)[0].T
        J = _gains_jacobian(m, g, A, sig)
        r = ((w_imu[k] - m @ A.T) / sig).ravel()
        step = np.linalg.lstsq(J.reshape(-1, 10), r, rcond=None)[0]
        A = A + step[:9].reshape(3, 3)
        delta += float(step[9])
        if abs(step[9]) < 1e-9:
            break
    k, j, a, m, g = _at(t_ref, w_ref, d_ref, t_imu + delta, windows)
    J = _gains_jacobian(m, g, A, sig)
    H = np.einsum("kcp,kcq->pq", J, J)
    # the reference's noise e_r reaches J^T e through -A times its interpolation (eq. T4)
    v = np.einsum("kcp,c,cd->kpd", J, 1.0 / sig, A)
    back = np.zeros((len(t_ref), 10, 3))
    np.add.at(back, j, (1 - a)[:, None, None] * v)
    np.add.at(back, j + 1, a[:, None, None] * v)
    Hi = np.linalg.pinv(H, rcond=1e-12)
    cov = Hi @ (H + np.einsum("npd,d,nqd->pq", back, var_ref, back)) @ Hi
    if not (np.isfinite(cov[9, 9]) and cov[9, 9] > 0 and np.isfinite(delta)):
        raise DesignError("the turns do not determine the offset with the gyros' matrix "
                          "unknown: no time offset")  # fmt: skip
    r = w_imu[k] - m @ A.T
    expected = np.mean(var_imu + (A**2 @ var_ref) * float(np.mean((1 - a) ** 2 + a**2)))
    return TimeOffset(value_s=delta, std_s=float(np.sqrt(cov[9, 9])), start_s=float(start_s),
                      samples=int(k.size), rms=float(np.sqrt(np.mean(r * r))),
                      rms_expected=float(np.sqrt(expected)), iterations=iterations,
                      method=GAINS_METHOD, units="raw")  # fmt: skip


def _at(t_ref, w_ref, d_ref, t, windows):
    """The IMU's samples at times ``t`` inside the turns: their indices, the interpolation's
    left indices and weights, the reference's rate and derivative there."""
    k = _inside(t, windows, t_ref)
    if k.size < 12:
        raise DesignError("too few samples of the IMU inside the turns: no time offset")
    j, a = _interp_weights(t_ref, t[k])
    m = (1 - a)[:, None] * w_ref[j] + a[:, None] * w_ref[j + 1]
    g = (1 - a)[:, None] * d_ref[j] + a[:, None] * d_ref[j + 1]
    return k, j, a, m, g


def _gains_jacobian(m: np.ndarray, g: np.ndarray, A: np.ndarray, sig: np.ndarray) -> np.ndarray:
    """The model's derivative (K, 3, 10) by ``A`` (row-major) and ``delta``, each channel
    divided by its noise ``sig``."""
    K = len(m)
    J = np.zeros((K, 3, 10))
    for c in range(3):
        J[:, c, 3 * c : 3 * c + 3] = m / sig[c]
    J[:, :, 9] = (g @ A.T) / sig
    return J


def _inside(t: np.ndarray, windows: list[tuple[float, float]], t_ref: np.ndarray) -> np.ndarray:
    """Indices of ``t`` inside any window and inside the reference's span."""
    ok = np.zeros(len(t), bool)
    for lo, hi in windows:
        ok |= (t >= lo) & (t <= hi)
    ok &= (t > t_ref[0]) & (t < t_ref[-1])
    return np.flatnonzero(ok)


def time_offset_bound(sdot_squared_integral: np.ndarray, var_ref: np.ndarray, rate_ref: float,
                      var_imu: np.ndarray, rate_imu: float) -> float:  # fmt: skip
    """The Cramér-Rao bound on ``delta``'s std, s (module notes; ``docs/imu-set.md`` eq. T3).

    Parameters
    ----------
    sdot_squared_integral : ndarray, shape (3,)
        ``int s_a'(t)^2 dt`` over the turns per axis, (rad/s^2)^2 s.
    var_ref, var_imu : ndarray, shape (3,) or float
        White noise variance per axis per sample, (rad/s)^2.
    rate_ref, rate_imu : float
        Sample rates, Hz.
    """
    density = np.asarray(var_ref, float) / rate_ref + np.asarray(var_imu, float) / rate_imu
    info = float(np.sum(np.asarray(sdot_squared_integral, float) / density))
    return float(1.0 / np.sqrt(info))
