"""The accelerometers of a rigid set of triads fitted jointly (issue 28; ``docs/imu-set.md``).

K triads on one body are held still in the same P poses.  Hwangbo & Kanade treat the stacked
channels of several sensing elements as one redundant unit (eqs. 2-5: ``z_i = f^T s_i + b_i``,
one motion ``f`` for every element); here the unit is K triads and the motion of pose p is
the gravity direction ``u_p`` (unit, the reference's calibrated frame), unknown (a nuisance,
2 angles each).  The mean raw reading of triad k in pose p is (eq. S1)::

    z_kp = g S_k u_p + b_k + e_kp,      e_kp ~ N(0, C_kp)   (C_kp = Sigma_k / n_kp)

with ``S_k = N_k^-1``: ``N_k`` maps triad k's bias-free raw reading into the reference's
calibrated frame.  The gauge (Qureshi eq. 3 for the reference): ``N_0 = M_0`` upper triangular
(the reference's own gravity-solver frame); the other ``N_k`` are full.  The maximum-likelihood
fit minimises ``sum_kp |L_kp^-1 (z_kp - b_k - g S_k u_p)|^2`` (``C_kp = L L^T``) over the
biases, the ``N_k`` and the ``u_p`` (Levenberg-Marquardt, analytic Jacobian, the Fisher
information ``J^T J`` at the solution its inverse covariance).

For K = 1 it is the gravity-magnitude model with its poses' directions as nuisances, the model
of :func:`imucal_cli.estimators.accel.crb.gravity_crb`.  Each further triad adds 3 equations
per pose and no new unknown direction, so the directions, and through them every triad's
calibration, are known better than from one triad alone.

Each triad's own calibration in its own gravity-solver frame and its rotation into the
reference's follow from ``N_k = R_k U_k`` (``U_k`` upper triangular, positive diagonal; eq. S2):
``calibrated_k = U_k (z - b_k)`` and ``rotation_to_reference = R_k``.  Their covariances come
from the joint covariance through that map (delta method).  :func:`set_information` evaluated
at the truth is the Cramér-Rao bound of the design.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.special import chdtrc

from imucal_cli.errors import DesignError
from imucal_cli.estimators.accel.gravity import model_to_params, params_to_model

__all__ = ["SetAccelFit", "fit_set_accel", "own_frame", "set_information", "split_covariance"]

_UPPER = (np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2]))


def _tangent(u: np.ndarray) -> np.ndarray:
    """Two unit vectors (3, 2) orthogonal to unit ``u`` and to each other."""
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(u, e1)])


@dataclass
class _Layout:
    """Where each block of the parameter vector sits."""

    K: int
    P: int

    @property
    def n(self) -> int:
        return 9 + 12 * (self.K - 1) + 2 * self.P

    def imu(self, k: int) -> slice:
        """``(b_0, m_0 upper)`` for k = 0, ``(b_k, N_k row-major)`` for the others."""
        return slice(0, 9) if k == 0 else slice(9 + 12 * (k - 1), 9 + 12 * k)

    def angles(self, p: int) -> slice:
        start = 9 + 12 * (self.K - 1) + 2 * p
        return slice(start, start + 2)


def _unpack(x: np.ndarray, lay: _Layout, u0: np.ndarray, basis: np.ndarray):
    """Biases (K, 3), matrices N (K, 3, 3), directions (P, 3) and their raw vectors (P, 3)."""
    b = np.empty((lay.K, 3))
    N = np.empty((lay.K, 3, 3))
    b[0], N[0] = params_to_model(x[lay.imu(0)])
    for k in range(1, lay.K):
        block = x[lay.imu(k)]
        b[k], N[k] = block[:3], block[3:].reshape(3, 3)
    alpha = x[9 + 12 * (lay.K - 1):].reshape(lay.P, 2)
    v = u0 + np.einsum("pij,pj->pi", basis, alpha)
    return b, N, v / np.linalg.norm(v, axis=1, keepdims=True), v


def _residuals_and_jacobian(x, lay, z, Linv, g, u0, basis, want_jac=True):
    """Whitened residuals (K P 3,) of eq. S1 and their Jacobian (K P 3, n)."""
    b, N, u, v = _unpack(x, lay, u0, basis)
    S = np.linalg.inv(N)
    r = np.empty((lay.K, lay.P, 3))
    J = np.zeros((lay.K, lay.P, 3, lay.n)) if want_jac else None
    norm = np.linalg.norm(v, axis=1)
    du = np.einsum("pij,pjk->pik", (np.eye(3) - u[:, :, None] * u[:, None, :])
                   / norm[:, None, None], basis)  # (P, 3, 2) d u / d alpha  # fmt: skip
    for k in range(lay.K):
        f = g * u @ S[k].T  # (P, 3) g S_k u_p
        r[k] = np.einsum("pij,pj->pi", Linv[k], z[k] - b[k] - f)
        if not want_jac:
            continue
        cols = lay.imu(k)
        J[k, :, :, cols.start:cols.start + 3] = -Linv[k]
        # d(g S u)/dN_ij = -S E_ij S g u = -S[:, i] (S[j] . g u); the residual gets the minus
        Su = g * u @ S[k].T  # S g u, (P, 3)
        pairs = zip(*_UPPER, strict=True) if k == 0 else ((i, j) for i in range(3)
                                                          for j in range(3))  # fmt: skip
        for c, (i, j) in enumerate(pairs):
            dz = np.outer(Su[:, j], S[k][:, i])  # (P, 3)
            J[k, :, :, cols.start + 3 + c] = np.einsum("pij,pj->pi", Linv[k], dz)
        for p in range(lay.P):
            J[k, p, :, lay.angles(p)] = -Linv[k][p] @ (g * S[k] @ du[p])
    return r.ravel(), None if J is None else J.reshape(-1, lay.n)


@dataclass
class SetAccelFit:
    """The joint fit of a set's accelerometers (:func:`fit_set_accel`).

    Attributes
    ----------
    bias : ndarray, shape (K, 3)
        Each triad's bias, raw units.
    matrix : ndarray, shape (K, 3, 3)
        Each triad's upper-triangular ``U_k`` (its own gravity-solver frame), m/s^2 per raw
        unit: ``calibrated_k = U_k (z - b_k)``.
    rotation : ndarray, shape (K, 3, 3)
        ``R_k``: triad k's calibrated frame into the reference's (identity for k = 0).
    params_cov : ndarray, shape (K, 9, 9)
        Covariance of each triad's ``(b_x, b_y, b_z, k_x, k_y, k_z, k_xy, k_xz, k_yz)``.
    rotation_cov : ndarray, shape (K, 3, 3)
        Covariance of each ``R_k``'s error rotation vector (``R_hat = Exp(phi) R_k``,
        reference frame), rad^2 (zero for k = 0).
    directions : ndarray, shape (P, 3)
        Each pose's gravity direction, the reference's calibrated frame.
    residual_rms : ndarray, shape (K,)
        RMS of ``N_k (z_kp - b_k) - g u_p`` per triad, m/s^2.
    chi2, dof : float, int
        Whitened residual sum of squares and its degrees of freedom (3 K P - parameters).
    noise_scale : float
        Factor applied to the covariances: 1 when the residuals agree with the noise
        (chi-square test at 0.1 %), ``chi2 / dof`` when not.
    iterations : int
    converged : bool
    message : str
    covariance : ndarray
        The joint covariance of every parameter (gauge as in the module notes).
    """

    bias: np.ndarray
    matrix: np.ndarray
    rotation: np.ndarray
    params_cov: np.ndarray
    rotation_cov: np.ndarray
    directions: np.ndarray
    residual_rms: np.ndarray
    chi2: float
    dof: int
    noise_scale: float
    iterations: int
    converged: bool
    message: str
    covariance: np.ndarray


def own_frame(N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``N = R U`` (eq. S2): the rotation ``R`` (proper) and upper-triangular ``U`` with a
    positive diagonal (a negative ``U[2, 2]`` when ``det N < 0``: a mirrored triad)."""
    Q, U = np.linalg.qr(N)
    D = np.diag(np.sign(np.diag(U)))
    Q, U = Q @ D, D @ U
    if np.linalg.det(Q) < 0:
        F = np.diag([1.0, 1.0, -1.0])
        Q, U = Q @ F, F @ U
    return Q, U


