"""Segmentation of a continuous recording into still periods and the motions between them.

Pure numerics: arrays in, :class:`Interval` lists out.  Every threshold comes from the data's
own noise (:func:`estimate_noise`) and from the chi-square distribution of a window variance,
so the false-alarm rate is a stated probability, not a guessed constant.

Model
-----
While the unit is still, each raw channel ``c`` is a constant plus noise of standard deviation
``sigma_c``.  The sample variance ``s_c^2`` of an ``n``-sample window of white Gaussian noise
satisfies ``(n - 1) s_c^2 / sigma_c^2 ~ chi2(n - 1)``, and over the ``C`` channels (accel and
gyro) of one window

    T = sum_c (n - 1) s_c^2 / sigma_c^2 ~ chi2(C (n - 1)).

A window is still when ``T <= chi2.ppf(1 - alpha, C (n - 1))``, i.e. when the mean normalised
variance ``mean_c(s_c^2 / sigma_c^2)`` is at most ``k = chi2.ppf(1 - alpha, C (n-1)) / (C (n-1))``:
a still window of white noise is rejected with probability ``alpha``.  Window variances come
from cumulative sums, so a one-hour 100 Hz recording is segmented in a fraction of a second.

The noise estimate is :mod:`.window_noise`'s; the thresholds and the still runs made still
periods, which :mod:`.static_stream` shares, :mod:`.still_periods`' (all importable from here).
"""

from __future__ import annotations

import numpy as np
from scipy.special import chdtri

from imucal_cli.design.steady_turns import turning_windows
from imucal_cli.design.still_periods import (
    DEFAULT_ALPHA,
    GYRO_TOLERANCE,
    HOLD_TOLERANCE,
    Interval,
    still_periods,
    still_runs,
    still_threshold,
    trim,
    window_samples,
)
from imucal_cli.design.window_noise import (
    NOISE_QUANTILE,
    NoiseEstimate,
    estimate_noise,
    noise_of,
    quantisation_step,
    rate_hz,
    sensor_channels,
    window_variance,
)
from imucal_cli.errors import InputError

__all__ = [
    "DEFAULT_ALPHA",
    "GYRO_TOLERANCE",
    "HOLD_TOLERANCE",
    "Interval",
    "NoiseEstimate",
    "estimate_noise",
    "find_rotations",
    "find_static",
    "find_steps",
    "still_threshold",
]


# --------------------------------------------------------------------------------------------
# Still periods
# --------------------------------------------------------------------------------------------


