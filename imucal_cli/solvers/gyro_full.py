"""Full gyroscope model from arbitrary hand rotations and the calibrated accelerometer.

Beyond Qureshi & Golnaraghi's per-axis model (eq. 15): 12 parameters, ``omega = M (z - b)``
with ``M`` a full 3 x 3 matrix (scale and misalignment of the gyro triad relative to the
accelerometer's frame) and ``b`` the bias. Each rotation between two still periods is
integrated (:mod:`imucal_cli.solvers.gyro_integration`: all rotations at once, the rate
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
(:mod:`imucal_cli.solvers.banded`): time and memory are linear in the number of turns.

Start values come from the data alone (:mod:`imucal_cli.solvers.gyro_start`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.special import chdtri

from imucal_cli.errors import DesignError, SolverError
from imucal_cli.solvers.banded import BandedWhitener
from imucal_cli.solvers.gyro_integration import (
    Stack,
    attitudes,
    end_sensitivity,
    integrate_rotations,
    matrix_rows,
    quat_to_matrix,
)
from imucal_cli.solvers.gyro_start import Start, start_values

#: A fit leaving a turn's gravity direction further off than this did not find the turns'
#: minimum: the next start is tried.
MAX_TURN_RESIDUAL_DEG = 10.0

__all__ = ["FullResult", "Rotations", "Stills", "fit_full", "full_information",
           "integrate_rotations"]  # fmt: skip


@dataclass
class Rotations:
    """The rotation segments of a session.

    Attributes
    ----------
    t : list of ndarray (n_k,)
        Sample times of each rotation, s (including the still samples at both ends is fine).
    z : list of ndarray (n_k, 3)
        Raw gyro samples.
    before, after : ndarray of int (K,)
        Index of the still period before and after each rotation (into :class:`Stills`).
    """

    t: list[np.ndarray]
    z: list[np.ndarray]
    before: np.ndarray
    after: np.ndarray


@dataclass
class Stills:
    """The still periods around the rotations.

    Attributes
    ----------
    g : ndarray (P, 3)
        Calibrated accelerometer mean of each still period (any units; only the direction
        counts).
    g_sigma : ndarray (P,)
        Standard deviation of each mean's direction, per tangent component, rad.
    z_mean : ndarray (P, 3)
        Raw gyro mean of each still period.
    z_sigma : ndarray (P,)
        Standard deviation of each gyro mean, per channel, raw units.
    """

    g: np.ndarray
    g_sigma: np.ndarray
    z_mean: np.ndarray
    z_sigma: np.ndarray


@dataclass
class FullResult:
    """Result of :func:`fit_full`.

    Attributes
    ----------
    b : ndarray (3,)
        Bias, raw units.
    M : ndarray (3, 3)
        ``omega [rad/s] = M (z - b)``.
    cov : ndarray (12, 12)
        Covariance of ``(b, vec(M))`` (row-major), after ``noise_scale``.
    angle_residual_deg : ndarray (K,)
        Angle between the predicted and the measured gravity direction after each rotation.
    rotation_angle_deg : ndarray (K,)
        Angle of each integrated rotation.
    chi2, dof, noise_scale, iterations, converged, message
        Fit statistics; ``noise_scale`` is ``chi2/dof`` when that is significantly above 1.
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

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))


# --------------------------------------------------------------------------- the model


