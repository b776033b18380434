"""A recording's still periods found block by block, in constant memory (``imucal noise``).

The variance test of :func:`imucal_cli.design.segmentation.find_static` (``find_static`` below)
over a recording given block by block: the same windows, thresholds, merging and trims.
"""

from __future__ import annotations

import numpy as np

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
from imucal_cli.design.window_noise import NoiseEstimate
from imucal_cli.errors import InputError
from imucal_cli.numerics.blocks import check_all_given, check_not_more

__all__ = ["StaticStream"]


class StaticStream:
    """:func:`find_static` over a recording given block by block, in constant memory.

    The noise comes from :func:`estimate_noise` beforehand (of the whole recording when it
    fits in memory, else of evenly spread parts of it); then every ``window_s`` window is
    tested as :func:`find_static` tests it (the mean over a sensor's channels of the window
    variance over the noise variance, against the same thresholds) and the still samples are
    merged, trimmed and kept by the same rules.  Given the noise :func:`find_static` would
    estimate, the periods are those of ``find_static(..., mean_rate=False)`` (up to rounding: a
    window's channel variances are summed before their small negative rounding errors are cut
    at zero).  The mean-rate test of :func:`find_static` (a steady turn about the vertical) is
    not made: it needs the common bias of every still period, a pass over the whole recording.

    Parameters
    ----------
    n_samples : int
        Samples that will be given.
    noise : NoiseEstimate
        Noise per channel and the sample rate (``rate_hz``) that sets the window and margins.
    accel, gyro : bool
        Which sensors :meth:`add` gets.
    min_still_s, window_s, alpha, margin_s
        As :func:`find_static`.
    """

    def __init__(
        self, n_samples: int, noise: NoiseEstimate, *, accel: bool = True, gyro: bool = True,
        min_still_s: float = 1.0, window_s: float = 0.5, alpha: float = DEFAULT_ALPHA,
        margin_s: float | None = None,
    ) -> None:  # fmt: skip
        rate = noise.rate_hz
        self.N = int(n_samples)
        self.n = window_samples(window_s, rate)
        self.margin, self.min_n = trim(rate, window_s, margin_s, min_still_s)
        self.groups = []  # (weights per channel, threshold) per sensor given
        for given, sigma, tolerance in ((accel, noise.accel, HOLD_TOLERANCE),
                                        (gyro, noise.gyro, GYRO_TOLERANCE)):  # fmt: skip
            if not given:
                continue
            if sigma is None:
                raise InputError("the noise estimate lacks a sensor that is given")
            sigma = np.asarray(sigma, dtype=np.float64)
            limit = tolerance * still_threshold(self.n, len(sigma), alpha)
            # mean_c var_c / sigma_c^2 = sum_c w_c (S2_c - S1_c^2 / n), w_c as below.
            weights = 1.0 / (len(sigma) * (self.n - 1) * sigma * sigma)
            self.groups.append((weights, limit))
        if not self.groups:
            raise InputError("segmentation needs accel or gyro data")
        self._centre: list[np.ndarray] | None = None
        self._carry: list[np.ndarray] = []  # per sensor, the last n - 1 samples given
        self._seen = 0
        self._runs: list[list[int]] = []  # still samples so far: [start, stop) in order

    def add(self, *blocks: np.ndarray) -> None:
        """The next samples of each sensor given (accel first), each shape (k, channels)."""
        if len(blocks) != len(self.groups):
            raise InputError(f"expected {len(self.groups)} sensors, got {len(blocks)}")
        k = len(blocks[0])
        if any(len(b) != k for b in blocks):
            raise InputError("the sensors' blocks differ in length")
        check_not_more(self._seen, k, self.N)
        if k == 0:
            return
        if self._centre is None:  # any constant; a typical value keeps the sums small
            self._centre = [np.nan_to_num(np.median(b[:: max(1, k // 1024)], axis=0))
                            for b in blocks]  # fmt: skip
            self._carry = [np.zeros((0, b.shape[1])) for b in blocks]
        first = self._seen - len(self._carry[0])  # sample index of the first row of x below
        self._seen += k
        xs = [np.concatenate([carry, block]) for carry, block in zip(self._carry, blocks,
                                                                       strict=True)]  # fmt: skip
        self._carry = [x[-(self.n - 1) :].copy() for x in xs]  # windows ending in the next block
        if len(xs[0]) < self.n:
            return
        still = None
        for (weights, limit), x, centre in zip(self.groups, xs, self._centre, strict=True):
            x -= centre
            if self._surely_still(x, weights, limit):
                continue
            ok = self._window_statistic(x, weights) <= limit  # NaN: not still
            still = ok if still is None else still & ok
        if still is None:  # every window of this block is still
            runs = [(0, len(x) - self.n + 1)]
        else:
            runs = still_runs(still)
        for a, b in runs:  # still window starts -> the samples they cover
            a, b = first + int(a), first + int(b) - 1 + self.n
            if self._runs and a <= self._runs[-1][1]:
                self._runs[-1][1] = max(self._runs[-1][1], b)
            else:
                self._runs.append([a, b])

    def _surely_still(self, x: np.ndarray, weights: np.ndarray, limit: float) -> bool:
        """True when every window of ``x`` is still, by a bound that costs a fraction of the
        windows themselves: a window lies inside a pair of consecutive n-sample chunks, and its
        sum of squared deviations from its own mean is at most the pair's from the pair's mean,
        so the pair's statistic bounds the window's."""
        n = self.n
        chunks = len(x) // n
        if chunks < 2:
            return False
        head = x[: chunks * n].reshape(chunks, n, x.shape[1])
        ones = np.ones(n)
        s1 = ones @ head  # chunk sums (a matrix product: numpy's fastest loop here)
        s2 = ones @ (head * head)
        # Pairs of chunks (b, b + 1) hold the windows starting in chunk b; the last chunk's
        # windows lie in [(chunks - 1) n, len(x)).
        tail = x[(chunks - 1) * n :]
        p1 = np.vstack([s1[:-1] + s1[1:], tail.sum(axis=0)])
        p2 = np.vstack([s2[:-1] + s2[1:], (tail * tail).sum(axis=0)])
        counts = np.full((chunks, 1), 2.0 * n)
        counts[-1] = len(tail)
        with np.errstate(invalid="ignore", over="ignore"):
            bound = (p2 - p1 * p1 / counts) @ weights
        return bool(np.all(bound <= limit))  # NaN (a non-finite sample): not sure

    def _window_statistic(self, x: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """For every window of ``x`` (rows, centred): the mean over channels of the window
        variance over the noise variance (the statistic :func:`find_static` thresholds); NaN
        for a window holding a non-finite sample."""
        n = self.n
        xt = np.ascontiguousarray(x.T)
        bad = ~np.isfinite(xt).all(axis=0)
        if bad.any():
            xt[:, bad] = 0.0
        s1 = np.zeros((xt.shape[0], xt.shape[1] + 1))
        np.cumsum(xt, axis=1, out=s1[:, 1:])
        q = np.zeros(xt.shape[1] + 1)
        np.cumsum(weights @ (xt * xt), out=q[1:])
        sum1 = s1[:, n:] - s1[:, :-n]
        stat = q[n:] - q[:-n] - weights @ (sum1 * sum1) / n
        if bad.any():
            count = np.concatenate([[0], np.cumsum(bad)])
            stat[(count[n:] - count[:-n]) > 0] = np.nan
        return stat

    def intervals(self) -> list[Interval]:
        """The still periods, as :func:`find_static` returns them.

        Raises
        ------
        InputError
            Fewer samples were given than announced.
        """
        check_all_given(self._seen, self.N)
        runs = [(a, min(b, self.N)) for a, b in self._runs]
        return still_periods(runs, self.N, self.n, self.margin, self.min_n)
