"""Gaps in a recording's sample times: steps far longer than the sampling interval (samples
lost in transit, a logger that paused).  A turn with a gap cannot be integrated across it: the
rotation during the missing samples is unknown (issue 26: a 2 s gap inside a turn was not
reported, and calibrate blamed a moved or clipped turn)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GAP_FACTOR", "Gap", "find_gaps", "gaps_within"]

GAP_FACTOR = 5.0
"""A step over this many median sampling intervals is a gap (jitter of a host-stamped serial
stream stays well below it; one lost sample is a step of 2, four lost in a row of 5)."""


@dataclass(frozen=True)
class Gap:
    """One gap: the samples ``index`` and ``index + 1`` are ``length_s`` apart.

    Attributes
    ----------
    index : int
        The sample before the gap.
    time_s : float
        Its time, s.
    length_s : float
        The step, s (the median step is what a sample interval should be).
    """

    index: int
    time_s: float
    length_s: float


def find_gaps(time: np.ndarray, factor: float = GAP_FACTOR) -> list[Gap]:
    """Steps of ``time`` (s, increasing, shape (N,)) longer than ``factor`` median steps."""
    time = np.asarray(time, np.float64)
    if len(time) < 3:
        return []
    dt = np.diff(time)
    step = float(np.median(dt))
    if not step > 0:
        return []
    at = np.flatnonzero(dt > factor * step)
    return [Gap(int(i), float(time[i]), float(dt[i])) for i in at]


def gaps_within(gaps: list[Gap], start: int, stop: int) -> list[Gap]:
    """The gaps between two samples of ``[start - 1, stop]``: inside the half-open segment
    ``[start, stop)`` or at its edges (the step into and out of it)."""
    return [g for g in gaps if start - 1 <= g.index < stop]
