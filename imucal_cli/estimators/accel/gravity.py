"""Gravity-magnitude accelerometer calibration (Qureshi & Golnaraghi 2017, section III-A).

Model (eqs. 3-8): the calibrated specific force of static pose k is

    h_k = K T (a_k - B) = M (a_k - B),                                  (8)

with ``B`` the bias (raw units) and ``M = K T`` upper triangular (eq. 3 after fixing the
sensor's x axis and x-y plane): 3 scale factors ``k_x, k_y, k_z`` on the diagonal and
3 misalignment factors ``k_xy, k_xz, k_yz`` above it, 9 parameters ``X`` in all (eq. 7).
Every static pose sees only gravity, so the cost (eq. 11) over the per-pose means is

    G(X) = sum_k ( |h(a_k, X)|^2 - g^2 )^2.                             (11)

We minimise it with Levenberg-Marquardt (``scipy.optimize.least_squares``) instead of the
paper's Newton iteration (eq. 12), on the residuals ``(|h_k|^2 - g^2) / (2 g)`` — the same
minimiser, in m/s^2 — optionally weighted by each pose mean's noise so that the fit is the
maximum-likelihood one to first order and its covariance is honest.

Initial values come from up/down pairs (eqs. 13-14) where the poses are labelled, otherwise
from an algebraic ellipsoid fit; both are tried when both are possible.

The 12-parameter variant keeps the 9-parameter solution and adds the rotation that gravity
magnitude cannot see: the one that best aligns the calibrated directions with the labelled
``up`` directions (Wahba's problem), so that ``matrix = R M`` is a full 3x3 matrix
(:mod:`.gravity_labels`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.special import chdtri  # inverse survival function of chi^2

from imucal_cli.design.outliers import Deletion, deletion
from imucal_cli.design.poses import angle_deg
from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.accel.gravity_labels import align_to_labels
from imucal_cli.estimators.ellipsoid import fit_ellipsoid

#: Names of the 9 parameters of eq. (7), in order.
PARAM_NAMES_9 = ["b_x", "b_y", "b_z", "k_x", "k_y", "k_z", "k_xy", "k_xz", "k_yz"]
#: Names of the 12 parameters of the full-matrix variant, in order.
PARAM_NAMES_12 = ["b_x", "b_y", "b_z"] + [f"m_{r}{c}" for r in "xyz" for c in "xyz"]

_UPPER = (np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2]))  # k_x k_y k_z k_xy k_xz k_yz


def triangular_and_rotation(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``M = Q K`` with ``K`` upper triangular (positive diagonal where ``det M > 0``) and
    ``Q`` a rotation, for one matrix (3, 3) or a stack (..., 3, 3). A mirrored matrix
    (``det M < 0``: labels in a left-handed frame relative to the sensor) keeps ``Q`` proper
    and gives ``K`` a negative ``k_z``."""
    Q, K = np.linalg.qr(M)
    sign = np.sign(np.diagonal(K, axis1=-2, axis2=-1))
    Q, K = Q * sign[..., None, :], K * sign[..., :, None]
    flip = np.where(np.linalg.det(Q) < 0, -1.0, 1.0)
    Q[..., :, 2] *= flip[..., None]
    K[..., 2, :] *= flip[..., None]
    return K, Q


