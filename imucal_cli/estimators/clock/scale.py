"""The device's sample clock measured against the host's: ``sample_clock_scale`` (issue 17.2).

A cheap part's sample clock (its RC oscillator, or the microcontroller's crystal that stamps
the samples) runs a fraction of a percent off; a gyro calibration that integrates the rates
over the device's time stamps absorbs that error into its scale factors. The host's clock
(NTP-disciplined, a few ppm) is the reference: each sample's host arrival time ``h_i`` beside
its device time ``d_i`` follows::

    h_i = h_0 + d_i / s + latency_i

with ``s`` the device seconds per true second (the formats page's ``sample_clock_scale``) and
``latency_i`` the USB/serial delivery delay.  The latency is never negative, and it is anything
but stationary: samples arrive in bursts (one read takes every line waiting, all stamped with
the read's time), a busy host reads late for seconds, a capture starting up finds a backlog,
and the typical delay follows the machine's load.  A fit through all arrivals (or their
means) takes a latency that grows or shrinks over the recording for a clock error: on a
captured session with no clock error at all it found -87 +- 12 ppm, and +932 +- 270 ppm on a
busy host (issue 24.4).

The floor of the latency is steady, though: the samples read right after the device sent
them arrive with the transport's least delay, whatever the load.  The estimate therefore
fits the *lower envelope* of the arrivals, in the spirit of Moon, Skelly & Towsley's
minimum-delay skew estimator (1999): the recording is cut into windows of device time
(:data:`WINDOW_S` or longer, at most :data:`MAX_WINDOWS`), the arrival with the least latency
in each window is taken (latency against the current line; two passes; of the samples one
read delivered together, only the newest counts: the others waited in a backlog), and a
straight line is fitted to those minima (Theil-Sen's median of slopes, then least squares).
While the host drains a backlog (the serial buffer hands it out a few kilobytes a read) even
a read's newest sample is late; those reads are recognised as later than a read after them
and left out.  A window whose least latency is far above the others (the host did not read
at all through it: :data:`OUTLIER_MAD` median absolute deviations) is left out.

Uncertainty: the slope's standard deviation comes from the scatter of the window minima about
the line -- the jitter of the latency floor and every window a burst or a stall lifted, as
they happened in this recording, and never less than :data:`FLOOR_WANDER_S` per window --
with the lag-1 correlation of those residuals allowed for (an AR(1)'s ``(1 + rho) / (1 -
rho)``).  The host's own clock is a reference only to
:data:`HOST_CLOCK_PPM`; an estimate is :attr:`ClockEstimate.significant` (worth correcting)
when it is further from zero than the two combined times Student's t quantile (the
windows' degrees of freedom) of what :data:`SIGNIFICANT` standard deviations are for a
normal: three and a bit for a long recording, nearly five for eight windows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, stdtrit

from imucal_cli.errors import DesignError

__all__ = [
    "HOST_CLOCK_PPM",
    "MIN_SPAN_S",
    "SIGNIFICANT",
    "ClockEstimate",
    "estimate_clock_scale",
]

#: Shortest recording (device seconds) the estimate needs.
MIN_SPAN_S = 10.0
#: Shortest window of device time, s.
WINDOW_S = 2.0
#: Fewest and most windows the recording is cut into.
MIN_WINDOWS, MAX_WINDOWS = 8, 60
#: Fewest windows the line is fitted to, outliers left out.
MIN_FITTED = 5
#: A window whose least latency is this many MADs from the line's is left out.
OUTLIER_MAD = 5.0
#: A read with this much more latency than a later one was catching up on a backlog, s.
FLOOR_TOL_S = 0.01
#: How much the latency floor wanders from window to window at least, s: a USB frame, the
#: host's scheduler (a floor that stepped by 1 ms went unseen in the scatter of 8 windows).
#: Over 19 captures through the virtual port at load (no clock error and 0.5 %) the errors
#: came to 0.89 of this std (RMS; none beyond 2): 0.5 ms gave 1.14 with 3 beyond 2, none
#: 1.5 with one at 4.5.
FLOOR_WANDER_S = 0.7e-3
#: Least scatter assumed for the outlier test, s (arrivals stamped to the microsecond).
MIN_SCATTER_S = 20e-6
#: A scale further than this from 1 is not a clock error but a mismatch (wrong time units).
MAX_ERROR = 0.05
#: How far the host's clock itself may be from true time, ppm (NTP-disciplined).
HOST_CLOCK_PPM = 5.0
#: An estimate is significant, and corrected, beyond this many standard deviations.
SIGNIFICANT = 3.0
#: A gap in the device times longer than this starts a new run, s: a resumed capture's
#: samples follow the earlier ones shifted by the host's time between them, so each run has
#: a latency floor of its own (one line through both took a 35 ms step for +810 +- 163 ppm).
RUN_GAP_S = 1.0


@dataclass
class ClockEstimate:
    """Result of :func:`estimate_clock_scale`.

    Attributes
    ----------
    scale, scale_std : float
        ``s``, device seconds per true second, and its standard deviation.
    ppm, ppm_std : float
        ``(s - 1) 1e6`` and its standard deviation (the arrivals' jitter and bursts).
    jitter_s : float
        Standard deviation of the arrival latency above the lower envelope (per sample), s.
    latency_max_s : float
        Largest latency above the envelope: the longest the host left samples waiting, s.
    duration_s : float
        Device time spanned, s.
    bins, bins_dropped : int
        Windows fitted, and windows left out as outliers.
    backlog_reads : int
        Reads left out as made while the host caught up on a backlog.
    correlation : float
        Lag-1 autocorrelation of the window residuals used for the standard deviation.
    threshold_ppm : float
        The standard deviation with the host clock's own :data:`HOST_CLOCK_PPM` combined,
        times Student's t quantile (``bins - 2`` degrees of freedom) of a normal's
        :data:`SIGNIFICANT` standard deviations: an error of this size or smaller is not told
        apart from none.
    significant : bool
        ``|ppm|`` exceeds ``threshold_ppm``: the clock error is real and worth correcting.
    """

    scale: float
    scale_std: float
    ppm: float
    ppm_std: float
    jitter_s: float
    latency_max_s: float
    duration_s: float
    bins: int
    bins_dropped: int
    backlog_reads: int
    correlation: float
    threshold_ppm: float
    significant: bool

    def to_dict(self) -> dict:
        return {"scale": self.scale, "scale_std": self.scale_std, "ppm": self.ppm,
                "ppm_std": self.ppm_std, "jitter_s": self.jitter_s,
                "latency_max_s": self.latency_max_s, "duration_s": self.duration_s,
                "bins": self.bins, "bins_dropped": self.bins_dropped,
                "backlog_reads": self.backlog_reads,
                "correlation": self.correlation, "threshold_ppm": self.threshold_ppm,
                "significant": self.significant,
                "method": "lower envelope of the host arrival times"}  # fmt: skip


def _check_units(d: np.ndarray, h: np.ndarray) -> None:
    """Refuse host times that do not follow the device's at all (device time in the wrong
    unit, clock resets): the slope of the reads of the recording's second half (a backlog
    is at its start), a median of pairwise slopes (bursts cannot move it)."""
    from scipy.stats import theilslopes  # start-up: see DEVELOPERS.md

    late = d >= d[-1] / 2
    if late.sum() < 3:
        return
    step = max(1, int(late.sum()) // 400)  # a few hundred reads say it
    slope = float(theilslopes(h[late][::step], d[late][::step])[0])
    if not abs(slope - 1.0) < 4 * MAX_ERROR:
        raise DesignError(
            f"the host arrival times run {slope:.4g} s per device second: not a clock error "
            "but a mismatch (device time units, or clock resets)"
        )


def _caught_up(d: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reads not made while the host was catching up on a backlog.

    While a reader drains a backlog (the serial buffer hands it out a few kilobytes a read),
    its latency falls by nearly a second per device second, and every read before the last
    of the drain is later than a read after it: a read is left out when a later one arrived
    with less latency by more than :data:`FLOOR_TOL_S`, the clock error allowed
    (:data:`MAX_ERROR` per device second) included.  Reads at the latency floor are never
    left out, whatever the clock error."""
    m = h - d + MAX_ERROR * d  # the latency against slope 1, tilted by the largest error
    later_min = np.minimum.accumulate(m[::-1])[::-1]
    later_min = np.r_[later_min[1:], np.inf]
    keep = m <= later_min + FLOOR_TOL_S
    return d[keep], h[keep]


