"""Online stillness detection and rotation extent, for a person at the bench.

Pure numerics: blocks of samples in, small dataclasses out.  No thresholds are guessed: the
noise is learned from the stream itself and the still/moving decision is a chi-square test of a
window variance at a stated false-alarm probability.

Model
-----
While the unit is still, each raw channel ``c`` (the accel channels, then the gyro channels) is
a constant plus white noise of standard deviation ``sigma_c``.  For the sample variance
``s_c^2`` of an ``n``-sample window, ``(n - 1) s_c^2 / sigma_c^2 ~ chi2(n - 1)``; over the
``C`` channels

    T = sum_c (n - 1) s_c^2 / sigma_c^2 ~ chi2(C (n - 1)).

A window is *moving* when ``T > chi2.ppf(1 - alpha, C (n - 1))``: a window of pure noise is
called moving with probability ``alpha`` (default 1e-4).  The statistic is reported as
``level = sqrt(T / (C (n - 1)))``, the RMS of the window's deviations in units of the noise:
about 1 when still; the threshold on ``level`` is ``sqrt(chi2.ppf(1 - alpha, dof) / dof)``
(1.27 for 25-sample windows of 6 channels).

Noise
-----
``sigma_c`` is learned from the data: the stream is cut into non-overlapping ``n``-sample
windows; a first estimate of ``sigma_c^2`` is a low quantile ``q`` (default 0.1) of their
variances divided by the same quantile of the ``chi2(n - 1) / (n - 1)`` distribution (right
if at least a fraction ``q`` of the windows seen so far were still; biased up by the moving
ones), then, twice, the mean variance of the windows that the test above calls still with
that estimate (unbiased up to the truncation at ``alpha``).  It is floored at the
quantisation variance ``step^2 / 12`` (``step``: the smallest non-zero change seen on the
channel), so integer data whose noise is below one count does not make every count flip a
motion.

Rotations
---------
:func:`motion_span` finds the samples of a turn between two still periods from the gyro: a
sample is in motion when ``z^2 = sum_c ((g_c - rest_c) / sigma_c)^2`` exceeds the
``1 - alpha`` quantile of ``chi2(C)`` (``k`` sigma with ``k = sqrt(chi2.isf(alpha, C))``,
4.6 for 3 channels); the span is the strongest cluster of such samples, extended outward
while ``z^2`` stays above its 0.9 quantile (2.5 sigma for 3 channels), i.e. down to where the
rate disappears in the noise.  :func:`integrate_rate` integrates the bias-free rate over the
span and :func:`rate_to_deg_s` converts raw gyro units to degrees.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri, gammaincinv

__all__ = [
    "DEFAULT_ALPHA",
    "StillState",
    "StillnessDetector",
    "integrate_rate",
    "motion_span",
    "rate_to_deg_s",
    "still_level_threshold",
]

DEFAULT_ALPHA = 1e-4
"""Probability that a window of pure sensor noise is called moving."""


def still_level_threshold(n: int, channels: int, alpha: float = DEFAULT_ALPHA) -> float:
    """Threshold on ``level`` (window RMS in noise units) for an ``n``-sample window.

    Parameters
    ----------
    n : int
        Samples per window (>= 2).
    channels : int
        Channels tested together (accel and gyro).
    alpha : float
        False-alarm probability of one window of pure noise.

    Returns
    -------
    float
        ``sqrt(chi2.ppf(1 - alpha, dof) / dof)`` with ``dof = channels * (n - 1)``.
    """
    dof = channels * (n - 1)
    return float(np.sqrt(chdtri(dof, alpha) / dof))


@dataclass(frozen=True)
class StillState:
    """The detector's verdict after one :meth:`StillnessDetector.update`.

    Attributes
    ----------
    still : bool
        The latest window is still (False until the noise is known).
    still_for_s : float
        Time from the start of the current still run to the latest sample, s (0 when moving).
    level : float
        The latest window's RMS deviation in units of the noise (about 1 when still; NaN
        until the noise is known).
    noise_ready : bool
        The noise has been learned (enough windows seen).
    still_start : int or None
        Index (counted from the first sample given to the detector) of the first sample of the
        current still run; None when moving.  Conservative: the end of the last moving window.
    moved : bool
        Some window evaluated during this update was moving.
    ended_runs : tuple of (int, int)
        Still runs that ended during this update, half-open sample ranges ``[start, stop)``;
        ``stop`` is the start of the first moving window (conservative).
    threshold : float
        Threshold on ``level`` (NaN until the noise is known).
    n_samples : int
        Samples seen so far.
    """

    still: bool
    still_for_s: float
    level: float
    noise_ready: bool
    still_start: int | None = None
    moved: bool = False
    ended_runs: tuple[tuple[int, int], ...] = ()
    threshold: float = float("nan")
    n_samples: int = 0


@dataclass
class _Buffer:
    """The last samples (time and stacked channels) with the index of the first one."""

    first: int = 0
    time: np.ndarray = field(default_factory=lambda: np.empty(0))
    x: np.ndarray | None = None

    def append(self, time: np.ndarray, x: np.ndarray) -> None:
        self.time = np.concatenate([self.time, time])
        self.x = x if self.x is None else np.concatenate([self.x, x])

    def keep_from(self, index: int) -> None:
        drop = max(0, min(index - self.first, len(self.time)))
        if drop:
            self.time = self.time[drop:]
            self.x = self.x[drop:]
            self.first += drop

    @property
    def end(self) -> int:
        return self.first + len(self.time)


class StillnessDetector:
    """Online still/moving detector with thresholds from the measured noise.

    Feed every block of the stream, in order, to :meth:`update`.  Sample indices in the
    returned :class:`StillState` count the samples given to the detector, starting at 0.

    Parameters
    ----------
    window_s : float
        Window length, s (converted to samples from the observed sample rate).
    alpha : float
        False-alarm probability of one window of pure noise (see module docstring).
    noise_quantile : float
        Quantile ``q`` of the window variances read as the noise: at least this fraction of
        the windows seen must be still.
    min_noise_windows : int
        Windows needed before the noise is trusted (``noise_ready``).
    min_window : int
        Smallest window, samples.
    max_history : int
        Noise windows remembered (the oldest are forgotten).
    noise_std : dict, optional
        Known noise, ``{"accel": (na,), "gyro": (ng,)}`` raw units per sample: skips learning.
    """

    def __init__(
        self,
        window_s: float = 0.25,
        alpha: float = DEFAULT_ALPHA,
        *,
        noise_quantile: float = 0.1,
        min_noise_windows: int = 8,
        min_window: int = 8,
        max_history: int = 4000,
        noise_std: dict[str, np.ndarray] | None = None,
    ) -> None:
        if not window_s > 0:
            raise ValueError(f"window_s must be > 0, got {window_s!r}")
        if not 0 < alpha < 1:
            raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
        if not 0 < noise_quantile < 1:
            raise ValueError(f"noise_quantile must be in (0, 1), got {noise_quantile!r}")
        self.window_s = float(window_s)
        self.alpha = float(alpha)
        self.noise_quantile = float(noise_quantile)
        self.min_noise_windows = int(min_noise_windows)
        self.min_window = max(2, int(min_window))
        self._known = noise_std
        self._history: deque[np.ndarray] = deque(maxlen=int(max_history))
        self._widths: tuple[int, int] | None = None  # (na, ng)
        self._n: int | None = None  # window, samples
        self._stride = 1
        self._buf = _Buffer()
        self._chunk: list[np.ndarray] = []
        self._chunk_len = 0
        self._step: np.ndarray | None = None
        self._last_row: np.ndarray | None = None
        self._var: np.ndarray | None = None
        self._threshold = float("nan")
        self._t_crit = float("nan")
        self._next_eval = 0
        self._run_start: int | None = None
        self._run_start_time = 0.0
        self._last_moving_end: int | None = None
        self._level = float("nan")
        self._still = False
        self._seen_time: list[float] = []

    # properties ------------------------------------------------------------------------
    @property
    def window(self) -> int | None:
        """Window length in samples (None until the sample rate is known)."""
        return self._n

    @property
    def threshold(self) -> float:
        """Threshold on ``level`` (NaN until the noise is known)."""
        return self._threshold

    @property
    def noise_ready(self) -> bool:
        """True once the noise is known."""
        return self._var is not None

    def noise_std(self) -> dict[str, np.ndarray | None]:
        """Learned noise per sample, raw units: ``{"accel": (na,) or None, "gyro": ...}``."""
        if self._var is None or self._widths is None:
            return {"accel": None, "gyro": None}
        sd = np.sqrt(self._var)
        na, ng = self._widths
        return {"accel": sd[:na] if na else None, "gyro": sd[na:] if ng else None}

    # update ----------------------------------------------------------------------------
    def update(
        self,
        block_time: np.ndarray,
        block_accel: np.ndarray | None,
        block_gyro: np.ndarray | None = None,
    ) -> StillState:
        """Add one block of samples and return the verdict.

        Parameters
        ----------
        block_time : ndarray, shape (k,)
            Sample times, s, increasing.  ``k`` may be 0.
        block_accel, block_gyro : ndarray, shape (k, na) / (k, ng), or None
            Raw samples.  The same sensors must be present in every non-empty block.

        Returns
        -------
        StillState
        """
        t = np.asarray(block_time, dtype=float).reshape(-1)
        k = len(t)
        if k == 0:
            return self._state(False, ())
        parts = []
        widths = []
        for arr in (block_accel, block_gyro):
            if arr is None:
                widths.append(0)
                continue
            a = np.asarray(arr, dtype=float).reshape(k, -1)
            parts.append(a)
            widths.append(a.shape[1])
        if not parts:
            raise ValueError("a block needs accel or gyro samples")
        x = np.concatenate(parts, axis=1)
        if self._widths is None:
            self._widths = (widths[0], widths[1])
            self._learn_known()
        elif tuple(widths) != self._widths:
            raise ValueError(f"block channels {tuple(widths)} differ from {self._widths}")
        self._track_step(x)
        self._buf.append(t, x)
        if self._n is None:
            self._seen_time.extend(t[:64].tolist())
            if len(self._seen_time) >= 3:
                dt = float(np.median(np.diff(self._seen_time)))
                n = int(round(self.window_s / dt)) if dt > 0 else self.min_window
                self._n = max(self.min_window, n)
                self._stride = max(1, self._n // 4)
                self._next_eval = self._n
                if self._var is not None:
                    self._set_threshold()
        if self._n is None:
            return self._state(False, ())
        self._learn(x)
        moved = False
        ended: list[tuple[int, int]] = []
        if self._var is not None:
            moved, ended = self._evaluate()
        self._buf.keep_from(min(self._buf.end, self._next_eval) - self._n)
        return self._state(moved, tuple(ended))

    # internals -------------------------------------------------------------------------
    def _learn_known(self) -> None:
        if self._known is None:
            return
        na, ng = self._widths
        parts = []
        for name, w in (("accel", na), ("gyro", ng)):
            if w:
                sd = self._known.get(name)
                if sd is None:
                    raise ValueError(f"noise_std has no {name!r} entry")
                parts.append(np.broadcast_to(np.asarray(sd, float), (w,)) ** 2)
        self._var = np.concatenate(parts)

    def _track_step(self, x: np.ndarray) -> None:
        rows = x if self._last_row is None else np.vstack([self._last_row, x])
        self._last_row = x[-1:].copy()
        d = np.abs(np.diff(rows, axis=0))
        d = np.where(d > 0, d, np.inf)
        step = d.min(axis=0) if len(d) else np.full(x.shape[1], np.inf)
        self._step = step if self._step is None else np.minimum(self._step, step)

    def _learn(self, x: np.ndarray) -> None:
        if self._known is not None:
            return
        self._chunk.append(x)
        self._chunk_len += len(x)
        n = self._n
        if self._chunk_len < n:
            return
        rows = np.concatenate(self._chunk)
        m = len(rows) // n
        for i in range(m):
            self._history.append(rows[i * n : (i + 1) * n].var(axis=0, ddof=1))
        rest = rows[m * n :]
        self._chunk = [rest] if len(rest) else []
        self._chunk_len = len(rest)
        if len(self._history) >= self.min_noise_windows:
            q = self.noise_quantile
            h = np.array(self._history)
            step = np.where(np.isfinite(self._step), self._step, 0.0)
            floor = np.maximum(step**2 / 12.0, 1e-24)
            chi2_q = 2 * gammaincinv((n - 1) / 2, q)  # chi^2(n - 1)'s q quantile
            v = np.maximum(np.quantile(h, q, axis=0) / (chi2_q / (n - 1)), floor)
            # The quantile is biased up by the moving windows among those seen; refine with
            # the mean variance of the windows the test calls still (truncated at alpha).
            crit = chdtri(h.shape[1] * (n - 1), self.alpha) / (n - 1)
            for _ in range(2):
                still = np.sum(h / v, axis=1) <= crit
                if still.sum() < self.min_noise_windows:
                    break
                v = np.maximum(h[still].mean(axis=0), floor)
            first = self._var is None
            self._var = v
            if first:
                self._set_threshold()

    def _set_threshold(self) -> None:
        channels = len(self._var)
        dof = channels * (self._n - 1)
        self._t_crit = float(chdtri(dof, self.alpha))
        self._threshold = float(np.sqrt(self._t_crit / dof))

    def _evaluate(self) -> tuple[bool, list[tuple[int, int]]]:
        n = self._n
        end = self._buf.end
        moved = False
        ended: list[tuple[int, int]] = []
        if self._next_eval < max(n, self._buf.first + n):
            self._next_eval = max(n, self._buf.first + n)
        # windows end on a fixed grid, whatever the blocks: the false-alarm rate is ``alpha``
        # per grid window (judging every block's last sample too tested up to ``stride``
        # times more windows when blocks are small, a sample each on a host that keeps up)
        points = list(range(self._next_eval, end + 1, self._stride))
        dof = len(self._var) * (n - 1)
        for p in points:
            i0 = p - n - self._buf.first
            w = self._buf.x[i0 : i0 + n]
            T = float(np.sum((n - 1) * w.var(axis=0, ddof=1) / self._var))
            self._level = float(np.sqrt(T / dof))
            if T > self._t_crit:
                moved = True
                if self._run_start is not None and p - n > self._run_start:
                    ended.append((self._run_start, p - n))
                self._run_start = None
                self._last_moving_end = p
                self._still = False
            else:
                if self._run_start is None:
                    start = p - n if self._last_moving_end is None else self._last_moving_end
                    start = max(start, p - n)
                    self._run_start = start
                    self._run_start_time = float(self._buf.time[start - self._buf.first])
                self._still = True
        if points:
            self._next_eval = points[-1] + self._stride
        if end >= n and (not points or points[-1] != end):  # the newest level, shown only
            w = self._buf.x[end - n - self._buf.first : end - self._buf.first]
            self._level = float(np.sqrt(np.sum((n - 1) * w.var(axis=0, ddof=1) / self._var) / dof))
        return moved, ended

    def _state(self, moved: bool, ended: tuple[tuple[int, int], ...]) -> StillState:
        ready = self._var is not None and self._n is not None
        still = bool(ready and self._still and self._run_start is not None)
        t_last = float(self._buf.time[-1]) if len(self._buf.time) else 0.0
        return StillState(
            still=still,
            still_for_s=max(0.0, t_last - self._run_start_time) if still else 0.0,
            level=self._level if ready else float("nan"),
            noise_ready=ready,
            still_start=self._run_start if still else None,
            moved=moved,
            ended_runs=ended,
            threshold=self._threshold if ready else float("nan"),
            n_samples=self._buf.end,
        )


def motion_span(
    rate: np.ndarray,
    rest: np.ndarray,
    noise_std: np.ndarray,
    *,
    alpha: float = DEFAULT_ALPHA,
    extend_quantile: float = 0.9,
    merge_gap: int = 10,
) -> tuple[int, int] | None:
    """The samples of one turn in a stretch of gyro data that is still before and after.

    Parameters
    ----------
    rate : ndarray, shape (N, ng)
        Raw gyro samples.
    rest : ndarray, shape (ng,)
        The gyro reading while still (its bias), raw units, e.g. the mean of the still period
        before the turn.
    noise_std : ndarray, shape (ng,)
        Noise per sample while still, raw units.
    alpha : float
        Probability that a still sample is called moving (threshold ``chi2.isf(alpha, ng)``
        on ``z^2``).
    extend_quantile : float
        The span is extended outward while ``z^2`` exceeds this quantile of ``chi2(ng)``.
    merge_gap : int
        Clusters of moving samples closer than this many samples are one turn.

    Returns
    -------
    (start, stop) or None
        Half-open sample range of the turn (the strongest cluster), or None when no sample
        is moving.
    """
    g = np.asarray(rate, dtype=float)
    if g.ndim != 2 or len(g) == 0:
        return None
    sd = np.maximum(np.asarray(noise_std, dtype=float), 1e-300)
    z2 = np.sum(((g - np.asarray(rest, float)) / sd) ** 2, axis=1)
    c = g.shape[1]
    high = chdtri(c, alpha)
    low = 2 * gammaincinv(c / 2, extend_quantile)
    idx = np.flatnonzero(z2 > high)
    if len(idx) == 0:
        return None
    breaks = np.flatnonzero(np.diff(idx) > merge_gap)
    starts = np.concatenate([[0], breaks + 1])
    stops = np.concatenate([breaks + 1, [len(idx)]])
    best = max(zip(starts, stops, strict=True), key=lambda ab: float(z2[idx[ab[0] : ab[1]]].sum()))
    a, b = int(idx[best[0]]), int(idx[best[1] - 1]) + 1
    while a > 0 and z2[a - 1] > low:
        a -= 1
    while b < len(z2) and z2[b] > low:
        b += 1
    return a, b


def integrate_rate(
    time: np.ndarray, rate: np.ndarray, rest: np.ndarray, start: int, stop: int
) -> np.ndarray:
    """Integral of the bias-free rate over samples ``[start, stop)``, raw units times s.

    The trapezoid rule runs from the sample before ``start`` to the sample at ``stop`` (the
    still neighbours, where available), so a turn that fills the span is integrated whole.
    For a turn about a fixed axis the result is ``axis * angle`` in raw units times seconds
    (convert with :func:`rate_to_deg_s`).

    Parameters
    ----------
    time : ndarray, shape (N,)
    rate : ndarray, shape (N, ng)
        Raw gyro samples.
    rest : ndarray, shape (ng,)
        Still reading (bias), raw units.
    start, stop : int
        Half-open sample range.

    Returns
    -------
    ndarray, shape (ng,)
    """
    t = np.asarray(time, dtype=float)
    g = np.asarray(rate, dtype=float) - np.asarray(rest, float)
    a, b = max(0, start - 1), min(len(t), stop + 1)
    if b - a < 2:
        return np.zeros(g.shape[1])
    dt = np.diff(t[a:b])[:, None]
    return np.sum(0.5 * (g[a : b - 1] + g[a + 1 : b]) * dt, axis=0)


def rate_to_deg_s(units: str | None, scale: float | None = None) -> float | None:
    """Factor that turns raw gyro units into deg/s, or None when unknown.

    Parameters
    ----------
    units : str or None
        ``rad/s``, ``deg/s``, ``counts``, ``V`` or None.
    scale : float, optional
        Raw units per rad/s (a datasheet sensitivity, e.g. 939.7 counts per rad/s for 16.4
        LSB per deg/s); used for ``counts`` and ``V`` (and overrides the others).

    Returns
    -------
    float or None
    """
    if scale is not None:
        return float(np.degrees(1.0 / float(scale)))
    if units == "rad/s":
        return float(np.degrees(1.0))
    if units == "deg/s":
        return 1.0
    return None