def _tangent(u: np.ndarray) -> np.ndarray:
    """(P, 3, 2) orthonormal bases of the planes normal to unit vectors ``u`` (P, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    t1 = np.cross(u, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(u, t1)
    return np.stack([t1, t2], axis=2)


def _skew(p: np.ndarray) -> np.ndarray:
    """(K, 3, 3) cross-product matrices ``[p]x`` of (K, 3) vectors."""
    out = np.zeros((len(p), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -p[:, 2], p[:, 1], -p[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = p[:, 2], -p[:, 1], p[:, 0]
    return out


class _Problem:
    """Residuals of the full model, their Jacobian, and their noise covariance.

    Parameters ``x = (b, vec(M))`` (row-major). Residuals: two per rotation (the predicted
    gravity direction after it, ``p = R^T u_before``, minus the measured one, in the tangent
    plane of the measured one), then three per still period (gyro mean minus bias).
    """

    def __init__(self, rot: Rotations, still: Stills, gyro_sigma: float, clock: float = 1.0):
        self.rot, self.still, self.clock = rot, still, clock
        self.stack = Stack.of(rot.t)
        self.z = np.ascontiguousarray(np.concatenate(rot.z).T, dtype=float)  # (3, N)
        self.u = still.g / np.linalg.norm(still.g, axis=1, keepdims=True)
        self.B = _tangent(self.u)
        self.gyro_sigma = gyro_sigma
        self.K, self.P = len(rot.t), len(still.g)
        # Integrated white gyro noise over a rotation: sigma * sqrt(sum dt^2) per axis (raw).
        h2 = (clock * np.diff(self.stack.t)) ** 2
        h2[self.stack.stop[:-1] - 1] = 0.0
        self.int_noise = gyro_sigma * np.sqrt(np.add.reduceat(np.r_[h2, 0.0], self.stack.start))
        self._last = (None, None)

    def _attitudes(self, x):
        """Every sample's attitude in its rotation (4, N); the last evaluation is kept (the
        solver asks for residuals, Jacobian and noise model at one point in turn)."""
        key = x.tobytes()
        if self._last[0] != key:
            b, M = x[:3], x[3:12].reshape(3, 3)
            self._last = (key, attitudes(self.stack, M @ (self.z - b[:, None]), self.clock))
        return self._last[1]

    def predicted(self, x):
        """Predicted gravity direction after each rotation (K, 3) and the rotations (K, 3, 3)."""
        q = self._attitudes(x)
        R = quat_to_matrix(q[:, self.stack.stop - 1])
        return np.einsum("kji,kj->ki", R, self.u[self.rot.before]), R  # R^T u0

    def _rotation_residuals(self, p):
        B1 = self.B[self.rot.after]
        return np.einsum("kij,ki->kj", B1, p - self.u[self.rot.after]).ravel()

    def raw_residuals(self, x):
        p, _ = self.predicted(x)
        return np.concatenate([self._rotation_residuals(p), (self.still.z_mean - x[:3]).ravel()])

    def residuals_and_jacobian(self, x):
        """Raw residuals and their analytic Jacobian (first order in the rate perturbation).

        A rate error ``d omega(t)`` rotates the end of a turn by
        ``d phi = integral R(t -> end) d omega(t) dt`` (body frame at the end), which moves the
        predicted gravity direction by ``d p = [p]x d phi``.
        """
        b, M = x[:3], x[3:12].reshape(3, 3)
        st, K = self.stack, self.K
        R = matrix_rows(self._attitudes(x))
        R_end = R[:, st.stop - 1].T.reshape(K, 3, 3)
        p = np.einsum("kji,kj->ki", R_end, self.u[self.rot.before])
        r = np.concatenate([self._rotation_residuals(p), (self.still.z_mean - b).ravel()])
        dphi_db = -end_sensitivity(st, R, clock=self.clock) @ M  # d omega_i = -M d b
        dphi_dM = end_sensitivity(st, R, self.z - b[:, None], self.clock).reshape(K, 3, 9)  # dM d_i
        G = np.einsum("kai,kab->kib", self.B[self.rot.after], _skew(p))  # B1^T [p]x
        J = np.zeros((2 * K + 3 * self.P, 12))
        J[: 2 * K, :3] = (G @ dphi_db).reshape(2 * K, 3)
        J[: 2 * K, 3:] = (G @ dphi_dM).reshape(2 * K, 9)
        J[2 * K :, :3] = -np.tile(np.eye(3), (self.P, 1))
        return r, J

    def rotation_covariance(self, x) -> sparse.csr_matrix:
        """Covariance of the rotation residuals (2K x 2K, sparse): each rotation's from the
        gravity directions before and after it (shared with its neighbours) and its
        integrated gyro noise."""
        p, R = self.predicted(x)
        M = x[3:12].reshape(3, 3)
        K, P = self.K, self.P
        i0, i1 = self.rot.before, self.rot.after
        B1 = self.B[i1]
        g_sigma = self.still.g_sigma
        # u_before perturbed in its tangent plane: d p = R^T B0 e
        c0 = np.einsum("kai,kba,kbj->kij", B1, R, self.B[i0]) * g_sigma[i0, None, None]
        # u_after perturbed: d(-u1) projected (B1 is fixed from the data, to first order)
        c1 = -np.broadcast_to(np.eye(2), (K, 2, 2)) * g_sigma[i1, None, None]
        # Integrated gyro noise: a small rotation eps (body, end) -> d p = [p]x eps
        cg = np.einsum("kai,kab,bc->kic", B1, _skew(p), M) * self.int_noise[:, None, None]
        rows = 2 * np.arange(K)[:, None, None] + np.arange(2)[None, :, None]
        blocks = [(c0, 2 * i0), (c1, 2 * i1), (cg, 2 * P + 3 * np.arange(K))]
        data, rr, cc = [], [], []
        for c, col0 in blocks:
            n = c.shape[2]
            cols = col0[:, None, None] + np.arange(n)[None, None, :]
            data.append(c.ravel())
            rr.append(np.broadcast_to(rows, c.shape).ravel())
            cc.append(np.broadcast_to(cols, c.shape).ravel())
        C = sparse.csr_matrix(
            (np.concatenate(data), (np.concatenate(rr), np.concatenate(cc))),
            shape=(2 * K, 2 * P + 3 * K),
        )
        return C @ C.T

    def whitener(self, x) -> _Whitener:
        return _Whitener(BandedWhitener(self.rotation_covariance(x)), self)


class _Whitener:
    """Whitens the stacked residuals: rotation rows by the banded factor, still rows by their
    standard deviation."""

    def __init__(self, rot: BandedWhitener, prob: _Problem):
        self.rot, self.n_rot = rot, 2 * prob.K
        self.zero_sigma = np.repeat(prob.still.z_sigma, 3)

    def __call__(self, a: np.ndarray) -> np.ndarray:
        top = self.rot(a[: self.n_rot])
        bottom = a[self.n_rot :] / (self.zero_sigma if a.ndim == 1 else self.zero_sigma[:, None])
        return np.concatenate([top, bottom])


def full_information(x: np.ndarray, rot: Rotations, still: Stills, gyro_sigma: float) -> np.ndarray:
    """Fisher information of ``(b, vec(M))`` for a design (first order), shape (12, 12).

    Its inverse is the Cramér-Rao bound when ``x`` and the data are the truth.
    """
    prob = _Problem(rot, still, gyro_sigma)
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


def _solve(prob: _Problem, x0: np.ndarray, max_iterations: int, start: str) -> _Solved | None:
    """Generalised least squares from ``x0``: solve with the noise model at the start, again
    with the noise model at that solution. None when it does not converge."""
    scale = np.r_[np.full(3, max(np.std(prob.z), 1e-9)), np.full(9, np.abs(x0[3:]).max())]
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
        return least_squares(fun, x_start, jac=jac, x_scale=scale, method="trf", xtol=1e-12,
                             ftol=1e-12, gtol=1e-12, max_nfev=max_iterations)  # fmt: skip

    first = run(x0)
    W = prob.whitener(first.x)  # the noise model at the solution, then again
    jac_at.clear()
    sol = run(first.x)
    if sol.status <= 0 or not np.all(np.isfinite(sol.x)):
        return None
    return _Solved(sol.x, sol.fun, jac(sol.x), int(first.nfev + sol.nfev), str(sol.message),
                   start)  # fmt: skip


def _explains(prob: _Problem, solved: _Solved) -> bool:
    """A fit that explains the turns: no rotation residual beyond what the fit's own noise
    level makes plausible (a start in the wrong basin leaves residuals of tens of degrees)."""
    p, _ = prob.predicted(solved.x)
    resid = np.arccos(np.clip(np.sum(p * prob.u[prob.rot.after], axis=1), -1, 1))
    return bool(np.degrees(resid).max() < MAX_TURN_RESIDUAL_DEG)


def fit_full(
    rot: Rotations,
    still: Stills,
    gyro_sigma: float,
    b0: np.ndarray,
    M0: np.ndarray | None = None,
    *,
    max_iterations: int = 100,
    clock: float = 1.0,
) -> FullResult:
    """Estimate the 12 parameters from rotations between still periods.

    Parameters
    ----------
    rot, still
        The rotations and the still periods around them.
    gyro_sigma : float
        Per-sample gyro noise, raw units.
    b0 : ndarray (3,)
        Initial bias (the still periods' gyro means).
    M0 : ndarray (3, 3), optional
        Initial matrix. Default: the starts of :func:`imucal_cli.solvers.gyro_start.start_values`
        (from the data alone, no nominal sensitivity), tried in turn until one explains the
        turns; the fit with the smallest chi^2 is kept.
    max_iterations : int
        Function evaluations of each solve (each integrates every rotation).
    clock : float
        Factor on every sample interval (sample-clock correction).

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
    prob = _Problem(rot, still, gyro_sigma, clock)
    if M0 is not None:
        starts = iter([Start(np.asarray(M0, float), 0.0, np.eye(3), 0.0, "given start")])
    else:
        starts = start_values(rot.t, rot.z, still.g[rot.before], still.g[rot.after], b0,
                              clock=clock)  # fmt: skip
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
    return _result(prob, best, tried)


def _result(prob: _Problem, solved: _Solved, tried: int) -> FullResult:
    """Covariance and diagnostics of a solution."""
    J = solved.J
    sv = np.linalg.svd(J, compute_uv=False)
    if sv[-1] < 1e-8 * sv[0]:
        raise DesignError(
            "the rotations leave the gyro model undetermined: turn the unit about at least two "
            "different horizontal axes (a turn about the vertical is invisible to gravity)"
        )
    dof = max(len(solved.f) - 12, 1)
    chi2 = solved.chi2
    noise_scale = chi2 / dof if chi2 > chdtri(dof, 0.01) else 1.0
    cov = noise_scale * np.linalg.inv(J.T @ J)
    p, R = prob.predicted(solved.x)
    u1 = prob.u[prob.rot.after]
    resid = np.degrees(np.arccos(np.clip(np.sum(p * u1, axis=1), -1, 1)))
    angles = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    notes = [solved.start + (f" (best of {tried} starts)" if tried > 1 else "")]
    return FullResult(
        b=solved.x[:3],
        M=solved.x[3:].reshape(3, 3),
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
    )
