"""Where a turn really starts and stops: the still periods' edges that already move (issue 24.5).

A turn between two still periods integrates to the rotation between them only over all of
its motion (Qureshi & Golnaraghi eq. 16: ``Delta theta = integral omega dt`` from rest to
rest). Segments cut by a live capture or an import's stillness test often start the still
period after the turn a few samples before the unit has settled, or end the one before it a
few samples after it has begun to turn (a smooth hand turn starts slowly: its first tenth of a
second is within a window variance test's noise). Those samples then belong to neither the
turn (its integral misses them: a 360-degree turn read as 359) nor, correctly, to the still
period (its gravity direction and gyro mean move with them).

:func:`settled_bounds` finds, at each end of a still period, the samples whose gyro reading
departs from the period's own middle by more than :data:`MOTION_SIGMAS` times the pooled per-
sample noise on any axis (or whose :data:`SMOOTH`-sample mean departs by that many of its own
std: a smooth turn's first and last tenth of a second), walking inward while such samples
follow each other within :data:`SETTLE_RUN` samples; the still period keeps the rest (at least
half of itself) and the turn next to it is integrated from there. Samples of a resting unit
cross the threshold with a probability of about 1e-4 per sample (three axes), and a stray one
at an edge moves the edge by a few samples at most: the turn then integrates a little more rest
(zero rate, its bias removed), which changes nothing but its noise.
"""

from __future__ import annotations

import numpy as np

#: A gyro sample departing from its still period's middle by more than this many per-sample
#: noise std on some axis is motion (normal tail per axis about 6e-5).
MOTION_SIGMAS = 4.0
#: Motion samples closer than this many samples to each other belong to one movement.
SETTLE_RUN = 5
#: Samples averaged by the test for slow motion.
SMOOTH = 8
#: A still period keeps at least this share of its samples (the rest is a movement through
#: it, which the still-period checks report).
KEEP_SHARE = 0.5


def still_noise(gyro: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Per-axis per-sample gyro noise pooled over the middle halves of the still periods
    (their edges may move), raw units (3,); at least half the smallest step between readings
    (quantised data whose noise rounds to one code)."""
    var, dof, steps = np.zeros(gyro.shape[1]), 0, []
    for a, b in zip(start.tolist(), stop.tolist(), strict=True):
        q = (b - a) // 4
        z = gyro[a + q : b - q]
        if len(z) < 2:
            continue
        var += ((z - z.mean(axis=0)) ** 2).sum(axis=0)
        dof += len(z) - 1
        d = np.abs(np.diff(z, axis=0))
        d = d[d > 0]
        if len(d):
            steps.append(float(d.min()))
    sigma = np.sqrt(var / max(dof, 1))
    floor = 0.5 * min(steps) if steps else 0.0
    return np.maximum(sigma, floor)


def _moving(z: np.ndarray, middle: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Samples that move: beyond :data:`MOTION_SIGMAS` std on some axis, alone or as the mean
    of the :data:`SMOOTH` samples centred on them (a slow start or end of a turn, whose rate
    stays within one sample's noise for a tenth of a second, rotates the unit all the same)."""
    limit = MOTION_SIGMAS * np.where(sigma > 0, sigma, np.inf)
    d = z - middle
    moving = np.any(np.abs(d) > limit, axis=1)
    if len(d) >= SMOOTH:
        c = np.cumsum(np.r_[np.zeros((1, d.shape[1])), d], axis=0)
        mean = (c[SMOOTH:] - c[:-SMOOTH]) / SMOOTH  # window starting at each sample
        slow = np.any(np.abs(mean) > limit / np.sqrt(SMOOTH), axis=1)
        h = SMOOTH // 2
        moving[h : h + len(slow)] |= slow
    return moving


def settled_bounds(gyro: np.ndarray, start: int, stop: int, sigma: np.ndarray,
                   *, trim_start: bool = True, trim_stop: bool = True) -> tuple[int, int]:
    """The still part ``[start', stop')`` of a still period ``gyro[start:stop]``: its edges
    that already move (see the module notes) cut off.

    Parameters
    ----------
    gyro : ndarray (N, 3)
        Raw gyro samples of the session.
    start, stop : int
        The still period's rows.
    sigma : ndarray (3,)
        Per-sample noise per axis (:func:`still_noise`), raw units.
    trim_start, trim_stop : bool
        Which edges may be cut (an edge next to a turn).
    """
    n = stop - start
    if n < 4 or not np.all(np.isfinite(sigma)):
        return start, stop
    z = gyro[start:stop]
    q = n // 4
    middle = z[q : n - q].mean(axis=0)  # the middle half rests
    moving = _moving(z, middle, sigma)
    if not moving.any():
        return start, stop
    keep = max(int(np.ceil(KEEP_SHARE * n)), 2)
    lo, hi = 0, n
    if trim_stop:
        hi = _walk(moving[::-1], n - keep)
        hi = n - hi
    if trim_start:
        lo = _walk(moving, max(hi - keep, 0))
    return start + lo, start + hi


def _walk(moving: np.ndarray, limit: int) -> int:
    """How many leading samples belong to a movement: from the first sample, the last motion
    sample reached through gaps shorter than :data:`SETTLE_RUN`, plus one (at most ``limit``)."""
    idx = np.flatnonzero(moving[: limit + SETTLE_RUN])
    if not len(idx) or idx[0] >= SETTLE_RUN:
        return 0
    gaps = np.flatnonzero(np.diff(idx) > SETTLE_RUN)
    last = idx[gaps[0]] if len(gaps) else idx[-1]
    return int(min(last + 1, limit))
