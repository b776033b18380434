"""Labelled-pose accelerometer calibration: bias and full 3x3 matrix from static poses whose
``up`` labels are known up to how well the unit was placed (issue 9.1).

The six-face procedure of PX4, ArduPilot and Ferraris et al. (the start of Qureshi &
Golnaraghi's section III-A, eqs. 13-14) knows which face is up in each pose, but a block on a
table is never exactly level. This solver treats each pose's true gravity direction as a
nuisance parameter with a prior around its label, and fits everything by maximum likelihood.

Model
-----
Pose k (k = 1..N) is held still with true unit gravity direction ``u_k`` (pointing away from
the earth, fixture frame). Its label ``up_k`` is where it should be; the placement error is a
small rotation of the label, two tangent angles ``delta_k`` (rad)::

    u_k = Exp(T_k delta_k) up_k,     delta_k ~ N(0, sigma_p^2 I_2),               (L1)

``T_k`` (3x2) an orthonormal basis of the plane perpendicular to ``up_k``, ``Exp`` the
exponential map of the sphere, and ``sigma_p = placement_deg / sqrt(2)`` per angle, so
``placement_deg`` is the RMS angle between the true and the labelled up. Where a face is held
more than once, ``delta_k`` is the face's own deviation plus the hold's, the first shared by
the poses on that face (L1b, :mod:`.labelled_placement`): the prior rows of (L3) are then
whitened by each face's covariance instead of ``1 / sigma_p``. The mean raw reading
of pose k, ``n_k`` samples, is (Qureshi eq. 4 with a full matrix)::

    a_k = B + g S u_k + e_k,         e_k ~ N(0, Sigma / n_k),                       (L2)

``S = M^-1`` the 3x3 sensitivity (raw units per m/s^2), ``B`` the bias (raw units) and
``Sigma`` the per-sample noise pooled over all holds. The calibration is
``calibrated = M (raw - B)``; unlike the gravity-magnitude model (Qureshi eq. 3, upper
triangular) the labels fix the rotation, so ``M`` is a full matrix in the fixture frame.
Poses without a label get a free direction (no prior): they add one magnitude equation each,
exactly as in the gravity solver.

Estimate
--------
Maximum a posteriori over ``theta = (B, S)`` and all ``delta_k`` (the maximum-likelihood
estimate of ``theta`` with the labels as a Gaussian prior), Levenberg-Marquardt on::

    sum_k |Sigma_k^-1/2 (a_k - B - g S u_k(delta_k))|^2 + sum_k |delta_k|^2 / sigma_p^2.  (L3)

Start: ``delta = 0`` makes (L2) linear in ``(B, S)``: one least-squares solve over the
labelled poses (needs no nominal sensitivity; issue 10.1). ``sigma_p`` is estimated from the
data where the degrees of freedom allow (Helmert variance-component estimation: the prior
rows' residual sum of squares over their redundancy ``r_p = sum (1 - h_ii)``), else taken from
the config.

Cramér-Rao bound with the labels as a prior
-------------------------------------------
The hybrid information matrix of ``phi = (theta, delta_1..delta_N)`` is::

    J = sum_k G_k^T Sigma_k^-1 G_k + diag(0_12, sigma_p^-2 I_2N),                   (L4)
    G_k = d a_k / d phi = [ I_3 | g (I_3 kron u_k^T) | 0 .. g S T_k .. 0 ],

and ``Cov(theta_hat) >= [J^-1]_theta``. Each pose's angles enter only its own block, so
``J = [[A, C], [C^T, D]]`` with ``D`` block diagonal (``D_k = g^2 T_k^T S^T Sigma_k^-1 S T_k +
I / sigma_p^2``) and the bound is the Schur complement::

    CRB(theta) = (A - sum_k C_k D_k^-1 C_k^T)^-1.                                   (L5)

Limits: ``sigma_p -> 0`` (a perfect fixture) gives the bound of the linear fit with known
directions; ``sigma_p -> infinity`` drops the labels and leaves the gravity-magnitude bound
(Qureshi III-A, see :mod:`.crb`), singular along the rotation that magnitude cannot see.
The solver's parameters are ``theta = (B, K, r)`` with ``M = R(r) K``, ``K`` upper triangular
(Qureshi eq. 3) and ``r`` a rotation vector: the rotation separates what the labels determine
(the frame) from what gravity magnitude determines (``K``), so neither carries the other's
error at second order. The estimator's covariance is (L4) evaluated at the estimate, so it
includes the placement error.

Second order
------------
Where the labels, not the data, fix a direction (six faces: bias, cross-axis terms and each
pose's tilt are confounded), the Gaussian approximation at the estimate misses two effects of
size ``sigma_p^2``: the reading along a tilted pose is ``g cos|delta|``, shorter on average by
``E|delta|^2 / 2``, and ``K`` is a curved function of the label-limited cross-axis terms. The
fit marginalises the first (each prediction's mean and variance over ``delta_k``'s remaining
uncertainty, :meth:`.labelled_model.Problem.marginalise`) and adds the second's variance (of
``K`` over the covariance of ``S``). Its mean is not subtracted: with the first marginalised the
estimate's gains are unbiased (mean error over 100 six-face sessions -0.05, -0.01 and +0.29 of
their std at 2 degrees, 0.00 and -0.13 at 0.5, +0.05 and -0.03 at 5), and subtracting the
second-order mean moved the saved matrix's x and y gains 0.35-0.6 std low (issue 24.7e: the
matrix a user applies no longer matched the parameters stated beside it, whose gains carried
the correction in the normalised units, a factor ``scale`` too small).

Placement beyond first order (the joint covariance)
---------------------------------------------------
(L4) at the estimate is the first-order covariance. Along the directions of the placement
that the data leave to the labels (six faces: the three strains of the faces' frame besides
its rotation), the fit moves on a curved set of equally good solutions: the gravity
magnitudes fix some combinations of gains, angles and biases to the noise, but only given
the strains, and to second order in them. Relative to the estimate's tangent the truth lies
off by a relative ``~ sigma_p^2`` (6e-4 at 2 degrees RMS), up to 30 times the noise that
(L4) states for those combinations: each parameter's variance is right, their joint
covariance is not (normalised error squared 60-1000 for 12 parameters on six faces at 2
degrees; 16 at 0.5, 1560 at 5). So the placement's label-limited directions are propagated
through the fit itself::

    Cov(theta) = [J^-1]_theta + E_z[(p(z) - p_hat)(p(z) - p_hat)^T] - G G^T,       (L6)

``z`` the placement's posterior (the labelled ``delta`` ~ ``N(delta_hat, P_delta)``) in the
``m`` directions whose variance is above :data:`.labelled_beyond.LABEL_LIMITED` of the prior's,
less the frame's rotation (the gauge: it turns the frame and every direction together, which
(L4) holds exactly); ``p(z)`` the parameters refitted to the measurements with those placements
held, ``G`` its first-order part (already in (L4)). The expectation is a fully symmetric
fifth-degree rule (exact for a quadratic ``p``: ``2 m^2 + 1`` refits; six faces m = 3,
qureshi18 m = 0). The expectation is over the placement given the data, so where a parameter's
error is the product of a label-limited quantity and an unknown one (a gain's error is its
axis's true misalignment times the error of its angle) the stated std is that of a sensor of
unknown misalignment: for nearly orthogonal axes the gains' std is conservative, up to twice
the error on six faces.

Modules
-------
This module fits (L3) and states (L4)-(L5); its start (``delta = 0``) and the labels that
start contradicts are :mod:`.labelled_start`'s, the model's predictions and Jacobian
:mod:`.labelled_model`'s, the parameters' covariance by part :mod:`.labelled_covariance`'s,
the placement's two parts (L1b) and the intervals' degrees of freedom
:mod:`.labelled_placement`'s, (L6) :mod:`.labelled_beyond`'s, each label's prior rows and the
misplaced labels :mod:`.labelled_checks`'. The fit's response to each pose's mean (eq. L7,
what a set of IMUs held in the same poses needs for its rotations) is
:mod:`.labelled_response`'s, computed from :attr:`LabelledResult.fit` only where a set asks for
it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.special import chdtri, stdtrit

from imucal_cli.design.outliers import Deletion, deletion
from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.accel.gravity import _UPPER, triangular_and_rotation
from imucal_cli.estimators.accel.labelled_checks import placement_rows
from imucal_cli.estimators.accel.labelled_covariance import covariance_parts, public_of_normalised
from imucal_cli.estimators.accel.labelled_holds import Runs, expand, one_placement_runs
from imucal_cli.estimators.accel.labelled_model import (
    Problem,
    faces_of,
    jacobian,
    public_params,  # noqa: F401 (re-exported: the truth in these parameters)
    sphere_exp,
    theta_floor,
)
from imucal_cli.estimators.accel.labelled_placement import (
    DEFAULT_PLACEMENT_DEG,
    MIN_PLACEMENT_DEG,
    interval_dof,
    part_deg,
    placement_parts,
    placement_split,
)
from imucal_cli.estimators.accel.labelled_start import (
    contradicted_labels,  # noqa: F401 (re-exported: the checks' import)
    init_linear,
)

#: Parameters: bias (raw units), the sensitivity of each axis (raw units per m/s^2, the
#: norms of the rows of ``S = M^-1``), the angles between the sensitivity axes minus 90 deg,
#: and the rotation vector (deg) turning the sensor's frame (``M = R(r) K``, K upper
#: triangular, Qureshi eq. 3) onto the labelled fixture frame.
PARAM_NAMES = [
    "b_x",
    "b_y",
    "b_z",
    "s_x",
    "s_y",
    "s_z",
    "a_xy",
    "a_xz",
    "a_yz",
    "r_x",
    "r_y",
    "r_z",
]

#: Redundancy of the prior rows needed to estimate the placement error from the data.
MIN_PLACEMENT_DOF = 2.0
#: Above this many poses the Jacobian is handed to the solver as a sparse matrix (and the
#: placement is propagated to first order only).
DENSE_MAX_POSES = 150


@dataclass
class LabelledResult:
    """Result of :func:`fit_labelled`.

    Attributes
    ----------
    bias : ndarray, shape (3,)
        ``B``, raw units.
    matrix : ndarray, shape (3, 3)
        ``M = S^-1``: ``calibrated = matrix @ (raw - bias)``, m/s^2 per raw unit, fixture frame.
    param_names, params, cov
        :data:`PARAM_NAMES`: bias, sensitivities, angles between the axes and the rotation
        onto the labels; their covariance (12, 12) includes the placement error, beyond
        first order where the labels limit it (eq. L6).
    t_dof : ndarray, shape (12,)
        Effective degrees of freedom of each parameter's variance (Satterthwaite: the
        placement part is estimated from ``placement_dof`` equations); ``inf`` when the
        variance is known.
    ci95 : ndarray, shape (12,)
        Half-width of each parameter's 95 % interval, ``t_0.975(t_dof) * std``.
    residuals : ndarray, shape (N,)
        ``|M (a_k - B)| - g`` per pose, m/s^2.
    residual_vectors : ndarray, shape (N, 3)
        ``M (a_k - B) - g u_k``, m/s^2 (what (L2) leaves unexplained, calibrated units).
    directions : ndarray, shape (N, 3)
        Estimated true gravity direction ``u_k`` of each pose, fixture frame.
    up_angle_deg : ndarray, shape (N,)
        Angle between ``u_k`` and the label, degrees (the placement error; NaN unlabelled).
    placement_deg : float
        RMS placement angle used in the prior, degrees.
    placement_source : str
        ``"estimated"`` (from the data), ``"config"`` (given), or ``"default"``
        (:data:`DEFAULT_PLACEMENT_DEG`, too few equations to estimate it).
    placement_dof : float
        Redundancy of the prior equations (what the placement estimate rests on).
    placement_face_deg, placement_hold_deg : float or None
        Where a face holds several labelled poses and the placement is estimated: its two
        parts (L1b), the face's own (RMS angle between the face's normal and its label,
        shared by every pose on it) and each hold's (the table's tilt at its heading, how it
        was seated), degrees, ``placement_deg`` their root sum of squares; None otherwise.
    chi2, dof : float, int
        Weighted sum of squares of (L3) and its degrees of freedom ``N + 2 L - 12``
        (L labelled poses).
    noise_scale : float
        Factor on the measurement variance: 1 when the residuals agree with the measured
        noise, the excess otherwise (significant at 1 %).
    residual_loo : ndarray, shape (N,)
        Held-out residual ``|M_(-k) (a_k - B_(-k))| - g`` of each pose, m/s^2: the fit
        without the pose (its rows deleted, first order; :mod:`.outliers`).
    deletion : Deletion
        Deletion diagnostics of every pose (studentized statistic for the outlier test).
    init : str
        ``"linear"``: the closed-form start with every ``delta = 0``.
    iterations, nfev : int
    converged : bool
    message : str
    cov_parts : dict
        ``cov`` by where it comes from, (12, 12) each, summing to it: ``"measurement"`` (the
        noise), ``"placement"`` (first order, scales with ``placement_deg^2``) and
        ``"placement_second_order"`` (eq. L6, scales with ``placement_deg^4``); with
        ``"label_limited"``, the number ``m`` of placement directions propagated.
    fit : FitPoint or None
        Where the fit ended (its problem, Jacobian, residuals, the parameters' map): what
        :func:`.labelled_response.pose_response` needs, computed only where a set of IMUs asks
        for it. Not part of the result's value (no repr, no comparison).
    """

    bias: np.ndarray
    matrix: np.ndarray
    param_names: list[str]
    params: np.ndarray
    cov: np.ndarray
    t_dof: np.ndarray
    ci95: np.ndarray
    residuals: np.ndarray
    residual_vectors: np.ndarray
    directions: np.ndarray
    up_angle_deg: np.ndarray
    placement_deg: float
    placement_source: str
    placement_dof: float
    chi2: float
    dof: int
    noise_scale: float
    residual_loo: np.ndarray
    deletion: Deletion
    init: str
    iterations: int
    nfev: int
    converged: bool
    message: str
    cov_parts: dict = field(default_factory=dict)
    placement_face_deg: float | None = None
    placement_hold_deg: float | None = None
    placement_sq: np.ndarray = field(default_factory=lambda: np.zeros(0))
    placement_redundancy: np.ndarray = field(default_factory=lambda: np.zeros(0))
    placement_tied: list = field(default_factory=list)
    fit: FitPoint | None = field(default=None, repr=False, compare=False)

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of ``params``."""
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))