def params_to_model(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split the 9-parameter vector ``X`` (eq. 7) into bias ``B`` (3,) and triangular ``M``."""
    M = np.zeros((3, 3))
    M[_UPPER] = X[3:9]
    return X[:3].copy(), M


def model_to_params(B: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Inverse of :func:`params_to_model`."""
    return np.concatenate([B, M[_UPPER]])


@dataclass
class GravityResult:
    """Result of :func:`fit_gravity`.

    Attributes
    ----------
    bias : ndarray, shape (3,)
        ``B``, raw units.
    matrix : ndarray, shape (3, 3)
        ``calibrated = matrix @ (raw - bias)``: ``M`` (upper triangular) for the 9-parameter
        variant, ``R M`` for the 12-parameter one. Output units m/s^2 per raw unit.
    variant : str
        ``"9-parameter"`` or ``"12-parameter"``.
    param_names, params, cov
        The estimated parameters (9 or 12; see :data:`PARAM_NAMES_9`, :data:`PARAM_NAMES_12`),
        and their covariance (p, p) in (raw units, m/s^2 per raw unit) as appropriate.
    residuals : ndarray, shape (N,)
        ``|h_k| - g`` per pose, m/s^2.
    cost_residuals : ndarray, shape (N,)
        ``(|h_k|^2 - g^2) / (2 g)``, the minimised quantity of eq. (11), m/s^2.
    chi2, dof : float, int
        Weighted residual sum of squares and degrees of freedom (N - 9).
    noise_scale : float
        Factor applied to the covariance: 1 when the residuals agree with the measured noise,
        ``chi2/dof`` when they are significantly larger (model error, moved poses, correlated
        noise), so the standard deviations stay honest. With equal weighting, the residual
        variance.
    weighting : str
        ``"noise"`` (each pose weighted by its mean's covariance) or ``"equal"``.
    init : str
        Which start won: ``"updown"`` (eqs. 13-14), ``"ellipsoid"`` or ``"sphere"``.
    iterations, nfev : int
        Jacobian and function evaluations of the winning Levenberg-Marquardt run.
    converged : bool
    message : str
    rotation : ndarray, shape (3, 3)
        ``R`` aligning the 9-parameter frame onto the labelled ``up`` directions (identity
        when no labels). Applied to ``matrix`` only for the 12-parameter variant.
    rotation_std_deg : float or None
        One-sigma uncertainty of that alignment (RMS over axes), degrees.
    up_angle_deg : ndarray, shape (N,)
        Angle between each pose's calibrated direction (after ``R``) and its labelled ``up``,
        degrees; NaN where unlabelled. The placement error of each pose.
    directions : ndarray, shape (N, 3)
        Calibrated unit gravity direction of each pose, in the output frame of ``matrix``.
    deletion : Deletion
        Deletion diagnostics of every pose (:mod:`.outliers`): parameter change and
        studentized statistic when the pose is left out.
    residual_loo : ndarray, shape (N,)
        Held-out residual of each pose from the first-order deletion: ``|M_(-k) (a_k -
        B_(-k))| - g``, m/s^2 (NaN where nothing else determines the pose).
    """

    bias: np.ndarray
    matrix: np.ndarray
    variant: str
    param_names: list[str]
    params: np.ndarray
    cov: np.ndarray
    residuals: np.ndarray
    cost_residuals: np.ndarray
    chi2: float
    dof: int
    noise_scale: float
    weighting: str
    init: str
    iterations: int
    nfev: int
    converged: bool
    message: str
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    rotation_std_deg: float | None = None
    up_angle_deg: np.ndarray | None = None
    directions: np.ndarray | None = None
    deletion: Deletion | None = None
    residual_loo: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of ``params`` (sqrt of the covariance diagonal)."""
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))

    @property
    def M(self) -> np.ndarray:
        """The upper-triangular 9-parameter matrix (``rotation.T @ matrix`` for 12)."""
        return self.rotation.T @ self.matrix if self.variant == "12-parameter" else self.matrix


# --------------------------------------------------------------------------- initial values


def init_updown(
    a_mean: np.ndarray, up: np.ndarray, g: float, tolerance_deg: float = 30.0
) -> tuple[np.ndarray, np.ndarray] | None:
    """Initial bias and scale from up/down pairs (eqs. 13-14).

    For each axis i, the labelled pose closest to ``+e_i`` up and the one closest to ``-e_i``
    (each within ``tolerance_deg``) give ``k = (a_up - a_down) / (2 g)`` and
    ``b = (a_up + a_down) / 2`` on that axis.

    Returns
    -------
    (B, M) or None
        ``M = diag(1/k)``; None when some axis lacks an up/down pair.
    """
    if up is None:
        return None
    labelled = ~np.isnan(up).any(axis=1)
    if not labelled.any():
        return None
    k = np.empty(3)
    b = np.empty(3)
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1.0
        picks = []
        for sign in (1.0, -1.0):
            ang = np.where(labelled, angle_deg(up, sign * e), np.inf)
            j = int(np.argmin(ang))
            if ang[j] > tolerance_deg:
                return None
            picks.append(j)
        a_up, a_down = a_mean[picks[0], i], a_mean[picks[1], i]
        k[i] = (a_up - a_down) / (2 * g)  # eq. (13)
        b[i] = (a_up + a_down) / 2  # eq. (14)
    if np.any(k == 0):
        return None
    return b, np.diag(1.0 / k)


# --------------------------------------------------------------------------- the fit


def _residuals_and_jacobian(x, a_n, g, w):
    """Weighted eq. (11) residuals and their Jacobian, in normalised raw coordinates."""
    B, M = params_to_model(x)
    d = a_n - B  # (N, 3)
    h = d @ M.T  # (N, 3), eq. (8)
    r = (np.sum(h * h, axis=1) - g * g) / (2 * g)
    J = np.empty((len(a_n), 9))
    J[:, :3] = -(h @ M) / g  # d r / d B
    J[:, 3:] = (h[:, _UPPER[0]] * d[:, _UPPER[1]]) / g  # d r / d M_ij = h_i d_j / g
    return r * w, J * w[:, None]


def _solve(a_n, g, w, x0, max_iterations):
    fun = lambda x: _residuals_and_jacobian(x, a_n, g, w)[0]  # noqa: E731
    jac = lambda x: _residuals_and_jacobian(x, a_n, g, w)[1]  # noqa: E731
    return least_squares(
        fun,
        x0,
        jac=jac,
        method="lm",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=max_iterations,
    )


def _pose_sigmas(a_mean, cov_mean, B, M, g):
    """Standard deviation of each pose's eq.-(11) residual from its mean's covariance, m/s^2."""
    h = (a_mean - B) @ M.T
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    v = u @ M  # d r / d a = u^T M
    var = np.einsum("ni,nij,nj->n", v, cov_mean, v)
    return np.sqrt(np.clip(var, 0, None))


def fit_gravity(
    a_mean: np.ndarray,
    g: float,
    *,
    cov_mean: np.ndarray | None = None,
    up: np.ndarray | None = None,
    variant: str = "9",
    init: str = "auto",
    max_iterations: int = 200,
) -> GravityResult:
    """Calibrate a triad accelerometer from static poses by the gravity magnitude.

    Parameters
    ----------
    a_mean : ndarray, shape (N, 3)
        Mean raw accelerometer reading of each static pose, raw units. N >= 9.
    g : float
        Local gravity magnitude, m/s^2.
    cov_mean : ndarray, shape (N, 3, 3), optional
        Covariance of each pose mean (sample covariance / samples), raw units^2. Given, the
        poses are weighted by their noise and the covariance of the result is in absolute
        terms; omitted, poses are weighted equally and the noise is estimated from the
        residuals.
    up : ndarray, shape (N, 3), optional
        Labelled up direction of each pose in the fixture frame (rows of NaN where
        unknown). Used for the up/down start (eqs. 13-14), for the 12-parameter variant and
        for the per-pose angle check.
    variant : {"9", "12"}
        ``"9"``: eqs. (3)-(8), upper-triangular matrix. ``"12"``: full matrix rotated onto the
        labelled up directions (needs at least two non-parallel labelled poses).
    init : {"auto", "updown", "ellipsoid"}
        Start of the iteration. ``"auto"`` tries both where the labels allow and keeps the
        lower cost.
    max_iterations : int
        Iteration limit of Levenberg-Marquardt.

    Returns
    -------
    GravityResult

    Raises
    ------
    DesignError
        Fewer than 9 poses, labels missing for the 12-parameter variant or the up/down
        start, or poses that leave the model undetermined.
    SolverError
        No convergence within ``max_iterations``.
    """
    a_mean = _checked(a_mean, variant)
    N = len(a_mean)
    up = None if up is None else np.asarray(up, dtype=float)
    starts = _starts(a_mean, g, up, init)
    norm = _Normalised(a_mean, *next(iter(starts.values())))
    w = np.ones(N)
    if cov_mean is not None:  # weights from the measured noise (they depend on M: two passes)
        cov_mean = np.asarray(cov_mean, dtype=float)
        w = _weights_from_sigmas(_pose_sigmas(a_mean, cov_mean, *next(iter(starts.values())), g))
    init_used, sol = _best_start(norm, g, w, starts, max_iterations)
    if cov_mean is not None:
        w = _weights_from_sigmas(_pose_sigmas(a_mean, cov_mean, *norm.model(sol.x), g))
        sol2 = _solve(norm.a_n, g, w, sol.x, max_iterations)
        sol = sol2 if sol2.status > 0 else sol
    if sol.status <= 0:
        raise SolverError(
            f"the gravity fit did not converge in {max_iterations} iterations ({sol.message}); "
            "check that the unit was still during each hold and capture more poses spread over "
            "the sphere (faces and 45-degree edges)"
        )
    # gauge: upper triangular with positive diagonal (flip rows; |h| is unchanged)
    Bn, Mn = params_to_model(sol.x)
    x = model_to_params(Bn, np.diag(np.sign(np.diag(Mn))) @ Mn)
    return _package(a_mean, g, up, variant, norm, x, w, cov_mean, init_used, sol)


def _checked(a_mean, variant: str) -> np.ndarray:
    """The pose means as floats, or the error that says why they cannot be fitted."""
    a_mean = np.asarray(a_mean, dtype=float)
    if a_mean.ndim != 2 or a_mean.shape[1] != 3:
        raise DesignError(
            f"the gravity solver needs 3 accelerometer channels, got {a_mean.shape[1:]}"
        )
    if len(a_mean) < 9:
        raise DesignError(
            f"{len(a_mean)} static poses cannot determine the {variant}-parameter "
            "gravity-magnitude model (9 parameters from the magnitudes); capture at least 9 "
            "(the qureshi18 plan: 6 faces and 12 edges), or label the poses for the "
            "labelled-pose solver"
        )
    if variant not in ("9", "12"):
        raise ValueError(f"variant must be '9' or '12', not {variant!r}")
    return a_mean


def _starts(a_mean, g, up, init) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Closed-form starts that need no nominal sensitivity (issue 10.1): up/down pairs
    (eqs. 13-14), the labels' linear fit, the algebraic ellipsoid (or sphere)."""
    if init not in ("auto", "updown", "ellipsoid"):
        raise ValueError(f"init must be 'auto', 'updown' or 'ellipsoid', not {init!r}")
    starts: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    if init in ("auto", "updown"):
        ud = init_updown(a_mean, up, g) if up is not None else None
        if ud is not None:
            starts["updown"] = ud
        elif init == "updown":
            raise DesignError(
                "the up/down start (eqs. 13-14) needs a labelled pose with each of +X, -X, +Y, -Y, "
                '+Z, -Z up; capture the six faces or use init = "ellipsoid"'
            )
    if init == "auto" and up is not None:
        lin = _labels_start(a_mean, up, g)
        if lin is not None:
            starts["labels"] = lin
    if init in ("auto", "ellipsoid"):
        ell = fit_ellipsoid(a_mean, g)
        starts[ell.kind] = (ell.bias, ell.M)
    return starts


def _labels_start(a_mean, up, g):
    """``a_k = B + g S up_k`` solved linearly over the labelled poses, as ``(B, M upper)``."""

    lab = np.isfinite(up).all(axis=1)
    X = np.column_stack([np.ones(lab.sum()), g * up[lab]])
    if lab.sum() < 4 or np.linalg.matrix_rank(X, tol=1e-6 * g) < 4:
        return None
    sol, *_ = np.linalg.lstsq(X, a_mean[lab], rcond=None)
    S = sol[1:].T
    if abs(np.linalg.det(S)) < 1e-12 * np.abs(S).max() ** 3:
        return None
    K, _ = triangular_and_rotation(np.linalg.inv(S))
    return sol[0], np.diag(np.sign(np.diag(K))) @ K


class _Normalised:
    """Raw coordinates ``a_n = (a - offset) / scale`` so that every parameter is O(1)."""

    def __init__(self, a_mean, B_ref, M_ref):
        self.offset = np.asarray(B_ref, float).copy()
        d = np.abs(np.diag(M_ref))
        self.scale = 1.0 / float(np.mean(d)) if np.all(d > 0) else 1.0
        self.a_n = (a_mean - self.offset) / self.scale

    def params(self, B, M):
        return model_to_params((B - self.offset) / self.scale, M * self.scale)

    def model(self, x):
        Bn, Mn = params_to_model(x)
        return self.offset + self.scale * Bn, Mn / self.scale


def _best_start(norm, g, w, starts, max_iterations):
    """Levenberg-Marquardt from every start; the lowest cost wins."""
    best = None
    for name, (B0, M0) in starts.items():
        sol = _solve(norm.a_n, g, w, norm.params(B0, M0), max_iterations)
        if best is None or sol.cost < best[1].cost:
            best = (name, sol)
    return best


def _package(a_mean, g, up, variant, norm, x, w, cov_mean, init_used, sol) -> GravityResult:
    """Covariance, residuals, deletion diagnostics and the label alignment of a solution."""
    N = len(a_mean)
    weighting = "noise" if cov_mean is not None else "equal"
    r_w, J = _residuals_and_jacobian(x, norm.a_n, g, w)
    B, M = norm.model(x)
    dof = N - 9
    chi2 = float(r_w @ r_w)
    cov_n, cov, noise_scale = _covariance(J, chi2, dof, weighting, norm.scale)
    dele = deletion(J, r_w, [np.array([k]) for k in range(N)], cov_n)
    loo = np.full(N, np.nan)
    for k in np.flatnonzero(dele.rank):
        Bk, Mk = norm.model(x + dele.dx[k])
        loo[k] = np.linalg.norm(Mk @ (a_mean[k] - Bk)) - g
    h = (a_mean - B) @ M.T
    mag = np.linalg.norm(h, axis=1)
    directions = h / mag[:, None]
    R, R_cov, up_angle = align_to_labels(directions, up, variant)
    if variant == "9":
        params, names, matrix = model_to_params(B, M), list(PARAM_NAMES_9), M
    else:
        matrix = R @ M
        directions = directions @ R.T
        params = np.concatenate([B, matrix.ravel()])
        names = list(PARAM_NAMES_12)
        cov = _cov_12(cov, M, R, R_cov)
    rot_std = None if R_cov is None else float(np.degrees(np.sqrt(np.trace(R_cov) / 3)))
    return GravityResult(
        bias=B,
        matrix=matrix,
        variant=f"{variant}-parameter",
        param_names=names,
        params=params,
        cov=cov,
        residuals=mag - g,
        cost_residuals=(mag**2 - g * g) / (2 * g),
        chi2=chi2,
        dof=dof,
        noise_scale=float(noise_scale),
        weighting=weighting,
        init=init_used,
        iterations=int(sol.njev or 0),
        nfev=int(sol.nfev),
        converged=True,
        message=str(sol.message),
        rotation=R,
        rotation_std_deg=rot_std,
        up_angle_deg=up_angle,
        directions=directions,
        deletion=dele,
        residual_loo=loo,
    )


def _covariance(J: np.ndarray, chi2: float, dof: int, weighting: str, scale: float):
    """``(J^T J)^-1`` in the normalised coordinates, the covariance of ``(B, upper(M))`` in raw
    units and m/s^2 per raw unit (normalisation ``scale``), and the factor on it: 1 with noise
    weights unless ``chi2`` is beyond the 99th percentile of chi^2(dof), else ``chi2 / dof``.

    Raises
    ------
    DesignError
        ``J`` (N, 9) is numerically rank-deficient: the poses leave the model undetermined.
    """
    svals = np.linalg.svd(J, compute_uv=False)
    if svals[-1] <= 1e-9 * svals[0]:
        raise DesignError(
            "the poses leave the 9-parameter model undetermined (they lie close to one plane "
            "or cone of gravity directions); capture poses with each face and 45-degree edge up"
        )
    cov_n = np.linalg.inv(J.T @ J)
    if weighting == "noise":
        noise_scale = 1.0
        if dof > 0 and chi2 > chdtri(dof, 0.01):  # beyond the 99th percentile of chi^2(dof)
            noise_scale = chi2 / dof
    else:
        noise_scale = chi2 / dof if dof > 0 else float("nan")
    T = np.diag(np.r_[np.full(3, scale), np.full(6, 1.0 / scale)])
    return cov_n, noise_scale * (T @ cov_n @ T), noise_scale


def _weights_from_sigmas(sig: np.ndarray) -> np.ndarray:
    # A pose whose samples never changed (noise below one quantisation step) would get an
    # infinite weight: floor each sigma at a tenth of the median.
    floor = 0.1 * np.median(sig[sig > 0]) if np.any(sig > 0) else 1.0
    return 1.0 / np.maximum(sig, floor)


def _cov_12(cov9: np.ndarray, M: np.ndarray, R: np.ndarray, R_cov: np.ndarray) -> np.ndarray:
    """Covariance of (B, vec(R M)) from that of (B, upper(M)) and of the rotation."""
    # d(RM) = R dM + [dphi]x R M
    J = np.zeros((12, 12))  # rows: B(3), vec(RM)(9); cols: B(3), upper M(6), phi(3)
    J[:3, :3] = np.eye(3)
    for c, (i, j) in enumerate(zip(*_UPPER, strict=True)):
        E = np.zeros((3, 3))
        E[i, j] = 1.0
        J[3:, 3 + c] = (R @ E).ravel()
    RM = R @ M
    for c in range(3):
        e = np.zeros(3)
        e[c] = 1.0
        J[3:, 9 + c] = (np.cross(e, RM.T).T).ravel()  # [e]x RM, column by column
    full = np.zeros((12, 12))
    full[:9, :9] = cov9
    full[9:, 9:] = R_cov
    return J @ full @ J.T


def leave_one_out(
    a_mean: np.ndarray,
    g: float,
    result: GravityResult,
    *,
    cov_mean: np.ndarray | None = None,
    max_iterations: int = 200,
) -> np.ndarray:
    """Held-out gravity-magnitude residual of each pose, m/s^2, shape (N,).

    For each pose k, the 9-parameter model is refitted without it (started from the full
    solution) and evaluated on it: ``|M_(-k) (a_k - B_(-k))| - g``. NaN for every pose when
    N - 1 < 9 poses remain.
    """
    a_mean = np.asarray(a_mean, float)
    N = len(a_mean)
    out = np.full(N, np.nan)
    if N - 1 < 9:
        return out
    B, M = result.bias, result.M
    offset, scale = B, 1.0 / np.mean(np.diag(M))
    a_n = (a_mean - offset) / scale
    x0 = model_to_params(np.zeros(3), M * scale)
    w = np.ones(N)
    if cov_mean is not None:
        w = _weights_from_sigmas(_pose_sigmas(a_mean, np.asarray(cov_mean, float), B, M, g))
    for k in range(N):
        keep = np.arange(N) != k
        sol = _solve(a_n[keep], g, w[keep], x0, max_iterations)
        Bn, Mn = params_to_model(sol.x)
        out[k] = np.linalg.norm(Mn @ (a_n[k] - Bn)) - g
    return out


def leave_one_out_press(
    a_mean: np.ndarray, g: float, result: GravityResult, *, cov_mean: np.ndarray | None = None
) -> np.ndarray:
    """Held-out residuals from each pose's leverage (PRESS): ``r_k / (1 - H_kk)``, m/s^2.

    The first-order equivalent of :func:`leave_one_out` without refitting: O(N) instead of
    N solves, for sessions with hundreds of poses. ``H`` is the hat matrix of the weighted,
    linearised problem at the solution.
    """
    a_mean = np.asarray(a_mean, float)
    B, M = result.bias, result.M
    w = np.ones(len(a_mean))
    if cov_mean is not None:
        w = _weights_from_sigmas(_pose_sigmas(a_mean, np.asarray(cov_mean, float), B, M, g))
    _, Jw = _residuals_and_jacobian(model_to_params(B, M), a_mean, g, w)
    leverage = np.einsum("ij,jk,ik->i", Jw, np.linalg.pinv(Jw.T @ Jw), Jw)
    residual = np.linalg.norm((a_mean - B) @ M.T, axis=1) - g
    return residual / np.clip(1 - leverage, 1e-6, None)
