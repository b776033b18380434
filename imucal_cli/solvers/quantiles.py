"""Distribution functions the solvers need, in pure Python/numpy (no ``scipy.special``).

``scipy.special`` costs about 0.3 s of start-up (and ``scipy.stats`` more) for a handful of
numbers per calibration: chi-square quantiles for the noise checks, a normal quantile, a
Student t quantile for confidence intervals, chi-square and F tail probabilities. Each is
computed here to about 1e-12 relative (tested against scipy in ``tests/test_quantiles.py``):
the regularised incomplete gamma and beta functions (Numerical Recipes 6.2 and 6.4: series
and Lentz's continued fractions), inverted by safeguarded Newton; the Student t quantile at
1000 or more degrees of freedom by its Cornish-Fisher expansion (about 1e-16 there).

The names and argument orders of ``scipy.special`` are kept (``chdtri(v, p)``,
``chdtrc(v, x)``, ``ndtri(p)``, ``stdtrit(df, p)``, ``fdtrc(dfn, dfd, x)``); they take
scalars or arrays.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np


def _gamma_p_q(a: float, x: float) -> tuple[float, float]:
    """Regularised incomplete gamma functions ``(P(a, x), Q(a, x))``: the series below
    ``a + 1``, Lentz's continued fraction for ``Q`` above (Numerical Recipes 6.2)."""
    if x <= 0.0:
        return 0.0, 1.0
    log_front = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:
        term = total = 1.0 / a
        n = a
        for _ in range(10_000):
            n += 1.0
            term *= x / n
            total += term
            if abs(term) < abs(total) * 1e-17:
                break
        p = total * math.exp(log_front)
        return p, 1.0 - p
    tiny = 1e-300
    b = x + 1.0 - a
    c = 1.0 / tiny
    d = 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    q = math.exp(log_front) * h
    return 1.0 - q, q


@lru_cache(maxsize=1024)  # the solvers ask for the same few quantiles per pose
def _chi2_quantile(dof: float, prob: float, upper: bool) -> float:
    """``x`` with ``P(chi2_dof <= x) = prob`` (``upper``: ``P(chi2_dof > x) = prob``)."""
    if upper and prob > 0.5:  # the lower tail is the small one: no cancellation in 1 - Q
        upper, prob = False, 1.0 - prob
    elif not upper and prob > 0.5:
        upper, prob = True, 1.0 - prob
    a = dof / 2.0
    # Wilson-Hilferty start, then safeguarded Newton on the tail that is not near 1.
    z = _normal_quantile(prob if not upper else 1.0 - prob) if 0 < prob < 1 else 0.0
    if upper:
        z = -_normal_quantile(prob)
    h = 2.0 / (9.0 * dof)
    x = max(dof * (1.0 - h + z * math.sqrt(h)) ** 3, 1e-8) / 2.0
    lo, hi = 0.0, math.inf
    for _ in range(200):
        p, q = _gamma_p_q(a, x)
        f = (q - prob) if upper else (p - prob)
        if (f > 0) != upper:
            hi = x
        else:
            lo = x
        density = math.exp(-x + (a - 1.0) * math.log(x) - math.lgamma(a))
        new = x - f / density * (-1.0 if upper else 1.0) if density > 0 else math.nan
        if not (lo < new < hi):
            new = (lo + hi) / 2.0 if math.isfinite(hi) else 2.0 * x
        if abs(new - x) <= 1e-15 * x:
            x = new
            break
        x = new
    return 2.0 * x


def _normal_quantile(p: float) -> float:
    """Standard normal quantile (Acklam's rational approximation, about 1e-9): a start."""
    a = (
        -3.969683028665376e01,
        2.209460984245205e02,
        -2.759285104469687e02,
        1.383577518672690e02,
        -3.066479806614716e01,
        2.506628277459239e00,
    )
    b = (
        -5.447609879822406e01,
        1.615858368580409e02,
        -1.556989798598866e02,
        6.680131188771972e01,
        -1.328068155288572e01,
    )
    c = (
        -7.784894002430293e-03,
        -3.223964580411365e-01,
        -2.400758277161838e00,
        -2.549732539343734e00,
        4.374664141464968e00,
        2.938163982698783e00,
    )
    d = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e00,
         3.754408661907416e00)  # fmt: skip
    if p < 0.02425:
        t = math.sqrt(-2.0 * math.log(p))
        num = ((((c[0] * t + c[1]) * t + c[2]) * t + c[3]) * t + c[4]) * t + c[5]
        return num / ((((d[0] * t + d[1]) * t + d[2]) * t + d[3]) * t + 1.0)
    if p > 1.0 - 0.02425:
        return -_normal_quantile(1.0 - p)
    t = (p - 0.5) ** 2
    num = (((((a[0] * t + a[1]) * t + a[2]) * t + a[3]) * t + a[4]) * t + a[5]) * (p - 0.5)
    return num / (((((b[0] * t + b[1]) * t + b[2]) * t + b[3]) * t + b[4]) * t + 1.0)


