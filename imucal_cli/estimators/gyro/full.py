"""Full gyroscope model from arbitrary hand rotations and the calibrated accelerometer.

Beyond Qureshi & Golnaraghi's per-axis model (eq. 15): 12 parameters, ``omega = M (z - b)``
with ``M`` a full 3 x 3 matrix (scale and misalignment of the gyro triad relative to the
accelerometer's frame) and ``b`` the bias. Each rotation between two still periods is
integrated (:mod:`imucal_cli.estimators.gyro.integration`: all rotations at once, the rate
linear between samples) into the body rotation ``R_k``; gravity, fixed in the world, must
then appear in the body as ``u_after = R_k^T u_before``, where the calibrated accelerometer
measures both directions. No known angles and no particular axes are needed.

Estimation is generalised least squares: each rotation gives two residual components (the
mismatch of the predicted gravity direction in the plane normal to the measured one), whose
noise comes from the accelerometer means before and after (shared by consecutive rotations)
and from the integrated gyro noise; the still periods' gyro means tie the bias. The residual
covariance is propagated from those noise sources and whitened, which makes the fit the
first-order maximum-likelihood estimate and its covariance the Cramér-Rao bound of the
design (:func:`full_information`). The covariance is sparse (a still period is shared by the
turn before and the turn after it) and is whitened through its banded Cholesky factor
(:mod:`imucal_cli.numerics.banded`): time and memory are linear in the number of turns.

Start values come from the data alone (:mod:`imucal_cli.estimators.gyro.start`); the model's
residuals, Jacobian and covariance are in :mod:`imucal_cli.estimators.gyro.model`.

**g-sensitivity** (issue 10.7): a MEMS gyro also responds to specific force. The model can
include ``G`` (3 x 3, raw units per m/s^2, Kalibr's ``A``): ``omega = M (z - b - G a)``. Still
periods in several orientations see it as a bias that changes with the gravity direction;
turns see it in their integral. With ``g_sensitivity="auto"`` the 21-parameter model is kept
when the design determines ``G`` and the fit improves significantly (F-test of the
likelihood ratio against the 12-parameter model, which allows for excess noise).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.special import chdtri, fdtrc

from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.gyro.integration import integrate_rotations
from imucal_cli.estimators.gyro.model import (
    Problem,
    Rotations,
    Stills,
    rounding_parameter_covariance,
)
from imucal_cli.estimators.gyro.start import Start, start_values

#: A fit leaving a turn's gravity direction further off than this did not find the turns'
#: minimum: the next start is tried.
MAX_TURN_RESIDUAL_DEG = 10.0
#: g-sensitivity "auto": included when the F-test's p-value is below this.
G_SELECT_P = 1e-3
#: A model whose whitened Jacobian has a singular value below this fraction of the largest
#: leaves a combination of its parameters undetermined.
UNDETERMINED = 1e-8
AXES = "xyz"

__all__ = ["FullResult", "Rotations", "Stills", "accel_sensitivity", "fit_full",
           "full_information", "integrate_rotations", "parameter_names",
           "refit_moved", "refit_without", "step_moved"]  # fmt: skip


def parameter_names(n: int) -> list[str]:
    """Names of the 12 (or 21) parameters: ``b_x..``, ``m_xx..``, ``g_xx..`` (row-major)."""
    names = [f"b_{a}" for a in AXES] + [f"m_{r}{c}" for r in AXES for c in AXES]
    return names + [f"g_{r}{c}" for r in AXES for c in AXES] if n == 21 else names


@dataclass
class FullResult:
    """Result of :func:`fit_full`.

    Attributes
    ----------
    b : ndarray (3,)
        Bias, raw units.
    M : ndarray (3, 3)
        ``omega [rad/s] = M (z - b - G a)``.
    G : ndarray (3, 3) or None
        g-sensitivity, raw units per m/s^2 (None when the model leaves it out).
    cov : ndarray (12, 12) or (21, 21)
        Covariance of ``(b, vec(M)[, vec(G)])`` (row-major), after ``noise_scale``.
    angle_residual_deg : ndarray (K,)
        Angle between the predicted and the measured gravity direction after each rotation.
    rotation_angle_deg : ndarray (K,)
        Angle of each integrated rotation.
    chi2, dof, noise_scale, iterations, converged, message
        Fit statistics; ``noise_scale`` is ``chi2/dof`` when that is significantly above 1.
    turn_chi2 : ndarray (K,)
        Each turn's squared residual in its own noise, ``r_k^T Sigma_kk^-1 r_k`` (2 degrees of
        freedom when the noise model holds).
    turn_sigma_deg : ndarray (K,)
        The residual angle each turn's noise predicts (one standard deviation), degrees.
    still_chi2 : ndarray (P,)
        Each still period's squared gyro-mean residual in its noise (3 degrees of freedom).
    g_test : dict or None
        The g-sensitivity decision: ``included``, ``observable``, ``F``, ``dof``, ``p_value``.
    """

    b: np.ndarray
    M: np.ndarray
    cov: np.ndarray
    angle_residual_deg: np.ndarray
    rotation_angle_deg: np.ndarray
    chi2: float
    dof: int
    noise_scale: float
    iterations: int
    converged: bool
    message: str
    notes: list[str] = field(default_factory=list)
    G: np.ndarray | None = None
    turn_chi2: np.ndarray | None = None
    turn_sigma_deg: np.ndarray | None = None
    still_chi2: np.ndarray | None = None
    g_test: dict | None = None
    #: The problem solved (its last evaluation, at the solution, saves the integration of the
    #: turns to :func:`accel_sensitivity`).
    problem: Problem | None = field(default=None, repr=False, compare=False)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))


def full_information(
    x: np.ndarray, rot: Rotations, still: Stills, gyro_sigma: float, clock: float = 1.0
) -> np.ndarray:
    """Fisher information of ``(b, vec(M)[, vec(G)])`` for a design (first order), shape
    (12, 12), or (21, 21) when ``x`` holds ``G``.

    Its inverse is the Cramér-Rao bound when ``x`` and the data are the truth.
    """
    prob = Problem(rot, still, gyro_sigma, clock, g_sensitivity=len(x) == 21)
    J = prob.whitener(x)(prob.residuals_and_jacobian(x)[1])
    return J.T @ J


@dataclass
class _Solved:
    """One Gauss-Newton run: the solution, its whitened residuals and Jacobian."""

    x: np.ndarray
    f: np.ndarray
    J: np.ndarray
    nfev: int
    message: str
    start: str

    @property
    def chi2(self) -> float:
        return float(self.f @ self.f)


def _solve(prob: Problem, x0: np.ndarray, max_iterations: int, start: str) -> _Solved | None:
    """Generalised least squares from ``x0``: solve with the noise model at the start, again
    with the noise model at that solution. None when it does not converge."""
    m_scale = np.abs(x0[3:12]).max()
    scale = np.r_[np.full(3, max(np.std(prob.z), 1e-9)), np.full(9, m_scale)]
    if prob.with_g:  # 1e-3 rad/s per m/s^2 in raw units
        scale = np.r_[scale, np.full(9, 1e-3 / m_scale)]
    W = prob.whitener(x0)
    jac_at = {}

    def fun(x):
        return W(prob.raw_residuals(x))

    def jac(x):
        key = x.tobytes()
        if key not in jac_at:
            jac_at.clear()
            jac_at[key] = W(prob.residuals_and_jacobian(x)[1])
        return jac_at[key]

    def run(x_start):
        return least_squares(fun, x_start, jac=jac, method="lm", x_scale=scale, xtol=1e-12,
                             ftol=1e-12, gtol=1e-12, max_nfev=max_iterations)  # fmt: skip

    first = run(x0)
    W = prob.whitener(first.x)  # the noise model at the solution, then again
    jac_at.clear()
    sol = run(first.x)
    if sol.status <= 0 or not np.all(np.isfinite(sol.x)):
        return None
    return _Solved(sol.x, sol.fun, jac(sol.x), int(first.nfev + sol.nfev), str(sol.message),
                   start)  # fmt: skip


def _explains(prob: Problem, solved: _Solved) -> bool:
    """A fit that explains the turns: no rotation residual beyond what the fit's own noise
    level makes plausible (a start in the wrong basin leaves residuals of tens of degrees)."""
    p, _ = prob.predicted(solved.x)
    resid = np.arccos(np.clip(np.sum(p * prob.u[prob.rot.after], axis=1), -1, 1))
    return bool(np.degrees(resid).max() < MAX_TURN_RESIDUAL_DEG)


def _multistart(prob: Problem, b0, M0, max_iterations: int) -> tuple[_Solved, int]:
    """Gauss-Newton from each start in turn until one explains the turns; the best fit."""
    rot, still = prob.rot, prob.still
    if M0 is not None:
        starts = iter([Start(np.asarray(M0, float), 0.0, np.eye(3), 0.0, "given start")])
    else:
        starts = start_values(rot.t, rot.z, still.g[rot.before], still.g[rot.after], b0,
                              clock=prob.clock)  # fmt: skip
    best, tried = None, 0
    for start in starts:  # lazily: the next start is computed only when needed
        tried += 1
        solved = _solve(prob, np.r_[b0, start.M.ravel()], max_iterations, start.describe)
        if solved is not None and (best is None or solved.chi2 < best.chi2):
            best = solved
        if best is not None and _explains(prob, best):
            break
    if best is None:
        raise SolverError(
            f"the full gyro model did not converge from {tried} start(s); capture more rotations "
            "about different axes with the unit still before and after each"
        )
    return best, tried


def fit_full(
    rot: Rotations,
    still: Stills,
    gyro_sigma: float,
    b0: np.ndarray,
    M0: np.ndarray | None = None,
    *,
    max_iterations: int = 100,
    clock: float = 1.0,
    g_sensitivity: str = "off",
) -> FullResult:
    """Estimate the 12 (or 21) parameters from rotations between still periods.

    Parameters
    ----------
    rot, still
        The rotations and the still periods around them.
    gyro_sigma : float
        Per-sample gyro noise, raw units.
    b0 : ndarray (3,)
        Initial bias (the still periods' gyro means).
    M0 : ndarray (3, 3), optional
        Initial matrix. Default: the starts of :func:`imucal_cli.estimators.gyro.start.start_values`
        (from the data alone, no nominal sensitivity), tried in turn until one explains the
        turns; the fit with the smallest chi^2 is kept.
    max_iterations : int
        Function evaluations of each solve (each integrates every rotation).
    clock : float
        Factor on every sample interval (sample-clock correction).
    g_sensitivity : {"off", "on", "auto"}
        Include the g-sensitivity ``G`` (needs ``rot.a``): never, always (refused when the
        design cannot determine it), or when the data call for it (F-test, reported in
        ``g_test``).

    Raises
    ------
    DesignError
        Too few rotations, or rotations that leave the model undetermined (all about one
        axis, or about the vertical only).
    SolverError
        No convergence from any start.
    """
    K = len(rot.t)
    if 2 * K < 9:
        raise DesignError(
            f"{K} rotations cannot determine the 12-parameter gyro model (each gives 2 equations "
            "for the 9 of the matrix); turn the unit at least 5 times (better 10 or more) about "
            "different axes, still before and after each"
        )
    prob = Problem(rot, still, gyro_sigma, clock)
    best, tried = _multistart(prob, b0, M0, max_iterations)
    result = _result(prob, best, tried)
    if g_sensitivity == "off":
        return result
    prob_g = Problem(rot, still, gyro_sigma, clock, g_sensitivity=True, like=prob)
    prob_g.share_without_g(prob, best.x)  # the attitudes at the start: the same rates
    solved_g = _solve(prob_g, np.r_[best.x, np.zeros(9)], max_iterations, best.start)
    test = _g_test(result, solved_g)
    result.g_test = test
    if g_sensitivity == "on" and not test["observable"]:
        raise DesignError(
            "the still periods and turns cannot determine the gyro's g-sensitivity: hold the "
            "unit still with each face up (opposite faces), or set [gyro.full] "
            'g_sensitivity = "off"'
        )
    if g_sensitivity == "on" or test["included"]:
        with_g = _result(prob_g, solved_g, tried)
        with_g.g_test = test
        return with_g
    return result


def _g_test(without: FullResult, solved_g: _Solved | None) -> dict:
    """Does the g-sensitivity belong in the model? Observable (the 21-parameter fit converged
    and its information has full rank) and significant (F-test of the chi^2 drop over the 9
    parameters against the 21-parameter fit's own noise level)."""
    if solved_g is None:
        return {"included": False, "observable": False, "reason": "the fit with it did not "
                "converge"}  # fmt: skip
    sv = np.linalg.svd(solved_g.J, compute_uv=False)
    observable = bool(sv[-1] >= UNDETERMINED * sv[0])
    dof = max(len(solved_g.f) - 21, 1)
    drop = without.chi2 - solved_g.chi2
    F = float(max(drop, 0.0) / 9 / (solved_g.chi2 / dof))
    p = float(fdtrc(9, dof, F))
    included = observable and p < G_SELECT_P
    return {"included": included, "observable": observable, "F": F, "dof": [9, dof],
            "p_value": p, "chi2_without": without.chi2, "chi2_with": solved_g.chi2,
            "criterion": f"F-test of the chi^2 drop, included when p < {G_SELECT_P:g}"}  # fmt: skip


def _diagonal_blocks(cov, K: int) -> np.ndarray:
    """The (K, 2, 2) diagonal blocks of a sparse (2K, 2K) covariance."""
    d = cov.diagonal()
    off = cov.diagonal(1)[::2]
    return np.stack([np.stack([d[0::2], off], -1), np.stack([off, d[1::2]], -1)], 1)


def _turn_statistics(prob: Problem, x: np.ndarray):
    """Per turn: the gravity residual angle (deg), the integrated rotation angle (deg), the
    residual's chi^2 in its own noise (2 x 2 block of the covariance) and that noise (deg)."""
    p, R = prob.predicted(x)
    u1 = prob.u[prob.rot.after]
    resid = np.degrees(np.arccos(np.clip(np.sum(p * u1, axis=1), -1, 1)))
    angles = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    blocks = _diagonal_blocks(prob.rotation_covariance(x), prob.K)
    r_rot = prob.raw_residuals(x)[: 2 * prob.K].reshape(-1, 2)
    turn_chi2 = np.einsum("ki,ki->k", r_rot, np.linalg.solve(blocks, r_rot[:, :, None])[:, :, 0])
    return resid, angles, turn_chi2, np.degrees(np.sqrt(np.trace(blocks, axis1=1, axis2=2)))


def refit_without(
    rot: Rotations,
    still: Stills,
    gyro_sigma: float,
    result: FullResult,
    drop: list[int],
    *,
    max_iterations: int = 100,
    clock: float = 1.0,
) -> tuple[FullResult, np.ndarray, np.ndarray]:
    """The same model refitted without the turns ``drop`` (from ``result``'s solution), and
    every turn's chi^2 and residual angle (deg) under the refit: for the dropped turns an
    out-of-sample check that the rest cannot pull towards them.

    Raises
    ------
    DesignError, SolverError
        As :func:`fit_full` (the remaining turns may not determine the model).
    """
    keep = np.setdiff1d(np.arange(len(rot.t)), drop)
    sub = Rotations(
        [rot.t[k] for k in keep], [rot.z[k] for k in keep], rot.before[keep], rot.after[keep],
        None if rot.a is None else [rot.a[k] for k in keep],
    )
    x0 = np.r_[result.b, result.M.ravel(), [] if result.G is None else result.G.ravel()]
    with_g = result.G is not None
    prob = Problem(sub, still, gyro_sigma, clock, g_sensitivity=with_g)
    solved = _solve(prob, x0, max_iterations, "refit")
    if solved is None:
        raise SolverError("the gyro model did not converge without the disagreeing turns")
    refit = _result(prob, solved, 1)
    every = Problem(rot, still, gyro_sigma, clock, g_sensitivity=with_g, like=result.problem)
    resid, _, chi2, _ = _turn_statistics(every, solved.x)
    return refit, chi2, resid


def refit_moved(
    rot: Rotations,
    still: Stills,
    gyro_sigma: float,
    result: FullResult,
    x0: np.ndarray | None = None,
    *,
    max_iterations: int = 100,
    clock: float = 1.0,
) -> np.ndarray | None:
    """The same model refitted with the still periods (and the turns' specific force) that
    another accelerometer calibration gives, from ``x0`` (default: ``result``'s solution; the
    first-order prediction saves iterations): the parameter vector ``(b, vec(M)[, vec(G)])``,
    or None when it does not converge or leaves a turn unexplained. For the sigma points of
    :mod:`imucal_cli.estimators.gyro.sigma`."""
    with_g = result.G is not None
    if x0 is None:
        x0 = np.r_[result.b, result.M.ravel(), result.G.ravel() if with_g else []]
    prob = Problem(rot, still, gyro_sigma, clock, g_sensitivity=with_g, like=result.problem)
    solved = _solve(prob, np.asarray(x0, float), max_iterations, "sigma point")
    if solved is None or not _explains(prob, solved):
        return None
    return solved.x


def step_moved(
    rot: Rotations,
    still: Stills,
    gyro_sigma: float,
    result: FullResult,
    x0: np.ndarray,
    *,
    clock: float = 1.0,
) -> np.ndarray | None:
    """One Gauss-Newton step of :func:`refit_moved` from ``x0`` (the noise model at ``x0``):
    the refit's solution to second order when ``x0`` is the first-order prediction, at the cost
    of one integration of the turns (a refit makes five to eight). None when ``x0`` leaves a
    turn unexplained or the step is not finite. For the pre-check of
    :mod:`imucal_cli.estimators.gyro.sigma`."""
    prob = Problem(rot, still, gyro_sigma, clock, g_sensitivity=result.G is not None,
                   like=result.problem)  # fmt: skip
    x0 = np.asarray(x0, float)
    if not _explains(prob, _Solved(x0, np.zeros(0), np.zeros((0, len(x0))), 0, "", "step")):
        return None
    W = prob.whitener(x0)
    r, J = prob.residuals_and_jacobian(x0)
    x = x0 - np.linalg.lstsq(W(J), W(r), rcond=None)[0]
    return x if np.all(np.isfinite(x)) else None


def _result(prob: Problem, solved: _Solved, tried: int) -> FullResult:
    """Covariance and diagnostics of a solution."""
    J = solved.J
    n = prob.n_params
    sv = np.linalg.svd(J, compute_uv=False)
    if sv[-1] < UNDETERMINED * sv[0]:
        raise DesignError(
            "the rotations leave the gyro model undetermined: turn the unit about at least two "
            "different horizontal axes (a turn about the vertical is invisible to gravity)"
        )
    dof = max(len(solved.f) - n, 1)
    chi2 = solved.chi2
    noise_scale = chi2 / dof if chi2 > chdtri(dof, 0.01) else 1.0
    # the rounding every still mean shares, which no residual shows (Stills.z_common)
    cov = noise_scale * np.linalg.inv(J.T @ J) + rounding_parameter_covariance(J, prob.still)
    resid, angles, turn_chi2, sigma = _turn_statistics(prob, solved.x)
    b, M, G = prob.split(solved.x)
    notes = [solved.start + (f" (best of {tried} starts)" if tried > 1 else "")]
    return FullResult(
        b=b.copy(),
        M=M.copy(),
        G=G.copy() if prob.with_g else None,
        cov=cov,
        angle_residual_deg=resid,
        rotation_angle_deg=angles,
        chi2=chi2,
        dof=dof,
        noise_scale=float(noise_scale),
        iterations=solved.nfev,
        converged=True,
        message=solved.message,
        notes=notes,
        turn_chi2=turn_chi2,
        still_chi2=np.sum(solved.f[2 * prob.K :].reshape(-1, 3) ** 2, axis=1),
        turn_sigma_deg=sigma,
        problem=prob,
    )


def accel_sensitivity(
    rot: Rotations,
    still: Stills,
    gyro_sigma: float,
    result: FullResult,
    dg: np.ndarray,
    *,
    clock: float = 1.0,
) -> np.ndarray:
    """How the estimate moves with the accelerometer calibration it measured gravity with.

    The turns are referenced to the still periods' gravity directions, which the calibrated
    accelerometer gives; an error of that calibration moves every direction together (not
    noise: it does not average out over turns). To first order (implicit function theorem on
    the normal equations), ``d x_hat = -(J^T J)^-1 J^T (d f / d theta) d theta`` with ``f`` the
    whitened residuals at the solution and ``theta`` the accelerometer's parameters.

    Parameters
    ----------
    rot, still, gyro_sigma, clock
        As given to :func:`fit_full`.
    result : FullResult
        The fit.
    dg : ndarray (P, 3, m)
        Change of each still period's calibrated accelerometer mean per unit of each of the
        ``m`` parameters, m/s^2.

    Returns
    -------
    ndarray (12 or 21, m)
        ``d x_hat / d theta``: the covariance of ``x_hat`` from the accelerometer calibration's
        covariance ``C`` is ``A C A^T``.
    """
    with_g = result.G is not None
    x = np.r_[result.b, result.M.ravel(), result.G.ravel() if with_g else []]
    like = getattr(result, "problem", None)
    prob = Problem(rot, still, gyro_sigma, clock, g_sensitivity=with_g, like=like)
    if like is not None:
        prob.share(like)  # the attitudes at the solution, already integrated
    W = prob.whitener(x)
    J = W(prob.residuals_and_jacobian(x)[1])
    m = dg.shape[2]
    F = np.empty((len(J), m))
    g_norm = float(np.median(np.linalg.norm(still.g, axis=1)))
    for j in range(m):
        size = np.abs(dg[:, :, j]).max()
        if size == 0:
            F[:, j] = 0.0
            continue
        h = 1e-6 * g_norm / size  # moves a direction by about 1e-6 rad
        f = [W(prob.with_still(replace(still, g=still.g + s * h * dg[:, :, j])).raw_residuals(x))
             for s in (1, -1)]  # fmt: skip
        F[:, j] = (f[0] - f[1]) / (2 * h)
    return -np.linalg.lstsq(J, F, rcond=None)[0]
