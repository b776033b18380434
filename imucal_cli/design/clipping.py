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

__all__ = ["clipped_rows"]


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
