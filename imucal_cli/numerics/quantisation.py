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
#: A sample's chance to be anything (a spike, the end of a move): so one stray code in a hold
#: does not make the noise that reaches it.
STRAY = 1e-3


def _log_interval(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``log(Phi(hi) - Phi(lo))`` without cancellation in either tail."""
    with np.errstate(divide="ignore", invalid="ignore"):
        left = log_ndtr(hi) + np.log1p(-np.exp(np.minimum(log_ndtr(lo) - log_ndtr(hi), -1e-16)))
        right = log_ndtr(-lo) + np.log1p(-np.exp(np.minimum(log_ndtr(-hi) - log_ndtr(-lo),
                                                            -1e-16)))  # fmt: skip
        middle = np.log(np.clip(ndtr(hi) - ndtr(lo), 1e-300, None))
    return np.where(hi <= 0, left, np.where(lo >= 0, right, middle))


def code_counts(blocks: list[np.ndarray], q: float) -> np.ndarray:
    """How often each code occurs in each hold and channel, counted from the hold's median
    code (``-CODE_SPAN .. CODE_SPAN``; further ones at the outermost), rows with a NaN left
    out: shape (holds x channels, 2 CODE_SPAN + 1)."""
    width = 2 * CODE_SPAN + 1
    finite = [np.asarray(b, float) for b in blocks]
    finite = [b[np.isfinite(b).all(axis=1)] for b in finite if b.ndim == 2]
    finite = [b for b in finite if len(b)]
    if not finite:
        return np.zeros((0, width))
    ref = finite[0][0]  # codes counted from one reading: any offset
    out = []
    for b in finite:
        codes = np.round((b - ref) / q)
        rel = np.clip(codes - np.round(np.median(codes, axis=0)), -CODE_SPAN, CODE_SPAN)
        idx = (rel.astype(np.int64) + CODE_SPAN) + width * np.arange(b.shape[1])
        out.append(np.bincount(idx.ravel(), minlength=width * b.shape[1]).reshape(-1, width))
    return np.concatenate(out).astype(float)


def noise_from_codes(blocks: list[np.ndarray], q: float) -> float:
    """The white noise before the rounding, by maximum likelihood from the codes of holds of
    constant input (each hold's input, per channel, profiled out), raw units.

    Parameters
    ----------
    blocks : list of ndarray, each (n_k, c)
        Raw samples of each hold, integer multiples of ``q`` plus one offset (rows with a NaN
        are left out).
    q : float
        Quantisation step, raw units (> 0).

    Returns
    -------
    float
        ``sigma``, the same for every channel and hold; 0 where no hold's code ever changes
        (nothing tells the noise from none), else between ``q / 100`` and ``3 q``.  A stray
        sample (:data:`STRAY`) is allowed any code.
    """
    n = code_counts(blocks, q)
    if not len(n) or np.all(np.count_nonzero(n, axis=1) <= 1):
        return 0.0
    offsets = np.arange(-CODE_SPAN, CODE_SPAN + 1)
    mu = np.linspace(-PLACE_SPAN / 2, PLACE_SPAN / 2, PLACES)  # input - median code, steps
    stray = np.log(STRAY / len(offsets))

    def minus_profile(log_s: float) -> float:
        s = np.exp(log_s)
        hi, lo = (offsets[:, None] + 0.5 - mu) / s, (offsets[:, None] - 0.5 - mu) / s
        hi[-1], lo[0] = np.inf, -np.inf  # the outermost codes take the tails
        logp = np.logaddexp(np.log1p(-STRAY) + _log_interval(lo, hi), stray)
        return -float(np.sum(np.max(n @ logp, axis=1)))

    res = minimize_scalar(minus_profile, bounds=(np.log(0.01), np.log(3.0)), method="bounded",
                          options={"xatol": 1e-3})  # fmt: skip
    return float(np.exp(res.x) * q)


#: Below this noise, in steps, the noise comes from the codes (:func:`noise_from_codes`);
#: above it from the variance (:func:`noise_before_rounding`), and the rounding no longer
#: matters (``v`` below ``1e-5 q^2``).
DITHERED = 0.7


def hold_rounding(blocks: list[np.ndarray], q: float, s: float) -> tuple[float, float]:
    """The noise before the rounding and the variance of a hold mean's rounding error that
    its samples do not average away, for holds whose samples show the per-sample noise ``s``
    (raw units; one channel, or channels alike).

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


def rounding_covariance(means: np.ndarray, sigma: float, q: float) -> np.ndarray:
    """Covariance of the rounding errors of hold means whose inputs lie ``means`` apart (one
    channel): ``C_ij = q^2 / (2 pi^2) sum_k exp(-4 pi^2 k^2 sigma^2 / q^2) cos(2 pi k (m_i -
    m_j) / q) / k^2``, the module's sawtooth at two places the same distance apart wherever
    the first sits.  Inputs at the same place share the whole ``v``; a step and a half apart
    the errors are opposite; many steps apart with noise, independent on average.

    Parameters
    ----------
    means : ndarray (P,)
        The holds' means (their inputs, to well within a step), raw units.
    sigma, q : float
        Noise before the rounding and the step, raw units.

    Returns
    -------
    ndarray (P, P)
        raw units^2 (zeros for ``q`` 0).
    """
    m = np.asarray(means, float)
    if q <= 0:
        return np.zeros((len(m), len(m)))
    x = np.mod((m[:, None] - m[None, :]) / q, 1.0)
    if sigma <= 0:  # sum_k cos(2 pi k x) / k^2 = pi^2 (1/6 - x + x^2) on [0, 1]
        return q * q / (2 * np.pi**2) * np.pi**2 * (1.0 / 6 - x + x * x)
    K = int(min(HARMONICS, np.ceil(np.sqrt(np.log(1e12)) / (2 * np.pi * sigma / q)) + 1))
    out = np.zeros_like(x)
    for k in range(1, K + 1):
        out += np.exp(-4 * np.pi**2 * k * k * (sigma / q) ** 2) * np.cos(2 * np.pi * k * x) / k**2
    return q * q / (2 * np.pi**2) * out
