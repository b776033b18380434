"""Host-clock time stamps for samples that carry no time of their own: :class:`HostClock`.

MotionCal's ``Raw:`` lines, i2cdevlib's ``a/g:`` lines, WitMotion's frames and text lines
without a ``t`` column are stamped by the host: each read brings ``k`` samples that arrived by
its time.  A device sends them at a steady rate, but they do not arrive so: a busy host reads
late (a backlog, read whole by :class:`~imucal_cli.capture.serial_port.SerialSource`), and
the bytes themselves come in bursts (the kernel's tty work and a USB adapter's packets wait for
a CPU too).  Spreading every read's samples evenly since the last read, as before, turned
such a burst into a gap: two samples after 0.12 s, then eighteen within 0.08 s (a turn with a
step of 0.06-0.12 s at 100 Hz is a turn with a gap, left out by calibrate).

So the clock keeps the stream's sample interval (``period``: a least-squares fit of the count
of samples received against their arrival, over the last :data:`PERIOD_WINDOW_S`) and stamps
each read's samples one period apart after the last stamp, never after they arrived:

- samples that came sooner than the period says are spread up to their arrival (a burst that
  catches up; a backlog);
- samples that came later, by less than :data:`PAUSE_S`, keep the period (a late burst is no
  gap), and a lag that lasts (the rate changed) is caught up over :data:`TRACK_S`;
- later by more (the device paused, or lost samples), the read's samples end at their arrival
  one period apart, after a gap as long as the pause.

The first read has no earlier stamp: its samples are spread from the port's open
(:meth:`HostClock.set_origin`; no sample was sent before it) to their arrival.  A device that
starts some time after the open (an Arduino that resets on open, the virtual device that
waits for the reader's flush), read late, makes that spread too slow: :func:`first_read_times`
re-times that first read once the rest of the stream has shown its rate (the recorder does so
when the capture ends).

Stamped live, the samples still carry the host's read jitter (1.4-1.8 ms RMS beside two CPU
burners): harmless to the holds, but the gyro integrates its rates over these times, and a
turn's angle then carries the jitter times the angular acceleration, far above the gyro's own
noise (gyro error 2.6-3.3 times its bound on qureshi18 captured as i2cdevlib lines, 0.91-1.0
with the jitter gone). When the capture ends, :func:`steady_times` puts each run of samples
between pauses on one line (a steady device clock: one offset, one interval), where the line
explains the stamps to within a few sample intervals (:data:`STEADY_MISS`).
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["PAUSE_S", "PERIOD_WINDOW_S", "TRACK_S", "HostClock", "first_read_times", "steady_times"]

PAUSE_S = 0.3
"""Samples later than the period says by more than this, s, follow a pause (a gap); later by
less, a burst that waited on a busy host (no gap)."""

TRACK_S = 0.2
"""A lag of the stamps behind their arrivals that every read of the last this many seconds
showed (not a burst that waited: the reads after it come early) is caught up over this many
seconds of samples, s: soon enough that a stream whose rate halves is followed without a lag
past :data:`PAUSE_S`; a burst that waited 0.12 s leaves steps of at most 1.5-1.8 periods, far
from the 5 of a gap, and the steps' median the period."""

PERIOD_WINDOW_S = 5.0
"""The sample interval is fitted to the arrivals of the last this many seconds, s (a bias of
0.1-0.3 % on a loaded host, from arrival delays that change over the window)."""

MIN_PERIOD_S = 0.25
"""Arrivals over at least this long, s, before the sample interval is known (until then every
read's samples are spread evenly since the last); an interval a few percent off at first
only makes the stamps lag their arrivals a little, caught up over :data:`TRACK_S`."""

_REFIT_S = 0.25  # the interval is refitted this often (host seconds)
_MIN_STEP = 1e-6  # s: stamps stay strictly increasing whatever arrives


