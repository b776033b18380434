"""Full gyroscope model from arbitrary hand rotations and the calibrated accelerometer.

Beyond Qureshi & Golnaraghi's per-axis model (eq. 15): 12 parameters, ``omega = M (z - b)``
with ``M`` a full 3 x 3 matrix (scale and misalignment of the gyro triad relative to the
accelerometer's frame) and ``b`` the bias. Each rotation between two still periods is
integrated (quaternions, 4th-order Runge-Kutta with the rate interpolated linearly between
samples) into the body rotation ``R_k``; gravity, fixed in the world, must then appear in the
body as ``u_after = R_k^T u_before``, where the calibrated accelerometer measures both
directions. No known angles and no particular axes are needed.

Estimation is generalised least squares: each rotation gives two residual components (the
mismatch of the predicted gravity direction in the plane normal to the measured one), whose
noise comes from the accelerometer means before and after (shared by consecutive rotations)
and from the integrated gyro noise; the still periods' gyro means tie the bias. The residual
covariance is propagated from those noise sources and whitened, which makes the fit the
first-order maximum-likelihood estimate and its covariance the Cramér-Rao bound of the
design (:func:`full_information`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from imucal_cli.errors import DesignError, SolverError


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


# --------------------------------------------------------------------------- quaternions


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of (K, 4) quaternions ``[w, x, y, z]``."""
    pw, px, py, pz = p.T
    qw, qx, qy, qz = q.T
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=1,
    )


