"""The samples of static holds: one pooled noise estimate, and faults inside a hold.

A calibration weights each pose mean by its noise. Estimating that noise from each hold's own
few samples makes the weights random: the fit loses efficiency and its stated uncertainty
falls below the Cramér-Rao bound (issue 10.7). The sensor's white noise does not depend on the
pose, so it is estimated once, pooled over every hold (``sum (n_k - 1) C_k / sum (n_k - 1)``,
thousands of degrees of freedom), and each mean's covariance is ``Sigma / n_k``.

Faults inside a hold (issue 10.6) are found against that pooled noise:

* a **spike** (one or a few samples far from the rest: a knock, a bit error) by a robust
  z-score about the hold's median, and left out of the mean;
* **slow motion** (the unit tilting or sliding while "still") by the straight-line trend of
  the hold's samples over time, tested against the pooled noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import chdtri, ndtri

#: Family-wise false-alarm probability of the spike test over a whole session.
SPIKE_ALPHA = 1e-3
#: Family-wise false-alarm probability of the trend (slow-motion) test over a session.
TREND_ALPHA = 1e-3
#: A trend is only a fault when the hold moves by more than this many pooled noise sigmas of
#: one sample end to end: smaller drifts do not bias a mean measurably.
TREND_MIN_SIGMAS = 10.0


@dataclass(frozen=True)
class PooledNoise:
    """Per-sample noise of the holds, pooled.

    Attributes
    ----------
    cov : ndarray, shape (n, n)
        Per-sample covariance, raw units^2, floored at the quantisation variance ``q^2/12``.
    dof : int
        Degrees of freedom behind it (``sum (n_k - 1)``).
    quantum : float
        Smallest step seen in the raw values (0 for unquantised data), raw units.
    """

    cov: np.ndarray
    dof: int
    quantum: float


def quantum(values: np.ndarray) -> float:
    """The raw data's quantisation step: the smallest non-zero difference between sorted
    values of a channel (0 when the data look continuous)."""
    steps = []
    for col in np.atleast_2d(np.asarray(values, float).T):
        v = np.unique(col[np.isfinite(col)])
        if len(v) < 2:
            continue
        d = np.diff(v)
        d = d[d > 0]
        # Continuous data have differences spread over many magnitudes; quantised data have
        # every difference a multiple of one step.
        q = d.min()
        if np.allclose(d / q, np.round(d / q), atol=1e-3):
            steps.append(q)
    return float(min(steps)) if steps else 0.0


def record_quantum(raw: np.ndarray, rows: int = 20000) -> float:
    """The quantisation step of a whole record (:func:`quantum`) from at most about ``rows``
    rows spread over it: the moves sweep the codes that a quiet sensor's holds do not."""
    return quantum(raw[:: max(len(raw) // rows, 1)])


def medians_and_spread(blocks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Each hold's median and its median absolute deviation about that median, per channel
    (a hold with NaN gives NaN).

    Parameters
    ----------
    blocks : list of ndarray, each shape (n_k, n), n_k >= 1

    Returns
    -------
    median, mad : ndarray, shape (len(blocks), n)
    """
    n = blocks[0].shape[1] if blocks else 0
    median, mad = np.empty((len(blocks), n)), np.empty((len(blocks), n))
    for k, b in enumerate(blocks):
        median[k] = np.median(b, axis=0)
        mad[k] = np.median(np.abs(b - median[k]), axis=0)
    return median, mad


def pooled_noise(blocks: list[np.ndarray], step: float = 0.0,
                 means: list[np.ndarray] | None = None) -> PooledNoise:  # fmt: skip
    """Pool the sample covariance of several holds.

    Parameters
    ----------
    blocks : list of ndarray, each shape (n_k, n)
        Raw samples of each hold (spikes already removed).
    step : float
        Quantisation step of the raw data (see :func:`quantum`); the covariance diagonal is
        floored at ``step^2 / 12`` so a hold that never changed still has a finite weight.
    means : list of ndarray, optional
        Each block's ``mean(axis=0)``, when the caller has them.

    Returns
    -------
    PooledNoise
    """
    n = blocks[0].shape[1]
    scatter = np.zeros((n, n))
    dof = 0
    for k, b in enumerate(blocks):
        if len(b) < 2:
            continue
        d = b - (b.mean(axis=0) if means is None else means[k])
        scatter += d.T @ d
        dof += len(b) - 1
    cov = scatter / dof if dof > 0 else np.zeros((n, n))
    floor = step * step / 12.0
    if floor > 0:
        cov = cov + np.diag(np.maximum(floor - np.diag(cov), 0.0))
    if not np.all(np.diag(cov) > 0):
        # Not a single varying sample and no quantum: one part in 10^9 of the signal.
        scale = max(float(np.max([np.abs(b).max() for b in blocks])), 1.0)
        cov = cov + np.eye(n) * (1e-9 * scale) ** 2
    return PooledNoise(cov, dof, step)


def spike_mask(block: np.ndarray, sigma: np.ndarray, n_total: int,
               median: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """Samples of one hold that are spikes: further from the hold's median than the
    Bonferroni threshold of a Gaussian over all ``n_total`` samples of the session.

    Parameters
    ----------
    block : ndarray, shape (n_k, n)
    sigma : ndarray, shape (n,)
        Pooled per-sample noise per channel, raw units.
    n_total : int
        Samples tested in the whole session (sets the threshold).
    median : ndarray, shape (n,), optional
        The block's ``median(axis=0)``, when the caller has it.

    Returns
    -------
    ndarray of bool, shape (n_k,)
        True for a spike sample.
    """
    dev = np.abs(block - (np.median(block, axis=0) if median is None else median)) / sigma
    # The half sigma above the threshold: a hold sitting exactly on two codes is not a spike.
    return np.any(dev > _spike_z(n_total, block.shape[1]) + 0.5, axis=1)


@lru_cache(maxsize=8)
def _spike_z(n_total: int, n: int) -> float:
    """The spike threshold in sigmas: Bonferroni over the session's ``n_total`` samples of
    ``n`` channels, never below 5 sigma."""
    return max(float(ndtri(1.0 - SPIKE_ALPHA / (2.0 * max(n_total, 1) * n))), 5.0)


@dataclass(frozen=True)
class Trend:
    """Straight-line trend of a hold's samples over time.

    Attributes
    ----------
    change : ndarray, shape (n,)
        Fitted change from the first to the last sample, raw units.
    chi2 : float
        ``slope^T Cov(slope)^-1 slope`` against the pooled noise (chi^2 with n dof if still).
    moved : bool
        Significant (family-wise ``TREND_ALPHA`` over ``n_holds``) and larger than
        ``TREND_MIN_SIGMAS`` of one sample's noise.
    """

    change: np.ndarray
    chi2: float
    moved: bool


def trend_limit(n: int, n_holds: int) -> float:
    """The chi^2 (``n`` degrees of freedom) a hold's trend must exceed: family-wise
    :data:`TREND_ALPHA` over ``n_holds``."""
    return float(chdtri(n, TREND_ALPHA / max(n_holds, 1)))


def trend(time: np.ndarray, block: np.ndarray, cov: np.ndarray, n_holds: int, *,
          mean: np.ndarray | None = None, limit: float | None = None) -> Trend:  # fmt: skip
    """Test one hold for slow motion: a linear trend of its samples over time (``mean``: the
    block's ``mean(axis=0)``, ``limit``: :func:`trend_limit`, when the caller has them)."""
    return trends([time], [block], cov, n_holds, means=None if mean is None else [mean],
                  limit=limit)[0]  # fmt: skip


def trends(times: list[np.ndarray], blocks: list[np.ndarray], cov: np.ndarray, n_holds: int,
           *, means: list[np.ndarray] | None = None, limit: float | None = None) -> list[Trend]:
    """:func:`trend` of several holds, with one solve against ``cov`` for all of them.

    Parameters
    ----------
    times : list of ndarray, each shape (n_k,)
        Sample times of each hold, s.
    blocks : list of ndarray, each shape (n_k, n)
        Raw samples of each hold.
    cov : ndarray, shape (n, n)
        Pooled per-sample noise covariance, raw units^2.
    n_holds : int
        Holds tested in the session (sets the family-wise threshold).
    means : list of ndarray, each shape (n,), optional
        Each block's ``mean(axis=0)``, when the caller has them.
    limit : float, optional
        :func:`trend_limit`, when the caller has it.
    """
    n = cov.shape[0]
    limit = trend_limit(n, n_holds) if limit is None else limit
    slope = np.zeros((len(blocks), n))  # raw units per s; zero for a hold too short to tell
    stt, span = np.ones(len(blocks)), np.zeros(len(blocks))
    for k, (time, block) in enumerate(zip(times, blocks, strict=True)):
        t = np.asarray(time, float)
        if len(t) < 3 or t[-1] <= t[0]:
            continue
        tc = t - t.mean()
        stt[k] = float(tc @ tc)
        mean = block.mean(axis=0) if means is None else means[k]
        slope[k] = tc @ (block - mean) / stt[k]  # least-squares slope
        span[k] = t[-1] - t[0]
    change = slope * span[:, None]
    # slope^T (cov / stt)^-1 slope and the change's size in sample sigmas, every hold at once
    w_slope, w_change = np.split(np.linalg.solve(cov, np.concatenate([slope, change]).T).T, 2)
    chi2 = stt * np.einsum("ki,ki->k", slope, w_slope)
    size = np.sqrt(np.maximum(np.einsum("ki,ki->k", change, w_change), 0.0))
    return [Trend(change[k], float(chi2[k]), bool(chi2[k] > limit and size[k] > TREND_MIN_SIGMAS))
            for k in range(len(blocks))]  # fmt: skip
