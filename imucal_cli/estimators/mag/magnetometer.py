"""Magnetometer calibration: hard iron, soft iron and the rotation onto the accelerometer frame.

Model
-----
A magnetometer reading ``m`` (raw units) of the local field ``h`` (a fixed vector in the world,
magnitude ``F``) seen in the sensor frame is

    m = W^-1 h + b + e,            calibrated  h = W (m - b),                          (1)

with ``b`` the hard-iron offset (raw units: the sensor's own offset plus fields of magnetised
parts on the board) and ``W`` the soft-iron correction (output units per raw unit: gains, axes
that are not orthogonal, and the distortion of the field by soft-magnetic parts), ``e`` white
noise of covariance ``Sigma`` (raw units^2).  Wherever the unit points,

    |W (m - b)| = F.                                                                    (2)

Magnitude alone fixes ``W`` only up to a rotation (``|Q W d| = |W d|``).  With a static pose
``k`` the calibrated accelerometer gives the up direction ``u_k`` in the accelerometer frame,
and the angle between gravity and the field (90 degrees plus the inclination ``I``) is the
same in every pose:

    u_k . W (m_k - b) / |W (m_k - b)| = s = -sin I.                                     (3)

Eq. (3) fixes the rotation, so ``W`` maps raw readings into the accelerometer frame.

Estimator
---------
Maximum likelihood to first order (the radial and the dip component of each reading's error
are what the parameters see; the direction of each sample along the sphere is a nuisance):
weighted least squares over

- eq. (2) for every sample of the motion and every static pose mean, each residual divided by
  its standard deviation ``sqrt(h^T W Sigma W^T h) / |h|`` and less the mean the noise gives it
  (the part of the noise across the sphere lengthens every reading by ``tr(P W Sigma W^T) /
  (2 |h|)``, ``P`` the projection across ``h``: left in, it shrinks ``W`` and, for a
  magnetometer whose soft iron is not round, distorts its shape); the remaining second-order
  bias (the Jacobian of a reading moves with its own noise) is taken out after the fit by one
  step, ``(J^T J)^-1 sum_i w_i^2 cov(J_i, r_i)``;
- eq. (3) for every static pose with an up direction, divided by the standard deviation that
  the pose's magnetometer and accelerometer noise give it.

Levenberg-Marquardt (``scipy.optimize.least_squares``) on ``(b, W, s)``, started from an
algebraic ellipsoid fit (:func:`imucal_cli.estimators.ellipsoid.fit_ellipsoid`; the symmetric
soft-iron matrix of that fit is what the hobby tools stop at) and from the rotation that best
satisfies eq. (3) (multi-start over the 24 axis permutations plus a linear solution, so that a
magnetometer mounted at any angle to the accelerometer, e.g. the AK8963's swapped axes in an
MPU-9250, is found).  Without up directions the gauge is fixed by a symmetric ``W`` (the frame
closest to the magnetometer's own axes).

The field magnitude ``F`` is given (microtesla) or, when unknown, 1: the calibrated output is
then in units of the local field.

The residuals of eqs. (2) and (3), their Jacobians and noise weights: :mod:`.residuals`; the
starts: :mod:`.start`; the rotation onto the accelerometer frame (eq. 3: whether the poses can
fix it, the joint fit, the dip and inclination it gives): :mod:`.align`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri

from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.mag.align import (
    MIN_ALIGN_POSES,
    MIN_UP_SPREAD_DEG,
    alignment_figures,
    fit_aligned,
    t_intervals,
)
from imucal_cli.estimators.mag.residuals import (
    SYM_INDEX,
    Problem,
    conditioning,
    magnitude_shift,
    magnitude_sigma,
    noise_weights,
    residual_sigmas,
    sym_params,
)
from imucal_cli.estimators.mag.start import ellipsoid_start, polar

__all__ = [
    "MIN_ALIGN_POSES",
    "MIN_UP_SPREAD_DEG",
    "PARAM_NAMES_ALIGNED",
    "PARAM_NAMES_SYMMETRIC",
    "MagData",
    "MagResult",
    "fit_magnetometer",
    "fit_plain_ellipsoid",
    "held_out_residuals",
    "polar",
    "residual_sigmas",
]

_AXES = "xyz"
PARAM_NAMES_SYMMETRIC = ["b_x", "b_y", "b_z"] + [f"w_{_AXES[i]}{_AXES[j]}" for i, j in SYM_INDEX]
PARAM_NAMES_ALIGNED = (
    ["b_x", "b_y", "b_z"] + [f"w_{r}{c}" for r in _AXES for c in _AXES] + ["s"]
)
@dataclass
class MagData:
    """What the magnetometer fit sees.

    Attributes
    ----------
    samples : ndarray, shape (N, 3)
        Raw readings taken while the unit moved (any attitude), raw units.  N may be 0.
    pose_mean : ndarray, shape (K, 3)
        Mean raw reading of each static pose.  K may be 0.
    sample_cov : ndarray, shape (3, 3), or None
        Noise covariance of one sample, raw units^2.  None: every reading weighs the same and
        the noise is estimated from the residuals.
    pose_cov : ndarray, shape (K, 3, 3), or None
        Covariance of each pose mean, raw units^2 (needed with ``sample_cov``).
    up : ndarray, shape (K, 3), or None
        Up direction of each pose (unit; rows of NaN where unknown) in the accelerometer's
        calibrated frame: what fixes the rotation, eq. (3).
    up_cov : ndarray, shape (K, 3, 3), or None
        Covariance of each ``up`` from its own pose's noise (unit-vector perturbation,
        rad^2); None: exact.
    up_shared : ndarray, shape (K, 3, m), or None
        The error every ``up`` shares (the accelerometer calibration's, which does not average
        out over poses): ``up[k]`` is off by ``up_shared[k] @ z``, ``z`` standard normal (m),
        to first order; None: none.  Eq. (3) is weighed with it (correlated over the poses),
        so the fit's covariance holds it.
    up_shared_dof : float
        Degrees of freedom of ``up_shared``'s variance (an accelerometer whose placement was
        estimated from few equations, e.g. six faces: its placement's); inf: known.  The
        intervals (:attr:`MagResult.ci95`) are Student t on them.
    """

    samples: np.ndarray
    pose_mean: np.ndarray
    sample_cov: np.ndarray | None = None
    pose_cov: np.ndarray | None = None
    up: np.ndarray | None = None
    up_cov: np.ndarray | None = None
    up_shared: np.ndarray | None = None
    up_shared_dof: float = np.inf

    def __post_init__(self) -> None:
        self.samples = np.asarray(self.samples, float).reshape(-1, 3)
        self.pose_mean = np.asarray(self.pose_mean, float).reshape(-1, 3)

    @property
    def points(self) -> np.ndarray:
        """Every reading eq. (2) uses: motion samples, then pose means, shape (N + K, 3)."""
        return np.concatenate([self.samples, self.pose_mean])

    def point_covs(self) -> np.ndarray | None:
        """Covariance of each of :attr:`points`, shape (N + K, 3, 3), or None (equal weights)."""
        if self.sample_cov is None:
            return None
        n, k = len(self.samples), len(self.pose_mean)
        out = np.empty((n + k, 3, 3))
        out[:n] = self.sample_cov
        if k:
            out[n:] = self.pose_cov if self.pose_cov is not None else self.sample_cov
        return out

    def labelled(self) -> np.ndarray:
        """Boolean mask of the poses with an up direction, shape (K,)."""
        if self.up is None or not len(self.pose_mean):
            return np.zeros(len(self.pose_mean), bool)
        return np.isfinite(np.asarray(self.up, float)).all(axis=1)

    def subset(self, samples: np.ndarray, poses: np.ndarray) -> MagData:
        """The data restricted to the motion samples and poses selected (masks or indices)."""

        def pick(a, idx):
            return None if a is None else np.asarray(a)[idx]

        return MagData(
            self.samples[samples], self.pose_mean[poses], self.sample_cov,
            pick(self.pose_cov, poses), pick(self.up, poses), pick(self.up_cov, poses),
            pick(self.up_shared, poses), self.up_shared_dof,
        )  # fmt: skip


@dataclass
class MagResult:
    """Result of :func:`fit_magnetometer` (or :func:`fit_plain_ellipsoid`).

    Attributes
    ----------
    bias : ndarray, shape (3,)
        Hard-iron offset ``b``, raw units.
    matrix : ndarray, shape (3, 3)
        Soft-iron correction ``W``: ``calibrated = matrix @ (raw - bias)``, output units (``field``
        units) per raw unit.  Aligned: output in the accelerometer frame; else symmetric.
    field : float
        ``F``, the magnitude every calibrated reading should have (uT, or 1: local field).
    aligned : bool
        Whether eq. (3) fixed the rotation (output in the accelerometer frame).
    param_names, params, cov
        ``b`` (raw units), the entries of ``W`` (9 row-major when aligned, else the 6 of a
        symmetric matrix), and ``s`` (aligned only); their covariance.
    inclination_deg, inclination_std_deg : float or None
        Inclination of the field below the horizontal (positive: pointing down), degrees.
    rotation : ndarray, shape (3, 3)
        ``R`` of the polar decomposition ``W = R P`` (``P`` symmetric positive definite): maps
        the magnetometer's own axes into the output frame.  Identity when not aligned.
    rotation_std_deg : float or None
        One-sigma uncertainty of ``R``, RMS over its three small-angle components, degrees.
    residuals : ndarray, shape (N + K,)
        ``|W (m - b)| - F`` of each motion sample, then each pose mean, output units.
    dip_residuals_deg : ndarray, shape (K,)
        Angle of each pose's field to gravity minus the fitted one, degrees (NaN unlabelled).
    chi2, dof, noise_scale, weighting
        Weighted residual sum of squares, degrees of freedom, the factor applied to ``cov``
        (1 when the residuals agree with the noise, else ``chi2 / dof``), ``"noise"`` or
        ``"equal"``.
    init : str
        ``"ellipsoid"`` or ``"sphere"`` (the algebraic start).
    iterations, nfev, converged, message
        Of the final Levenberg-Marquardt run.
    notes : list of str
        What the fit decided (e.g. why it did not align).
    cov_shared : ndarray or None
        The part of ``cov`` from the error the up directions share (:attr:`MagData.up_shared`).
    ci95 : ndarray or None
        Half-width of each parameter's 95 % interval (Student t on the degrees of freedom of
        its variance, Satterthwaite: the noise's and ``up_shared_dof``); None: not aligned.
    inclination_ci95_deg : float or None
        The same for the inclination, degrees.
    ambiguity : str or None
        Words for another rotation onto the accelerometer frame that fits as well (the poses
        cannot tell them apart: the stated std hold only near this one); None: none found.
    """

    bias: np.ndarray
    matrix: np.ndarray
    field: float
    aligned: bool
    param_names: list[str]
    params: np.ndarray
    cov: np.ndarray
    inclination_deg: float | None
    inclination_std_deg: float | None
    rotation: np.ndarray
    rotation_std_deg: float | None
    residuals: np.ndarray
    dip_residuals_deg: np.ndarray
    chi2: float
    dof: int
    noise_scale: float
    weighting: str
    init: str
    iterations: int
    nfev: int
    converged: bool
    message: str
    notes: list[str] = field(default_factory=list)
    cov_shared: np.ndarray | None = None
    ci95: np.ndarray | None = None
    inclination_ci95_deg: float | None = None
    ambiguity: str | None = None

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of ``params``."""
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))

    def calibrate(self, raw: np.ndarray) -> np.ndarray:
        """``matrix @ (raw - bias)`` for raw readings (..., 3)."""
        return (np.asarray(raw, float) - self.bias) @ self.matrix.T