class HostClock:
    """Stamps for samples without a time of their own (module notes).

    Attributes
    ----------
    origin : float or None
        When the stream could start (the port opened), host clock, s.
    period : float or None
        The stream's sample interval, s (None until :data:`MIN_PERIOD_S` of arrivals).
    first_read : int
        Samples of the first read (stamped from the origin).
    """

    def __init__(self) -> None:
        self.origin: float | None = None
        self.period: float | None = None
        self.first_read = 0
        self._last: float | None = None  # the last stamp, s
        self._count = 0  # samples stamped
        self._arrivals: deque[tuple[int, float]] = deque()  # (count, arrival) after the first
        self._fitted_at = -np.inf
        self._lags: deque[tuple[float, float]] = deque()  # (arrival, lag) of the last TRACK_S

    def set_origin(self, host_time: float) -> None:
        """When the stream could start (the port opened), host clock, s: the first read's
        samples are spread from there to their arrival (not crowded before it)."""
        if self._last is None:
            self.origin = float(host_time)

    def stamps(self, k: int, host_time: float, after: float | None = None) -> np.ndarray:
        """Times of ``k`` samples that arrived by ``host_time`` (s), shape (k,), strictly
        increasing after every earlier stamp and after ``after`` (the last sample kept)."""
        a = float(host_time)
        last = self._last if after is None or self._last is None else max(self._last, after)
        if last is None:
            self.first_read = k
            start = a - 1e-3 * k if self.origin is None else self.origin
            if after is not None:
                start = max(start, after)
            end = max(a, start + _MIN_STEP * k)
            times = start + (end - start) * np.arange(1, k + 1) / k
        else:
            times = self._following(k, a, last)
        self._count += k
        self._last = float(times[-1])
        self._arrived(a)
        return times

    def _following(self, k: int, a: float, last: float) -> np.ndarray:
        """Stamps of a read after the first (module notes)."""
        steps = np.arange(1, k + 1)
        floor = last + _MIN_STEP * k
        if self.period is None:
            end = max(a, floor)
            return last + (end - last) * steps / k
        span = k * self.period
        lag = a - (last + span)  # how far the arrival is past the period's stamps
        if lag > PAUSE_S:  # a pause: the samples end at their arrival, a period apart
            self._arrivals.clear()  # the pause is no part of the rate
            return a - (k - steps) * self.period
        lags = self._lags
        lags.append((a, lag))
        while a - lags[0][0] > TRACK_S:
            lags.popleft()
        if lag <= 0:  # sooner than the period says: up to the arrival
            return last + (max(a, floor) - last) * steps / k
        persistent = min(lag for _, lag in lags)  # a burst that waited is not
        end = last + span + max(persistent, 0.0) * min(1.0, span / TRACK_S)
        return last + (max(end, floor) - last) * steps / k

    def _arrived(self, a: float) -> None:
        """Record an arrival; refit the sample interval when due."""
        self._arrivals.append((self._count, a))
        if self._count == self.first_read:
            return  # the first read: the fit starts at its end (it began at an unknown time)
        while self._arrivals and a - self._arrivals[0][1] > PERIOD_WINDOW_S:
            self._arrivals.popleft()
        if a - self._arrivals[0][1] < MIN_PERIOD_S or a - self._fitted_at < _REFIT_S:
            return
        count, arrival = np.array(self._arrivals, dtype=np.float64).T
        if count[-1] - count[0] < 5:
            return
        slope = np.polyfit(count - count[0], arrival - arrival[0], 1)[0]
        if slope > 0:
            self.period, self._fitted_at = float(slope), a


def first_read_times(times: np.ndarray, origin: float | None, period: float) -> np.ndarray:
    """The first read's stamps (shape (k,), s, spread from ``origin`` to its arrival) again,
    ``period`` apart and ending at its arrival: the samples of a device that started after the
    port opened.  Never before ``origin``: a spread already tighter than ``period`` stays."""
    times = np.asarray(times, np.float64)
    k = times.size
    if k < 2 or not period > 0:
        return times
    end = float(times[-1])
    spread = (end - origin) / k if origin is not None else np.inf
    step = min(period, spread)
    if step >= float(np.mean(np.diff(times))):
        return times
    return end - step * np.arange(k - 1, -1, -1)


#: A run of samples between pauses needs this many, after the first read, to be put on a line.
MIN_STEADY = 50
#: The line must pass within this many sample intervals of every live stamp in its run (the
#: host's read jitter: at most 2.3 beside two CPU burners); missed by more, the run is no
#: steady clock (its rate changed, or samples were lost for less than a pause, which the line
#: would spread over the whole run as an interval error) and keeps its live stamps.
STEADY_MISS = 5.0


#: How far before the port's open the line may place the first read, s: the host's own delay
#: in stamping it (the open's start is taken before pyserial's open returns, but a sender
#: that bursts its first lines, or a reader descheduled on a busy host, can still put the
#: line's start a few sample intervals earlier: 9.6 ms at 200 Hz in a CI run at load).  A
#: first read the line would start farther back is no part of the device's steady run.
ORIGIN_SLACK_S = 0.05


def steady_times(times: np.ndarray, first_read: int = 0,
                 origin: float | None = None) -> np.ndarray:  # fmt: skip
    """Host stamps (shape (n,), s) with each run between pauses (steps over :data:`PAUSE_S`)
    put on its least-squares line against the sample count: a device's steady clock, without
    the host's read jitter.  The first ``first_read`` samples (spread from the port's open)
    take no part in the fit; the line extends over them unless that would start before
    ``origin`` (by more than :data:`ORIGIN_SLACK_S`).  A run the line misses anywhere by
    more than :data:`STEADY_MISS` intervals
    (the device's rate changed, samples lost), or shorter than :data:`MIN_STEADY`, keeps its
    stamps; so does every run when the
    result would not increase strictly."""
    t = np.asarray(times, np.float64)
    out = t.copy()
    cuts = np.flatnonzero(np.diff(t) > PAUSE_S) + 1
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, t.size], strict=True):
        fit_lo = max(int(lo), int(first_read))
        if hi - fit_lo < MIN_STEADY:
            continue
        slope, offset = np.polyfit(np.arange(hi - fit_lo), t[fit_lo:hi], 1)
        line = offset + slope * np.arange(lo - fit_lo, hi - fit_lo)
        if not slope > 0 or np.abs(line[fit_lo - lo:] - t[fit_lo:hi]).max() > STEADY_MISS * slope:
            continue
        if origin is not None and line[0] < origin - ORIGIN_SLACK_S:  # the first read stays
            line[: fit_lo - lo] = t[lo:fit_lo]
        out[lo:hi] = line
    return out if (np.diff(out) > 0).all() and np.isfinite(out).all() else t