def split_covariance(N: np.ndarray, cov_N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Covariances of ``U``'s 6 upper entries and of ``R``'s error rotation vector (reference
    frame) from that of ``N``'s 9 entries (row-major), through :func:`own_frame` (delta
    method, central differences).  Returns ``(J_U (6, 9), J_phi (3, 9))`` times ``cov_N``
    as ``(cov_U (6, 6), cov_phi (3, 3), cross (6, 3))`` packed in one (9, 9) array's blocks:
    ``[U entries, phi]``."""
    R0, _ = own_frame(N)
    J = np.empty((9, 9))
    h = 1e-7 * np.abs(N).max()
    for c in range(9):
        d = np.zeros(9)
        d[c] = h
        out = []
        for sign in (1.0, -1.0):
            R, U = own_frame(N + sign * d.reshape(3, 3))
            out.append(np.r_[U[_UPPER], Rotation.from_matrix(R @ R0.T).as_rotvec()])
        J[:, c] = (out[0] - out[1]) / (2 * h)
    C = J @ cov_N @ J.T
    return (C + C.T) / 2, J


def _start(z, bias0, matrix0, rotation0):
    """The starting vector from each triad's own fit and rotation, and the directions' mean."""
    K = len(bias0)
    N0 = np.array([rotation0[k] @ matrix0[k] for k in range(K)])
    a = np.einsum("kij,kpj->kpi", N0, z - bias0[:, None, :])
    u0 = a.sum(axis=0)
    u0 /= np.linalg.norm(u0, axis=1, keepdims=True)
    x0 = [model_to_params(bias0[0], matrix0[0])]
    x0 += [np.r_[bias0[k], N0[k].ravel()] for k in range(1, K)]
    x0.append(np.zeros(2 * z.shape[1]))
    return np.concatenate(x0), u0


def fit_set_accel(
    z: np.ndarray, cov: np.ndarray, g: float, bias0: np.ndarray, matrix0: np.ndarray,
    rotation0: np.ndarray, max_iterations: int = 100,
) -> SetAccelFit:  # fmt: skip
    """Fit eq. S1 to the pose means of K triads in P shared poses (module notes).

    Parameters
    ----------
    z : ndarray, shape (K, P, 3)
        Mean raw reading of each triad in each pose, raw units (the reference first).
    cov : ndarray, shape (K, P, 3, 3)
        Covariance of each mean, raw units^2.
    g : float
        Gravity, m/s^2.
    bias0, matrix0 : ndarray, shape (K, 3), (K, 3, 3)
        Each triad's own calibration (its gravity fit: ``matrix0[k]`` upper triangular), the
        starting point.
    rotation0 : ndarray, shape (K, 3, 3)
        Each triad's rotation into the reference's frame (identity for the reference), start.

    Raises
    ------
    DesignError
        Fewer than 2 triads, or too few poses for the parameters.
    """
    K, P = z.shape[:2]
    lay = _Layout(K, P)
    if K < 2 or 3 * K * P <= lay.n:
        raise DesignError(f"{K} triads in {P} shared poses do not determine a joint fit")
    Linv = np.linalg.inv(np.linalg.cholesky(cov))
    x0, u0 = _start(z, bias0, matrix0, rotation0)
    basis = np.array([_tangent(u) for u in u0])

    def fun(x):
        return _residuals_and_jacobian(x, lay, z, Linv, g, u0, basis, want_jac=False)[0]

    def jac(x):
        return _residuals_and_jacobian(x, lay, z, Linv, g, u0, basis)[1]

    res = least_squares(fun, x0, jac=jac, method="lm", x_scale="jac",
                        max_nfev=max_iterations * (lay.n + 1))  # fmt: skip
    r, J = _residuals_and_jacobian(res.x, lay, z, Linv, g, u0, basis)
    chi2 = float(r @ r)
    dof = 3 * K * P - lay.n
    scale = chi2 / dof if chdtrc(dof, chi2) < 1e-3 and chi2 > dof else 1.0
    cov_all = np.linalg.pinv(J.T @ J) * scale
    return _result(res, lay, cov_all, z, g, u0, basis, chi2, dof, scale)


def _result(res, lay, cov_all, z, g, u0, basis, chi2, dof, scale) -> SetAccelFit:
    b, N, u, _ = _unpack(res.x, lay, u0, basis)
    K = lay.K
    matrix, rotation = np.empty((K, 3, 3)), np.empty((K, 3, 3))
    params_cov, rotation_cov = np.empty((K, 9, 9)), np.zeros((K, 3, 3))
    rms = np.empty(K)
    for k in range(K):
        block = cov_all[lay.imu(k), lay.imu(k)]
        a = np.einsum("ij,pj->pi", N[k], z[k] - b[k])
        rms[k] = float(np.sqrt(np.mean((a - g * u) ** 2)))
        if k == 0:
            matrix[0], rotation[0], params_cov[0] = N[0], np.eye(3), block
            continue
        rotation[k], matrix[k] = own_frame(N[k])
        C, _ = split_covariance(N[k], block[3:, 3:])
        _, Jk = split_covariance(N[k], np.eye(9))
        cross = block[:3, 3:] @ Jk[:6].T  # cov(b, U entries)
        params_cov[k][:3, :3], params_cov[k][3:, 3:] = block[:3, :3], C[:6, :6]
        params_cov[k][:3, 3:], params_cov[k][3:, :3] = cross, cross.T
        rotation_cov[k] = C[6:, 6:]
    return SetAccelFit(
        bias=b, matrix=matrix, rotation=rotation, params_cov=params_cov,
        rotation_cov=rotation_cov, directions=u, residual_rms=rms, chi2=chi2, dof=dof,
        noise_scale=scale, iterations=int(res.nfev), converged=bool(res.success),
        message=str(res.message), covariance=cov_all,
    )  # fmt: skip


def set_information(bias: np.ndarray, N: np.ndarray, u: np.ndarray, cov: np.ndarray,
                    g: float) -> np.ndarray:  # fmt: skip
    """The Fisher information of eq. S1 at given parameters (the truth, for the Cramér-Rao
    bound): ``bias`` (K, 3), ``N`` (K, 3, 3) (``N[0]`` upper triangular), directions ``u``
    (P, 3), mean covariances ``cov`` (K, P, 3, 3).  Parameter order as the fit's
    (:func:`bound_blocks` splits its inverse)."""
    K, P = cov.shape[:2]
    lay = _Layout(K, P)
    basis = np.array([_tangent(x) for x in u])
    x = np.concatenate([model_to_params(bias[0], N[0])]
                       + [np.r_[bias[k], N[k].ravel()] for k in range(1, K)]
                       + [np.zeros(2 * P)])  # fmt: skip
    z = np.einsum("kij,pj->kpi", g * np.linalg.inv(N), u) + bias[:, None, :]
    Linv = np.linalg.inv(np.linalg.cholesky(cov))
    _, J = _residuals_and_jacobian(x, lay, z, Linv, g, u, basis)
    return J.T @ J


def bound_blocks(info: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """From :func:`set_information` (at ``N``, (K, 3, 3)): the bound on each triad's 9 own
    parameters (K, 9, 9) and on each rotation vector (K, 3, 3) (rad^2)."""
    K = len(N)
    lay = _Layout(K, (info.shape[0] - 9 - 12 * (K - 1)) // 2)
    crb = np.linalg.inv(info)
    own, rot = np.empty((K, 9, 9)), np.zeros((K, 3, 3))
    own[0] = crb[lay.imu(0), lay.imu(0)]
    for k in range(1, K):
        block = crb[lay.imu(k), lay.imu(k)]
        C, J = split_covariance(N[k], block[3:, 3:])
        own[k][:3, :3], own[k][3:, 3:] = block[:3, :3], C[:6, :6]
        own[k][:3, 3:] = block[:3, 3:] @ J[:6].T
        own[k][3:, :3] = own[k][:3, 3:].T
        rot[k] = C[6:, 6:]
    return own, rot