# --------------------------------------------------------------------------- the fit


def _solve(prob: Problem, x0, max_iterations):
    sparse = prob.N > DENSE_MAX_POSES
    if sparse:  # hundreds of placement parameters: scipy's sparse trust region (lsmr)
        return least_squares(
            prob.residuals, x0, jac=lambda x: prob.jacobian(x, sparse=True), method="trf",
            tr_solver="lsmr", x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12,
            max_nfev=max_iterations,
        )  # fmt: skip
    return least_squares(
        prob.residuals,
        x0,
        jac=prob.jacobian,
        method="lm",
        x_scale=1.0,
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=max_iterations,
    )


def _hat_diag(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal of the hat matrix ``J (J^T J)^-1 J^T`` and ``(J^T J)^-1``."""
    Q, R = np.linalg.qr(J)
    P = np.linalg.inv(R)
    return np.sum(Q * Q, axis=1), P @ P.T


@dataclass
class _State:
    sol: object
    prob: Problem
    placement_dof: float
    meas_dof: float
    chi2_meas: float
    hat: np.ndarray
    P: np.ndarray
    J: np.ndarray
    r: np.ndarray


@dataclass(frozen=True)
class FitPoint:
    """Where a labelled fit ended: its state (the problem, Jacobian ``J``, residuals ``r``,
    ``(J^T J)^-1``), ``T`` (12, 12) the map from its normalised ``theta`` to
    :data:`PARAM_NAMES` and the raw scale of the normalised coordinates."""

    state: _State
    T: np.ndarray
    scale: float
    runs: Runs | None = None  # holds fitted as one (:mod:`.labelled_holds`)


def _evaluate(prob: Problem, sol) -> _State:
    if isinstance(sol.jac, np.ndarray):  # least_squares' residuals and Jacobian at sol.x
        J, r = sol.jac, sol.fun
    else:  # scipy's sparse solve
        J, r = prob.jacobian(sol.x), prob.residuals(sol.x)
    h, P = _hat_diag(J)
    n_meas = 3 * prob.N
    return _State(
        sol,
        prob,
        float(np.sum(1 - h[n_meas:])),
        float(np.sum(1 - h[:n_meas])),
        float(r[:n_meas] @ r[:n_meas]),
        h,
        P,
        J,
        r,
    )


def _variance_components(prob, x0, max_iterations, estimate_placement, n_iter=30):
    """Fit (L3), re-estimating the placement (Helmert; its face and hold parts where a face
    holds several poses, :mod:`.labelled_placement`) and the measurement scale until stable."""
    two = estimate_placement and prob.repeated
    if two:  # start with the placement split evenly between the face and the hold
        prob.set_placement(prob.sigma_p / np.sqrt(2), prob.sigma_p / np.sqrt(2))
    sol = _solve(prob, x0, max_iterations)
    st = _evaluate(prob, sol)
    for _ in range(n_iter):
        old = (prob.sigma_f, prob.sigma_h, prob.meas_scale)
        prob.marginalise(sol.x, st.P)
        if estimate_placement and st.placement_dof >= MIN_PLACEMENT_DOF:
            if two:
                prob.set_placement(*placement_parts(prob, st.sol.x, st.P))
            else:
                d = prob.split(sol.x)[3][prob.lab]
                sp2 = float(np.sum(d * d)) / st.placement_dof
                prob.sigma_p = max(np.sqrt(sp2), np.radians(MIN_PLACEMENT_DEG) / np.sqrt(2))
        chi2_m = st.chi2_meas * prob.meas_scale**2  # in units of the measured noise
        if st.meas_dof >= 1 and chi2_m > chdtri(st.meas_dof, 0.01):
            prob.meas_scale = np.sqrt(chi2_m / st.meas_dof)
        else:
            prob.meas_scale = 1.0
        sol = _solve(prob, sol.x, max_iterations)
        st = _evaluate(prob, sol)
        new = (prob.sigma_f, prob.sigma_h, prob.meas_scale)
        if all(abs(a - b) <= 1e-3 * max(b, 1e-12) for a, b in zip(new, old, strict=True)):
            break
    return st


def fit_labelled(
    a_mean: np.ndarray,
    up: np.ndarray,
    g: float,
    cov_mean: np.ndarray,
    *,
    placement_deg: float | None = None,
    noise_dof: float = np.inf,
    max_iterations: int = 200,
) -> LabelledResult:
    """Calibrate a triad accelerometer from labelled static poses (module docstring).

    Consecutive poses with one label whose means agree within their noise (the holds either
    side of a turn on the table) are fitted as one placement (:mod:`.labelled_holds`); the
    result still has one row per pose.

    Parameters
    ----------
    a_mean : ndarray, shape (N, 3)
        Mean raw reading of each pose, raw units.
    up : ndarray, shape (N, 3)
        Labelled up direction of each pose, fixture frame (NaN rows where unlabelled).
    g : float
        Local gravity, m/s^2.
    cov_mean : ndarray, shape (N, 3, 3)
        Covariance of each pose mean, raw units^2 (pooled noise / samples).
    placement_deg : float, optional
        RMS placement error of the poses, degrees. Omitted: estimated from the data when the
        prior equations have at least :data:`MIN_PLACEMENT_DOF` of redundancy, else
        :data:`DEFAULT_PLACEMENT_DEG`.
    noise_dof : float
        Degrees of freedom of the pooled noise estimate (for the parameters' t intervals).
    max_iterations : int
        Function evaluations of each Levenberg-Marquardt run.

    Returns
    -------
    LabelledResult

    Raises
    ------
    DesignError
        Fewer than four labelled poses spanning 3-D, or a design the fit cannot determine.
    SolverError
        No convergence.
    """
    runs = one_placement_runs(a_mean, cov_mean, up)
    if not runs.merged:
        return _fit(a_mean, up, g, cov_mean, placement_deg, noise_dof, max_iterations)
    # holds either side of a turn on the table: one placement (L1b) each run
    res = _fit(runs.a_mean, runs.up, g, runs.cov_mean, placement_deg, noise_dof, max_iterations)
    return expand(res, runs, a_mean, g)


def _fit(a_mean, up, g, cov_mean, placement_deg, noise_dof, max_iterations) -> LabelledResult:
    """:func:`fit_labelled` of poses each placed on its own."""
    a_mean = np.asarray(a_mean, float)
    up = np.asarray(up, float)
    N = len(a_mean)
    labelled = np.isfinite(up).all(axis=1)
    B0, S0 = init_linear(a_mean, up, g)
    # Normalised raw coordinates: every parameter O(1).
    offset = B0.copy()
    scale = float(np.mean(np.abs(np.diag(S0)))) * g or 1.0
    a_n = (a_mean - offset) / scale
    cov_n = np.asarray(cov_mean, float) / scale**2
    K0, Q0 = triangular_and_rotation(np.linalg.inv(S0))
    u0 = np.where(labelled[:, None], up, 0.0)
    if not labelled.all():  # unlabelled poses start at their measured direction
        est = (a_mean[~labelled] - B0) @ np.linalg.inv(S0).T
        u0[~labelled] = est / np.linalg.norm(est, axis=1, keepdims=True)
    u0 = u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    source = "config" if placement_deg is not None else "estimated"
    sigma_p = np.radians(placement_deg if placement_deg is not None else DEFAULT_PLACEMENT_DEG)
    prob = Problem(a_n, cov_n, u0, labelled, g, max(sigma_p, 1e-9) / np.sqrt(2),
                   faces=faces_of(up))
    phi0 = Rotation.from_matrix(Q0).as_rotvec()
    x0 = np.concatenate([np.zeros(3), (K0 * scale)[_UPPER], phi0, np.zeros(2 * N)])
    st = _variance_components(prob, x0, max_iterations, placement_deg is None)
    if source == "estimated" and st.placement_dof < MIN_PLACEMENT_DOF:
        source = "default"
    if st.sol.status <= 0:
        raise SolverError(
            f"the labelled-pose fit did not converge in {max_iterations} iterations "
            f"({st.sol.message}); check that the unit was still during each hold and that the "
            "labels name the face that was up"
        )
    return _result(st, offset, scale, a_mean, up, labelled, g, source, noise_dof)


def _result(st: _State, offset, scale, a_mean, up, labelled, g, source, noise_dof):
    """The :class:`LabelledResult` of the fit's end ``st``: the parameters and their
    covariance (L4)-(L6), their t intervals, and what each pose says (``offset``, ``scale``
    the normalisation of the raw coordinates; ``source`` where ``sigma_p`` came from)."""
    prob = st.prob
    if _undetermined(st):
        raise DesignError(
            "the poses and labels leave the matrix undetermined; label more poses (each face up)"
        )
    x12 = st.sol.x[:12]
    public = public_of_normalised(offset, scale)
    T = jacobian(public, x12, floor=theta_floor(x12), many=True)
    params, parts, m = covariance_parts(st, public, T, prob.N <= DENSE_MAX_POSES)
    cov = parts["measurement"] + parts["placement"] + parts["placement_second_order"]
    B, M = _bias_and_matrix(x12, offset, scale)
    split = (placement_split(prob, st.P, T) if source == "estimated" and prob.repeated
             else None)
    t_dof = interval_dof(parts, st.placement_dof, source, noise_dof, split)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    q = np.where(np.isfinite(t_dof), stdtrit(np.minimum(t_dof, 1e6), 0.975), 1.959964)
    u, h, up_angle = _poses(st, B, M, a_mean, up, labelled)
    dele = deletion(st.J, st.r, prob.groups(), st.P)
    return LabelledResult(
        bias=B,
        matrix=M,
        param_names=list(PARAM_NAMES),
        params=params,
        cov=cov,
        t_dof=t_dof,
        ci95=q * std,
        residuals=np.linalg.norm(h, axis=1) - g,
        residual_vectors=h - g * u,
        directions=u,
        up_angle_deg=up_angle,
        placement_deg=float(np.degrees(prob.sigma_p) * np.sqrt(2)),
        placement_face_deg=part_deg(prob, prob.sigma_f, source),
        placement_hold_deg=part_deg(prob, prob.sigma_h, source),
        placement_source=source,
        placement_dof=st.placement_dof,
        chi2=float(st.r @ st.r),
        dof=prob.N + 2 * int(labelled.sum()) - 12,
        noise_scale=float(prob.meas_scale**2),
        residual_loo=_held_out(prob, st, dele, offset, scale, a_mean, g),
        deletion=dele,
        init="linear",
        iterations=int(st.sol.njev or 0),
        nfev=int(st.sol.nfev),
        converged=True,
        message=str(st.sol.message),
        cov_parts={**parts, "label_limited": m},
        fit=FitPoint(st, T, scale),
        **placement_rows(st.J, st.r, st.prob.N, labelled),
    )


def _bias_and_matrix(x12: np.ndarray, offset, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``B`` (3,), raw units, and ``M = R(r) K`` (3, 3), m/s^2 per raw unit, of normalised
    ``x12 = (B, K upper, r)``."""
    Kn = np.zeros((3, 3))
    Kn[_UPPER] = x12[3:9]
    B = offset + scale * x12[:3]
    M = Rotation.from_rotvec(x12[9:12]).as_matrix() @ Kn / scale
    return B, M


def _poses(st: _State, B, M, a_mean, up, labelled):
    """What the fit says of each pose: its estimated up ``u_k`` (N, 3), its calibrated mean
    ``h_k = M (a_k - B)`` (N, 3), m/s^2, and the angle between ``u_k`` and its label (N,),
    degrees (NaN unlabelled)."""
    prob = st.prob
    u, _ = sphere_exp(prob.u0, prob.T, prob.split(st.sol.x)[3])
    h = (a_mean - B) @ M.T
    up_angle = np.full(prob.N, np.nan)
    cosang = np.clip(np.sum(u[labelled] * up[labelled], axis=1), -1, 1)
    up_angle[labelled] = np.degrees(np.arccos(cosang))
    return u, h, up_angle


def _undetermined(st: _State) -> bool:
    """Whether the Jacobian's condition number is at least 1e10. ``tr(J^T J) tr(P)`` bounds its
    square from above: where that bound is below 1e18 the singular values are not needed."""
    bound = float(np.sum(st.J * st.J)) * float(np.trace(st.P))
    if np.isfinite(bound) and bound < 1e18:
        return False
    svals = np.linalg.svd(st.J, compute_uv=False)
    return bool(svals[-1] <= 1e-10 * svals[0])


def _held_out(prob: Problem, st: _State, dele: Deletion, offset, scale, a_mean, g):
    """Gravity-magnitude residual of each pose under the fit without it, m/s^2."""
    X = st.sol.x[:12] + dele.dx[:, :12]  # (B, K, phi) without each pose
    Kn = np.zeros((prob.N, 3, 3))
    Kn[:, _UPPER[0], _UPPER[1]] = X[:, 3:9]
    M = Rotation.from_rotvec(X[:, 9:12]).as_matrix() @ Kn / scale
    h = np.einsum("nij,nj->ni", M, a_mean - offset - scale * X[:, :3])
    return np.where(dele.rank > 0, np.linalg.norm(h, axis=1) - g, np.nan)