# --------------------------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------------------------


def fit_plain_ellipsoid(data: MagData, field: float = 1.0) -> MagResult:
    """The algebraic ellipsoid fit alone (what the hobby tools do): symmetric ``W``, no weights,
    no alignment.  Standard deviations from the Jacobian of eq. (2) at that solution."""
    points = data.points
    _check_points(points)
    c, P, kind = ellipsoid_start(points)
    n = len(points)
    prob = Problem(points, np.ones(n))
    x = prob.pack(c, P)
    r, J = prob.evaluate(x)
    return _result(
        prob, x, r, J, field, weighting="equal", init=kind, sol=None, data=data, notes=[]
    )


#: Readings whose thinnest principal spread is below this fraction of the widest lie in one
#: plane (turns about one axis only): hard and soft iron across that plane are not seen.
MIN_FLATNESS = 0.05


def _check_points(points: np.ndarray) -> None:
    if len(points) < 9:
        raise DesignError(
            f"{len(points)} magnetometer readings cannot determine the 9 parameters of hard and "
            "soft iron; record the unit turning through every direction"
        )
    spread = np.sqrt(np.clip(np.linalg.eigvalsh(np.cov(points, rowvar=False)), 0, None))
    if spread[-1] == 0:
        raise DesignError(
            "every magnetometer reading is the same: the sensor is stuck or not connected"
        )
    if spread[0] < MIN_FLATNESS * spread[-1]:
        raise DesignError(
            "the magnetometer readings lie in one plane (the unit was turned about one axis "
            "only, e.g. flat on a table), which leaves hard and soft iron across it "
            "undetermined; turn the unit through every direction: a slow figure-eight, then "
            "each face up"
        )


