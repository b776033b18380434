"""Overlapping Allan deviation accumulated block by block, in constant memory.

The overlapping Allan deviation (NIST SP 1065 eq. 11, rate samples as "frequency" data, as
``allantools.oadev`` computes it) of a recording given a block at a time
(:class:`AllanAccumulator`), so that ``imucal noise`` analyses a day of samples in a few MB.
allantools needs the whole signal in memory for ``oadev`` (and several temporaries of its
length per tau), and its ``realtime.oadev_realtime`` keeps every phase sample in a Python list
and loops over samples in Python: DEVELOPERS.md ("What stayed home-made") has the measurement.
Taus are log-spaced (:data:`POINTS_PER_DECADE` per decade) from one sample to
``max_tau_fraction`` of the recording.

The sum behind each point
-------------------------
With the phase ``x_k = sum_{i<k} (y_i - c)`` (``x_0 = 0``; any constant ``c`` leaves the
deviation unchanged), the point at ``tau = m / rate_hz`` is
``sigma^2 = sum_i (x_{i+2m} - 2 x_{i+m} + x_i)^2 / (2 n m^2)`` over ``n`` terms ``i``.  The
fully overlapping estimator takes every ``i`` (``n = N + 1 - 2m``, allantools' ``oadev``).
Here each point takes at most :data:`MAX_TERMS` terms, at an even stride ``s`` (``i = 0, s,
2s, ...``), and points whose three phase samples lie further apart than the
:data:`CARRY` samples kept between blocks (``2m > CARRY``) at most :data:`MAX_FAR_TERMS`
(their phase samples are gathered as they stream by).  Each term is the same unbiased
estimate of the Allan variance; a stride only leaves out terms that overlap the ones kept.  So
a recording of up to ``MAX_TERMS + 2 m`` samples (27 minutes at 100 Hz for every point) gives
exactly allantools' curve, a longer one the same curve within its scatter, at a cost that
no longer grows with the number of taus.  ``n`` and ``adev_err = adev / sqrt(n)`` count the
terms used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import InputError

from .blocks import check_all_given, check_not_more

__all__ = ["AllanAccumulator", "AllanCurve", "MIN_SAMPLES", "POINTS_PER_DECADE", "allan_deviation",
           "log_taus"]  # fmt: skip

POINTS_PER_DECADE = 10
"""Log-spaced taus per decade."""

MIN_SAMPLES = 100
"""Fewest samples for an Allan deviation worth reading."""

MAX_TERMS = 1 << 17
"""Most terms summed for one point (every term up to this many: allantools' sum exactly)."""

CARRY = 1 << 16
"""Phase samples kept from one block to the next: points with ``2m`` up to this are summed
from the blocks as they come."""

BATCH = 1 << 17
"""Phase samples gathered before their terms are summed (few, long numpy loops)."""

MAX_FAR_TERMS = 1 << 13
"""Most terms of a point with ``2m > CARRY`` (its phase samples are gathered, 3 per term):
at a stride of ``m / 4`` or less up to 4 days at 100 Hz, where a point holds under 40
independent averages."""


@dataclass(frozen=True)
class AllanCurve:
    """Overlapping Allan deviation of one axis.

    Attributes
    ----------
    tau_s : ndarray
        Averaging times, s.
    adev : ndarray
        Allan deviation at each tau, in the rate's units.
    adev_err : ndarray
        1-sigma error of each point as ``allantools`` states it (``adev / sqrt(n)``).
    n : ndarray
        Number of terms in each point's sum (module notes).
    """

    tau_s: np.ndarray
    adev: np.ndarray
    adev_err: np.ndarray
    n: np.ndarray


def log_taus(
    rate_hz: float, n_samples: int, max_tau_fraction: float = 0.1,
    points_per_decade: int = POINTS_PER_DECADE,
) -> np.ndarray:  # fmt: skip
    """Log-spaced averaging times from one sample to ``max_tau_fraction`` of the recording.

    Parameters
    ----------
    rate_hz : float
        Sample rate, Hz.
    n_samples : int
        Samples in the recording.
    max_tau_fraction : float
        Longest tau as a fraction of the duration ``n_samples / rate_hz``.
    points_per_decade : int

    Returns
    -------
    ndarray
        Distinct taus, s, each a whole number of samples.
    """
    tau0 = 1.0 / rate_hz
    longest = max(1, int(n_samples * max_tau_fraction))
    m = np.unique(
        np.round(np.logspace(0, math.log10(longest), max(2, int(
            points_per_decade * math.log10(max(longest, 10))) + 1))).astype(int)
    )  # fmt: skip
    return m[m >= 1] * tau0


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


class AllanAccumulator:
    """Overlapping Allan deviation of ``channels`` rate signals, fed block by block.

    Memory is constant (a few MB per channel) however long the recording; the sums are those
    of the module notes.  Give every sample, in order, to :meth:`add`, then read
    :meth:`curves`.

    Parameters
    ----------
    n_samples : int
        Samples per channel that will be given (the taus depend on it).
    rate_hz : float
        Sample rate, Hz.
    channels : int
        Signals analysed side by side (e.g. the 3 axes of a sensor).
    max_tau_fraction : float
        Longest tau as a fraction of the recording.
    centre : array_like, optional
        Subtracted from each channel before integrating (leaves the deviation unchanged, keeps
        the phase small); default the mean of the first block (of the whole signal when it
        comes in one block, as allantools does).

    Raises
    ------
    InputError
        Fewer than :data:`MIN_SAMPLES` samples or a non-positive rate.
    """

    def __init__(
        self, n_samples: int, rate_hz: float, channels: int = 1, *,
        max_tau_fraction: float = 0.1, centre=None,
    ) -> None:  # fmt: skip
        if not rate_hz > 0 or not math.isfinite(rate_hz):
            raise InputError(f"sample rate must be > 0 Hz, got {rate_hz!r}")
        if n_samples < MIN_SAMPLES:
            raise InputError(
                f"{n_samples} samples are too few for an Allan deviation (need {MIN_SAMPLES}; "
                "record minutes, not seconds)"
            )
        self.n = int(n_samples)
        self.rate_hz = float(rate_hz)
        self.channels = int(channels)
        # The averaging factors as allantools makes them from the taus.
        m = np.round(log_taus(rate_hz, n_samples, max_tau_fraction) * rate_hz)
        m = np.unique(m[(m > 0) & (m < n_samples + 1)]).astype(np.int64)
        self.m = m[self.n + 1 - 2 * m > 1]  # allantools leaves out points of one term
        full = self.n + 1 - 2 * self.m
        self.near = 2 * self.m <= CARRY
        cap = np.where(self.near, MAX_TERMS, MAX_FAR_TERMS)
        self.stride = np.maximum(1, -(-full // cap))
        self.terms = (full - 1) // self.stride + 1
        self.centre = None if centre is None else np.asarray(centre, float).reshape(channels)
        self._sums = np.zeros((self.channels, len(self.m)))
        self._far = {
            int(p): np.empty((3, self.channels, int(self.terms[p])))
            for p in np.flatnonzero(~self.near)
        }
        # Phase samples, a row per channel: the last CARRY of the blocks before, then the
        # current block (long rows: numpy's loops run fast along them).
        self._window = np.zeros((self.channels, 0))
        self._kept = 0  # columns of _window whose terms are summed (the last CARRY of them)
        self._end = 0  # columns of _window filled
        self._carry = np.zeros(self.channels)
        self._seen = 0

    def add(self, y: np.ndarray) -> None:
        """The next samples: shape (k, channels), or (k,) for one channel.

        Raises
        ------
        InputError
            Non-finite samples, or more samples than ``n_samples``.
        """
        y = np.asarray(y, dtype=np.float64)
        if y.ndim == 1:
            y = y[:, None]
        if y.ndim != 2 or y.shape[1] != self.channels:
            raise InputError(f"expected samples of {self.channels} channels, got {y.shape}")
        k = len(y)
        if k == 0:
            return
        check_not_more(self._seen, k, self.n)
        if self.centre is None:
            self.centre = y.mean(axis=0)
        first = self._seen == 0  # the phase starts with x_0 = 0
        start = self._end + first
        if self._window.shape[1] < start + k:
            grown = np.empty((self.channels, max(start + k, CARRY + BATCH)))
            grown[:, : self._end] = self._window[:, : self._end]
            self._window = grown
        if first:
            self._window[:, 0] = 0.0
        phase = self._window[:, start : start + k]
        np.subtract(y.T, self.centre[:, None], out=phase)
        phase[:, 0] += self._carry  # the running sum goes on: as one cumsum of all samples
        np.cumsum(phase, axis=1, out=phase)
        self._carry = phase[:, -1].copy()
        if not np.isfinite(self._carry).all():  # NaN and inf reach the running sum
            raise InputError("the recording holds NaN or infinite samples")
        self._seen += k
        self._end = start + k
        if self._end - self._kept >= BATCH:
            self._terms()

    def _terms(self) -> None:
        """Add every term that ends in the phase samples not summed yet
        (``_window[:, _kept:_end]``), then keep the last CARRY samples."""
        end = self._end
        window = self._window[:, :end]
        g1 = self._seen + 1  # phase index after the last one in the window
        w0 = g1 - end  # phase index of window[:, 0]
        g0 = w0 + self._kept  # phase index of the first sample not summed yet
        for p in np.flatnonzero(self.near):
            m, s = int(self.m[p]), int(self.stride[p])
            first = _ceil_div(max(0, g0 - 2 * m), s) * s
            last = g1 - 1 - 2 * m
            if first > last:
                continue
            a = first - w0
            stop = a + (last - first) + 1
            v = window[:, a + 2 * m : stop + 2 * m : s] - 2.0 * window[:, a + m : stop + m : s]
            v += window[:, a:stop:s]
            self._sums[:, p] += np.einsum("ij,ij->i", v, v)
        for p, store in self._far.items():
            m, s, n = int(self.m[p]), int(self.stride[p]), int(self.terms[p])
            for which, offset in enumerate((0, m, 2 * m)):
                lo = max(0, _ceil_div(g0 - offset, s))
                hi = min(n, _ceil_div(g1 - offset, s))
                if lo < hi:
                    a = offset + lo * s - w0
                    store[which, :, lo:hi] = window[:, a : a + (hi - lo - 1) * s + 1 : s]
        # Keep the last CARRY phase samples for the next block.
        self._kept = self._end = min(CARRY, end)
        window[:, : self._kept] = window[:, end - self._kept :]

    def curves(self) -> list[AllanCurve]:
        """One curve per channel (points of zero or non-finite deviation left out).

        Raises
        ------
        InputError
            Fewer samples were given than announced.
        """
        check_all_given(self._seen, self.n)
        if self._end > self._kept:
            self._terms()
        sums = self._sums.copy()
        for p, store in self._far.items():
            v = store[2] - 2.0 * store[1] + store[0]
            sums[:, p] = np.einsum("ij,ij->i", v, v)
        out = []
        for c in range(self.channels):
            adev = np.sqrt(sums[c] / (2.0 * self.terms)) / self.m
            err = adev / np.sqrt(self.terms)
            keep = np.isfinite(adev) & (adev > 0)
            out.append(AllanCurve(self.m[keep] / self.rate_hz, adev[keep], err[keep],
                                  self.terms[keep].astype(float)))  # fmt: skip
        return out


def allan_deviation(y: np.ndarray, rate_hz: float, *, max_tau_fraction: float = 0.1) -> AllanCurve:
    """Overlapping Allan deviation of one rate signal (allantools' ``oadev`` of frequency data,
    for up to :data:`MAX_TERMS` samples exactly; module notes).

    Parameters
    ----------
    y : ndarray, shape (N,)
        Rate samples (m/s^2 or rad/s), evenly spaced.
    rate_hz : float
        Sample rate, Hz.
    max_tau_fraction : float
        Longest tau as a fraction of the recording.

    Returns
    -------
    AllanCurve

    Raises
    ------
    InputError
        Fewer than :data:`MIN_SAMPLES` samples, a non-positive rate or non-finite samples.
    """
    y = np.asarray(y, dtype=np.float64).ravel()
    acc = AllanAccumulator(len(y), rate_hz, 1, max_tau_fraction=max_tau_fraction)
    acc.add(y)
    return acc.curves()[0]
