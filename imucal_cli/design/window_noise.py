"""The noise of still data read from a recording that may be mostly motion
(:func:`estimate_noise`, for :mod:`~imucal_cli.design.segmentation`): the variance of every
window from cumulative sums (:func:`window_variance`), its low quantile against the chi-square
distribution, capped by the first differences' and floored by the quantisation step.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaincinv

from imucal_cli.design.still_periods import window_samples
from imucal_cli.errors import InputError

NOISE_QUANTILE = 0.05
"""The noise is read from this low quantile of the window variances (at least this fraction
of the recording must be still for the estimate to be the sensor's noise)."""

DIFF_CAP = 3.0
"""The noise estimate never exceeds this multiple of the first-difference estimate: in a
recording with no still period the quietest windows are slow motion, whose first differences
still show only the noise.  3 leaves room for low-pass filtered (coloured) sensor noise, whose
first differences are smaller than its standard deviation (MPU-9150 gyro: about 0.45)."""

READING_LIMIT = 1e100
"""Beyond this magnitude (any unit) a sample is no reading but a damaged value: segmentation
takes it as non-finite (its square would overflow and turn every later window's sums NaN)."""


@dataclass(frozen=True)
class NoiseEstimate:
    """Per-channel noise of still data, estimated from the recording itself.

    Attributes
    ----------
    accel, gyro : ndarray, shape (na,) / (ng,), or None
        Standard deviation of one sample while still, raw units (None: sensor absent).
    accel_step, gyro_step : ndarray, shape (na,) / (ng,), or None
        Quantisation step of each channel, raw units (0 when the data is not quantised).
    window : int
        Window length used, samples.
    rate_hz : float
        Sample rate from the median time step, Hz.
    """

    accel: np.ndarray | None
    gyro: np.ndarray | None
    accel_step: np.ndarray | None
    gyro_step: np.ndarray | None
    window: int
    rate_hz: float


def rate_hz(time: np.ndarray) -> float:
    time = np.asarray(time, dtype=np.float64)
    if time.ndim != 1 or len(time) < 2:
        raise InputError("segmentation needs at least 2 samples")
    dt = np.diff(time)
    if not np.all(dt > 0):
        raise InputError("segmentation needs strictly increasing time")
    return float(1.0 / np.median(dt))


def sensor_channels(accel, gyro, n_time: int) -> tuple[np.ndarray, int]:
    """Stack the present sensors as (N, C) float64 (a sample beyond ``READING_LIMIT`` NaN);
    return it and the number of accel columns."""
    parts = []
    na = 0
    for name, x in (("accel", accel), ("gyro", gyro)):
        if x is None:
            continue
        x = np.asarray(x, dtype=np.float64)
        if x.ndim == 1:
            x = x[:, None]
        if x.ndim != 2 or len(x) != n_time:
            raise InputError(f"{name} must have shape (N, channels) with N = {n_time} samples")
        if name == "accel":
            na = x.shape[1]
        parts.append(x)
    if not parts:
        raise InputError("segmentation needs accel or gyro data")
    x = np.hstack(parts)
    x[~(np.abs(x) <= READING_LIMIT)] = np.nan  # no reading: as a lost one, not a square of inf
    return x, na


def window_variance(x: np.ndarray, n: int) -> np.ndarray:
    """Sample variance (ddof 1) of every ``n``-sample window, from cumulative sums.

    Parameters
    ----------
    x : ndarray, shape (N, C)
    n : int
        Window length, samples (``2 <= n <= N``).

    Returns
    -------
    ndarray, shape (N - n + 1, C)
        Row ``j`` is the variance of ``x[j:j+n]``.  Non-finite samples give NaN windows.
    """
    x = np.asarray(x, dtype=np.float64)
    # Centre each channel first so the cumulative sums stay small (no cancellation); the
    # median of about a thousand evenly spread samples is as good a centre as any.
    finite = np.isfinite(x)
    sample = x[:: max(1, len(x) // 1024)]
    if np.isfinite(sample).all():
        centre = np.median(sample, axis=0)
    else:
        with warnings.catch_warnings():  # an all-NaN channel: centre 0
            warnings.simplefilter("ignore", RuntimeWarning)
            centre = np.nan_to_num(np.nanmedian(sample, axis=0))
    xc = np.where(finite, x - centre, 0.0)
    zero = np.zeros((1, x.shape[1]))
    # The same arithmetic in place (a few arrays of the input's size, not a dozen).
    s1 = np.zeros((len(x) + 1, x.shape[1]))
    np.cumsum(xc, axis=0, out=s1[1:])
    xc *= xc
    s2 = np.zeros_like(s1)
    np.cumsum(xc, axis=0, out=s2[1:])
    del xc
    sum1 = s1[n:] - s1[:-n]
    del s1
    var = s2[n:] - s2[:-n]  # sum2
    del s2
    sum1 *= sum1
    sum1 /= n
    var -= sum1
    del sum1
    np.maximum(var, 0.0, out=var)
    var /= n - 1
    if not finite.all():
        bad = np.concatenate([zero, np.cumsum(~finite, axis=0)])
        var[(bad[n:] - bad[:-n]) > 0] = np.nan
    return var


def quantisation_step(x: np.ndarray) -> np.ndarray:
    """Per-channel quantisation step: the most common smallest non-zero difference.

    Returns 0 for a channel whose values are not on a grid (continuous data).
    """
    steps = np.zeros(x.shape[1])
    for c in range(x.shape[1]):
        col = x[:, c]
        col = col[np.isfinite(col)]
        if len(col) < 3:
            continue
        d = np.abs(np.diff(col))
        d = d[d > 0]
        if len(d) == 0:
            continue
        step = float(np.quantile(d, 0.01))
        if step <= 0:
            continue
        # On a grid, every difference is a near-integer multiple of the step.
        ratio = d / step
        on_grid = np.abs(ratio - np.rint(ratio)) < 1e-3 * np.maximum(ratio, 1.0)
        if on_grid.mean() > 0.99:
            steps[c] = step
    return steps


def _quantile(x: np.ndarray, q: float) -> np.ndarray:
    """Per-column quantile ignoring NaN (the plain, faster one when there is none)."""
    return np.nanquantile(x, q, axis=0) if np.isnan(x).any() else np.quantile(x, q, axis=0)


def _differences(x: np.ndarray) -> np.ndarray:
    """The first differences of ``x`` (N, C) along time, the last repeated: N rows, in one
    array (``np.vstack`` of ``np.diff`` held two at the peak of an import, issue 14.1)."""
    d = np.empty(x.shape, dtype=x.dtype)
    np.subtract(x[1:], x[:-1], out=d[:-1])
    d[-1] = d[-2]
    return d


def noise_of(
    x: np.ndarray, n: int, quantile: float, var: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Still-noise std and quantisation step per channel of ``x`` (N, C); ``var``: its
    window variances when already computed."""
    if var is None:
        var = window_variance(x, n)
    dof = n - 1
    # E.g. the 5 % quantile of chi2(dof)/dof: the low quantile of still-window variances.
    q_factor = 2 * gammaincinv(dof / 2, quantile) / dof
    sigma2_window = _quantile(var, quantile) / q_factor
    # First differences: mean square of the differences in each window, over 2.
    if len(x) > n:
        var = None  # free (unless the caller's) before the differences' variances: less memory
        d2 = window_variance(_differences(x), n)
    else:
        d2 = var
    # window_variance of differences ~ 2 sigma^2 for white noise (mean of d is ~0 when still)
    sigma2_diff = _quantile(d2, quantile) / q_factor / 2.0
    sigma2 = np.minimum(sigma2_window, DIFF_CAP**2 * sigma2_diff)
    step = quantisation_step(x)
    # Quantised data whose noise is below one count: the rounding error, step^2 / 12.
    sigma2 = np.maximum(sigma2, step * step / 12.0)
    # Continuous data that is exactly constant: a tiny floor, relative to the signal level.
    scale = np.nanmax(np.abs(x), axis=0)
    floor = (np.where(np.isfinite(scale) & (scale > 0), scale, 1.0) * 1e-9) ** 2
    sigma2 = np.maximum(np.nan_to_num(sigma2, nan=0.0), floor)
    return np.sqrt(sigma2), step


def estimate_noise(
    time: np.ndarray,
    accel: np.ndarray | None = None,
    gyro: np.ndarray | None = None,
    *,
    window_s: float = 0.5,
    quantile: float = NOISE_QUANTILE,
) -> NoiseEstimate:
    """Estimate the per-channel noise of still data from a recording that may be mostly motion.

    For each channel, the variance of every ``window_s`` window is computed (cumulative sums);
    the still windows are the quietest, so the ``quantile`` (default 5 %) of the window
    variances, divided by the same quantile of ``chi2(n-1)/(n-1)``, estimates ``sigma^2``
    whenever at least that fraction of the recording is still.  The estimate is capped at
    ``DIFF_CAP`` times the same statistic of the first differences (over 2), which sees only the
    noise even during slow motion, so a recording without a still period does not take its
    slowest motion for noise.  Quantised channels whose noise is below one step get the
    rounding noise ``step / sqrt(12)``.

    Parameters
    ----------
    time : ndarray, shape (N,)
        Seconds, strictly increasing.
    accel : ndarray, shape (N, na), optional
        Raw accelerometer channels, any units.
    gyro : ndarray, shape (N, ng), optional
        Raw gyroscope channels, any units.
    window_s : float
        Window length, s.
    quantile : float
        The low quantile of window variances read as noise, in (0, 0.5].

    Returns
    -------
    NoiseEstimate
        Standard deviations in the raw units of each channel.

    Raises
    ------
    InputError
        No sensor data, bad shapes, non-increasing time, or fewer samples than one window.
    """
    time = np.asarray(time, dtype=np.float64)
    rate = rate_hz(time)
    n = window_samples(window_s, rate)
    if len(time) < n:
        raise InputError(f"{len(time)} samples are fewer than one {window_s:g} s window ({n})")
    if not 0 < quantile <= 0.5:
        raise InputError(f"quantile must be in (0, 0.5], got {quantile:g}")
    x, na = sensor_channels(accel, gyro, len(time))
    sigma, step = noise_of(x, n, quantile)
    has_a, has_g = accel is not None, gyro is not None
    return NoiseEstimate(
        accel=sigma[:na] if has_a else None,
        gyro=sigma[na:] if has_g else None,
        accel_step=step[:na] if has_a else None,
        gyro_step=step[na:] if has_g else None,
        window=n,
        rate_hz=rate,
    )
