"""The device's sample clock measured against the host's: ``sample_clock_scale`` (issue 17.2).

A cheap part's sample clock (its RC oscillator, or the microcontroller's crystal that stamps
the samples) runs a fraction of a percent off; a gyro calibration that integrates the rates
over the device's time stamps absorbs that error into its scale factors. The host's clock
(NTP-disciplined, a few ppm) is the reference: each sample's host arrival time ``h_i`` beside
its device time ``d_i`` follows::

    h_i = h_0 + d_i / s + latency_i

with ``s`` the device seconds per true second (the formats page's ``sample_clock_scale``) and
``latency_i`` the USB/serial delivery delay: non-negative, bursty (samples arrive in batches)
and correlated from one sample to the next, but stationary, so it leaves the slope alone.

The estimate averages the arrival times in bins of ``bin_s`` of device time (a batch's
samples share one bin), drops bins whose latency is far off (a stall of the host:
:data:`OUTLIER_MAD` median absolute deviations), and fits a straight line to the bin means by
least squares. Its standard deviation comes from the bins' residual scatter with the lag-1
correlation of the residuals allowed for (an AR(1)'s ``(1 + rho) / (1 - rho)``): for white
jitter ``sigma`` over a recording of length ``T`` that is about ``sigma sqrt(12 / n) / T``
(``n`` samples), so a minute of samples with a millisecond of jitter gives a few ppm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import DesignError

__all__ = ["ClockEstimate", "MIN_BINS", "estimate_clock_scale"]

#: Fewest bins (of ``bin_s`` device seconds) the recording must fill.
MIN_BINS = 10
#: Bins whose mean latency is this many MADs from the median are left out.
OUTLIER_MAD = 8.0
#: A scale further than this from 1 is not a clock error but a mismatch (wrong time units).
MAX_ERROR = 0.05


@dataclass
class ClockEstimate:
    """Result of :func:`estimate_clock_scale`.

    Attributes
    ----------
    scale, scale_std : float
        ``s``, device seconds per true second, and its standard deviation.
    ppm, ppm_std : float
        ``(s - 1) 1e6`` and its standard deviation.
    jitter_s : float
        Standard deviation of the arrival latency about the line (per sample), s.
    duration_s : float
        Device time spanned, s.
    bins, bins_dropped : int
        Bins fitted, and bins left out as outliers.
    correlation : float
        Lag-1 autocorrelation of the bin residuals used for the standard deviation.
    """

    scale: float
    scale_std: float
    ppm: float
    ppm_std: float
    jitter_s: float
    duration_s: float
    bins: int
    bins_dropped: int
    correlation: float

    def to_dict(self) -> dict:
        return {"scale": self.scale, "scale_std": self.scale_std, "ppm": self.ppm,
                "ppm_std": self.ppm_std, "jitter_s": self.jitter_s,
                "duration_s": self.duration_s, "bins": self.bins,
                "bins_dropped": self.bins_dropped, "correlation": self.correlation}  # fmt: skip


def _bin_means(d: np.ndarray, h: np.ndarray, bin_s: float):
    """Mean device and host time per bin of ``bin_s`` device seconds, and counts."""
    idx = np.floor((d - d[0]) / bin_s).astype(np.int64)
    counts = np.bincount(idx)
    keep = counts > 0
    dm = np.bincount(idx, d)[keep] / counts[keep]
    hm = np.bincount(idx, h)[keep] / counts[keep]
    return dm, hm, counts[keep]


def estimate_clock_scale(
    device_time: np.ndarray, host_time: np.ndarray, *, bin_s: float = 1.0
) -> ClockEstimate:
    """Estimate the device clock's scale against the host's arrival times.

    Parameters
    ----------
    device_time, host_time : ndarray, shape (N,)
        Each sample's device time stamp and host arrival time, s.
    bin_s : float
        Device seconds per bin.

    Raises
    ------
    DesignError
        Too short a recording (fewer than :data:`MIN_BINS` bins), or host times that do not
        follow the device's (a scale off by more than 5 %: wrong time units or resets).
    """
    d = np.asarray(device_time, float)
    h = np.asarray(host_time, float)
    ok = np.isfinite(d) & np.isfinite(h)
    d, h = d[ok], h[ok]
    if len(d) < 3 or d[-1] - d[0] < MIN_BINS * bin_s:
        span = 0.0 if len(d) < 2 else d[-1] - d[0]
        raise DesignError(
            f"the recording spans {span:.1f} s of device time: the sample clock needs at "
            f"least {MIN_BINS * bin_s:g} s of host arrival times"
        )
    dm, hm, counts = _bin_means(d - d[0], h - h[0], bin_s)
    keep = np.ones(len(dm), bool)
    for _ in range(3):  # fit, drop outlying bins, refit
        A = np.column_stack([np.ones(keep.sum()), dm[keep]])
        coef, *_ = np.linalg.lstsq(A * np.sqrt(counts[keep])[:, None],
                                   hm[keep] * np.sqrt(counts[keep]), rcond=None)  # fmt: skip
        r = hm - (coef[0] + coef[1] * dm)
        mad = 1.4826 * np.median(np.abs(r[keep] - np.median(r[keep])))
        new = np.abs(r - np.median(r[keep])) <= OUTLIER_MAD * max(mad, 1e-9)
        if (new == keep).all() or new.sum() < MIN_BINS:
            break
        keep = new
    slope = float(coef[1])  # true seconds per device second = 1 / s
    if not abs(slope - 1.0) < MAX_ERROR:
        raise DesignError(
            f"the host arrival times run {slope:.4f} s per device second: not a clock error "
            "but a mismatch (device time units, or clock resets)"
        )
    rk, dk, nk = r[keep], dm[keep], counts[keep]
    rho = 0.0
    if len(rk) > 3 and float(rk @ rk) > 0:
        rho = float(np.clip((rk[1:] @ rk[:-1]) / (rk @ rk), 0.0, 0.95))
    w = nk / nk.mean()
    dof = max(len(rk) - 2, 1)
    s2 = float(np.sum(w * rk**2) / dof)  # variance of a bin mean of average weight
    sxx = float(np.sum(w * (dk - np.average(dk, weights=w)) ** 2))
    slope_std = float(np.sqrt(s2 / sxx * (1 + rho) / (1 - rho)))
    scale = 1.0 / slope
    scale_std = slope_std / slope**2
    per_sample = h - h[0] - (coef[0] + coef[1] * (d - d[0]))
    return ClockEstimate(scale, scale_std, (scale - 1.0) * 1e6, scale_std * 1e6,
                         float(np.std(per_sample)), float(d[-1] - d[0]), int(keep.sum()),
                         int((~keep).sum()), rho)  # fmt: skip
