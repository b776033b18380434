"""What :func:`~imucal_cli.design.segmentation.find_static` and its block-by-block form
:class:`~imucal_cli.design.static_stream.StaticStream` share: the window variance test's
thresholds (:func:`still_threshold`, its false-alarm probability and the sensors' tolerances),
the window's length, and runs of still samples made still periods (:class:`Interval`: merged
across short gaps, trimmed, kept when long enough).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri

from imucal_cli.errors import InputError

DEFAULT_ALPHA = 1e-4
"""Probability that a window of pure sensor noise is called moving (before ``k`` inflation)."""

HOLD_TOLERANCE = 4.0
"""Default accelerometer threshold, in units of the chi-square multiple of
:func:`still_threshold`.  The noise estimate is that of the quietest windows (a unit resting on
a table); a hand-held or hand-placed hold adds tremor.  In the four real recordings of
``shared/data`` the accelerometer variance of the holds reaches about 3 times that of the
quietest windows, motion starts at about 10 times (see the module docstring of the tests)."""

GYRO_TOLERANCE = 100.0
"""Default gyroscope threshold, in the same units.  The gyroscope test is there to catch a
rotation that leaves the accelerometer unchanged (a turn about the vertical); vibration and
tremor raise the gyro variance of a hold 10 to 100 times above the quietest windows
(MPU-9150: 0.006 rad/s early in the recording against 0.0009 rad/s later), while a rotation
of even 10 deg/s is 10^3 to 10^5 times the noise variance."""


@dataclass(frozen=True)
class Interval:
    """A half-open range of sample indices ``[start, stop)``."""

    start: int
    stop: int

    @property
    def n_samples(self) -> int:
        """``stop - start``."""
        return self.stop - self.start


def window_samples(window_s: float, rate_hz: float) -> int:
    if not window_s > 0:
        raise InputError(f"window must be > 0 s, got {window_s:g}")
    return max(3, int(round(window_s * rate_hz)))


def still_threshold(n: int, channels: int, alpha: float = DEFAULT_ALPHA) -> float:
    """The multiple ``k`` of the noise variance below which a window counts as still.

    ``k = chi2.ppf(1 - alpha, C (n - 1)) / (C (n - 1))``: a window of ``n`` samples of white
    Gaussian noise on ``C`` channels has a mean normalised variance above ``k`` with
    probability ``alpha``.

    Parameters
    ----------
    n : int
        Window length, samples.
    channels : int
        Number of channels tested together.
    alpha : float
        False-alarm probability per window, in (0, 1).

    Returns
    -------
    float
        ``k`` (dimensionless, > 1).
    """
    if not 0 < alpha < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha:g}")
    dof = channels * (n - 1)
    return float(chdtri(dof, alpha) / dof)


def still_runs(mask: np.ndarray) -> np.ndarray:
    """Start and stop (half-open) of every run of True, shape (R, 2)."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    return edges.reshape(-1, 2)


def trim(rate: float, window_s: float, margin_s: float | None,
          min_still_s: float) -> tuple[int, int]:  # fmt: skip
    """Samples trimmed from each end of a still run (``margin_s``, default half a window) and
    the fewest samples a still period keeps (``min_still_s``), at ``rate``."""
    margin = int(round((window_s / 2 if margin_s is None else margin_s) * rate))
    if margin < 0:
        raise InputError(f"margin must be >= 0 s, got {margin_s:g}")
    return margin, int(np.ceil(min_still_s * rate - 1e-9))


def still_periods(runs, N: int, n: int, margin: int, min_n: int) -> list[Interval]:
    """Runs of still samples (in order) merged across short gaps, trimmed by ``margin`` (not
    at the ends of the recording) and kept when ``min_n`` samples long (steps 3 and 4 of
    :func:`find_static`)."""
    if len(runs) == 0:
        return []
    # Merge runs split by a short gap (an isolated outlier sample).
    max_gap = max(1, n // 4)
    merged = [list(runs[0])]
    for a, b in runs[1:]:
        if a - merged[-1][1] <= max_gap:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    out = []
    for a, b in merged:
        a2 = a + margin if a > 0 else a
        b2 = b - margin if b < N else b
        if b2 - a2 >= max(min_n, 2):
            out.append(Interval(int(a2), int(b2)))
    return out