def chi2_ppf(q: float, dof: float) -> float:
    """Quantile ``q`` of the chi-square distribution with ``dof`` degrees of freedom (lower
    tail), to about 1e-13 relative: inverse of the regularised incomplete gamma function by
    safeguarded Newton."""
    return _chi2_quantile(float(dof), float(q), upper=False)


def chi2_isf(p: float, dof: float) -> float:
    """Upper-tail quantile: ``x`` with ``P(chi2_dof > x) = p`` (accurate for tiny ``p``)."""
    return _chi2_quantile(float(dof), float(p), upper=True)


# --------------------------------------------------------------------------- normal, t, F


def _normal_ppf(p: float) -> float:
    """Standard normal quantile to full precision: Acklam's start, two Halley steps on
    ``erfc``."""
    if not 0.0 < p < 1.0:
        return -math.inf if p == 0.0 else (math.inf if p == 1.0 else math.nan)
    if p > 0.5:
        return -_normal_ppf(1.0 - p)
    x = _normal_quantile(p)
    for _ in range(2):
        e = 0.5 * math.erfc(-x / math.sqrt(2.0)) - p
        u = e * math.sqrt(2.0 * math.pi) * math.exp(x * x / 2.0)
        x = x - u / (1.0 + x * u / 2.0)
    return x


def _beta_cf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (Lentz; Numerical Recipes 6.4)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (tiny if abs(d) < tiny else d)
    h = d
    for m in range(1, 10_000):
        m2 = 2 * m
        for num in (m * (b - m) * x / ((a + m2 - 1) * (a + m2)),
                    -(a + m) * (a + b + m) * x / ((a + m2) * (a + m2 + 1))):  # fmt: skip
            d = 1.0 + num * d
            d = 1.0 / (tiny if abs(d) < tiny else d)
            c = 1.0 + num / c
            c = tiny if abs(c) < tiny else c
            h *= d * c
        if abs(d * c - 1.0) < 1e-16:
            break
    return h