def fit_magnetometer(
    data: MagData, field: float = 1.0, *, align: bool = True, max_iterations: int = 100
) -> MagResult:
    """Calibrate a magnetometer triad by maximum likelihood on eqs. (2) and (3).

    Parameters
    ----------
    data : MagData
        Readings of the motion and of the static poses, their noise, and the up directions.
    field : float
        ``F``: the local field magnitude the output should have (uT), or 1 when unknown (the
        output is then in units of the local field).
    align : bool
        Use eq. (3) to rotate the output onto the accelerometer frame (needs at least
        :data:`MIN_ALIGN_POSES` poses with up directions that are not all parallel).
    max_iterations : int
        Function evaluations of each Levenberg-Marquardt run.

    Returns
    -------
    MagResult

    Raises
    ------
    DesignError
        Fewer than 9 readings, or readings that leave hard and soft iron undetermined (they
        cover too little of the sphere).
    SolverError
        No convergence within ``max_iterations``.
    """
    points = data.points
    _check_points(points)
    if not field > 0:
        raise ValueError("field must be positive")
    c, P, kind = ellipsoid_start(points)
    rho = 1.0 / float(np.cbrt(abs(np.linalg.det(P))))  # mean radius, raw units
    notes: list[str] = []

    pts_n = (points - c) / rho
    covs = data.point_covs()
    covs_n = None if covs is None else covs / rho**2
    weighting = "equal" if covs is None else "noise"
    b0, W0 = np.zeros(3), P * rho

    # ---- magnitude only, symmetric gauge (eq. 2)
    w_mag = np.ones(len(points))
    if covs_n is not None:
        w_mag = noise_weights(magnitude_sigma(pts_n, covs_n, b0, W0))
    prob = Problem(pts_n, w_mag, shift=magnitude_shift(pts_n, covs_n, b0, W0))
    sol = prob.solve(prob.pack(b0, W0), max_iterations)
    _check_converged(sol, max_iterations)
    b1, W1, _ = prob.unpack(sol.x)

    # ---- rotation onto the accelerometer frame (eq. 3)
    fit = fit_aligned(data, pts_n, covs_n, rho, b1, W1, max_iterations, notes) if align else None
    aligned = fit is not None
    if aligned:
        prob, sol, ambiguity = fit
    if not aligned and covs_n is not None:  # second pass, weights at the solution
        w_mag = noise_weights(magnitude_sigma(pts_n, covs_n, b1, W1))
        prob = Problem(pts_n, w_mag, shift=magnitude_shift(pts_n, covs_n, b1, W1),
                        covs=covs_n)  # fmt: skip
        sol2 = prob.solve(sol.x, max_iterations)
        sol = sol2 if sol2.status > 0 else sol
    x = sol.x
    r, J = prob.evaluate(x)
    if prob.covs is not None:
        x = x + _bias_step(prob, x, J)
        r, J = prob.evaluate(x)
    if conditioning(J) <= 1e-6:
        raise DesignError(
            "the magnetometer readings leave hard and soft iron undetermined (they lie in one "
            "plane or cone of directions, e.g. turned flat on a table); turn the unit through "
            "every direction: a slow figure-eight, then each face up"
        )
    result = _result(  # back to raw units
        prob, x, r, J, field, weighting=weighting, init=kind, sol=sol, data=data, notes=notes,
        scale=(c, rho),
    )  # fmt: skip
    result.ambiguity = ambiguity if aligned else None
    return result