def _qdot(q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``q' = 1/2 q (0, w)`` for body rates ``w`` (K, 3)."""
    return 0.5 * _qmul(q, np.column_stack([np.zeros(len(w)), w]))


def integrate_rotations(
    t: list[np.ndarray], w: list[np.ndarray], *, path: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Body rotation over each segment by 4th-order Runge-Kutta, all segments at once.

    Parameters
    ----------
    t : list of ndarray (n_k,)
        Sample times, s.
    w : list of ndarray (n_k, 3)
        Body angular rate, rad/s, linearly interpolated between samples.

    path : bool
        Also return the rotation at every sample (for the Jacobian).

    Returns
    -------
    ndarray (K, 3, 3)
        ``R_k``: the body frame at the end expressed in the body frame at the start.
    ndarray (K, L, 3, 3), only with ``path``
        The same from the start to every sample (the last one repeated past a segment's end).
    """
    K = len(t)
    L = max(len(x) for x in t)
    W = np.zeros((K, L, 3))
    dt = np.zeros((K, L - 1))
    for k in range(K):
        n = len(t[k])
        W[k, :n] = w[k]
        W[k, n:] = w[k][-1]
        dt[k, : n - 1] = np.diff(t[k])  # zero after the segment's end: the state stays put
    q = np.tile([1.0, 0.0, 0.0, 0.0], (K, 1))
    Q = np.empty((K, L, 4)) if path else None
    if path:
        Q[:, 0] = q
    for i in range(L - 1):
        h = dt[:, i : i + 1]
        w0, w1 = W[:, i], W[:, i + 1]
        wm = 0.5 * (w0 + w1)
        k1 = _qdot(q, w0)
        k2 = _qdot(q + 0.5 * h * k1, wm)
        k3 = _qdot(q + 0.5 * h * k2, wm)
        k4 = _qdot(q + h * k3, w1)
        q = q + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        if path:
            Q[:, i + 1] = q
    if path:
        return _quat_to_matrix(q), _quat_to_matrix(Q.reshape(-1, 4)).reshape(K, L, 3, 3)
    return _quat_to_matrix(q)


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions -> (N, 3, 3) rotation matrices."""
    w_, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w_), 2 * (x * z + y * w_)], -1),
            np.stack([2 * (x * y + z * w_), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w_)], -1),
            np.stack([2 * (x * z - y * w_), 2 * (y * z + x * w_), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


# --------------------------------------------------------------------------- the model


def _tangent(u: np.ndarray) -> np.ndarray:
    """(P, 3, 2) orthonormal bases of the planes normal to unit vectors ``u`` (P, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    t1 = np.cross(u, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(u, t1)
    return np.stack([t1, t2], axis=2)


class _Problem:
    """Residuals of the full model, and how they depend on every noise source."""

    def __init__(self, rot: Rotations, still: Stills, gyro_sigma: float):
        self.rot, self.still = rot, still
        self.u = still.g / np.linalg.norm(still.g, axis=1, keepdims=True)
        self.B = _tangent(self.u)
        self.gyro_sigma = gyro_sigma
        self.K, self.P = len(rot.t), len(still.g)
        # Integrated white gyro noise over a rotation: sigma * sqrt(sum dt^2) per axis (raw).
        self.int_noise = np.array([gyro_sigma * np.sqrt(np.sum(np.diff(t) ** 2)) for t in rot.t])

    def predicted(self, x):
        b, M = x[:3], x[3:].reshape(3, 3)
        w = [(z - b) @ M.T for z in self.rot.z]
        R = integrate_rotations(self.rot.t, w)
        u0 = self.u[self.rot.before]
        return np.einsum("kji,kj->ki", R, u0), R  # R^T u0

    def residuals_and_jacobian(self, x):
        """Raw residuals and their analytic Jacobian (first order in the rate perturbation).

        A rate error ``d omega(t)`` rotates the end of a turn by
        ``d phi = integral R(t -> end) d omega(t) dt`` (body frame at the end), which moves the
        predicted gravity direction by ``d p = [p]x d phi``.
        """
        b, M = x[:3], x[3:].reshape(3, 3)
        d = [z - b for z in self.rot.z]
        R, Rpath = integrate_rotations(self.rot.t, [di @ M.T for di in d], path=True)
        u0 = self.u[self.rot.before]
        p = np.einsum("kji,kj->ki", R, u0)
        u1 = self.u[self.rot.after]
        B1 = self.B[self.rot.after]
        K, P = self.K, self.P
        r = np.concatenate([np.einsum("kij,ki->kj", B1, p - u1).ravel(),
                            (self.still.z_mean - b).ravel()])  # fmt: skip
        J = np.zeros((2 * K + 3 * P, 12))
        for k in range(K):
            n = len(self.rot.t[k])
            dt = np.diff(self.rot.t[k])
            wts = np.zeros(n)  # trapezoid weights of the integral
            wts[:-1] += dt / 2
            wts[1:] += dt / 2
            # E_i = R_end^T R_i carries a small rotation at t_i (body at t_i) to the end.
            E = np.einsum("ba,ibc->iac", R[k], Rpath[k, :n])
            dphi_db = -np.einsum("i,iac->ac", wts, E) @ M  # d omega_i = -M d b
            dphi_dM = np.einsum("i,iac,ij->acj", wts, E, d[k]).reshape(3, 9)  # d omega = dM d_i
            px = np.array([[0, -p[k, 2], p[k, 1]], [p[k, 2], 0, -p[k, 0]],
                           [-p[k, 1], p[k, 0], 0]])  # fmt: skip
            G = B1[k].T @ px
            J[2 * k : 2 * k + 2, :3] = G @ dphi_db
            J[2 * k : 2 * k + 2, 3:] = G @ dphi_dM
        J[2 * K :, :3] = -np.tile(np.eye(3), (P, 1))
        return r, J

    def raw_residuals(self, x):
        p, _ = self.predicted(x)
        u1 = self.u[self.rot.after]
        B1 = self.B[self.rot.after]
        r_rot = np.einsum("kij,ki->kj", B1, p - u1).ravel()  # 2 per rotation
        b = x[:3]
        r_zero = (self.still.z_mean - b).ravel()  # still periods: z = b
        return np.concatenate([r_rot, r_zero])

    def noise_jacobian(self, x) -> np.ndarray:
        """d raw residuals / d noise sources (each in units of its standard deviation)."""
        p, R = self.predicted(x)
        M = x[3:].reshape(3, 3)
        K, P = self.K, self.P
        n_res = 2 * K + 3 * P
        n_noise = 2 * P + 3 * K + 3 * P
        C = np.zeros((n_res, n_noise))
        for k in range(K):
            i0, i1 = self.rot.before[k], self.rot.after[k]
            B1 = self.B[i1]
            rows = slice(2 * k, 2 * k + 2)
            # u_before perturbed in its tangent plane: d p = R^T B0 e
            C[rows, 2 * i0 : 2 * i0 + 2] += B1.T @ R[k].T @ self.B[i0] * self.still.g_sigma[i0]
            # u_after perturbed: d(-u1) projected (B1 is fixed from the data, to first order)
            C[rows, 2 * i1 : 2 * i1 + 2] -= B1.T @ self.B[i1] * self.still.g_sigma[i1]
            # Integrated gyro noise: a small rotation eps (body, end) -> d p = -eps x p = [p]x eps
            px = np.array([[0, -p[k, 2], p[k, 1]], [p[k, 2], 0, -p[k, 0]],
                           [-p[k, 1], p[k, 0], 0]])  # fmt: skip
            C[rows, 2 * P + 3 * k : 2 * P + 3 * k + 3] = B1.T @ px @ M * self.int_noise[k]
        zero = slice(2 * K, 2 * K + 3 * P)
        C[zero, 2 * P + 3 * K :] = np.diag(np.repeat(self.still.z_sigma, 3))
        return C


def _whitener(C: np.ndarray) -> np.ndarray:
    cov = C @ C.T
    cov += 1e-12 * np.trace(cov) / len(cov) * np.eye(len(cov))
    return np.linalg.inv(np.linalg.cholesky(cov))


def full_information(x: np.ndarray, rot: Rotations, still: Stills, gyro_sigma: float) -> np.ndarray:
    """Fisher information of ``(b, vec(M))`` for a design (first order), shape (12, 12).

    Its inverse is the Cramér-Rao bound when ``x`` and the data are the truth.
    """
    prob = _Problem(rot, still, gyro_sigma)
    W = _whitener(prob.noise_jacobian(x))
    J = W @ prob.residuals_and_jacobian(x)[1]
    return J.T @ J


def fit_full(
    rot: Rotations,
    still: Stills,
    gyro_sigma: float,
    b0: np.ndarray,
    M0: np.ndarray,
    *,
    max_iterations: int = 100,
) -> FullResult:
    """Estimate the 12 parameters from rotations between still periods.

    Parameters
    ----------
    rot, still
        The rotations and the still periods around them.
    gyro_sigma : float
        Per-sample gyro noise, raw units.
    b0, M0 : ndarray (3,), (3, 3)
        Initial values (bias from still data; a nominal or per-axis scale).
    max_iterations : int
        Function evaluations of the solver (each integrates every rotation).

    Raises
    ------
    DesignError
        Too few rotations, or rotations that leave the model undetermined (all about one
        axis, or about the vertical only).
    SolverError
        No convergence.
    """
    K = len(rot.t)
    if K < 4:
        raise DesignError(
            f"{K} rotations cannot determine the 12-parameter gyro model; turn the unit at least "
            "4 times (better 10 or more) about different axes, still before and after each"
        )
    prob = _Problem(rot, still, gyro_sigma)
    x0 = np.r_[b0, M0.ravel()]
    W = _whitener(prob.noise_jacobian(x0))
    scale = np.r_[np.full(3, max(np.std(np.vstack(rot.z)), 1e-9)), np.full(9, np.abs(M0).max())]

    cache = {}

    def evaluate(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            r, J = prob.residuals_and_jacobian(x)
            cache[key] = (W @ r, W @ J)
        return cache[key]

    def solve(x_start):
        return least_squares(lambda x: evaluate(x)[0], x_start, jac=lambda x: evaluate(x)[1],
                             x_scale=scale, method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12,
                             max_nfev=max_iterations)  # fmt: skip

    sol = solve(x0)
    W = _whitener(prob.noise_jacobian(sol.x))  # the noise model at the solution, then again
    cache.clear()
    sol = solve(sol.x)
    if sol.status <= 0:
        raise SolverError(
            f"the full gyro model did not converge ({sol.message}); capture more rotations about "
            "different axes with the unit still before and after each"
        )
    J = evaluate(sol.x)[1]
    sv = np.linalg.svd(J, compute_uv=False)
    if sv[-1] < 1e-8 * sv[0]:
        raise DesignError(
            "the rotations leave the gyro model undetermined: turn the unit about at least two "
            "different horizontal axes (a turn about the vertical is invisible to gravity)"
        )
    r = sol.fun
    dof = max(len(r) - 12, 1)
    chi2 = float(r @ r)
    from scipy.special import chdtri

    noise_scale = chi2 / dof if chi2 > chdtri(dof, 0.01) else 1.0
    cov = noise_scale * np.linalg.inv(J.T @ J)
    p, R = prob.predicted(sol.x)
    u1 = prob.u[rot.after]
    resid = np.degrees(np.arccos(np.clip(np.sum(p * u1, axis=1), -1, 1)))
    angles = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return FullResult(
        b=sol.x[:3],
        M=sol.x[3:].reshape(3, 3),
        cov=cov,
        angle_residual_deg=resid,
        rotation_angle_deg=angles,
        chi2=chi2,
        dof=dof,
        noise_scale=float(noise_scale),
        iterations=int(sol.nfev),
        converged=True,
        message=str(sol.message),
    )
