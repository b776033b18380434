"""The rotation between two IMUs of a rigid set from vectors both measured (issue 28).

Wahba's problem with each pair's own covariance (``docs/imu-set.md``, "Rotation, two
steps"): pairs ``(a_p, b_p)`` of calibrated vectors, the reference's and the IMU's, with
``a_p = R b_p`` but for errors, are

- the gravity of a shared still pose (each IMU's calibrated mean reading), and
- the rotation of a shared turn (each IMU's calibrated rate integrated from rest to rest:
  ``int w_r dt = R int w_i dt`` exactly for a rigid body, whatever its clock's offset).

Each vector's error has a noise part (the pose mean's, the integrated rate's) and a part of
its calibration's error (``d v / d (bias, matrix)`` times that calibration's error, shared by
every pair of the same sensor).  The estimate starts from
:meth:`scipy.spatial.transform.Rotation.align_vectors` and takes Gauss-Newton steps on
``sum_p (a_p - R b_p)^T W_p (a_p - R b_p)``, ``W_p`` the inverse of the pair's whole error
covariance (eq. R1); its covariance (eq. R2) is ``H^-1 (sum_p J_p^T W_p C_p W_p J_p + sum_c G_c
Sigma_c G_c^T) H^-1`` with ``J_p = [R b_p]x``, ``H = sum_p J_p^T W_p J_p``, ``C_p`` the pair's
noise and ``G_c = sum_p J_p^T W_p D_cp`` the reach of calibration ``c`` (covariance
``Sigma_c``) through the pairs.  Calibration errors are taken independent of the pairs' noise:
exact to first order for the gravity-magnitude fit, whose errors come from the radial part of
each pose's noise while the rotation sees its tangential part.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import DesignError

__all__ = ["PairGroup", "RotationFit", "calibration_derivative", "relative_rotation", "skew"]


def skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` (..., 3, 3): ``skew(v) @ w = v x w``."""
    v = np.asarray(v, float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def calibration_derivative(matrix: np.ndarray, d: np.ndarray, t: np.ndarray | float = 1.0
                           ) -> np.ndarray:  # fmt: skip
    """``d v / d (bias, matrix row-major)`` (P, 3, 12) of ``v = matrix @ d`` where ``d = Z -
    bias t`` (a pose's mean minus the bias: ``t`` = 1; a turn's integrated raw rate minus the
    bias times its duration ``t``)."""
    d = np.atleast_2d(np.asarray(d, float))
    t = np.broadcast_to(np.asarray(t, float), (len(d),))
    out = np.zeros((len(d), 3, 12))
    out[:, :, :3] = -matrix[None] * t[:, None, None]
    for i in range(3):
        out[:, i, 3 + 3 * i:6 + 3 * i] = d
    return out


@dataclass
class PairGroup:
    """Vector pairs of one kind (poses, or turns) and what their errors depend on.

    Attributes
    ----------
    ref, imu : ndarray, shape (P, 3)
        The reference's and the IMU's calibrated vectors.
    cov_ref, cov_imu : ndarray, shape (P, 3, 3)
        Their noise covariances (each in its own frame).
    d_ref, d_imu : ndarray, shape (P, 3, 12), or None
        :func:`calibration_derivative` of each vector w.r.t. its calibration.
    cal_ref, cal_imu : ndarray, shape (12, 12), or None
        The covariance of that calibration's ``(bias, matrix row-major)`` (None: taken exact).
    name : str
        ``"poses"`` or ``"turns"``.
    cross_ref, cross_imu : ndarray, shape (P, 12, 3), or None
        The covariance of that calibration's error with each vector's noise (None: taken
        independent, eq. R2): a calibration fitted to these very poses whose frame the labels
        pin (eq. R3).
    """

    ref: np.ndarray
    imu: np.ndarray
    cov_ref: np.ndarray
    cov_imu: np.ndarray
    d_ref: np.ndarray | None = None
    d_imu: np.ndarray | None = None
    cal_ref: np.ndarray | None = None
    cal_imu: np.ndarray | None = None
    name: str = "poses"
    cross_ref: np.ndarray | None = None
    cross_imu: np.ndarray | None = None

    def calibration_terms(self, R: np.ndarray
                          ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:  # fmt: skip
        """``(D (P, 3, 12), Sigma (12, 12), X (P, 12, 3))`` of each calibration the residuals
        ``a_p - R b_p`` depend on: ``D`` its reach into them, ``X`` the covariance of its
        error with their noise ``nu_p`` (zeros where independent)."""
        out = []
        zero = np.zeros((len(self.ref), 12, 3))
        if self.d_ref is not None and self.cal_ref is not None:
            out.append((self.d_ref, self.cal_ref,
                        zero if self.cross_ref is None else self.cross_ref))  # fmt: skip
        if self.d_imu is not None and self.cal_imu is not None:
            X = zero if self.cross_imu is None else -self.cross_imu @ R.T  # nu_p = a_p - R b_p
            out.append((-np.einsum("ij,pjk->pik", R, self.d_imu), self.cal_imu, X))
        return out


@dataclass
class RotationFit:
    """:func:`relative_rotation`'s result.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        ``R``: the IMU's calibrated frame into the reference's.
    cov : ndarray, shape (3, 3)
        Covariance of the error rotation vector (``R_hat = Exp(phi) R``, reference frame),
        rad^2.
    residual_deg : dict of str to float
        RMS angle between ``a_p`` and ``R b_p`` per group, degrees.
    pairs : dict of str to int
        Pairs used per group.
    """

    matrix: np.ndarray
    cov: np.ndarray
    residual_deg: dict[str, float] = field(default_factory=dict)
    pairs: dict[str, int] = field(default_factory=dict)

    @property
    def std_deg(self) -> np.ndarray:
        """Std of the error rotation vector's components, degrees."""
        return np.degrees(np.sqrt(np.clip(np.diag(self.cov), 0, None)))


def _weights(group: PairGroup, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pair's noise covariance ``C_p`` and weight ``W_p``: its whole error's inverse
    (eq. R1), or, where the calibrations are fits to these very pairs (eq. R3), the inverse
    within the plane across ``a_p`` (:func:`tangent_weights`)."""
    C = group.cov_ref + np.einsum("ij,pjk,lk->pil", R, group.cov_imu, R)
    total = C.copy()
    for D, S, X in group.calibration_terms(R):
        DX = np.einsum("pij,pjk->pik", D, X)
        total += np.einsum("pij,jk,plk->pil", D, S, D) + DX + np.swapaxes(DX, 1, 2)
    if group.cross_ref is not None or group.cross_imu is not None:
        return C, tangent_weights(total, group.ref)
    return C, np.linalg.inv(total)


def tangent_weights(total: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``W_p = T_p (T_p^T V_p T_p)^-1 T_p^T`` (P, 3, 3): the inverse of each pair's error
    covariance ``V_p`` within the plane across ``a_p`` (``T_p`` (3, 2) an orthonormal basis of
    it), nothing along ``a_p`` (eq. R3's weights, ``docs/imu-set.md``).

    A rotation moves ``R b_p`` across itself only (``J_p = [R b_p]x``), so the part of the
    residual along ``a_p`` says nothing of it at first order. Where both calibrations are fits
    to the pairs' own means (the labelled solver), each calibrated mean sits on the gravity
    sphere as closely as its fit matches the magnitudes (exactly on six faces: 18 equations,
    24 unknowns), so ``V_p``'s variance along ``a_p`` nearly cancels (``C_p`` against the
    calibrations' covariance with the means) and its inverse would weigh the residual's part
    along ``a_p``, second order in the errors, by the inverse of a first-order variance near
    zero: on six faces the rotations' errors were 10-40 times their std."""
    n = a / np.linalg.norm(a, axis=1, keepdims=True)
    # an orthonormal basis of the plane across each n: the last two left singular vectors
    T = np.linalg.svd(n[:, :, None], full_matrices=True)[0][:, :, 1:]  # (P, 3, 2)
    inner = np.einsum("pia,pij,pjb->pab", T, total, T)
    return np.einsum("pia,pab,pjb->pij", T, np.linalg.inv(inner), T)


def relative_rotation(groups: list[PairGroup], iterations: int = 5) -> RotationFit:
    """``R`` and its covariance from vector pairs (module notes, eqs. R1-R2).

    Raises
    ------
    DesignError
        The pairs do not determine a rotation (all along one direction).
    """
    groups = [g for g in groups if len(g.ref)]
    a = np.concatenate([g.ref for g in groups]) if groups else np.empty((0, 3))
    b = np.concatenate([g.imu for g in groups]) if groups else np.empty((0, 3))
    if len(a) < 2 or np.linalg.matrix_rank(a / np.linalg.norm(a, axis=1, keepdims=True),
                                           tol=1e-3) < 2:  # fmt: skip
        raise DesignError("the shared poses and turns all point one way: they do not "
                          "determine the rotation between the IMUs (hold them in two "
                          "directions at least)")  # fmt: skip
    w0 = np.concatenate([1.0 / np.trace(g.cov_ref + g.cov_imu, axis1=1, axis2=2)
                         for g in groups])  # fmt: skip
    R = Rotation.align_vectors(a, b, weights=w0 / w0.max())[0].as_matrix()
    for _ in range(iterations):
        H, grad = np.zeros((3, 3)), np.zeros(3)
        for g in groups:
            _, W = _weights(g, R)
            Rb = g.imu @ R.T
            J = skew(Rb)
            e = g.ref - Rb
            H += np.einsum("pji,pjk,pkl->il", J, W, J)
            grad += np.einsum("pji,pjk,pk->i", J, W, e)
        step = -np.linalg.solve(H, grad)
        R = Rotation.from_rotvec(step).as_matrix() @ R
        if np.linalg.norm(step) < 1e-12:
            break
    return _covariance(groups, R)


def _covariance(groups: list[PairGroup], R: np.ndarray) -> RotationFit:
    H, middle = np.zeros((3, 3)), np.zeros((3, 3))
    reach = []
    fit = RotationFit(matrix=R, cov=np.zeros((3, 3)))
    for g in groups:
        C, W = _weights(g, R)
        Rb = g.imu @ R.T
        J = skew(Rb)
        JW = np.einsum("pji,pjk->pik", J, W)  # J^T W, (P, 3, 3)
        H += np.einsum("pij,pjk->ik", JW, J)
        middle += np.einsum("pij,pjk,plk->il", JW, C, JW)
        # each calibration's reach G_c, Sigma_c, and its covariance with sum_p J^T W nu_p
        reach += [(np.einsum("pij,pjk->ik", JW, D), S, np.einsum("pkj,pij->ki", X, JW))
                  for D, S, X in g.calibration_terms(R)]  # fmt: skip
        cosang = np.einsum("pi,pi->p", g.ref, Rb) / (np.linalg.norm(g.ref, axis=1)
                                                     * np.linalg.norm(Rb, axis=1))  # fmt: skip
        angle = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
        fit.residual_deg[g.name] = float(np.sqrt(np.mean(angle**2)))
        fit.pairs[g.name] = len(g.ref)
    for G, S, X in reach:  # eqs. R2, R3
        GX = G @ X
        middle += G @ S @ G.T + GX + GX.T
    Hi = np.linalg.inv(H)
    fit.cov = Hi @ middle @ Hi
    fit.cov = (fit.cov + fit.cov.T) / 2
    return fit