def _bias_step(prob: Problem, x: np.ndarray, J: np.ndarray) -> np.ndarray:
    """The step that takes out the second-order bias of eq. (2)'s estimating equation.

    At the truth ``E[sum w^2 J_i r_i] = sum w^2 cov(J_i, r_i)`` is not zero, because a
    reading's Jacobian row moves with its own noise.  With ``g = W^T h^`` (``r``'s gradient by
    the reading) and ``A = (I - h^ h^T) W / |h|`` (``h^``'s), ``cov(J_b, r) = -W^T A Sigma g``
    and ``cov(J_W_ij, r) = (A Sigma g)_i d_j + h^_i (Sigma g)_j``.  The estimate is biased by
    ``-(J^T J)^-1`` times their weighted sum; this returns the opposite.
    """
    b, W, _ = prob.unpack(x)
    d = prob.points - b
    h = d @ W.T
    r = np.linalg.norm(h, axis=1)
    hu = h / r[:, None]
    Sg = np.einsum("nij,nj->ni", prob.covs, hu @ W)  # Sigma g
    v = Sg @ W.T
    ASg = (v - np.sum(v * hu, axis=1, keepdims=True) * hu) / r[:, None]
    w2 = prob.w_mag**2
    c = np.zeros(J.shape[1])
    c[:3] = -(w2 @ (ASg @ W))
    c[3 : 3 + prob.n_w] = w2 @ (prob._dW(ASg, d) + prob._dW(hu, Sg))
    return np.linalg.solve(J.T @ J, c)


