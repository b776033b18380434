"""The accelerometer's bias temperature model fitted jointly with its gravity-magnitude model.

Qureshi & Golnaraghi's static model (eq. 8) with a bias that follows the temperature of each
pose (the formats page's ``bias_tempco``)::

    h_k = M (a_k - B - sum_j c_j (T_k - T_ref)^j),        |h_k| = g              (8), (11)

``M`` upper triangular (eq. 3), ``B`` the bias at ``T_ref``, ``c_j`` (3,) the coefficients of
degree ``j`` per channel (raw units per C^j). Poses held at different temperatures during a
warm-up or a hair-dryer ramp separate the temperature terms from the bias: a bias error
changes ``|h|`` differently in different orientations, so each channel's bias is observable at
every temperature the poses visit.

The minimised quantity is eq. (11)'s, ``(|h_k|^2 - g^2) / (2 g)`` in m/s^2, weighted by each
pose mean's noise (as :mod:`imucal_cli.estimators.accel.gravity` does), by Levenberg-Marquardt with
the analytic Jacobian: the temperature columns are the bias columns times ``(T_k -
T_ref)^j``. The elimination starts from the highest degree the distinct poses determine (more
poses than parameters: points of one pose, blocks of a long still period, differ by a fraction
of a degree and count once, ``groups``); :attr:`JointResult.design_degree` says which. Each
channel's degree (at most 3) is then chosen by backward elimination: the least
significant top term of any channel is dropped while the F-test of its drop in chi^2 is not
significant (:data:`imucal_cli.estimators.thermal.temperature.SELECT_P`) and dropping it
narrows no kept parameter by more than
:data:`~imucal_cli.estimators.thermal.temperature.ALIAS_MAX` of its variance (a term aliased
with the kept ones is kept: see that module's notes); what a dropped term still adds (the
highest degree's estimate and covariance) stays in the kept parameters' covariance
(:func:`_held_terms`). The terms above the design degree (a ramp's cubic) are carried from a
prior (:func:`_unfitted_terms`), checked against the data where it can be: a channel whose
fitted linear term exceeds the prior's ``tempco_max`` by more than 2 of its std gets its prior
widened to it (:func:`_prior_check`).

The fit gives the temperature terms and their covariance; the calibration itself (any
accelerometer solver) is then run on the pose means with the temperature terms taken out.
:attr:`JointResult.bias_var_extra` is what the temperature terms' uncertainty adds to the
bias variance (joint minus conditional), for the solver's bias standard deviations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.accel.gravity import model_to_params, params_to_model
from imucal_cli.estimators.thermal.temperature import (
    ALIAS_MAX,
    MAX_DEGREE,
    MIN_SPAN_C,
    SELECT_P,
    alias_inflation,
    check_span,
    consider_cov,
    f1_pvalue,
    noise_scale,
)

__all__ = ["JointResult", "fit_gravity_tempco"]

#: A Jacobian with a singular value below this fraction of the largest leaves the model
#: undetermined.
UNDETERMINED = 1e-9


@dataclass
class JointResult:
    """Result of :func:`fit_gravity_tempco`.

    Attributes
    ----------
    bias : ndarray (3,)
        ``B`` at ``temperature_ref``, raw units.
    M : ndarray (3, 3)
        Upper-triangular matrix, m/s^2 per raw unit.
    temperature_ref, t_min, t_max : float
        ``T_ref`` and the range of the poses' temperatures, degrees C.
    degree : ndarray of int (3,)
        Chosen degree per channel.
    tempco, tempco_std : ndarray (K, 3)
        ``bias_tempco`` and its standard deviations (0 above a channel's degree), raw units
        per C^k.
    bias_var_extra : ndarray (3,)
        Variance the temperature terms add to each bias (joint minus conditional on them).
    residuals : ndarray (N,)
        ``|h_k| - g`` per pose, m/s^2.
    chi2, dof, noise_scale
        Weighted residual sum of squares, its degrees of freedom, and the covariance factor
        (``chi2/dof`` when beyond the 99th percentile of chi^2, else 1).
    tests : list of dict
        The backward elimination: each dropped or kept top term's ``channel``, ``degree``,
        ``F``, ``dof``, ``p_value`` and ``kept``.
    nfev : int
        Function evaluations of all fits.
    model_cov_extra : ndarray (9, 9)
        What the temperature terms' uncertainty adds to the covariance of ``(B, M's upper
        triangle)`` (:func:`~imucal_cli.estimators.accel.gravity.model_to_params`'s order, raw
        units): joint minus conditional, for a solver that takes the terms as known.
    design_degree : int
        The highest degree the poses determined (the elimination's start); a higher term of
        the part's bias (up to the cubic) is not fitted, and what it does to the kept terms is
        in their std only with ``unfitted_std`` (the caller says which).
    terms_columns : list of (int, int)
        ``(degree, channel)`` of each temperature term in :attr:`terms_cov`: the fitted ones,
        then the unfitted ones carried with their prior (held at zero).
    terms_cov : ndarray (9 + T, 9 + T)
        Covariance of the errors of ``(B, M's upper triangle, the terms_columns)`` (raw units):
        what the compensated poses' error is made of, for a solver that reads them (the gyro's:
        :func:`imucal_cli.calibrate.thermal.widen_accel`).
    pose_degree : int
        The highest degree the number of distinct poses allows (more poses than the 9 + 3
        degree parameters), whatever ``max_degree``: :attr:`design_degree` below it is a cap.
    prior_scale : ndarray (3,)
        Factor each channel's prior of the unfitted terms was widened by (1: as given): a
        fitted linear term beyond ``tempco_max`` by more than 2 of its std (noise only) scales
        that channel's prior up to it (:func:`_prior_check`).
    tempco_std_prior : ndarray (K, 3)
        The part of :attr:`tempco_std` that comes from the prior of the unfitted terms
        (``tempco_std^2 = noise^2 + prior^2``), raw units per C^k.
    """

    bias: np.ndarray
    M: np.ndarray
    temperature_ref: float
    t_min: float
    t_max: float
    degree: np.ndarray
    tempco: np.ndarray
    tempco_std: np.ndarray
    bias_var_extra: np.ndarray
    residuals: np.ndarray
    chi2: float
    dof: int
    noise_scale: float
    tests: list[dict] = field(default_factory=list)
    nfev: int = 0
    model_cov_extra: np.ndarray = field(default_factory=lambda: np.zeros((9, 9)))
    design_degree: int = 0
    terms_columns: list = field(default_factory=list)
    terms_cov: np.ndarray | None = None
    pose_degree: int = 0
    prior_scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    tempco_std_prior: np.ndarray | None = None


class _Model:
    """Residuals and Jacobian of eq. (11) with the temperature terms, in normalised units:
    ``a_n = (a - offset) / scale`` and ``tau = (T - T_ref) / t_scale``."""

    def __init__(self, a_mean, T, t_ref, g, w, B0, M0, n_poses=None):
        self.n_poses = len(a_mean) if n_poses is None else int(n_poses)
        self.offset = np.asarray(B0, float).copy()
        d = np.abs(np.diag(M0))
        self.scale = 1.0 / float(np.mean(d)) if np.all(d > 0) else 1.0
        self.a_n = (a_mean - self.offset) / self.scale
        self.t_scale = max(float(np.max(np.abs(T - t_ref))), 1e-9)
        self.tau = (T - t_ref) / self.t_scale
        self.g, self.w, self.t_ref = g, w, t_ref

    def columns(self, degree):
        """The (power, channel) of each temperature parameter, in order."""
        return [(j, c) for c in range(3) for j in range(1, degree[c] + 1)]

    def start(self, B, M, degree):
        x = model_to_params((B - self.offset) / self.scale, M * self.scale)
        return np.r_[x, np.zeros(len(self.columns(degree)))]

    def residuals_and_jacobian(self, x, degree):
        cols = self.columns(degree)
        B, M = params_to_model(x[:9])
        shift = np.zeros_like(self.a_n)
        for (j, c), v in zip(cols, x[9:], strict=True):
            shift[:, c] += v * self.tau**j
        d = self.a_n - B - shift
        h = d @ M.T  # eq. (8)
        g = self.g
        r = (np.sum(h * h, axis=1) - g * g) / (2 * g)  # eq. (11)
        J = np.empty((len(d), 9 + len(cols)))
        J[:, :3] = -(h @ M) / g
        up = (np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2]))
        J[:, 3:9] = (h[:, up[0]] * d[:, up[1]]) / g
        for i, (j, c) in enumerate(cols):
            J[:, 9 + i] = J[:, c] * self.tau**j
        return r * self.w, J * self.w[:, None]

    def raw(self, x, degree):
        """``(B, M, tempco (K, 3))`` in raw units from a normalised parameter vector."""
        Bn, Mn = params_to_model(x[:9])
        K = int(max(degree, default=0))
        tc = np.zeros((K, 3))
        for (j, c), v in zip(self.columns(degree), x[9:], strict=True):
            tc[j - 1, c] = v * self.scale / self.t_scale**j
        return self.offset + self.scale * Bn, Mn / self.scale, tc

    def to_raw_jacobian(self, degree) -> np.ndarray:
        """Diagonal factors from normalised to raw parameters (B, upper M, tempco)."""
        t = [self.scale / self.t_scale**j for j, _ in self.columns(degree)]
        return np.r_[np.full(3, self.scale), np.full(6, 1.0 / self.scale), t]


@dataclass
class _Fit:
    x: np.ndarray
    f: np.ndarray
    J: np.ndarray
    nfev: int

    @property
    def chi2(self) -> float:
        return float(self.f @ self.f)


def _solve(model: _Model, x0: np.ndarray, degree, max_iterations: int) -> _Fit | None:
    """Levenberg-Marquardt from ``x0`` for the temperature terms of ``degree``; None where the
    poses do not determine them (fewer distinct poses than parameters plus one: points of one
    pose differ by a fraction of a degree, and a term only they fix is fitted to within-pose
    differences the chi-square cannot check), or it does not converge."""

    def fun(v):
        return model.residuals_and_jacobian(v, degree)[0]

    def jac(v):
        return model.residuals_and_jacobian(v, degree)[1]

    if model.n_poses <= len(x0):
        return None
    sol = least_squares(fun, x0, jac=jac, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12,
                        gtol=1e-12, max_nfev=max_iterations)  # fmt: skip
    if not sol.success or not np.all(np.isfinite(sol.x)):
        return None
    f, J = model.residuals_and_jacobian(sol.x, degree)
    sv = np.linalg.svd(J, compute_uv=False)
    if sv[-1] <= UNDETERMINED * sv[0]:
        return None
    return _Fit(sol.x, f, J, int(sol.nfev))


def _pose_weights(a_mean, cov_mean, B, M) -> np.ndarray:
    """1 / the standard deviation of each pose's eq.-(11) residual (floored as gravity's)."""
    if cov_mean is None:
        return np.ones(len(a_mean))
    h = (a_mean - B) @ M.T
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    v = u @ M
    sig = np.sqrt(np.clip(np.einsum("ni,nij,nj->n", v, cov_mean, v), 0, None))
    floor = 0.1 * np.median(sig[sig > 0]) if np.any(sig > 0) else 1.0
    return 1.0 / np.maximum(sig, floor)


def fit_gravity_tempco(
    a_mean: np.ndarray,
    temperature: np.ndarray,
    g: float,
    start: tuple[np.ndarray, np.ndarray],
    *,
    cov_mean: np.ndarray | None = None,
    temperature_ref: float | None = None,
    groups: np.ndarray | None = None,
    max_degree: int = MAX_DEGREE,
    min_span_c: float = MIN_SPAN_C,
    select_p: float = SELECT_P,
    max_iterations: int = 400,
    unfitted_std: dict[int, float] | None = None,
    tempco_max: float | None = None,
    what: str = "the poses",
) -> JointResult:
    """Fit the gravity-magnitude model with a temperature-dependent bias.

    Parameters
    ----------
    a_mean : ndarray, shape (N, 3)
        Mean raw accelerometer reading of each static pose, raw units.
    temperature : ndarray, shape (N,)
        Mean temperature of each pose, degrees C.
    g : float
        Local gravity, m/s^2.
    start : (B, M)
        A calibration to start from (bias (3,) raw units, matrix (3, 3)): an ordinary fit of
        the same poses.
    cov_mean : ndarray, shape (N, 3, 3), optional
        Covariance of each pose mean, raw units^2 (weights; absolute covariance).
    temperature_ref : float, optional
        ``T_ref``; default the mean pose temperature.
    groups : ndarray of int, shape (N,), optional
        The still period (pose) of each point, when a pose gives several (blocks of a long
        one); default each point its own pose. The degrees fitted are those the distinct poses
        determine (more poses than parameters), not the points.
    max_degree, min_span_c, select_p
        As :func:`imucal_cli.estimators.thermal.temperature.fit_tempco`.
    max_iterations : int
        Function evaluations of each Levenberg-Marquardt run.
    unfitted_std : dict, optional
        ``{degree: std}``, m/s^2 per C^degree: the prior of a term up to the cubic the poses
        cannot determine (above :attr:`JointResult.design_degree`), carried in the covariance
        (:func:`_unfitted_terms`; from
        :func:`~imucal_cli.estimators.thermal.temperature.unfitted_prior`).
        None: such a term is left out of the std (the caller says so).
    tempco_max : float, optional
        m/s^2 per C: the largest linear term ``unfitted_std`` was drawn for (the datasheet's
        tempco). A channel whose fitted linear term exceeds it by more than 2 of its std (the
        noise's) gets its prior scaled up to the fitted value (:attr:`JointResult.prior_scale`):
        the prior is checked against the data it can be.

    Raises
    ------
    DesignError
        A span under ``min_span_c``, or poses that cannot determine even a linear term with
        the 9 parameters.
    SolverError
        No convergence.
    """
    a_mean = np.asarray(a_mean, float)
    T = np.asarray(temperature, float)
    if a_mean.ndim != 2 or a_mean.shape[1] != 3 or len(T) != len(a_mean):
        raise DesignError(f"{what}: the joint temperature fit needs a 3-channel accelerometer "
                          "and one temperature per pose")  # fmt: skip
    if not np.isfinite(T).all():
        raise DesignError(f"{what}: a pose without a temperature reading")
    check_span(T, what, min_span_c)
    t_ref = float(np.mean(T)) if temperature_ref is None else float(temperature_ref)
    B0, M0 = (np.asarray(v, float) for v in start)
    w = _pose_weights(a_mean, None if cov_mean is None else np.asarray(cov_mean, float), B0, M0)
    n_poses = len(T) if groups is None else len(np.unique(np.asarray(groups)))
    model = _Model(a_mean, T, t_ref, g, w, B0, M0, n_poses)
    top, top_degree, nfev = _design_fit(model, B0, M0, max_degree, max_iterations, what)
    fit, degree, tests, n = _eliminate(model, top, top_degree, select_p, max_iterations)
    weighted = cov_mean is not None
    held = _held_terms(model, fit, degree, top, top_degree, weighted)
    widen = np.ones(3)
    if unfitted_std and tempco_max:
        widen = _prior_check(model, fit, degree, held, weighted, tempco_max)
    A_u, p_u, cols_u = _unfitted_terms(model, fit, degree, top_degree[0], unfitted_std or {},
                                       widen)  # fmt: skip
    prior_part = (A_u * p_u**2) @ A_u.T
    out = _package(model, fit, degree, T, tests, nfev + n, weighted, held + prior_part)
    out.design_degree = top_degree[0]
    out.pose_degree = max(d for d in range(MAX_DEGREE + 1) if n_poses > 9 + 3 * d or d == 0)
    out.prior_scale = widen
    out.tempco_std_prior = _prior_std(model, degree, prior_part, out.tempco_std.shape)
    _terms_cov(out, model, fit, degree, held, A_u, p_u, cols_u, weighted)
    return out


def _prior_std(model, degree, prior_part, shape) -> np.ndarray:
    """The part of each kept term's std the unfitted terms' prior gives (``shape`` (K, 3)),
    raw units per C^k, from its covariance ``prior_part`` (normalised units)."""
    D = model.to_raw_jacobian(degree)
    out = np.zeros(shape)
    for i, (j, c) in enumerate(model.columns(degree)):
        out[j - 1, c] = np.sqrt(max(prior_part[9 + i, 9 + i], 0.0)) * D[9 + i]
    return out


def _design_fit(model, B0, M0, max_degree, max_iterations, what):
    """``(fit, degree, nfev)``: the fit of the highest degree (up to ``max_degree``) the poses
    determine, the backward elimination's start."""
    for d in range(max_degree, 0, -1):
        degree = [d, d, d]
        fit = _solve(model, model.start(B0, M0, degree), degree, max_iterations)
        if fit is not None:
            return fit, degree, fit.nfev
    raise DesignError(
        f"{what}: {model.n_poses} poses cannot determine the gravity-magnitude model with a "
        "temperature-dependent bias: capture more poses (faces and 45-degree edges) while "
        "the temperature changes, or record a still warm-up (plan warmup:MINUTES)"
    )


def _prior_check(model, fit, degree, held, weighted, tempco_max) -> np.ndarray:
    """Per channel, the factor the unfitted terms' prior is widened by (3,): where the fitted
    linear term exceeds ``tempco_max`` (m/s^2 per C) by more than 2 of its std (the fit's
    noise and the dropped terms', without the prior's), the prior, drawn for a part within
    ``tempco_max``, is not this part's: its bound is scaled up to the fitted value."""
    C = noise_scale(fit.chi2, len(fit.f) - len(fit.x), weighted) * \
        np.linalg.inv(fit.J.T @ fit.J) + held  # fmt: skip
    out = np.ones(3)
    for i, (j, c) in enumerate(model.columns(degree)):
        if j != 1:
            continue
        tc = abs(fit.x[9 + i]) / model.t_scale  # normalised units (m/s^2) per C
        std = np.sqrt(max(C[9 + i, 9 + i], 0.0)) / model.t_scale
        if tc > tempco_max + 2.0 * std:
            out[c] = tc / tempco_max
    return out


def _terms_cov(out, model, fit, degree, held, A_u, p_u, cols_u, weighted) -> None:
    """:attr:`JointResult.terms_cov`: the kept parameters' covariance with the unfitted terms
    appended (their error is ``-c``, the kept ones' shift ``A c``: cross-covariance ``-A P``)."""
    scale = noise_scale(fit.chi2, len(fit.f) - len(fit.x), weighted)
    P = np.diag(p_u**2)
    K = scale * np.linalg.inv(fit.J.T @ fit.J) + held + A_u @ P @ A_u.T
    full = np.block([[K, -A_u @ P], [-P @ A_u.T, P]])
    D = np.r_[model.to_raw_jacobian(degree),
              [model.scale / model.t_scale**j for j, _ in cols_u]]  # fmt: skip
    out.terms_columns = model.columns(degree) + cols_u
    out.terms_cov = full * np.outer(D, D)


def _held_terms(model, fit, degree, top, top_degree, weighted) -> np.ndarray:
    """What the temperature terms the eliminations dropped add to the covariance of the kept
    parameters (normalised units): held at zero, not known to be zero, they shift the kept
    ones by ``A delta`` (``A = (J_k^T J_k)^-1 J_k^T J_drop`` at the kept fit, the alias
    matrix of the linearised eq. (11)), ``delta`` known as the highest-degree fit's estimate
    with its covariance (:func:`~imucal_cli.estimators.thermal.temperature.consider_cov`)."""
    n = 9 + len(model.columns(degree))
    cols_top, cols = model.columns(top_degree), model.columns(degree)
    drop = [9 + i for i, jc in enumerate(cols_top) if jc not in cols]
    if not drop:
        return np.zeros((n, n))
    kept = list(range(9)) + [9 + cols_top.index(jc) for jc in cols]
    x = np.zeros(9 + len(cols_top))
    x[kept] = fit.x
    _, J = model.residuals_and_jacobian(x, top_degree)
    Jk = J[:, kept]
    A = np.linalg.solve(Jk.T @ Jk, Jk.T @ J[:, drop])
    dof = len(top.f) - len(top.x)
    C = noise_scale(top.chi2, dof, weighted) * np.linalg.inv(top.J.T @ top.J)
    return consider_cov(A, top.x[drop], C[np.ix_(drop, drop)])


def _unfitted_terms(model, fit, degree, design_degree, prior, widen=None):
    """``(A, p, columns)``: the terms above ``design_degree`` (up to the cubic), which no fit
    of these poses can determine, add to the kept parameters' covariance (normalised units):
    held at zero they
    shift them by ``A c`` (``A = (J_k^T J_k)^-1 J_k^T J_u``, the alias matrix of the
    linearised eq. (11) at the kept fit), ``c`` known only by its prior (``prior[j]``, m/s^2
    per C^j, i.e. ``p = prior[j] t_scale^j`` normalised): they add ``A P A^T`` (``P =
    diag(p^2)``), a Schmidt consider covariance with a zero-mean prior; ``widen`` (3,) scales
    each channel's (:func:`_prior_check`)."""
    n = 9 + len(model.columns(degree))
    full = [MAX_DEGREE] * 3
    cols_full, cols = model.columns(full), model.columns(degree)
    unfit = [i for i, (j, _) in enumerate(cols_full) if j > design_degree and j in prior]
    if not unfit:
        return np.zeros((n, 0)), np.zeros(0), []
    x = np.zeros(9 + len(cols_full))
    x[:9] = fit.x[:9]
    x[[9 + cols_full.index(jc) for jc in cols]] = fit.x[9:]
    _, J = model.residuals_and_jacobian(x, full)
    A = np.linalg.solve(fit.J.T @ fit.J, fit.J.T @ J[:, [9 + i for i in unfit]])
    widen = np.ones(3) if widen is None else widen
    p = np.array([prior[j] * widen[c] * model.t_scale**j for j, c in (cols_full[i] for i in unfit)])
    return A, p, [cols_full[i] for i in unfit]


def _alias(model, fit, degree, sub, smaller) -> float:
    """:func:`~imucal_cli.estimators.thermal.temperature.alias_inflation` of dropping the
    term ``sub`` leaves out of ``fit`` (the linearised eq. (11) at each fit)."""
    cols, cols_small = model.columns(degree), model.columns(smaller)
    kept = list(range(9)) + [9 + cols.index(jc) for jc in cols_small]
    C = np.linalg.inv(fit.J.T @ fit.J)
    return alias_inflation(C[np.ix_(kept, kept)], np.linalg.inv(sub.J.T @ sub.J))


def _eliminate(model, fit, degree, select_p, max_iterations):
    """Backward elimination of top terms over the three channels."""
    tests, nfev = [], 0
    while any(degree):
        dof = len(fit.f) - len(fit.x)
        candidates = []
        for c in range(3):
            if degree[c] == 0:
                continue
            smaller = list(degree)
            smaller[c] -= 1
            prev = dict(zip(model.columns(degree), fit.x[9:], strict=True))
            x0 = np.r_[fit.x[:9], [prev[jc] for jc in model.columns(smaller)]]
            sub = _solve(model, x0, smaller, max_iterations)
            if sub is None:
                continue
            nfev += sub.nfev
            F = max(sub.chi2 - fit.chi2, 0.0) / max(fit.chi2 / dof, 1e-300)
            p = f1_pvalue(F, dof)
            lam = _alias(model, fit, degree, sub, smaller)
            candidates.append((lam <= ALIAS_MAX, p, c, F, dof, lam, sub, smaller))
        if not candidates:
            break
        # the least significant of the terms that may go (not aliased with the kept ones)
        free, p, c, F, dof, lam, sub, smaller = max(candidates, key=lambda t: t[:2])
        kept = p < select_p or not free
        tests.append({"channel": "xyz"[c], "degree": degree[c], "F": float(F),
                      "dof": [1, int(dof)], "p_value": p, "alias": lam,
                      "kept": kept})  # fmt: skip
        if kept:
            break
        fit, degree = sub, smaller
    return fit, degree, tests, nfev


def _package(model, fit, degree, T, tests, nfev, weighted, held) -> JointResult:
    dof = len(fit.f) - len(fit.x)
    chi2 = fit.chi2
    scale = noise_scale(chi2, dof, weighted)
    D = model.to_raw_jacobian(degree)
    JtJ = fit.J.T @ fit.J
    cov = (scale * np.linalg.inv(JtJ) + held) * np.outer(D, D)
    cond = scale * np.linalg.inv(JtJ[:9, :9]) * np.outer(D[:9], D[:9])
    B, M, tc = model.raw(fit.x, degree)
    if not np.all(np.isfinite(B)):
        raise SolverError("the joint temperature fit did not converge")
    K = tc.shape[0]
    std = np.zeros((K, 3))
    for i, (j, c) in enumerate(model.columns(degree)):
        std[j - 1, c] = np.sqrt(max(cov[9 + i, 9 + i], 0.0))
    shift = np.zeros_like(model.a_n)
    for (j, c), v in zip(model.columns(degree), fit.x[9:], strict=True):
        shift[:, c] += v * model.tau**j
    Bn, Mn = params_to_model(fit.x[:9])
    h = (model.a_n - Bn - shift) @ Mn.T
    extra = np.clip(np.diag(cov)[:3] - np.diag(cond)[:3], 0, None)
    model_extra = cov[:9, :9] - cond
    w, V = np.linalg.eigh((model_extra + model_extra.T) / 2)  # PSD (a Schur complement)
    model_extra = (V * np.clip(w, 0.0, None)) @ V.T
    return JointResult(
        bias=B, M=M, temperature_ref=model.t_ref,
        t_min=float(T.min()), t_max=float(T.max()), degree=np.array(degree, int), tempco=tc,
        tempco_std=std, bias_var_extra=extra, residuals=np.linalg.norm(h, axis=1) - model.g,
        chi2=chi2, dof=int(dof), noise_scale=float(scale), tests=tests, nfev=nfev,
        model_cov_extra=model_extra,
    )  # fmt: skip
