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

import numpy as np

from imucal_cli.solvers.quantiles import chdtri, ndtri

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
        v = _distinct(col[np.isfinite(col)])
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


def _distinct(v: np.ndarray) -> np.ndarray:
    """``np.unique(v)``: for whole numbers over a moderate range (counts) by counting them,
    a pass instead of a sort."""
    if len(v) > 64:
        lo, hi = v.min(), v.max()
        if hi - lo < 4 * len(v) + 1024 and np.array_equal(v, np.round(v)):
            counts = np.bincount((v - lo).astype(np.int64))
            return np.flatnonzero(counts) + lo
    return np.unique(v)


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
    z_max = float(ndtri(1.0 - SPIKE_ALPHA / (2.0 * max(n_total, 1) * block.shape[1])))
    # Never below 5 sigma, and a little above the quantisation so a hold sitting exactly on
    # two codes is not a spike.
    z_max = max(z_max, 5.0)
    dev = np.abs(block - (np.median(block, axis=0) if median is None else median)) / sigma
    return np.any(dev > z_max + 0.5, axis=1)


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
    n = block.shape[1]
    t = np.asarray(time, float)
    if len(t) < 3 or t[-1] <= t[0]:
        return Trend(np.zeros(n), 0.0, False)
    tc = t - t.mean()
    stt = float(tc @ tc)
    slope = tc @ (block - (block.mean(axis=0) if mean is None else mean)) / stt  # per s
    chi2 = float(slope @ np.linalg.solve(cov / stt, slope))
    change = slope * (t[-1] - t[0])
    limit = trend_limit(n, n_holds) if limit is None else limit
    size = float(np.sqrt(change @ np.linalg.solve(cov, change)))
    return Trend(change, chi2, chi2 > limit and size > TREND_MIN_SIGMAS)
