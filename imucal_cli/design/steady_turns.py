"""Turns that the window variance cannot see: a steady rate about the vertical (issue 27).

Pure numerics, a step of :func:`imucal_cli.design.segmentation.find_static`.

Why
---
The still test of :mod:`~imucal_cli.design.segmentation` thresholds each window's variance
about its own mean.  A turn at a steady (or slowly changing) rate about the vertical changes
neither gravity in the body frame nor the gyro's variance within a window: a vehicle's slow
yaw, a robot turning in place, the gentle end of a move.  Its windows pass as still, and the
calibration then reads the turn's rate as the gyro's bias.  What the variance misses is the
window's *mean* rate: while still it is the bias, during a turn it is the bias plus the rate.

Model
-----
For the gyro channels ``c`` of a window ``j`` of ``n`` samples, its mean ``m_jc`` against the
common still bias ``b_c``:

    z_jc = (m_jc - b_c) / sqrt(max(s_jc^2, sigma_c^2) / n + tau_c^2),
    D_j = sum_c z_jc^2,

``s_jc^2`` the window's variance (tremor and vibration widen what its mean may do), ``sigma_c``
the sensor's noise, ``tau_c^2`` what the still windows' means scatter beyond that (below).
Still, ``D_j`` is about ``chi2(C)`` distributed (``C`` channels; the window's variance floored
at the noise makes it smaller), above its bound ``chi2.isf(alpha, C)`` with probability about
``alpha``.  As hysteresis, a still period is split where ``D_j`` exceeds
:data:`RATE_TOLERANCE` times the bound, and its ends are trimmed while ``D_j`` exceeds the
bound itself.

The common bias and its scatter come from the windows the variance test calls still, in runs
of consecutive still windows long enough to be kept (``min_n`` samples covered): each run's
median window mean, then

- ``b_c`` the median over the runs (one vote per still period: a long rest counts once, a
  slow turn merged into a hold is outvoted within its run);
- ``tau_c^2`` the sum of two robust spreads (``1.4826 MAD``, the normal's std): the runs'
  medians about ``b_c`` (the bias differs between still periods: g-sensitivity, temperature;
  this also bounds the uncertainty of ``b_c`` itself, about ``1.25 tau / sqrt(runs)``), and
  every still window's mean about its run's median beyond the noise (a hand's slow wander,
  coloured noise whose window means scatter more than ``sigma / sqrt(n)``, a drift within a
  long rest).

The split is repeated on the windows it leaves still (:data:`PASSES`): a turn that made up much
of a run widened that run's scatter; once split off, the holds' own scatter is what its ends
are trimmed against.

A turn's samples deviate by its rate, ``sqrt(n)`` times more in ``z`` than in one sample: a
2 deg/s turn on a gyro of 0.29 deg/s noise (0.5 s windows at 100 Hz) has ``z`` near 49, ``D``
about 115 times the bound.  Only sustained deviations matter: a sample is still while some
still window covers it, so a gap opens where more than ``n`` consecutive windows turn.
"""

from __future__ import annotations

import numpy as np
from scipy.special import chdtri

__all__ = ["PASSES", "RATE_TOLERANCE", "mean_rate_statistic", "turning_windows", "window_means"]

RATE_TOLERANCE = 4.0
"""Multiple of the chi-square bound on ``D`` (module notes) above which a still period is split
(its ends are trimmed at the bound itself: :func:`turning_windows`).  The eleven real
recordings of ``shared/data`` (Xsens, five MPU-9150s, three MPU-6050 files, MaD Lab's two
Ferraris sessions): of the 119,115 windows of their still periods (as the variance alone finds
them), ``D`` exceeds the bound in 2 %, twice it in 0.4 % (99th percentile 1.4 times, 99.9th
3.1, largest 7.4), four times it in 47 (0.04 %).  Splitting at the bound itself, a bump (about
1 s, its mean rate up to 4 noise std) cuts the 77 s rest of an MPU-6050's recording in two;
at 4 times it no period of the eleven is split or lost, and the trimmed ends take 0-3 % of
their still samples (16 % of one hold at most; the four largest, looked at, are where the gyro
shows the unit settling or starting to move: 6-30 noise std in 0.1 s means).  A 2 deg/s turn
on a gyro of 0.29 deg/s noise exceeds 4 times the bound 29-fold."""

