"""Readings a sensor clipped: at the end of its range, or stuck at an extreme while it moved.

A clipped channel reads its largest (or smallest) value while the quantity it measures goes
further.  Two signs of it:

- the reading reaches the configured output range (``limits``);
- without a range: the channel sits exactly at its extreme over the whole recording for at
  least ``min_run`` consecutive readings while another channel of the same sensor changes by
  more than ``moving`` (the unit turned, yet the channel did not move: a flat top).  A still
  unit whose extreme happens to repeat is not flagged, since nothing else moves then.
"""

from __future__ import annotations

import numpy as np

__all__ = ["clipped_rows", "flat_top_levels"]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open ``[start, stop)`` of every run of True in a boolean array."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2], edges[1::2], strict=True))


def clipped_rows(
    raw: np.ndarray,
    limits: tuple[float, float] | None = None,
    *,
    min_run: int = 3,
    moving: float | None = None,
) -> np.ndarray:
    """Boolean mask of the readings (rows of ``raw``, (N, n)) that are clipped.

    Parameters
    ----------
    raw : ndarray, shape (N, n)
        Raw readings; rows with NaN are never flagged.
    limits : (low, high), optional
        Output range, raw units: a reading at or beyond it is clipped.
    min_run : int
        Consecutive readings at a channel's extreme that make a flat top.
    moving : float, optional
        Change of another channel during a flat top that proves motion, raw units; default
        5 % of that channel's span over the recording.
    """
    raw = np.asarray(raw, float)
    out = np.zeros(len(raw), bool)
    finite = np.isfinite(raw).all(axis=1)
    if not finite.any():
        return out
    if limits is not None:
        lo, hi = limits
        out |= ((raw <= lo) | (raw >= hi)).any(axis=1)
    data = raw[finite]
    rows = np.flatnonzero(finite)
    span = data.max(axis=0) - data.min(axis=0)
    for ch in range(raw.shape[1]):
        others = [c for c in range(raw.shape[1]) if c != ch]
        for extreme in (data[:, ch].max(), data[:, ch].min()):
            for start, stop in _runs(data[:, ch] == extreme):
                if stop - start < min_run:
                    continue
                block = data[start:stop][:, others]
                change = block.max(axis=0) - block.min(axis=0)
                need = 0.05 * span[others] if moving is None else np.full(len(others), moving)
                if np.any(change > need):
                    out[rows[start:stop]] = True
    return out


def flat_top_levels(raw: np.ndarray, moving: np.ndarray, still: np.ndarray, *,
                    min_run: int = 3, away: float = 50.0) -> tuple[np.ndarray, np.ndarray]:
    """Per channel, the levels at which it is clipped below and above (flat tops while the
    unit moves), whatever the converter's width.

    A channel is clipped at a level where, while the unit moves (``moving`` rows), it sits
    on its extreme over those rows for at least ``min_run`` consecutive readings, that
    extreme being more than ``away`` times its still noise (or its quantum, the smallest step
    it takes) from its still reading (``still`` rows): a turn's rate goes on changing at
    that distance, so a reading that does not is held by the part's range. Each sign is
    judged on its own (a turn one way clips the top only).

    Parameters
    ----------
    raw : ndarray, shape (N, n)
        Raw readings (NaN rows are ignored).
    moving, still : ndarray of bool, shape (N,)
        Rows the unit turns in, rows it is still in.
    min_run : int
        Consecutive readings at the extreme that make a flat top.
    away : float
        Least distance of a flat top from the still reading, in still noise (or quanta).

    Returns
    -------
    low, high : ndarray, shape (n,)
        The clipping levels, raw units; -inf / +inf where a channel shows none.
    """
    raw = np.asarray(raw, float)
    n = raw.shape[1]
    low, high = np.full(n, -np.inf), np.full(n, np.inf)
    finite = np.isfinite(raw).all(axis=1)
    moving, still = moving & finite, still & finite
    if moving.sum() < min_run or not still.any():
        return low, high
    for ch in range(n):
        x = raw[:, ch]
        centre, noise, quantum = _still_scale(x[still], x[finite])
        run = _chance_run(noise, quantum, min_run)
        for extreme, out in ((x[moving].max(), high), (x[moving].min(), low)):
            if abs(extreme - centre) <= away * max(noise, quantum, 1e-12):
                continue
            if any(b - a >= run for a, b in _runs(moving & (x == extreme))):
                out[ch] = extreme
    return low, high


#: A flat top is a run of equal readings that noise repeats by chance with less than this
#: probability (:func:`_chance_run`).
CHANCE_RUN = 1e-4


def _chance_run(noise: float, quantum: float, min_run: int) -> int:
    """Fewest consecutive equal readings that are not the noise repeating a reading by chance
    at a turn's peak (where the rate barely changes): two readings of Gaussian noise of
    ``noise`` rounded to ``quantum`` are equal with probability about
    ``quantum / (2 sqrt(pi) noise)``; the run must be that unlikely to within
    :data:`CHANCE_RUN` (a quiet 16-bit gyro at its peak repeats a count 3 times in a few
    turns in a hundred). Unquantised readings (``quantum`` 0) never repeat by chance."""
    if quantum <= 0:
        return min_run
    p = quantum / (2 * np.sqrt(np.pi) * max(noise, 1e-300))
    if p >= 0.9:
        p = 0.9  # quieter than its quantum: only long runs are flat tops
    return max(min_run, 1 + int(np.ceil(np.log(CHANCE_RUN) / np.log(p))))


def _still_scale(still: np.ndarray, everything: np.ndarray) -> tuple[float, float, float]:
    """A channel's still reading (median), its still noise (std from the MAD) and its
    quantum (the smallest step between distinct readings, 0 for readings that are not on a
    grid of that step)."""
    centre = float(np.median(still))
    noise = 1.4826 * float(np.median(np.abs(still - centre)))
    sample = everything[:: max(1, len(everything) // 20000)]
    values = np.unique(sample)
    steps = np.diff(values)
    quantum = float(steps.min()) if len(steps) else 0.0
    if quantum > 0:
        k = (values - values[0]) / quantum
        if np.max(np.abs(k - np.round(k))) > 1e-3:
            quantum = 0.0  # not on a grid of that step: not quantised
    return centre, noise, quantum