def find_static(
    time: np.ndarray,
    accel: np.ndarray | None = None,
    gyro: np.ndarray | None = None,
    *,
    min_still_s: float = 1.0,
    window_s: float = 0.5,
    k: float | None = None,
    gyro_k: float | None = None,
    alpha: float = DEFAULT_ALPHA,
    margin_s: float | None = None,
    noise: NoiseEstimate | None = None,
    mean_rate: bool = True,
) -> list[Interval]:
    """Find the still periods of a continuous recording.

    1. Noise per channel from the recording itself (:func:`estimate_noise`), unless given.
    2. A ``window_s`` window is still when, for each sensor present, the mean over its channels
       of the window variance divided by the noise variance is at most that sensor's threshold:
       ``k`` for the accelerometer (default ``HOLD_TOLERANCE`` times the chi-square multiple of
       :func:`still_threshold` at false-alarm probability ``alpha``) and ``gyro_k`` for the
       gyroscope (default ``GYRO_TOLERANCE`` times it).  With the gyro (and ``mean_rate``),
       a still window whose mean rate differs from the still periods' common bias by more
       than its noise allows is a turn the variance cannot see (a steady turn about the
       vertical), not still (:mod:`imucal_cli.design.steady_turns`).
    3. A sample is still when a still window covers it; runs of still samples separated by at
       most a quarter window (a single noise spike) are merged.
    4. Each run is trimmed by ``margin_s`` at both ends (not at the ends of the recording), so a
       hold does not include the gentle start or end of a motion, and kept when it lasts at
       least ``min_still_s``.

    Parameters
    ----------
    time : ndarray, shape (N,)
        Seconds, strictly increasing.
    accel : ndarray, shape (N, na), optional
        Raw accelerometer channels.
    gyro : ndarray, shape (N, ng), optional
        Raw gyroscope channels.
    min_still_s : float
        Shortest still period returned (after trimming), s.
    window_s : float
        Variance window, s.
    k : float, optional
        Accelerometer threshold on the mean normalised window variance (dimensionless).
    gyro_k : float, optional
        Gyroscope threshold on the mean normalised window variance (dimensionless).
    alpha : float
        False-alarm probability per window of pure noise (for the default thresholds).
    margin_s : float, optional
        Trimmed from both ends of each still run, s; default ``window_s / 2``.
    noise : NoiseEstimate, optional
        Use this noise instead of estimating it (its ``window`` is ignored).
    mean_rate : bool
        Test the still windows' mean gyro rate too (step 2); False: the variance alone, as
        :class:`~imucal_cli.design.static_stream.StaticStream` tests it.

    Returns
    -------
    list of Interval
        Half-open sample ranges in time order, not overlapping.

    Raises
    ------
    InputError
        No sensor data, bad shapes, non-increasing time or bad options.
    """
    time = np.asarray(time, dtype=np.float64)
    rate = rate_hz(time)
    n = window_samples(window_s, rate)
    N = len(time)
    x, na = sensor_channels(accel, gyro, N)
    if N < n:
        return []
    var = window_variance(x, n)
    if noise is None:
        sigma, _ = noise_of(x, n, NOISE_QUANTILE, var)
    else:
        sigma = _given_noise(noise, accel, gyro)
    for name, value in (("k", k), ("gyro_k", gyro_k)):
        if value is not None and not value > 0:
            raise InputError(f"{name} must be > 0, got {value:g}")
    margin, min_n = trim(rate, window_s, margin_s, min_still_s)
    still_window = _still_windows(var / (sigma * sigma), na, accel is not None, gyro is not None,
                                  k, gyro_k, n, alpha)  # fmt: skip
    if gyro is not None and mean_rate:
        g = slice(na, x.shape[1])
        still_window &= ~turning_windows(x[:, g], var[:, g], sigma[g], still_window, n, min_n,
                                         alpha)  # fmt: skip
    return still_periods(still_runs(_covered(still_window, N, n)), N, n, margin, min_n)


def _still_windows(normalised: np.ndarray, na: int, has_accel: bool, has_gyro: bool,
                   k: float | None, gyro_k: float | None, n: int, alpha: float) -> np.ndarray:
    """Step 2 of :func:`find_static`: the windows whose mean normalised variance (channels
    ``:na`` the accelerometer's, the rest the gyroscope's) is at most its sensor's threshold,
    for every sensor given (``k``, ``gyro_k``; None: the sensor's tolerance times the
    chi-square multiple of :func:`still_threshold`)."""  # fmt: skip
    groups = []  # (channels, threshold or None, tolerance) per sensor given
    if has_accel:
        groups.append((slice(0, na), k, HOLD_TOLERANCE))
    if has_gyro:
        groups.append((slice(na, normalised.shape[1]), gyro_k, GYRO_TOLERANCE))
    still_window = np.ones(len(normalised), dtype=bool)
    for cols, limit, tolerance in groups:
        channels = cols.stop - cols.start
        if limit is None:
            limit = tolerance * still_threshold(n, channels, alpha)
        still_window &= np.mean(normalised[:, cols], axis=1) <= limit  # NaN: not still
    return still_window


def _given_noise(noise: NoiseEstimate, accel, gyro) -> np.ndarray:
    """Step 1 of :func:`find_static` with the noise given: its channels of the sensors given."""
    parts = [s for s, given in ((noise.accel, accel), (noise.gyro, gyro)) if given is not None]
    if any(p is None for p in parts):
        raise InputError("the noise estimate lacks a sensor that is given")
    return np.concatenate([np.asarray(p, float) for p in parts])


def _covered(still_window: np.ndarray, N: int, n: int) -> np.ndarray:
    """Step 3 of :func:`find_static`: a sample is still when a still window covers it (the
    window starts dilated by ``n - 1``)."""
    cover = np.zeros(N + 1, dtype=np.int64)
    starts = np.flatnonzero(still_window)
    cover[starts] += 1  # indices unique within each of the two updates
    cover[starts + n] -= 1
    return np.cumsum(cover[:N]) > 0


STEP_SIGMAS = 20.0
"""A hold's mean may not jump by more than this many noise standard deviations (one sample's)
between consecutive windows: more is a different pose (10 degrees of tilt is about 20 sigma
of a cheap accelerometer's noise), not tremor."""