MAD_TO_STD = 1.4826
"""The standard deviation of a normal distribution per median absolute deviation."""


def window_means(x: np.ndarray, n: int) -> np.ndarray:
    """The mean of every ``n``-sample window of ``x``, from cumulative sums.

    Parameters
    ----------
    x : ndarray, shape (N, C)
        Samples; non-finite ones give NaN windows.
    n : int
        Window length, samples (``1 <= n <= N``).

    Returns
    -------
    ndarray, shape (N - n + 1, C)
        Row ``j`` is the mean of ``x[j:j+n]``.
    """
    x = np.asarray(x, dtype=np.float64)
    finite = np.isfinite(x)
    centre = np.nan_to_num(x[np.argmax(finite.all(axis=1))]) if finite.any() else 0.0
    s1 = np.zeros((len(x) + 1, x.shape[1]))
    np.cumsum(np.where(finite, x - centre, 0.0), axis=0, out=s1[1:])  # centred: no cancellation
    means = (s1[n:] - s1[:-n]) / n + centre
    bad = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(~finite, axis=0)])
    means[(bad[n:] - bad[:-n]) > 0] = np.nan
    return means


def _voting_runs(still: np.ndarray, n: int, min_n: int) -> list[tuple[int, int]]:
    """Runs ``[a, b)`` of consecutive still windows that cover at least ``min_n`` samples (a
    still period :func:`find_static` would keep before its trims)."""
    m = np.concatenate([[False], still, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m)).reshape(-1, 2)
    return [(int(a), int(b)) for a, b in edges if b - a + n - 1 >= min_n]


def _robust_spread(dev: np.ndarray) -> np.ndarray:
    """``1.4826 * median(|dev|)`` per column (finite rows): the normal's std (0 when empty)."""
    if len(dev) == 0:
        return np.zeros(dev.shape[1])
    return MAD_TO_STD * np.median(np.abs(dev), axis=0)


def resolution(gyro: np.ndarray) -> np.ndarray:
    """Each channel's smallest step between two values it takes (raw units, shape (C,)): the
    quantisation of an integer ADC, or of counts converted to units; 0 for a constant channel."""
    out = np.zeros(gyro.shape[1])
    for c in range(gyro.shape[1]):
        steps = np.diff(np.unique(gyro[np.isfinite(gyro[:, c]), c]))
        out[c] = steps.min() if len(steps) else 0.0
    return out


