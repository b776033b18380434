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
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri, gammaincinv

from imucal_cli.design.steady_turns import turning_windows
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

DEFAULT_ALPHA = 1e-4
"""Probability that a window of pure sensor noise is called moving (before ``k`` inflation)."""

NOISE_QUANTILE = 0.05
"""The noise is read from this low quantile of the window variances (at least this fraction
of the recording must be still for the estimate to be the sensor's noise)."""

DIFF_CAP = 3.0
"""The noise estimate never exceeds this multiple of the first-difference estimate: in a
recording with no still period the quietest windows are slow motion, whose first differences
still show only the noise.  3 leaves room for low-pass filtered (coloured) sensor noise, whose
first differences are smaller than its standard deviation (MPU-9150 gyro: about 0.45)."""

HOLD_TOLERANCE = 4.0
"""Default accelerometer threshold, in units of the chi-square multiple of
:func:`still_threshold`.  The noise estimate is that of the quietest windows (a unit resting on
a table); a hand-held or hand-placed hold adds tremor.  In the four real recordings of
``shared/data`` the accelerometer variance of the holds reaches about 3 times that of the
quietest windows, motion starts at about 10 times (see the module docstring of the tests)."""

GYRO_TOLERANCE = 100.0
"""Default gyroscope threshold, in the same units.  The gyroscope test is there to catch a
rotation that leaves the accelerometer unchanged (a turn about the vertical); vibration and
tremor raise the gyro variance of a hold 10 to 100 times above the quietest windows
(MPU-9150: 0.006 rad/s early in the recording against 0.0009 rad/s later), while a rotation
of even 10 deg/s is 10^3 to 10^5 times the noise variance."""


@dataclass(frozen=True)
class Interval:
    """A half-open range of sample indices ``[start, stop)``."""

    start: int
    stop: int

    @property
    def n_samples(self) -> int:
        """``stop - start``."""
        return self.stop - self.start


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


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def _rate_hz(time: np.ndarray) -> float:
    time = np.asarray(time, dtype=np.float64)
    if time.ndim != 1 or len(time) < 2:
        raise InputError("segmentation needs at least 2 samples")
    dt = np.diff(time)
    if not np.all(dt > 0):
        raise InputError("segmentation needs strictly increasing time")
    return float(1.0 / np.median(dt))


def _window_samples(window_s: float, rate_hz: float) -> int:
    if not window_s > 0:
        raise InputError(f"window must be > 0 s, got {window_s:g}")
    return max(3, int(round(window_s * rate_hz)))


def _channels(accel, gyro, n_time: int) -> tuple[np.ndarray, int]:
    """Stack the present sensors as (N, C) float64; return it and the number of accel columns."""
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
    return np.hstack(parts), na


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


def _quantisation_step(x: np.ndarray) -> np.ndarray:
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


def _noise_of(
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
    step = _quantisation_step(x)
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
    rate = _rate_hz(time)
    n = _window_samples(window_s, rate)
    if len(time) < n:
        raise InputError(f"{len(time)} samples are fewer than one {window_s:g} s window ({n})")
    if not 0 < quantile <= 0.5:
        raise InputError(f"quantile must be in (0, 0.5], got {quantile:g}")
    x, na = _channels(accel, gyro, len(time))
    sigma, step = _noise_of(x, n, quantile)
    has_a, has_g = accel is not None, gyro is not None
    return NoiseEstimate(
        accel=sigma[:na] if has_a else None,
        gyro=sigma[na:] if has_g else None,
        accel_step=step[:na] if has_a else None,
        gyro_step=step[na:] if has_g else None,
        window=n,
        rate_hz=rate,
    )


def still_threshold(n: int, channels: int, alpha: float = DEFAULT_ALPHA) -> float:
    """The multiple ``k`` of the noise variance below which a window counts as still.

    ``k = chi2.ppf(1 - alpha, C (n - 1)) / (C (n - 1))``: a window of ``n`` samples of white
    Gaussian noise on ``C`` channels has a mean normalised variance above ``k`` with
    probability ``alpha``.

    Parameters
    ----------
    n : int
        Window length, samples.
    channels : int
        Number of channels tested together.
    alpha : float
        False-alarm probability per window, in (0, 1).

    Returns
    -------
    float
        ``k`` (dimensionless, > 1).
    """
    if not 0 < alpha < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha:g}")
    dof = channels * (n - 1)
    return float(chdtri(dof, alpha) / dof)


def _runs(mask: np.ndarray) -> np.ndarray:
    """Start and stop (half-open) of every run of True, shape (R, 2)."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    return edges.reshape(-1, 2)


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
    rate = _rate_hz(time)
    n = _window_samples(window_s, rate)
    N = len(time)
    x, na = _channels(accel, gyro, N)
    if N < n:
        return []
    var = window_variance(x, n)
    if noise is None:
        sigma, _ = _noise_of(x, n, NOISE_QUANTILE, var)
    else:
        sigma = _given_noise(noise, accel, gyro)
    for name, value in (("k", k), ("gyro_k", gyro_k)):
        if value is not None and not value > 0:
            raise InputError(f"{name} must be > 0, got {value:g}")
    margin, min_n = _trim(rate, window_s, margin_s, min_still_s)
    still_window = _still_windows(var / (sigma * sigma), na, accel is not None, gyro is not None,
                                  k, gyro_k, n, alpha)  # fmt: skip
    if gyro is not None and mean_rate:
        g = slice(na, x.shape[1])
        still_window &= ~turning_windows(x[:, g], var[:, g], sigma[g], still_window, n, min_n,
                                         alpha)  # fmt: skip
    return _still_periods(_runs(_covered(still_window, N, n)), N, n, margin, min_n)


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


def _trim(rate: float, window_s: float, margin_s: float | None,
          min_still_s: float) -> tuple[int, int]:  # fmt: skip
    """Samples trimmed from each end of a still run (``margin_s``, default half a window) and
    the fewest samples a still period keeps (``min_still_s``), at ``rate``."""
    margin = int(round((window_s / 2 if margin_s is None else margin_s) * rate))
    if margin < 0:
        raise InputError(f"margin must be >= 0 s, got {margin_s:g}")
    return margin, int(np.ceil(min_still_s * rate - 1e-9))


def _covered(still_window: np.ndarray, N: int, n: int) -> np.ndarray:
    """Step 3 of :func:`find_static`: a sample is still when a still window covers it (the
    window starts dilated by ``n - 1``)."""
    cover = np.zeros(N + 1, dtype=np.int64)
    starts = np.flatnonzero(still_window)
    cover[starts] += 1  # indices unique within each of the two updates
    cover[starts + n] -= 1
    return np.cumsum(cover[:N]) > 0


def _still_periods(runs, N: int, n: int, margin: int, min_n: int) -> list[Interval]:
    """Runs of still samples (in order) merged across short gaps, trimmed by ``margin`` (not
    at the ends of the recording) and kept when ``min_n`` samples long (steps 3 and 4 of
    :func:`find_static`)."""
    if len(runs) == 0:
        return []
    # Merge runs split by a short gap (an isolated outlier sample).
    max_gap = max(1, n // 4)
    merged = [list(runs[0])]
    for a, b in runs[1:]:
        if a - merged[-1][1] <= max_gap:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    out = []
    for a, b in merged:
        a2 = a + margin if a > 0 else a
        b2 = b - margin if b < N else b
        if b2 - a2 >= max(min_n, 2):
            out.append(Interval(int(a2), int(b2)))
    return out


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
    g, _ = _channels(None, gyro, len(time))
    if not 0 < alpha < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha:g}")
    step = _quantisation_step(g)
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