def find_steps(
    accel: np.ndarray, sigma: np.ndarray, n: int, *, limit: float = STEP_SIGMAS
) -> list[int]:
    """Where the level of a (supposedly) still stretch jumps: two poses joined together.

    The mean of the ``n`` samples before each index is compared with the mean of the ``n``
    after it, per channel, in units of the channel's noise ``sigma``; a step is where the
    largest such jump exceeds ``limit`` (one index per step: the peak of each excursion).

    Parameters
    ----------
    accel : ndarray, shape (N, C)
        Raw samples of the stretch.
    sigma : ndarray, shape (C,)
        Noise standard deviation per channel (:func:`estimate_noise`).
    n : int
        Window length, samples.
    limit : float
        Threshold on the jump, noise standard deviations.

    Returns
    -------
    list of int
        Indices into ``accel`` where a new level starts (empty: one level throughout).
    """
    x = np.asarray(accel, dtype=np.float64)
    N = len(x)
    if N < 2 * n:
        return []
    with np.errstate(over="ignore", invalid="ignore"):  # a damaged value: no step near it
        s1 = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x - x[0], axis=0)])
        means = (s1[n:] - s1[:-n]) / n  # means[j] = mean of x[j:j+n]
        jump = np.max(np.abs(means[n:] - means[:-n]) / np.maximum(sigma, 1e-300), axis=1)
    over = jump > limit  # jump[k] compares x[k:k+n] with x[k+n:k+2n]: a step at k + n
    if not over.any():
        return []
    m = np.concatenate([[False], over, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m)).reshape(-1, 2)
    return [int(a + np.argmax(jump[a:b]) + n) for a, b in edges]


# --------------------------------------------------------------------------------------------
# Motions
# --------------------------------------------------------------------------------------------


def find_rotations(
    time: np.ndarray,
    gyro: np.ndarray,
    static: list[Interval],
    *,
    alpha: float = DEFAULT_ALPHA,
) -> list[Interval]:
    """The motions between consecutive still periods, where the gyro shows a rotation.

    For each pair of consecutive still periods the candidate is ``[first.stop, second.start)``.
    The gyro bias is the mean over the two still periods and its noise their pooled standard
    deviation per channel; each sample's ``d^2 = sum_c ((g_c - bias_c) / sigma_c)^2`` is
    ``chi2(ng)`` under no rotation, and the candidate is kept when some sample exceeds the
    ``1 - alpha / m`` quantile (``m`` samples in the candidate, Bonferroni).

    Parameters
    ----------
    time : ndarray, shape (N,)
        Seconds, strictly increasing.
    gyro : ndarray, shape (N, ng)
        Raw gyroscope channels.
    static : list of Interval
        Still periods in time order (from :func:`find_static`).
    alpha : float
        Probability that a gap of pure noise is called a rotation.

    Returns
    -------
    list of Interval
        One per kept gap, in time order.
    """
    time = np.asarray(time, dtype=np.float64)
    g, _ = sensor_channels(None, gyro, len(time))
    if not 0 < alpha < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha:g}")
    step = quantisation_step(g)
    gaps: list[tuple[int, int]] = []
    peaks: list[float] = []
    ordered = sorted(static, key=lambda s: s.start)
    for first, second in zip(ordered[:-1], ordered[1:], strict=True):
        a, b = first.stop, second.start
        if b <= a:
            continue
        still = np.vstack([g[first.start : first.stop], g[second.start : second.stop]])
        bias = still.mean(axis=0)
        resid = np.vstack(
            [
                g[first.start : first.stop] - g[first.start : first.stop].mean(axis=0),
                g[second.start : second.stop] - g[second.start : second.stop].mean(axis=0),
            ]
        )
        sigma2 = np.maximum(np.mean(resid * resid, axis=0), step * step / 12.0)
        sigma2 = np.maximum(sigma2, 1e-300)
        d2 = np.sum((g[a:b] - bias) ** 2 / sigma2, axis=1)
        gaps.append((a, b))
        peaks.append(np.nanmax(d2))
    if not gaps:
        return []
    limits = [chdtri(g.shape[1], alpha / (b - a)) for a, b in gaps]
    return [
        Interval(int(a), int(b))
        for (a, b), peak, limit in zip(gaps, peaks, limits, strict=True)
        if peak > limit
    ]