def mean_rate_statistic(means: np.ndarray, var: np.ndarray, sigma: np.ndarray,
                        still: np.ndarray, n: int, min_n: int,
                        q: np.ndarray | float = 0.0) -> np.ndarray | None:  # fmt: skip
    """``D_j`` of every window (module notes); None when no run of still windows votes.

    Parameters
    ----------
    means, var : ndarray, shape (W, C)
        Each window's mean and variance (ddof 1) of the gyro channels, raw units.
    sigma : ndarray, shape (C,)
        The gyro's noise per channel, raw units (``estimate_noise``).
    still : ndarray of bool, shape (W,)
        The windows the variance test calls still (one holding a non-finite sample never
        votes).
    n, min_n : int
        Window length and the fewest samples a still period keeps.
    q : ndarray, shape (C,), or float
        The channels' quantisation step (:func:`resolution`): with noise below a step the
        readings do not dither, and a window's mean is off its rate by up to ``q / 2`` however
        long the window (variance ``q^2 / 12``, not divided by ``n``).

    Returns
    -------
    ndarray, shape (W,), or None
        NaN where a window holds a non-finite sample.
    """
    # the variance of one window's mean: the noise's, and the rounding's that does not average
    noise2 = np.maximum(var, sigma * sigma) / n + np.square(q) / 12.0
    finite = np.isfinite(means).all(axis=1) & np.isfinite(noise2).all(axis=1)
    runs = _voting_runs(still & finite, n, min_n)
    if not runs:
        return None
    step = max(1, n // 4)  # windows closer than that share most samples: no news in the medians
    medians = np.array([np.median(means[a:b:step], axis=0) for a, b in runs])
    bias = np.median(medians, axis=0)
    within = np.concatenate([means[a:b:step] - medians[k] for k, (a, b) in enumerate(runs)])
    typical = np.median(np.concatenate([noise2[a:b:step] for a, b in runs]), axis=0)
    wander2 = np.maximum(_robust_spread(within) ** 2 - typical, 0.0)
    tau2 = _robust_spread(medians - bias) ** 2 + wander2
    with np.errstate(invalid="ignore"):
        return np.sum((means - bias) ** 2 / (noise2 + tau2), axis=1)


PASSES = 4
"""At most this many rounds of the split: each round's runs are the still windows left by the
last, so a turn that made up much of a run (and widened its scatter) no longer hides in it."""


def _ends_over(left: np.ndarray, D: np.ndarray, limit: float) -> np.ndarray:
    """The windows at either end of each run of ``left`` whose ``D`` exceeds ``limit``, up to
    the first one inward that does not (a run over it throughout is left alone)."""
    out = np.zeros(len(left), dtype=bool)
    m = np.concatenate([[False], left, [False]]).astype(np.int8)
    for a, b in np.flatnonzero(np.diff(m)).reshape(-1, 2):
        over = ~(D[a:b] <= limit)
        if over.all():
            continue
        out[a : a + int(np.argmin(over))] = True
        out[b - int(np.argmin(over[::-1])) : b] = True
    return out


def turning_windows(gyro: np.ndarray, var: np.ndarray, sigma: np.ndarray, still: np.ndarray,
                    n: int, min_n: int, alpha: float) -> np.ndarray:  # fmt: skip
    """The still windows whose mean rate is a turn's, not the bias (module notes).

    Two thresholds, as hysteresis: a still period is split where ``D`` exceeds
    :data:`RATE_TOLERANCE` times the chi-square bound (repeated on the windows left, at most
    :data:`PASSES` times, until nothing changes), then each period's ends are trimmed while
    ``D`` exceeds the bound itself (a turn's gentle start or end, where the rate grows out of
    the noise; a bump within a rest splits nothing).

    Parameters
    ----------
    gyro : ndarray, shape (N, C)
        Raw gyroscope channels.
    var : ndarray, shape (N - n + 1, C)
        Their window variances (``window_variance``).
    sigma : ndarray, shape (C,)
        Noise per channel, raw units.
    still : ndarray of bool, shape (N - n + 1,)
        The windows the variance test calls still.
    n, min_n : int
        Window length and the fewest samples a still period keeps.
    alpha : float
        Probability that a still window of white noise exceeds the bound.

    Returns
    -------
    ndarray of bool, shape (N - n + 1,)
        True where a window the variance calls still turns (never where it is not still).
    """
    means, q = window_means(gyro, n), resolution(gyro)
    bound = chdtri(gyro.shape[1], alpha)  # chi2.isf(alpha, C)
    left = still.copy()
    for k in range(PASSES + 1):
        D = mean_rate_statistic(means, var, sigma, left, n, min_n, q)
        if D is None:
            return still & ~left
        turning = left & ~(D <= RATE_TOLERANCE * bound)  # NaN: not still already
        if k == PASSES or not turning.any():
            break  # D is that of the windows left
        left &= ~turning
    left &= ~_ends_over(left, D, bound)
    return still & ~left