def _check_converged(sol, max_iterations: int) -> None:
    if sol.status <= 0:
        raise SolverError(
            f"the magnetometer fit did not converge in {max_iterations} iterations "
            f"({sol.message}); turn the unit slowly through every direction, away from steel "
            "and magnets"
        )


def _result(prob, x, r, J, field, *, weighting, init, sol, data, notes, scale=None):
    """Assemble a :class:`MagResult` in raw units from the normalised solution ``x`` (``r``,
    ``J`` its whitened residuals and Jacobian; ``scale = (c, rho)`` the normalisation, None for
    the plain fit's raw units with field 1)."""
    if scale is None:  # the plain fit works in raw units with field 1
        c, rho = np.zeros(3), 1.0
    else:
        c, rho = scale
    b_n, W_n, s = prob.unpack(x)
    bias = c + rho * b_n
    matrix = field * W_n / rho
    cov, cov_shared, (chi2, dof, noise_scale) = _covariance(prob, x, r, J, field, rho,
                                                            weighting)  # fmt: skip
    params = np.r_[bias, W_n.ravel() * field / rho if prob.aligned else sym_params(matrix)]
    if prob.aligned:
        params = np.r_[params, s]
        names = list(PARAM_NAMES_ALIGNED)
    else:
        names = list(PARAM_NAMES_SYMMETRIC)

    residuals = np.linalg.norm((data.points - bias) @ matrix.T, axis=1) - field
    dip = np.full(len(data.pose_mean), np.nan)
    inc = inc_std = rot_std = None
    R = np.eye(3)
    if prob.aligned:
        dip, inc, inc_std, R, rot_std = alignment_figures(data, bias, matrix, s, cov)
    return MagResult(
        bias=bias,
        matrix=matrix,
        field=float(field),
        aligned=bool(prob.aligned),
        param_names=names,
        params=params,
        cov=cov,
        inclination_deg=inc,
        inclination_std_deg=inc_std,
        rotation=R,
        rotation_std_deg=rot_std,
        residuals=residuals,
        dip_residuals_deg=dip,
        chi2=chi2,
        dof=int(dof),
        noise_scale=float(noise_scale),
        weighting=weighting,
        init=init,
        iterations=0 if sol is None else int(sol.njev or 0),
        nfev=0 if sol is None else int(sol.nfev),
        converged=True if sol is None else bool(sol.status > 0),
        message="algebraic fit" if sol is None else str(sol.message),
        notes=list(notes),
        cov_shared=cov_shared,
        **(_intervals(cov, cov_shared, data.up_shared_dof, dof, s) if prob.aligned else {}),
    )


