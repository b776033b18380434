"""The rounding of a quantised sensor that its noise does not dither.

A sensor read as integer codes of step ``q`` with white noise ``sigma`` before the rounding:
the mean of ``n`` samples of a constant input ``mu`` errs by ``e(mu) = E[Q(mu + n)] - mu``,
which does not average away with ``n``.  The rounding error is a sawtooth of period ``q``
(Fourier series ``sum_k (-1)^(k+1) q / (pi k) sin(2 pi k mu / q)``); the noise smooths each
harmonic by its characteristic function, ``exp(-2 pi^2 k^2 sigma^2 / q^2)``.  Over an
input whose place within a step is unknown (uniform), the mean's error has variance

    v(sigma) = q^2 / (2 pi^2) sum_k exp(-4 pi^2 k^2 sigma^2 / q^2) / k^2      (Widrow & Kollar,
                                                                              Quantization
                                                                              Noise, ch. 5)

``q^2 / 12`` with no noise (a constant reading: the mean errs by up to half a step), 0.7 %
of it at ``sigma = q / 2`` and nothing measurable above: noise of half a step or more dithers
the rounding and the mean is unbiased.  The quantised samples' own variance, over the same
unknown place, is ``sigma^2 + q^2 / 12 - v(sigma)`` (the total ``E[(Q - mu)^2] = sigma^2 +
q^2 / 12`` less the part that does not vary): :func:`noise_before_rounding` inverts it for the
noise ``sigma`` from the variance the samples show.  That variance depends on where the input
sits within its step (a reading at a step's centre rarely flips, one at its edge flips half
the time), so a few holds give a poor ``sigma`` below a step: :func:`noise_from_codes` finds
it by maximum likelihood from how often each code occurs in each hold, each hold's place in
its step profiled out (the codes of a Gaussian read through a rounding are the differences of
its distribution function at the step edges).

Arrays in, numbers out; numpy and scipy only.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq, minimize_scalar
from scipy.special import log_ndtr, ndtr

#: Harmonics summed; the rest is bounded by the tail of ``sum 1 / k^2`` (below 1/K).
HARMONICS = 200


def rounding_variance(sigma: float, q: float) -> float:
    """Variance of a hold mean's rounding error that no number of samples averages away.

    Parameters
    ----------
    sigma : float
        White noise before the rounding, per sample, raw units (>= 0).
    q : float
        Quantisation step, raw units (0: not quantised).

    Returns
    -------
    float
        ``v(sigma)`` of the module's equation, raw units^2: ``q^2 / 12`` at ``sigma = 0``,
        below ``1e-4 q^2`` from ``sigma = 0.6 q`` on.
    """
    if q <= 0:
        return 0.0
    k = np.arange(1, HARMONICS + 1, dtype=float)
    damp = np.exp(-4.0 * np.pi**2 * k * k * (sigma / q) ** 2)
    tail = damp[-1] / HARMONICS  # sum_{k > K} damp_k / k^2 <= damp_K / K
    return float(q * q / (2 * np.pi**2) * (np.sum(damp / (k * k)) + tail))


def noise_before_rounding(s2: float, q: float) -> float:
    """The white noise ``sigma`` before the rounding whose quantised samples show the
    variance ``s2`` (per sample, raw units^2), from ``s2 = sigma^2 + q^2 / 12 - v(sigma)``.

    ``sqrt(s2)`` when not quantised (``q`` 0); 0 for samples that never change; Sheppard's
    ``sqrt(s2 - q^2 / 12)`` where the noise dithers the rounding.
    """
    if q <= 0:
        return float(np.sqrt(max(s2, 0.0)))
    if s2 <= 0:
        return 0.0

    def shown(sigma: float) -> float:
        return sigma * sigma + q * q / 12.0 - rounding_variance(sigma, q) - s2

    hi = float(np.sqrt(s2)) + q
    return float(brentq(shown, 0.0, hi, xtol=1e-9 * q))


#: Codes either side of a hold's median kept apart (the rest are counted at the outermost).
CODE_SPAN = 4
#: Places within a step tried per hold when profiling it out, and their span in steps.
PLACES, PLACE_SPAN = 241, 1.2


def noise_from_codes(blocks: list[np.ndarray], q: float) -> float:
    """The white noise before the rounding, by maximum likelihood from the codes of holds of
    constant input (each hold's input, per channel, profiled out), raw units.

    Parameters
    ----------
    blocks : list of ndarray, each (n_k, c)
        Raw samples of each hold, integer multiples of ``q`` plus one offset.
    q : float
        Quantisation step, raw units (> 0).

    Returns
    -------
    float
        ``sigma``, the same for every channel and hold; between ``q / 100`` (codes that never
        change) and ``3 q``.
    """
    offsets = np.arange(-CODE_SPAN, CODE_SPAN + 1)
    counts = []
    ref = np.asarray(blocks[0], float)[0]  # codes counted from one reading: any offset
    for b in blocks:
        codes = np.round((np.asarray(b, float) - ref) / q)
        med = np.median(codes, axis=0)
        rel = np.clip(codes - med, -CODE_SPAN, CODE_SPAN)
        counts.append((rel[:, :, None] == offsets).sum(axis=0))  # (c, codes)
    n = np.concatenate(counts).astype(float)  # (holds x channels, codes)
    mu = np.linspace(-PLACE_SPAN / 2, PLACE_SPAN / 2, PLACES)  # input - median code, steps

    def minus_profile(log_s: float) -> float:
        s = np.exp(log_s)
        hi, lo = (offsets[:, None] + 0.5 - mu) / s, (offsets[:, None] - 0.5 - mu) / s
        hi[-1], lo[0] = np.inf, -np.inf  # the outermost codes take the tails
        p = np.clip(ndtr(hi) - ndtr(lo), 1e-300, None)
        logp = np.where(hi < 0, log_ndtr(hi) + np.log1p(-np.exp(np.minimum(
            log_ndtr(lo) - log_ndtr(hi), -1e-16))), np.log(p))  # fmt: skip
        return -float(np.sum(np.max(n @ logp, axis=1)))

    res = minimize_scalar(minus_profile, bounds=(np.log(0.01), np.log(3.0)), method="bounded",
                          options={"xatol": 1e-3})  # fmt: skip
    return float(np.exp(res.x) * q)


#: Below this noise, in steps, the noise comes from the codes (:func:`noise_from_codes`);
#: above it from the variance (:func:`noise_before_rounding`), and the rounding no longer
#: matters (``v`` below ``1e-5 q^2``).
DITHERED = 0.7


def hold_rounding(blocks: list[np.ndarray], q: float, s: float) -> tuple[float, float]:
    """The noise before the rounding and the variance of the rounding error every hold's mean
    shares, for holds whose samples show the per-sample noise ``s`` (raw units).

    Returns
    -------
    sigma, v : float
        raw units and raw units^2; ``(s, 0)`` for data not quantised (``q`` 0).
    """
    if q <= 0:
        return float(s), 0.0
    if s >= DITHERED * q:
        sigma = noise_before_rounding(s * s, q)
    else:
        sigma = noise_from_codes(blocks, q)
    return sigma, rounding_variance(sigma, q)
