"""Allan deviation of a still recording and the noise parameters read from it.

The overlapping Allan deviation (NIST SP 1065 eq. 11, rate samples as "frequency" data, as
``allantools.oadev`` computes it, accumulated block by block by
:class:`imucal_cli.numerics.allan.AllanAccumulator`) and the noise read from it.  For each
axis of a rate signal ``y`` (m/s^2 for an accelerometer, rad/s for a gyroscope) sampled at
``rate_hz``:

random walk ``N``
    White noise on the rate gives ``sigma(tau) = N / sqrt(tau)`` (slope -1/2 on a log-log plot;
    IEEE Std 952, annex C).  ``N`` is the -1/2 line read at ``tau = 1 s``.  The line is fitted
    by least squares in log-log with its slope fixed at -1/2 (so ``log N`` is the mean of
    ``log sigma + log(tau) / 2``) over the *short-tau region where the local slope is near
    -1/2*: the first run of at least :data:`MIN_FIT_POINTS` taus, from the shortest, whose
    local slope lies within :data:`SLOPE_TOLERANCE` of -1/2.  Taus below that run (a -1 slope
    of quantisation noise) and above it (where bias instability flattens the curve) are left
    out, so the estimate is the white-noise level and not a compromise with the other terms.
    For white noise of standard deviation ``s`` per sample, ``N = s / sqrt(rate_hz)``.
    Accelerometer: velocity random walk (VRW), m/s/sqrt(s) = (m/s^2)/sqrt(Hz).
    Gyroscope: angle random walk (ARW), rad/sqrt(s).
bias instability ``B``
    The flat floor of the curve: ``B = sigma_min / 0.664`` (flicker noise gives
    ``sigma = 0.664 B``).  When the minimum is at the longest tau computed the curve has not
    turned up yet: ``B`` is then only an upper bound (record longer) and is flagged.
rate random walk ``K`` (optional)
    A +1/2 slope at long taus, ``sigma(tau) = K sqrt(tau / 3)``, read at ``tau = 3 s``; fitted
    like ``N`` over the longest run of taus after the minimum whose local slope is within
    :data:`RRW_SLOPE_TOLERANCE` of +1/2.
    ``None`` when the curve shows no such run (the usual case for a recording of minutes).

Taus are log-spaced (:data:`POINTS_PER_DECADE` per decade) from one sample to
``max_tau_fraction`` of the recording (default a tenth: beyond it fewer than ten independent
averages make each point and the curve's scatter hides its shape).

The curve itself is :mod:`imucal_cli.numerics.allan`'s (block by block).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.numerics.allan import AllanCurve, allan_deviation

__all__ = [
    "AxisNoise",
    "FLICKER_FACTOR",
    "MIN_FIT_POINTS",
    "RRW_SLOPE_TOLERANCE",
    "SLOPE_TOLERANCE",
    "axis_noise",
    "noise_from_curve",
]

FLICKER_FACTOR = 0.664
"""sigma_min / B for flicker (bias instability) noise: sqrt(2 ln 2 / pi)."""

SLOPE_TOLERANCE = 0.2
"""A local log-log slope within this of -1/2 (+1/2) belongs to the random-walk (rate random
walk) region."""

RRW_SLOPE_TOLERANCE = 0.3
"""The same for the +1/2 region, wider: the long-tau end of the curve scatters more."""

MIN_FIT_POINTS = 3
"""Fewest taus a slope line is fitted over."""


@dataclass(frozen=True)
class AxisNoise:
    """Noise parameters of one axis, in the rate's units (SI).

    Attributes
    ----------
    curve : AllanCurve
    random_walk : float or None
        ``N``, rate unit * sqrt(s) (m/s/sqrt(s) or rad/sqrt(s)); None when no -1/2 region.
    random_walk_taus : tuple of float
        First and last tau of the fitted -1/2 region, s (empty when none).
    bias_instability : float
        ``B = sigma_min / 0.664``, rate unit.
    bias_instability_tau_s : float
        Tau of the minimum, s.
    bias_instability_bound : bool
        True when the minimum is at the longest tau: ``B`` is an upper bound only.
    rate_random_walk : float or None
        ``K``, rate unit / sqrt(s); None when no +1/2 region.
    rate_random_walk_taus : tuple of float
        First and last tau of the fitted +1/2 region, s.
    notes : list of str
        Why a figure is missing or what limits it.
    """

    curve: AllanCurve
    random_walk: float | None
    random_walk_taus: tuple[float, ...]
    bias_instability: float
    bias_instability_tau_s: float
    bias_instability_bound: bool
    rate_random_walk: float | None
    rate_random_walk_taus: tuple[float, ...]
    notes: list[str] = field(default_factory=list)


def _local_slopes(tau: np.ndarray, adev: np.ndarray) -> np.ndarray:
    """Log-log slope at each tau (central differences, one-sided at the ends)."""
    if len(tau) < 2:
        return np.full(len(tau), np.nan)
    return np.gradient(np.log(adev), np.log(tau))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open index runs where ``mask`` is true."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def _fixed_slope_fit(tau, adev, slope: float, tau_read: float) -> float:
    """Least-squares line of fixed ``slope`` in log-log, read at ``tau_read``."""
    return float(np.exp(np.mean(np.log(adev) - slope * np.log(tau / tau_read))))


def axis_noise(y: np.ndarray, rate_hz: float, *, max_tau_fraction: float = 0.1) -> AxisNoise:
    """The noise parameters of one axis (module notes): :func:`noise_from_curve` of the
    :func:`allan_deviation` of ``y``, rate samples in SI (m/s^2 or rad/s), with its
    parameters."""
    return noise_from_curve(allan_deviation(y, rate_hz, max_tau_fraction=max_tau_fraction))


def noise_from_curve(curve: AllanCurve) -> AxisNoise:
    """The noise parameters read from one axis's Allan deviation (module notes).

    Raises
    ------
    InputError
        Fewer than :data:`MIN_FIT_POINTS` taus.
    """
    tau, adev = curve.tau_s, curve.adev
    if len(tau) < MIN_FIT_POINTS:
        raise InputError(
            f"only {len(tau)} averaging times: the recording is too short for an Allan "
            "deviation (record minutes)"
        )
    slopes = _local_slopes(tau, adev)
    notes: list[str] = []

    white = [r for r in _runs(np.abs(slopes + 0.5) <= SLOPE_TOLERANCE)
             if r[1] - r[0] >= MIN_FIT_POINTS]  # fmt: skip
    if white:
        a, b = white[0]
        random_walk = _fixed_slope_fit(tau[a:b], adev[a:b], -0.5, 1.0)
        random_walk_taus = (float(tau[a]), float(tau[b - 1]))
        if not tau[a] <= 1.0 <= tau[b - 1]:
            notes.append(
                f"random walk: -1/2 line fitted over {tau[a]:.3g}-{tau[b - 1]:.3g} s and read "
                "at tau = 1 s outside it"
            )
    else:
        random_walk, random_walk_taus = None, ()
        notes.append("random walk: the curve has no -1/2 slope region (not white noise)")

    i_min = int(np.argmin(adev))
    bound = i_min == len(adev) - 1
    if bound:
        notes.append(
            "bias instability: the curve still falls at the longest tau; B is an upper bound "
            "(record longer: tens of minutes)"
        )

    # The long-tau end is scattered (few independent averages): a wider tolerance, and the
    # longest run after the minimum.
    rising = [r for r in _runs(np.abs(slopes - 0.5) <= RRW_SLOPE_TOLERANCE)
              if r[1] - r[0] >= MIN_FIT_POINTS and r[0] > i_min]  # fmt: skip
    if rising:
        a, b = max(rising, key=lambda r: r[1] - r[0])
        rate_random_walk = _fixed_slope_fit(tau[a:b], adev[a:b], 0.5, 3.0)
        rrw_taus = (float(tau[a]), float(tau[b - 1]))
    else:
        rate_random_walk, rrw_taus = None, ()

    return AxisNoise(
        curve=curve,
        random_walk=random_walk,
        random_walk_taus=random_walk_taus,
        bias_instability=float(adev[i_min] / FLICKER_FACTOR),
        bias_instability_tau_s=float(tau[i_min]),
        bias_instability_bound=bound,
        rate_random_walk=rate_random_walk,
        rate_random_walk_taus=rrw_taus,
        notes=notes,
    )