def _intervals(cov, cov_shared, shared_dof: float, noise_dof: float, s: float) -> dict:
    """:attr:`MagResult.ci95` and ``inclination_ci95_deg`` of an aligned fit."""
    ci95 = t_intervals(cov, cov_shared, shared_dof, noise_dof)
    return {"ci95": ci95,
            "inclination_ci95_deg": float(np.degrees(ci95[-1]) / max(np.sqrt(1 - s * s), 1e-9))}


def _covariance(prob, x, r, J, field: float, rho: float, weighting: str):
    """The parameters' covariance in raw and output units from the normalised fit's Jacobian,
    scaled by the excess of the residuals over the noise.

    Returns
    -------
    cov : ndarray, shape (n, n)
        Of ``(b, W entries[, s])``: raw units, output units per raw unit, 1.
    cov_shared : ndarray, shape (n, n), or None
        Its part from the error the up directions share (``prob.shared``; None: none).
    chi2 : float
        Weighted residual sum of squares.
    dof : int
        ``len(r) - len(x)``.
    noise_scale : float
        Factor applied to ``(J^T J)^-1``: ``"noise"`` weighting, 1 unless ``chi2`` exceeds its
        99 % point; ``"equal"``, ``chi2 / dof``.
    """
    n_res = len(r)
    n_par = len(x)
    dof = n_res - n_par
    chi2 = float(r @ r)
    JtJ = J.T @ J
    cov_n = np.linalg.pinv(JtJ, hermitian=True)
    if weighting == "noise":
        noise_scale = 1.0
        if dof > 0 and chi2 > chdtri(dof, 0.01):
            noise_scale = chi2 / dof
    else:
        noise_scale = chi2 / dof if dof > 0 else float("nan")
    T = np.r_[np.full(3, rho), np.full(prob.n_w, field / rho), np.ones(n_par - 3 - prob.n_w)]
    cov = noise_scale * (T[:, None] * cov_n * T[None, :])
    cov_shared = None
    if prob.shared is not None:  # x moves by -cov_n J^T (the whitened residuals' move)
        G = cov_n @ J[len(J) - len(prob.shared) :].T @ prob.shared
        cov_shared = noise_scale * (T[:, None] * (G @ G.T) * T[None, :])
    return cov, cov_shared, (chi2, dof, noise_scale)


def held_out_residuals(
    data: MagData,
    folds_samples: np.ndarray,
    folds_poses: np.ndarray,
    field: float = 1.0,
    *,
    align: bool = True,
    max_iterations: int = 100,
) -> np.ndarray:
    """Eq.-(2) residual of every reading predicted by a fit that did not see it (k-fold).

    Parameters
    ----------
    folds_samples, folds_poses : ndarray of int, shapes (N,), (K,)
        Fold number of each motion sample and pose (0 .. k-1).

    Returns
    -------
    ndarray, shape (N + K,)
        ``|W_(-f) (m - b_(-f))| - F`` per reading, NaN where its fold could not be fitted.
    """
    out = np.full(len(data.samples) + len(data.pose_mean), np.nan)
    n = len(data.samples)
    for f in np.unique(np.r_[folds_samples, folds_poses]):
        train = data.subset(folds_samples != f, folds_poses != f)
        try:
            res = fit_magnetometer(train, field, align=align, max_iterations=max_iterations)
        except (DesignError, SolverError):
            continue
        test_s, test_p = folds_samples == f, folds_poses == f
        for idx, pts in ((np.flatnonzero(test_s), data.samples[test_s]),
                         (n + np.flatnonzero(test_p), data.pose_mean[test_p])):  # fmt: skip
            if len(pts):
                out[idx] = np.linalg.norm(res.calibrate(pts), axis=1) - field
    return out
