"""The recent samples of a guided capture, indexed by the recorder's sample index."""

from __future__ import annotations

import numpy as np

HISTORY_SAMPLES = 200_000
"""Samples kept in memory for holds and turns (about half an hour at 100 Hz)."""


class SampleHistory:
    """The last :data:`HISTORY_SAMPLES` samples (more while a long hold needs them).

    Parameters
    ----------
    first : int
        Recorder index of the first sample that will be appended.
    keep_s : float
        Never drop samples younger than this, s (the longest hold of the plan).
    """

    def __init__(self, first: int, keep_s: float = 0.0) -> None:
        self.first = first
        self.keep_s = keep_s
        self.time = np.empty(0)
        self.accel: np.ndarray | None = None
        self.gyro: np.ndarray | None = None

    def append(self, time, accel, gyro) -> None:
        """Add one block (``time`` (k,), ``accel``/``gyro`` (k, n) or None)."""
        self.time = np.concatenate([self.time, np.asarray(time, float)])
        if accel is not None:
            a = np.asarray(accel, float)
            self.accel = a if self.accel is None else np.concatenate([self.accel, a])
        if gyro is not None:
            g = np.asarray(gyro, float)
            self.gyro = g if self.gyro is None else np.concatenate([self.gyro, g])
        drop = len(self.time) - HISTORY_SAMPLES
        if drop > 0 and self.keep_s > 0:
            young = int(np.searchsorted(self.time, self.time[-1] - self.keep_s, side="left"))
            drop = min(drop, young)
        if drop > 0:
            self.first += drop
            self.time = self.time[drop:]
            self.accel = None if self.accel is None else self.accel[drop:]
            self.gyro = None if self.gyro is None else self.gyro[drop:]

    @property
    def end(self) -> int:
        """Recorder index one past the last sample."""
        return self.first + len(self.time)

    def t(self, index: int) -> float:
        """Time of sample ``index`` (clamped to the samples kept), s."""
        i = min(max(index - self.first, 0), len(self.time) - 1)
        return float(self.time[i])

    def rows(self, arr: np.ndarray | None, start: int, stop: int) -> np.ndarray | None:
        """Rows ``[start, stop)`` (recorder indices) of ``accel``/``gyro``/``time``."""
        if arr is None:
            return None
        return arr[max(start - self.first, 0) : max(stop - self.first, 0)]