def _window_minima(d: np.ndarray, h: np.ndarray, window: np.ndarray, slope: float):
    """Per window, the arrival with the least latency against ``h = a + slope d``."""
    latency = h - slope * d
    order = np.lexsort((latency, window))  # by window, then latency
    first = np.ones(len(order), bool)
    first[1:] = window[order][1:] != window[order][:-1]
    pick = order[first]
    return d[pick], h[pick]


def _robust_line(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A line through the points that outliers cannot pull: Theil-Sen's (the median of the
    pairwise slopes: up to 29 % of the points may be anything), then least squares on the
    points within :data:`OUTLIER_MAD` MADs of it, repeated on the new line; returns the
    coefficients (intercept, slope), the residuals of every point and which were kept."""
    from scipy.stats import theilslopes  # start-up: see DEVELOPERS.md

    slope, intercept = theilslopes(y, x)[:2]
    coef = np.array([intercept, slope])
    keep = np.ones(len(x), bool)
    for _ in range(3):
        r = y - (coef[0] + coef[1] * x)
        centre = np.median(r[keep])
        mad = 1.4826 * np.median(np.abs(r[keep] - centre))
        new = np.abs(r - centre) <= OUTLIER_MAD * max(mad, MIN_SCATTER_S)
        if new.sum() < MIN_FITTED or ((new == keep).all() and _ > 0):
            break
        keep = new
        A = np.column_stack([np.ones(keep.sum()), x[keep]])
        coef = np.linalg.lstsq(A, y[keep], rcond=None)[0]
    r = y - (coef[0] + coef[1] * x)
    return coef, r, keep


def estimate_clock_scale(
    device_time: np.ndarray, host_time: np.ndarray, *, window_s: float = WINDOW_S
) -> ClockEstimate:
    """Estimate the device clock's scale against the host's arrival times (module notes).

    Parameters
    ----------
    device_time, host_time : ndarray, shape (N,)
        Each sample's device time stamp and host arrival time, s.
    window_s : float
        Shortest window of device time, s.

    Raises
    ------
    DesignError
        Too short a recording (under :data:`MIN_SPAN_S`), or host times that do not follow
        the device's (a scale off by more than 5 %: wrong time units or resets).
    """
    d = np.asarray(device_time, float)
    h = np.asarray(host_time, float)
    ok = np.isfinite(d) & np.isfinite(h)
    d, h = d[ok], h[ok]
    if len(d) < 3 or d[-1] - d[0] < MIN_SPAN_S:
        span = 0.0 if len(d) < 2 else d[-1] - d[0]
        raise DesignError(
            f"the recording spans {span:.1f} s of device time: the sample clock needs at "
            f"least {MIN_SPAN_S:g} s of host arrival times"
        )
    d, h = d - d[0], h - h[0]
    # A read delivers every line waiting with one arrival time: only its newest sample
    # arrived with the read's own latency, the older ones waited for it (a backlog).
    newest = np.r_[h[1:] != h[:-1], True]
    _check_units(d[newest], h[newest])
    run = np.cumsum(np.r_[0, np.diff(d) > RUN_GAP_S])
    if not run[-1]:
        return _estimate(d, h, newest, window_s)
    runs = [run == j for j in range(int(run[-1]) + 1)]
    runs = [r for r in runs if d[r][-1] - d[r][0] >= MIN_SPAN_S]
    if not runs:
        raise DesignError(f"no stretch of the recording without a pause spans {MIN_SPAN_S:g} "
                          "s of device time: the sample clock needs one")  # fmt: skip
    ests, why = [], None
    for r in runs:
        try:
            ests.append(_estimate(d[r] - d[r][0], h[r] - h[r][0], newest[r], window_s))
        except DesignError as exc:  # this run was all backlog: the others may do
            why = exc
    if not ests:
        raise why
    return ests[0] if len(ests) == 1 else _combined(ests, span=float(d[-1]))


def _combined(ests: list[ClockEstimate], span: float) -> ClockEstimate:
    """One estimate from those of the runs between pauses (each with its own latency floor:
    a resumed capture), weighted by their inverse variances."""
    w = np.array([1.0 / e.ppm_std**2 for e in ests])
    ppm = float(w @ [e.ppm for e in ests] / w.sum())
    ppm_std = float(1.0 / np.sqrt(w.sum()))
    scale = 1.0 + ppm * 1e-6
    bins = sum(e.bins for e in ests)
    quantile = float(stdtrit(max(bins - 2 * len(ests), 1), ndtr(SIGNIFICANT)))
    threshold = quantile * float(np.hypot(ppm_std, HOST_CLOCK_PPM))
    return ClockEstimate(scale, ppm_std * 1e-6, ppm, ppm_std, max(e.jitter_s for e in ests),
                         max(e.latency_max_s for e in ests), span, bins,
                         sum(e.bins_dropped for e in ests), sum(e.backlog_reads for e in ests),
                         max(e.correlation for e in ests), threshold,
                         bool(abs(ppm) > threshold))  # fmt: skip


def _estimate(d, h, newest, window_s: float) -> ClockEstimate:
    """:func:`estimate_clock_scale` of times from 0, ``newest`` marking each read's last."""
    span = float(d[-1])
    _check_units(d[newest], h[newest])
    dr, hr = _caught_up(d[newest], h[newest])
    backlog = int(newest.sum()) - len(dr)
    timed = float(dr[-1] - dr[0])
    if timed < MIN_SPAN_S:
        raise DesignError(
            f"the host read the samples of {timed:.1f} of the {span:.1f} s of device time as "
            f"they came (the rest was a backlog): the sample clock needs {MIN_SPAN_S:g} s"
        )
    n_windows = int(np.clip(timed // window_s, MIN_WINDOWS, MAX_WINDOWS))
    window = np.minimum(((dr - dr[0]) / timed * n_windows).astype(np.int64), n_windows - 1)
    slope = 1.0
    for _ in range(2):  # the minima depend a little on the slope: choose them again
        dk, hk = _window_minima(dr, hr, window, slope)
        coef, r, keep = _robust_line(dk, hk)
        slope = float(coef[1])  # true seconds per device second = 1 / s
        if not abs(slope - 1.0) < MAX_ERROR:
            raise DesignError(
                f"the host arrival times run {slope:.4f} s per device second: not a clock "
                "error but a mismatch (device time units, or clock resets)"
            )
    rk, xk = r[keep], dk[keep]
    rho = 0.0
    if len(rk) > 3 and float(rk @ rk) > 0:
        rho = float(np.clip((rk[1:] @ rk[:-1]) / (rk @ rk), 0.0, 0.95))
    dof = max(len(rk) - 2, 1)
    s2 = max(float(rk @ rk) / dof, FLOOR_WANDER_S**2)  # a few windows can look too calm
    sxx = float(np.sum((xk - xk.mean()) ** 2))
    slope_std = float(np.sqrt(s2 / sxx * (1 + rho) / (1 - rho)))
    scale = 1.0 / slope
    scale_std = slope_std / slope**2
    ppm, ppm_std = (scale - 1.0) * 1e6, scale_std * 1e6
    above = h - (coef[0] + coef[1] * d)  # every sample's latency above the envelope
    quantile = float(stdtrit(dof, ndtr(SIGNIFICANT)))  # few windows: a wider margin
    threshold = quantile * float(np.hypot(ppm_std, HOST_CLOCK_PPM))
    return ClockEstimate(scale, scale_std, ppm, ppm_std, float(np.std(above)),
                         float(np.max(above)), span, int(keep.sum()), int((~keep).sum()),
                         backlog, rho, threshold, bool(abs(ppm) > threshold))  # fmt: skip
