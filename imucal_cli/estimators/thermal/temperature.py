"""Temperature dependence of a sensor's bias: each channel's bias a polynomial in temperature.

Model (the formats page's ``temperature_ref`` and ``bias_tempco``)::

    bias(T) = bias + sum_{k=1..K} c_k (T - T_ref)^k          raw units, per channel

This module fits the polynomial to points ``(T_i, y_i)`` of one channel or several: the means
of a still warm-up recording over short blocks of time (the level is gravity's projection
plus the bias, or the gyro's bias itself), or the means of still periods at different
temperatures (gyro, several sessions). Each point may have its own level (``groups``: a unit
put down in another orientation keeps the same temperature curve). The joint fit inside the
accelerometer's gravity-magnitude model is :mod:`imucal_cli.estimators.thermal.joint`.

**Degree** (at most :data:`MAX_DEGREE`): backward elimination, per channel. The highest term
is dropped while an F-test of the drop in the residual sum of squares, against the residual
variance of the larger model, is not significant at :data:`SELECT_P`; degree 0 means no
significant dependence. A polynomial is only fitted where the design can determine it (more
distinct temperatures than terms, residual degrees of freedom left).

**Aliased terms are kept.** A term the test cannot find is dropped only when holding it at
zero cannot move the kept coefficients: the variance its uncertainty adds to each of them
(through the alias matrix, :func:`alias_inflation`) is at most :data:`ALIAS_MAX` of that
coefficient's variance without it. Held at zero, a term of ``u`` of its std (``|u| < 2.6``,
undetected at 1 %) shifts a kept coefficient by ``sqrt(lambda) u`` of that coefficient's std
(``lambda`` its inflation); over 5-40 C, ``(T - T_ref)^3`` and ``T - T_ref`` are so alike that
``lambda`` is 2-4, and no interval about the smaller fit's estimate covers such shifts without
being wider than the larger fit's own (the pre-test estimator's coverage; Leeb & Poetscher
2005, Econometric Theory 21). So on such spans the degree stays the highest the design
determines, and its intervals are the fit's own. What a dropped term still adds (at most
``ALIAS_MAX``) is carried by :func:`consider_cov`.

**Correlated residuals.** The points of a recording follow each other in time, and what the
polynomial leaves (bias instability, flicker, the temperature sensor's lag) is correlated
from one point to the next. With ``serial=True`` the lag-1 autocorrelation ``rho`` of the
residuals inflates the covariance and deflates the F-test's degrees of freedom by
``(1 + rho) / (1 - rho)`` (an AR(1) noise's effective sample size), so that the standard
deviations stay honest and correlated wander does not pass for a cubic.

**Span.** A fit over less than :data:`MIN_SPAN_C` is refused (:func:`check_span`): the bias
change across a narrow span is of the order of the noise and of run-to-run drift, and a
polynomial extrapolated outside its span grows as ``(distance / span)^degree``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from math import comb

import numpy as np
from scipy.special import chdtri, fdtrc

from imucal_cli.errors import DesignError

__all__ = [
    "ALIAS_MAX",
    "MAX_DEGREE",
    "MIN_SPAN_C",
    "SELECT_P",
    "UNFITTED_FRACTION",
    "UNFITTED_HALF_SPAN_C",
    "ChannelFit",
    "TempcoFit",
    "alias_inflation",
    "check_span",
    "consider_cov",
    "f1_pvalue",
    "fit_tempco",
    "noise_scale",
    "polynomial_bound",
    "powers",
    "reexpand",
    "unfitted_prior",
]

#: Highest degree of the bias polynomial.
MAX_DEGREE = 3
#: Smallest temperature span a temperature model is fitted over, degrees C.
MIN_SPAN_C = 10.0
#: A polynomial term is kept when the F-test of dropping it gives a p-value below this.
SELECT_P = 0.01
#: A term the F-test cannot find is still kept when dropping it would take more than this
#: fraction off a kept coefficient's variance (:func:`alias_inflation`). At 0.1, a dropped
#: term's largest undetected shift (2.6 of its std, the 1 % test's edge) moves a kept one by
#: 0.8 of its std: with :func:`consider_cov`, 93.1 % of the 95 % intervals or more cover,
#: whatever the term's size (one term, a normal model, drops and keeps together; worst at 2.5
#: of its std), and the kept ones lose at most 5 % of their std.
ALIAS_MAX = 0.1
#: The prior of a term the design cannot fit (:func:`unfitted_prior`): its largest bias change
#: at :data:`UNFITTED_HALF_SPAN_C` from ``T_ref``, as a fraction of the linear term's at the
#: sensor's datasheet tempco: a quadratic 30 %, a cubic 10 % (MEMS bias curves are fitted with
#: cubics, PX4's ``TC_*_X3`` and ArduPilot's ``INS_TCAL``; their higher terms are smaller).
UNFITTED_FRACTION = {2: 0.3, 3: 0.1}
#: Half the span over which :data:`UNFITTED_FRACTION` holds, degrees C.
UNFITTED_HALF_SPAN_C = 15.0


def noise_scale(chi2: float, dof: float, known_sigma: bool) -> float:
    """The factor on a least-squares covariance from its residuals: ``chi2/dof`` where the
    noise is unknown, or given but exceeded (``chi2`` beyond the 99th percentile of
    ``chi^2(dof)``), else 1 (the given noise explains the residuals)."""
    if not known_sigma:
        return chi2 / dof
    return chi2 / dof if dof > 0 and chi2 > chdtri(dof, 0.01) else 1.0


def unfitted_prior(linear_max: float, degrees) -> dict[int, float]:
    """Prior standard deviation of each polynomial term a design cannot fit, per degree.

    A term the poses cannot determine is still in the part's bias; held at zero it shifts the
    fitted ones by ``A c`` (``A`` the alias matrix), which no fit of those poses can see. With
    ``c`` drawn from a prior of variance ``P`` that shift has covariance ``A P A^T`` (a Schmidt
    consider parameter, the truncation error in the std): uniform within
    ``UNFITTED_FRACTION[k] linear_max h / h^k`` (``h`` = :data:`UNFITTED_HALF_SPAN_C`), so
    ``std = that / sqrt(3)``.

    Parameters
    ----------
    linear_max : float
        The sensor's largest linear bias coefficient (its datasheet's tempco), units per C.
    degrees : iterable of int
        The degrees not fitted (2 or 3).

    Returns
    -------
    dict
        ``{degree: std}``, units per C^degree.
    """
    h = UNFITTED_HALF_SPAN_C
    return {int(k): UNFITTED_FRACTION[int(k)] * linear_max * h / h ** int(k) / np.sqrt(3.0)
            for k in degrees}  # fmt: skip


def alias_inflation(cov_big: np.ndarray, cov_small: np.ndarray) -> float:
    """How much dropping terms narrows the coefficients kept: the largest
    ``var_big / var_small - 1`` over them (``lambda``: ``A C_drop A^T``'s diagonal over the
    smaller fit's variance, as ``C_big,kept = C_small + A C_drop A^T`` for nested least squares).

    Parameters
    ----------
    cov_big : ndarray, shape (p, p)
        The larger fit's covariance, its first ``k`` coefficients the kept ones (same scale).
    cov_small : ndarray, shape (k, k)
        The smaller fit's covariance (same weights and scale).
    """
    k = cov_small.shape[0]
    small = np.diag(cov_small)
    ok = small > 0
    return float(np.max(np.diag(cov_big)[:k][ok] / small[ok] - 1.0, initial=0.0))


def consider_cov(A: np.ndarray, delta: np.ndarray, cov_delta: np.ndarray) -> np.ndarray:
    """What terms held at zero add to the kept coefficients' covariance: they shift them by
    ``A delta`` (omitted-variable bias, ``A`` the alias matrix), and ``delta_hat delta_hat^T
    - C_delta`` estimates ``delta delta^T`` without bias (``E[delta_hat delta_hat^T] = delta
    delta^T + C_delta``); clipped to positive semi-definite (an estimate cannot take variance
    away): ``A max(delta_hat delta_hat^T - C_delta, 0) A^T``, shape (k, k)."""
    w, V = np.linalg.eigh(np.outer(delta, delta) - cov_delta)
    return A @ (V * np.clip(w, 0.0, None)) @ V.T @ A.T


def f1_pvalue(F: float, dof: float) -> float:
    """Upper tail ``P(F(1, dof) > F)`` of Fisher's F with one numerator degree of freedom
    (``dof`` may be fractional)."""
    return float(fdtrc(1.0, dof, max(F, 0.0)))


def check_span(temperature: np.ndarray, what: str, min_span_c: float = MIN_SPAN_C) -> float:
    """The span of ``temperature`` (degrees C); refused below ``min_span_c``, saying why.

    Raises
    ------
    DesignError
        No finite temperature, or a span under ``min_span_c``.
    """
    t = np.asarray(temperature, float)
    t = t[np.isfinite(t)]
    if len(t) == 0:
        raise DesignError(f"{what}: no temperature readings (/raw/temperature): a temperature "
                          "model needs the sensor's temperature with every sample")  # fmt: skip
    lo, hi = float(t.min()), float(t.max())
    span = hi - lo
    if span < min_span_c:
        raise DesignError(
            f"{what}: the temperature spans only {span:.1f} C ({lo:.1f} .. {hi:.1f} C); a bias "
            f"model fitted over less than {min_span_c:g} C is swamped by noise and run-to-run "
            "drift and grows wrong fast outside its span: record through at least "
            f"{min_span_c:g} C (a cold start or a hair-dryer ramp, see docs/temperature.md)"
        )
    return span


def powers(temperature: np.ndarray, temperature_ref: float, degree: int) -> np.ndarray:
    """``(T - T_ref)^k`` for ``k = 1 .. degree``, shape (N, degree)."""
    dt = np.asarray(temperature, float) - temperature_ref
    return dt[:, None] ** np.arange(1, degree + 1)[None, :]


def reexpand(tempco: np.ndarray, old_ref: float, new_ref: float) -> tuple[np.ndarray, np.ndarray]:
    """The same polynomial about another reference temperature.

    ``sum_k c_k (T - old_ref)^k = d_0 + sum_k d_k (T - new_ref)^k``.

    Parameters
    ----------
    tempco : ndarray, shape (K, n)
        ``c_1 .. c_K`` per channel.

    Returns
    -------
    d0 : ndarray (n,)
        The polynomial's value at ``new_ref`` (the bias change from ``old_ref`` to it).
    d : ndarray (K, n)
        The coefficients about ``new_ref``.
    """
    c = np.vstack([np.zeros((1, tempco.shape[1])), np.asarray(tempco, float)])  # c_0 = 0
    K = c.shape[0] - 1
    s = new_ref - old_ref
    out = np.zeros_like(c)
    for k in range(K + 1):  # (x + s)^k = sum_j comb(k, j) s^(k-j) x^j
        for j in range(k + 1):
            out[j] += comb(k, j) * s ** (k - j) * c[k]
    return out[0], out[1:]


@dataclass
class ChannelFit:
    """One channel's polynomial.

    Attributes
    ----------
    degree : int
        Chosen degree (0: no significant dependence).
    level : ndarray (G,)
        Value at ``T_ref`` of each group's curve, raw units.
    tempco : ndarray (degree,)
        ``c_1 .. c_degree``, raw units per C^k.
    cov : ndarray (G + degree, G + degree)
        Covariance of ``(level, tempco)`` (after ``noise_scale`` and the correlation factor).
    residual_rms : float
        RMS of the residuals (unweighted), raw units.
    noise_scale : float
        Factor on the covariance from the residuals: ``chi2/dof`` (unknown or exceeded noise)
        or 1 (the given noise explains them).
    correlation : float
        Lag-1 autocorrelation of the residuals used for the inflation (0 unless serial).
    tests : list of dict
        The backward elimination: per degree tried, ``F``, ``dof``, ``p_value`` of its top
        term, ``alias`` (:func:`alias_inflation` of dropping it) and ``kept``.
    """

    degree: int
    level: np.ndarray
    tempco: np.ndarray
    cov: np.ndarray
    residual_rms: float
    noise_scale: float
    correlation: float
    tests: list[dict] = field(default_factory=list)

    @property
    def tempco_cov(self) -> np.ndarray:
        G = len(self.level)
        return self.cov[G:, G:]


@dataclass
class TempcoFit:
    """Result of :func:`fit_tempco`: every channel's polynomial about one reference.

    Attributes
    ----------
    temperature_ref : float
        ``T_ref``, degrees C.
    t_min, t_max : float
        Temperature range of the data, degrees C (the model's valid range).
    channels : list of ChannelFit
    n_points : int
    """

    temperature_ref: float
    t_min: float
    t_max: float
    channels: list[ChannelFit]
    n_points: int

    @property
    def degree(self) -> np.ndarray:
        """Chosen degree per channel, (n,)."""
        return np.array([c.degree for c in self.channels], dtype=int)

    @property
    def K(self) -> int:
        """Number of ``bias_tempco`` vectors: the highest degree of any channel."""
        return int(self.degree.max(initial=0))

    @property
    def tempco(self) -> np.ndarray:
        """``bias_tempco`` (K, n): zero above a channel's degree, raw units per C^k."""
        out = np.zeros((self.K, len(self.channels)))
        for i, c in enumerate(self.channels):
            out[: c.degree, i] = c.tempco
        return out

    @property
    def tempco_std(self) -> np.ndarray:
        """Standard deviations of :attr:`tempco` (0 where a term is not in the model)."""
        out = np.zeros((self.K, len(self.channels)))
        for i, c in enumerate(self.channels):
            out[: c.degree, i] = np.sqrt(np.clip(np.diag(c.tempco_cov), 0, None))
        return out

    @property
    def level(self) -> np.ndarray:
        """Each group's value at ``T_ref`` (G, n), raw units."""
        return np.column_stack([c.level for c in self.channels])

    @property
    def level_std(self) -> np.ndarray:
        return np.column_stack(
            [np.sqrt(np.clip(np.diag(c.cov)[: len(c.level)], 0, None)) for c in self.channels]
        )

    def change(self, temperature: np.ndarray) -> np.ndarray:
        """Bias change from ``T_ref`` at each temperature, (N, n) raw units."""
        return powers(temperature, self.temperature_ref, self.K) @ self.tempco

    def change_std(self, temperature: np.ndarray) -> np.ndarray:
        """Standard deviation of :meth:`change` (the curve's shape, level excluded), (N, n)."""
        t = np.asarray(temperature, float)
        out = np.zeros((len(t), len(self.channels)))
        for i, c in enumerate(self.channels):
            if c.degree:
                X = powers(t, self.temperature_ref, c.degree)
                out[:, i] = np.sqrt(np.clip(np.einsum("nj,jk,nk->n", X, c.tempco_cov, X), 0,
                                            None))  # fmt: skip
        return out


def _lag1(r: np.ndarray) -> float:
    """Lag-1 autocorrelation of a residual series, clipped to [0, 0.95]."""
    r = r - r.mean()
    den = float(r @ r)
    if len(r) < 3 or den <= 0:
        return 0.0
    return float(np.clip((r[1:] @ r[:-1]) / den, 0.0, 0.95))


def _design(dt: np.ndarray, groups: np.ndarray, n_groups: int, degree: int) -> np.ndarray:
    """Columns: one indicator per group (its level), then ``dt^1 .. dt^degree``."""
    X = np.zeros((len(dt), n_groups + degree))
    X[np.arange(len(dt)), groups] = 1.0
    X[:, n_groups:] = dt[:, None] ** np.arange(1, degree + 1)[None, :]
    return X


@dataclass
class _Solved:
    beta: np.ndarray
    XtX_inv: np.ndarray
    chi2: float
    dof: int
    r: np.ndarray  # unweighted residuals


def _wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> _Solved | None:
    """Weighted least squares; None when ``X`` does not determine the coefficients."""
    Xw = X * w[:, None]
    yw = y * w
    sv = np.linalg.svd(Xw, compute_uv=False)
    if len(sv) < X.shape[1] or sv[-1] <= 1e-10 * sv[0]:
        return None
    beta, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
    rw = yw - Xw @ beta
    return _Solved(beta, np.linalg.inv(Xw.T @ Xw), float(rw @ rw), len(y) - X.shape[1],
                   y - X @ beta)  # fmt: skip


def _scaled_cov(s: _Solved, known_sigma: bool, serial: bool) -> tuple[np.ndarray, float, float]:
    """A fit's covariance with the residuals' scale (:func:`noise_scale`) and the AR(1)
    inflation ``(1 + rho) / (1 - rho)``; the scale and ``rho``."""
    rho = _lag1(s.r) if serial else 0.0
    infl = (1 + rho) / (1 - rho)
    scale = noise_scale(s.chi2, s.dof, known_sigma)
    return s.XtX_inv * scale * infl, float(scale), float(rho)


def _held_terms(dt, w, groups, n_groups, d, top, small: _Solved, big: _Solved,
                known_sigma: bool, serial: bool) -> np.ndarray:  # fmt: skip
    """What the terms of degree ``d+1 .. top`` the F-tests dropped add to the covariance of
    the degree-``d`` fit: held at zero, they shift the kept coefficients by ``A delta``
    (``A = (X_d^T W X_d)^-1 X_d^T W X_drop``, the alias matrix), ``delta`` known as the
    degree-``top`` fit's estimate with its covariance (:func:`consider_cov`)."""
    X = _design(dt, groups, n_groups, top) * w[:, None]
    kept, drop = X[:, : n_groups + d], X[:, n_groups + d :]
    A = small.XtX_inv @ (kept.T @ drop)
    cov_big, _, _ = _scaled_cov(big, known_sigma, serial)
    delta = big.beta[n_groups + d :]
    return consider_cov(A, delta, cov_big[n_groups + d :, n_groups + d :])


def _fit_channel(dt, y, w, groups, n_groups, max_degree, known_sigma, serial, select_p):
    """Backward elimination from the highest degree the design determines."""
    fits: dict[int, _Solved] = {}
    for d in range(max_degree, -1, -1):
        s = _wls(_design(dt, groups, n_groups, d), y, w)
        if s is not None and s.dof >= 1:
            fits[d] = s
    if not fits:
        raise DesignError("the points cannot determine even a constant per group")
    d = max(fits)
    tests = []
    while d > 0 and d - 1 in fits:
        big, small = fits[d], fits[d - 1]
        rho = _lag1(big.r) if serial else 0.0
        infl = (1 + rho) / (1 - rho)
        dof = max(big.dof / infl, 1.0)
        F = max(small.chi2 - big.chi2, 0.0) / max(big.chi2 / big.dof, 1e-300) / infl
        p = f1_pvalue(F, dof)
        lam = alias_inflation(big.XtX_inv, small.XtX_inv)
        tests.append({"degree": d, "F": float(F), "dof": [1, float(dof)], "p_value": p,
                      "alias": lam, "kept": bool(p < select_p or lam > ALIAS_MAX)})  # fmt: skip
        if tests[-1]["kept"]:
            break
        d -= 1
    s = fits[d]
    cov, scale, rho = _scaled_cov(s, known_sigma, serial)
    top = max(fits)
    if d < top:  # the terms the F-tests dropped are held at zero, not known to be zero
        cov = cov + _held_terms(dt, w, groups, n_groups, d, top, s, fits[top], known_sigma,
                                serial)  # fmt: skip
    return ChannelFit(
        degree=d, level=s.beta[:n_groups].copy(), tempco=s.beta[n_groups:].copy(), cov=cov,
        residual_rms=float(np.sqrt(np.mean(s.r**2))), noise_scale=float(scale),
        correlation=float(rho), tests=tests,
    )  # fmt: skip


def _clean(temperature, values, sigma, groups, max_degree):
    """Validated ``(T (N,), Y (N, n), groups (N,), sigma (N, n) or None)``, non-finite rows
    left out."""
    T = np.asarray(temperature, float)
    Y = np.asarray(values, float)
    Y = Y[:, None] if Y.ndim == 1 else Y
    if not 1 <= max_degree <= MAX_DEGREE:
        raise ValueError(f"max_degree must be 1 .. {MAX_DEGREE}, not {max_degree}")
    if T.ndim != 1 or len(T) != len(Y):
        raise ValueError("temperature must be (N,) and values (N, n)")
    ok = np.isfinite(T) & np.isfinite(Y).all(axis=1)
    g = np.zeros(len(T), int) if groups is None else np.asarray(groups, int)
    sig = None
    if sigma is not None:
        sig = np.asarray(sigma, float)
        sig = np.broadcast_to(sig[:, None] if sig.ndim == 1 else sig, Y.shape)
        ok &= np.isfinite(sig).all(axis=1) & (sig > 0).all(axis=1)
        sig = sig[ok]
    return T[ok], Y[ok], g[ok], sig


def fit_tempco(
    temperature: np.ndarray,
    values: np.ndarray,
    *,
    sigma: np.ndarray | None = None,
    groups: np.ndarray | None = None,
    temperature_ref: float | None = None,
    max_degree: int = MAX_DEGREE,
    min_span_c: float = MIN_SPAN_C,
    serial: bool = False,
    select_p: float = SELECT_P,
    what: str = "the data",
) -> TempcoFit:
    """Fit each channel's bias as a polynomial in temperature, its degree chosen by the data.

    Parameters
    ----------
    temperature : ndarray, shape (N,)
        Temperature of each point, degrees C.
    values : ndarray, shape (N, n) or (N,)
        The channels at each point, raw units (a mean over a block of a still recording, or
        over a still period).
    sigma : ndarray, shape (N,) or (N, n), optional
        Standard deviation of each point, raw units: the weights, and the noise the
        covariance assumes unless the residuals exceed it (chi-square test at 1 %). Omitted:
        equal weights, noise from the residuals.
    groups : ndarray of int, shape (N,), optional
        Group of each point (0 .. G-1): each group has its own level (an orientation of the
        unit, a session); the temperature terms are shared. Default: one group.
    temperature_ref : float, optional
        ``T_ref``; default the mean temperature of the points.
    max_degree : int
        Highest degree tried (1 .. 3).
    min_span_c : float
        Refuse a temperature span below this, degrees C.
    serial : bool
        The points are a time series: inflate for the residuals' lag-1 correlation.
    select_p : float
        Significance level of the backward elimination.
    what : str
        Names the data in messages.

    Returns
    -------
    TempcoFit

    Raises
    ------
    DesignError
        Fewer than 3 points, a span under ``min_span_c``, or points that determine no
        polynomial.
    """
    T, Y, g, sig = _clean(temperature, values, sigma, groups, max_degree)
    if len(T) < 3:
        raise DesignError(f"{what}: {len(T)} points with a temperature cannot determine a "
                          "temperature model")  # fmt: skip
    check_span(T, what, min_span_c)
    _, g = np.unique(g, return_inverse=True)
    G = int(g.max()) + 1
    t_ref = float(np.mean(T)) if temperature_ref is None else float(temperature_ref)
    dt = T - t_ref
    channels = []
    for i in range(Y.shape[1]):
        w = np.ones(len(T)) if sig is None else 1.0 / sig[:, i]
        try:
            channels.append(_fit_channel(dt, Y[:, i], w, g, G, max_degree, sigma is not None,
                                         serial, select_p))  # fmt: skip
        except DesignError:
            raise DesignError(
                f"{what}: {len(T)} points at {len(np.unique(np.round(T, 3)))} temperatures in "
                f"{G} group(s) cannot determine a temperature model: record more of the ramp"
            ) from None
    return TempcoFit(t_ref, float(T.min()), float(T.max()), channels, len(T))


def polynomial_bound(
    temperature: np.ndarray, sigma: float | np.ndarray, degree: int, temperature_ref: float,
    groups: np.ndarray | None = None,
) -> np.ndarray:  # fmt: skip
    """Cramér-Rao bound of ``(levels, c_1 .. c_degree)`` for independent Gaussian points.

    ``sigma^2 (X^T X)^-1`` with ``X`` the design of :func:`fit_tempco` (per-point ``sigma``
    weights the rows): what no unbiased estimator of a degree-``degree`` polynomial can beat
    on these temperatures with white noise.
    """
    T = np.asarray(temperature, float)
    g = np.zeros(len(T), int) if groups is None else np.unique(groups, return_inverse=True)[1]
    X = _design(T - temperature_ref, g, int(g.max()) + 1, degree)
    w = 1.0 / np.broadcast_to(np.asarray(sigma, float), T.shape)
    Xw = X * w[:, None]
    return np.linalg.inv(Xw.T @ Xw)