def betainc(a: float, b: float, x: float) -> float:
    """Regularised incomplete beta function ``I_x(a, b)``."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x)
                 + b * math.log1p(-x))  # fmt: skip
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_cf(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_cf(b, a, 1.0 - x) / b


def _t_sf(t: float, df: float) -> float:
    """``P(T_df > t)``."""
    tail = 0.5 * betainc(df / 2.0, 0.5, df / (df + t * t))
    return tail if t >= 0 else 1.0 - tail


def _t_ppf(p: float, df: float) -> float:
    """Student t quantile: at large ``df`` Cornish-Fisher's expansion where it is exact to
    rounding (:func:`_t_upper_expansion`), else Newton on the upper tail (bisection where
    Newton leaves the bracket), started from the normal quantile."""
    if not 0.0 < p < 1.0:
        return -math.inf if p == 0.0 else (math.inf if p == 1.0 else math.nan)
    if p == 0.5:
        return 0.0
    sign, q = (-1.0, p) if p < 0.5 else (1.0, 1.0 - p)  # find t > 0 with P(T > t) = q
    t = _t_upper_expansion(q, df)
    return sign * (t if t is not None else _t_upper(q, df))


#: The expansion serves from this many degrees of freedom up ...
T_EXPANSION_MIN_DF = 1000.0
#: ... where its last term is at most this fraction of the quantile (the first term left out
#: is then below 1e-15 of it: 3e-19 at df = 1000 and p = 0.975, 4e-15 at df = 1000 and
#: p = 1 - 1e-7, which the bound sends to Newton; checked against mpmath in the tests).
T_EXPANSION_LAST_TERM = 1e-13


def _t_upper_expansion(q: float, df: float) -> float | None:
    """``t > 0`` with ``P(T_df > t) = q < 0.5`` by the Cornish-Fisher expansion of the t
    quantile about the normal one ``z`` (Abramowitz & Stegun 26.7.5, Hill 1970), five terms::

        t = z + g1/df + g2/df^2 + g3/df^3 + g4/df^4 + g5/df^5,

    or None where the last term shows that five are not enough (small ``df``, far tails).
    The Newton solve it replaces needs 20 evaluations of the incomplete beta function, each
    a continued fraction of ``sqrt(df)`` terms: 1.3 ms at 35,000 degrees of freedom (the
    labelled solver's t intervals), here 10 us. It is also the more accurate there (the
    incomplete beta's prefactor, from lgamma of ``df / 2``, loses about 1e-11 at 35,000)."""
    if df < T_EXPANSION_MIN_DF:
        return None
    z = -_normal_ppf(q)
    z2 = z * z
    g1 = (z2 + 1.0) * z / 4.0
    g2 = ((5.0 * z2 + 16.0) * z2 + 3.0) * z / 96.0
    g3 = (((3.0 * z2 + 19.0) * z2 + 17.0) * z2 - 15.0) * z / 384.0
    g4 = ((((79.0 * z2 + 776.0) * z2 + 1482.0) * z2 - 1920.0) * z2 - 945.0) * z / 92160.0
    g5 = (((((27.0 * z2 + 339.0) * z2 + 930.0) * z2 - 1782.0) * z2 - 765.0) * z2
          + 17955.0) * z / 368640.0  # fmt: skip
    v = 1.0 / df
    last = g5 * v**5
    if not abs(last) <= T_EXPANSION_LAST_TERM * z:
        return None
    return z + v * (g1 + v * (g2 + v * (g3 + v * (g4 + v * g5))))


def _t_upper(q: float, df: float) -> float:
    """``t > 0`` with ``P(T_df > t) = q < 0.5``."""
    p = 1.0 - q
    t = max(_normal_ppf(p), 1e-3)
    lo, hi = 0.0, math.inf
    log_c = math.lgamma((df + 1) / 2) - math.lgamma(df / 2) - 0.5 * math.log(df * math.pi)
    for _ in range(300):
        f = _t_sf(t, df) - q
        if f > 0:
            lo = t
        else:
            hi = t
        density = math.exp(log_c - (df + 1) / 2 * math.log1p(t * t / df))
        new = t + f / density
        if not lo < new < hi:
            new = (lo + hi) / 2.0 if math.isfinite(hi) else 2.0 * t
        if abs(new - t) <= 1e-15 * t:
            return new
        t = new
    return t


def _elementwise(fn, *args):
    """Apply a scalar function to scalars (a float back) or arrays (broadcast)."""
    if all(np.ndim(a) == 0 for a in args):
        return float(fn(*(float(a) for a in args)))
    arrays = np.broadcast_arrays(*(np.asarray(a, float) for a in args))
    out = np.array([fn(*vals) for vals in zip(*(a.ravel() for a in arrays), strict=True)])
    return out.reshape(arrays[0].shape)


# --------------------------------------------------------------------------- scipy.special names


def chdtri(v, p):
    """``x`` with ``P(chi2_v > x) = p`` (scipy.special.chdtri)."""
    return _elementwise(lambda v_, p_: chi2_isf(p_, v_), v, p)


def chdtrc(v, x):
    """``P(chi2_v > x)`` (scipy.special.chdtrc)."""
    return _elementwise(lambda v_, x_: _gamma_p_q(v_ / 2.0, x_ / 2.0)[1], v, x)


def ndtri(p):
    """Standard normal quantile (scipy.special.ndtri)."""
    return _elementwise(_normal_ppf, p)


def stdtrit(df, p):
    """Student t quantile: ``t`` with ``P(T_df <= t) = p`` (scipy.special.stdtrit)."""
    return _elementwise(lambda d, p_: _t_ppf(p_, d), df, p)


def fdtrc(dfn, dfd, x):
    """``P(F_{dfn, dfd} > x)`` (scipy.special.fdtrc)."""
    return _elementwise(
        lambda a, b, x_: 1.0 if x_ <= 0 else betainc(b / 2.0, a / 2.0, b / (b + a * x_)),
        dfn, dfd, x,
    )  # fmt: skip
