"""Fisher information of a calibration design at a fit: the std each term would have.

A *design* is what a capture holds or would hold: still poses (a gravity direction and how
many samples) and the turns between them (an axis, an angle, a duration).  At a *fit* (the
current calibration, or nominal values before there is one) its Fisher information gives, to
first order, the std of every term a target names (:class:`TermStd`): each sensor's gains
(relative), biases (SI units) and misalignments (the angles between its own axes minus 90,
degrees).  The guided capture evaluates it for the design it has, for the same design with the
current hold held longer, and for every pose it could propose next (:mod:`.next_pose`).

Accelerometer (Qureshi & Golnaraghi III-A, with the labels of :mod:`.labelled`)
    Pose k's mean raw reading is ``a_k = M^-1 (g u_k) + B + e_k`` (eq. 4), ``cov e_k =
    sigma_a^2 / n_k I``, with ``M = R(r) K`` (``K`` upper triangular, eq. 3) and ``u_k`` the
    pose's true gravity direction: two nuisance angles per pose, with the label as a prior of
    RMS ``placement_deg`` (2 degrees by hand; ``inf``: no label, the pose gives its magnitude
    only, as in the gravity-magnitude fit).  The information on ``theta = (B, K, r)`` is the
    sum of the poses' Schur complements (:func:`pose_information`, as
    :func:`.crb.labelled_crb`); the gains, biases and axis angles do not depend on the
    rotation ``r``, which gravity magnitude alone cannot see (a pseudo-inverse fixes it).

Gyroscope (the 12-parameter model of :mod:`.gyro_full`: ``omega = M (z - b)``)
    A turn about the body axis ``n`` by ``Theta`` between the still poses p and q predicts the
    gravity direction after it, ``p = R^T u_p``, ``R = Exp(Theta n)``; the calibrated
    accelerometer measures ``u_q``.  A rate error ``d omega = dM d - M db`` (``d = z - b``)
    turns the end by ``d phi = int R(t -> end) d omega dt`` and moves ``p`` by ``[p]x d phi``
    (:mod:`.gyro_model`).  For a turn about a fixed axis the integral is closed-form in the
    angle: ``int_0^Theta Exp(-s n) ds = Theta I - (1 - cos Theta)[n]x + (Theta - sin
    Theta)[n]x^2`` times ``dM M^-1 n``; the bias part integrates the smootherstep profile a
    hand turn follows.  The residual's noise is the two directions' (``sigma_a / (g sqrt n)``
    per tangent component) and the integrated gyro noise (``sigma_z sqrt(T dt)`` per axis);
    each still pose's gyro mean gives ``n_p / sigma_z^2`` on the bias.  The accelerometer
    calibration measures every direction, so its covariance is carried into the gyro's by
    the first-order two-step formula of :func:`.gyro_full.accel_sensitivity`: ``H C_a H^T``,
    ``H = -I_g^-1 sum_k J_k^T C_k^-1 F_k`` (``F_k``: the residual's change with the
    accelerometer's parameters).

What the first order leaves out: the correlation of consecutive turns through the still pose
they share (its direction noise, a few % of a turn's noise at 1 s holds), g-sensitivity and
the earth's rate.  The capture states the refitted calibration's own std; this module only
predicts and ranks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.estimators.accel.gravity import _UPPER, triangular_and_rotation
from imucal_cli.estimators.accel.labelled_model import jacobian, public_from_theta, theta_floor

__all__ = [
    "DesignStd",
    "Fit",
    "Noise",
    "Pose",
    "TermStd",
    "Turn",
    "accel_information",
    "axes_std",
    "design_std",
    "pose_information",
    "rotation_integral",
    "TurnRows",
    "design_turns",
    "turn_rows",
]

TURN_MARGIN_S = 0.3
"""Still samples a turn's segment holds besides its motion (both ends), s: its integrated
noise runs over them too."""

PROFILE_POINTS = 64
"""Quadrature points of a turn's smootherstep profile (the bias term)."""


@dataclass(frozen=True)
class Noise:
    """White noise per sample and channel of the raw readings, and the sample rate.

    Attributes
    ----------
    accel_raw, gyro_raw : float
        Raw units per sample (the still periods' own scatter).
    rate_hz : float
        Samples per second.
    """

    accel_raw: float
    gyro_raw: float
    rate_hz: float


@dataclass(frozen=True)
class Pose:
    """A still pose: ``up`` the calibrated gravity direction (unit, the accelerometer
    matrix's frame), ``n`` samples, ``placement_deg`` the RMS error of its label (``inf``:
    unlabelled, the gravity-magnitude model)."""

    up: np.ndarray
    n: int
    placement_deg: float = np.inf


@dataclass(frozen=True)
class Turn:
    """A turn from pose ``before`` to pose ``after`` (indices) about the body ``axis`` (unit)
    by ``angle_rad`` (right hand), taking ``duration_s``."""

    before: int
    after: int
    axis: np.ndarray
    angle_rad: float
    duration_s: float


@dataclass(frozen=True)
class Fit:
    """Where the information is evaluated: the accelerometer's ``matrix`` (m/s^2 per raw
    unit, 3 x 3) and ``bias`` (raw), the gyroscope's (rad/s per raw unit, raw), gravity."""

    accel_matrix: np.ndarray
    accel_bias: np.ndarray
    gyro_matrix: np.ndarray
    gyro_bias: np.ndarray
    gravity: float = 9.80665
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def theta(self) -> np.ndarray:
        """The accelerometer's ``(B, K upper, r in degrees)`` with ``M = R(r) K``."""
        if "theta" not in self._cache:
            K, Q = triangular_and_rotation(np.asarray(self.accel_matrix, float))
            r = np.degrees(Rotation.from_matrix(Q).as_rotvec())
            self._cache["theta"] = np.concatenate([self.accel_bias, K[_UPPER], r])
        return self._cache["theta"]

    def frame(self) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """``K^-1``, ``R`` and ``dR / dr_c`` (r in radians) of ``M = R(r) K``."""
        if "frame" not in self._cache:
            theta = self.theta()
            K = np.zeros((3, 3))
            K[_UPPER] = theta[3:9]
            phi = np.radians(theta[9:])
            h = 1e-6
            steps = np.repeat(h * np.eye(3), 2, axis=0) * np.array([1.0, -1.0] * 3)[:, None]
            Rs = Rotation.from_rotvec(phi + steps).as_matrix()
            dR = [(Rs[2 * c] - Rs[2 * c + 1]) / (2 * h) for c in range(3)]
            self._cache["frame"] = (np.linalg.inv(K), Rotation.from_rotvec(phi).as_matrix(), dR)
        return self._cache["frame"]

    def public_jacobian(self) -> np.ndarray:
        """d(bias, gains, axis angles, r) / d theta (12 x 12)."""
        if "public" not in self._cache:
            theta = self.theta()
            self._cache["public"] = jacobian(public_from_theta, theta, floor=theta_floor(theta))
        return self._cache["public"]

    def matrix_jacobian(self) -> np.ndarray:
        """d vec(M) / d theta for ``theta``'s K and r (9 x 9, row-major M)."""
        if "dM" not in self._cache:
            theta = self.theta()

            def matrix(x):
                K = np.zeros((3, 3))
                K[_UPPER] = x[:6]
                return (Rotation.from_rotvec(np.radians(x[6:])).as_matrix() @ K).ravel()

            self._cache["dM"] = jacobian(matrix, theta[3:], floor=theta_floor(theta)[3:])
        return self._cache["dM"]


@dataclass(frozen=True)
class TermStd:
    """The std of a sensor's terms, per axis: ``gain`` relative (x, y, z), ``bias`` in SI
    units (m/s^2 or rad/s), ``misalignment_deg`` (xy, xz, yz)."""

    gain: np.ndarray
    bias: np.ndarray
    misalignment_deg: np.ndarray


@dataclass(frozen=True)
class DesignStd:
    """What a design determines: each sensor's :class:`TermStd` (None: undetermined)."""

    accel: TermStd | None
    gyro: TermStd | None


# --------------------------------------------------------------------------------------------
# Accelerometer
# --------------------------------------------------------------------------------------------


def pose_jacobians(fit: Fit, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``d a_k / d theta`` (N, 3, 12) and ``d a_k / d delta_k`` (N, 3, 2) of the mean raw
    reading ``a_k = g K^-1 R^T u_k + B`` at directions ``u`` (N, 3) (as
    :func:`.labelled_model.design_jacobian`, in closed form)."""
    Kinv, R, dR = fit.frame()
    g = fit.gravity
    u = np.atleast_2d(np.asarray(u, float))
    z = (u @ R) @ Kinv.T  # K^-1 R^T u_k
    Gt = np.empty((len(u), 3, 12))
    Gt[:, :, :3] = np.eye(3)
    for c, (i, j) in enumerate(zip(*_UPPER, strict=True)):
        Gt[:, :, 3 + c] = -g * Kinv[:, i][None, :] * z[:, j][:, None]  # d K^-1 = -K^-1 E K^-1
    for c in range(3):
        Gt[:, :, 9 + c] = g * np.radians(1.0) * (u @ dR[c]) @ Kinv.T
    T = _tangents(u)
    Gd = g * np.einsum("ij,kj,nkc->nic", Kinv, R, T)
    return Gt, Gd


def _tangents(u: np.ndarray) -> np.ndarray:
    """(N, 3, 2) orthonormal bases of the planes normal to unit vectors ``u`` (N, 3)."""
    helper = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    t1 = np.cross(u, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return np.stack([t1, np.cross(u, t1)], axis=2)


def pose_information(fit: Fit, poses: list[Pose], noise: Noise) -> np.ndarray:
    """Each pose's information on ``theta = (B, K, r)`` (N, 12, 12): the Schur complement of
    its two direction angles (with the label's prior), the labelled solver's (L5)."""
    u = np.array([p.up for p in poses], float).reshape(-1, 3)
    Gt, Gd = pose_jacobians(fit, u)
    n = np.array([p.n for p in poses], float)
    w = n / noise.accel_raw**2  # Sigma_k^-1 = n / sigma^2 I
    placement = np.array([p.placement_deg for p in poses], float)
    prior = np.where(np.isfinite(placement), 2.0 / np.radians(np.where(
        np.isfinite(placement), placement, 1.0)) ** 2, 0.0)  # fmt: skip
    A = np.einsum("k,kia,kib->kab", w, Gt, Gt)
    D = np.einsum("k,kia,kib->kab", w, Gd, Gd) + prior[:, None, None] * np.eye(2)
    C = np.einsum("k,kia,kib->kab", w, Gt, Gd)
    return A - C @ np.linalg.solve(D, np.transpose(C, (0, 2, 1)))


def accel_information(fit: Fit, poses: list[Pose], noise: Noise) -> np.ndarray:
    """The design's information on ``theta`` (12 x 12)."""
    if not poses:
        return np.zeros((12, 12))
    return pose_information(fit, poses, noise).sum(axis=0)


FRAME_SEEN = 1e-6
"""Information on the frame's rotation ``r`` below this (deg^-2: known to worse than 1000
degrees) is none: gravity magnitude alone, the rotation is a gauge."""


def _inverse(A: np.ndarray) -> np.ndarray | None:
    """Equilibrated inverse of a symmetric information matrix; None when it is singular
    (an eigenvalue below 1e-10 of the largest, after equilibration)."""
    diag = np.diag(A)
    if np.any(diag <= 0):
        return None
    d = 1.0 / np.sqrt(diag)
    E = d[:, None] * A * d
    w, V = np.linalg.eigh((E + E.T) / 2)
    if not w[0] > 1e-10 * w[-1]:
        return None
    return d[:, None] * ((V / w) @ V.T) * d


def accel_covariance(info: np.ndarray) -> np.ndarray | None:
    """The covariance of ``theta = (B, K, r)`` from its information; None when the bias or
    ``K`` are undetermined.  Without labels the rotation ``r`` is a gauge (gravity magnitude
    cannot see it, :data:`FRAME_SEEN`): it is held, and gets no variance."""
    BK, r = slice(0, 9), slice(9, 12)
    inv_bk = _inverse(info[BK, BK])
    if inv_bk is None:
        return None
    schur = info[r, r] - info[r, BK] @ inv_bk @ info[BK, r]
    if np.linalg.eigvalsh((schur + schur.T) / 2)[-1] < FRAME_SEEN:
        cov = np.zeros((12, 12))
        cov[BK, BK] = inv_bk
        return cov
    return _inverse(info)


def accel_terms(fit: Fit, info: np.ndarray, cov: np.ndarray | None = None) -> TermStd | None:
    """The accelerometer's :class:`TermStd` from its information (None: undetermined)."""
    cov = accel_covariance(info) if cov is None else cov
    if cov is None:
        return None
    cov = fit.public_jacobian() @ cov @ fit.public_jacobian().T
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    gains = public_from_theta(fit.theta())[3:6]
    return TermStd(gain=std[3:6] / np.abs(gains), bias=std[:3] / np.abs(gains),
                   misalignment_deg=std[6:9])  # fmt: skip


# --------------------------------------------------------------------------------------------
# Gyroscope
# --------------------------------------------------------------------------------------------


def _skews(v: np.ndarray) -> np.ndarray:
    """(K, 3, 3) cross-product matrices of (K, 3) vectors."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def rotation_integral(axis: np.ndarray, angle) -> np.ndarray:
    """``int_0^angle Exp(-s n) ds``: how a rate error proportional to the turn's own rate
    turns its end (closed form for a fixed axis ``n``); (3, 3), or (K, 3, 3) for (K, 3) axes
    and (K,) angles."""
    N = _skews(np.atleast_2d(axis))
    a = np.atleast_1d(np.asarray(angle, float))[:, None, None]
    out = a * np.eye(3) - (1.0 - np.cos(a)) * N + (a - np.sin(a)) * (N @ N)
    return out[0] if np.ndim(axis) == 1 else out


def _profile_integral(N: np.ndarray, angle: np.ndarray, duration_s: np.ndarray) -> np.ndarray:
    """``int_0^T Exp(-(Theta - theta(t)) n) dt`` for the smootherstep profile ``theta(t)``
    (K, 3, 3), s: how a constant rate error (a bias) turns the end; ``N`` the axes' skew
    matrices (K, 3, 3)."""
    tau = (np.arange(PROFILE_POINTS) + 0.5) / PROFILE_POINTS
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    left = angle[:, None] * (1.0 - s)[None, :]
    c1, c2 = -np.mean(np.sin(left), axis=1), np.mean(1.0 - np.cos(left), axis=1)
    return duration_s[:, None, None] * (np.eye(3) + c1[:, None, None] * N
                                        + c2[:, None, None] * (N @ N))  # fmt: skip


def _direction_sigma2(fit: Fit, n: np.ndarray, noise: Noise) -> np.ndarray:
    """Variance of still poses' calibrated gravity directions (``n`` samples each), rad^2
    per tangent component."""
    gain = float(np.mean(np.linalg.norm(np.asarray(fit.accel_matrix, float), axis=1)))
    return (noise.accel_raw * gain / fit.gravity) ** 2 / np.maximum(np.asarray(n, float), 1.0)


def _direction_derivatives(fit: Fit, up: np.ndarray) -> np.ndarray:
    """How the calibrated directions ``unit(M (a - B))`` of poses' fixed raw means move with
    the accelerometer's ``theta`` (K, 3, 12), for their directions ``up`` (K, 3)."""
    M = np.asarray(fit.accel_matrix, float)
    x = np.linalg.solve(M, fit.gravity * up.T).T  # a - B, (K, 3)
    d = np.empty((len(up), 3, 12))
    d[:, :, :3] = -M
    dM = fit.matrix_jacobian().reshape(3, 3, 9)  # (row, col, theta[3:])
    d[:, :, 3:] = np.einsum("ijc,kj->kic", dM, x)
    P = np.eye(3) - np.einsum("ki,kj->kij", up, up)
    return P @ d / fit.gravity


@dataclass(frozen=True)
class TurnRows:
    """Turns' first-order residual model (K turns): ``J`` (K, 2, 12) on the gyro's ``(b, vec
    M)``, the inverse noise covariance ``W`` (K, 2, 2), ``F`` (K, 2, 12) on the
    accelerometer's ``theta``."""

    J: np.ndarray
    W: np.ndarray
    F: np.ndarray

    def information(self) -> tuple[np.ndarray, np.ndarray]:
        """Their summed information (12 x 12) and cross term ``sum J^T W F`` (12 x 12)."""
        JW = np.einsum("kai,kab->kib", self.J, self.W)
        return np.einsum("kib,kbj->ij", JW, self.J), np.einsum("kib,kbj->ij", JW, self.F)


def turn_rows(fit: Fit, up_before: np.ndarray, axes: np.ndarray, angles: np.ndarray,
              durations: np.ndarray, n_before: np.ndarray, n_after: np.ndarray,
              noise: Noise) -> TurnRows:  # fmt: skip
    """The residual model of turns from the still poses whose gravity directions are
    ``up_before`` (K, 3) about the body ``axes`` (K, 3, unit) by ``angles`` (K,, rad) taking
    ``durations`` (K,, s), between poses held ``n_before`` and ``n_after`` samples."""
    M = np.asarray(fit.gyro_matrix, float)
    up = np.atleast_2d(np.asarray(up_before, float))
    n = np.atleast_2d(np.asarray(axes, float))
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    angles = np.atleast_1d(np.asarray(angles, float))
    durations = np.atleast_1d(np.asarray(durations, float))
    N = _skews(n)
    a = angles[:, None, None]
    R = np.eye(3) + np.sin(a) * N + (1.0 - np.cos(a)) * (N @ N)  # Exp(Theta n)
    p = np.einsum("kji,kj->ki", R, up)  # R^T u_before: the direction after
    Bq = _tangents(p)
    G = np.einsum("kai,kab->kib", Bq, _skews(p))  # d residual / d phi (K, 2, 3)
    v = np.linalg.solve(M, n.T).T  # bias-free raw rate per unit of turn rate
    J = np.empty((len(n), 2, 12))
    J[:, :, :3] = -G @ _profile_integral(N, angles, durations) @ M
    kron = np.zeros((len(n), 3, 9))  # d (dM v) / d vec(dM)
    for i in range(3):
        kron[:, i, 3 * i : 3 * i + 3] = v
    J[:, :, 3:] = G @ rotation_integral(n, angles) @ kron
    window = durations + TURN_MARGIN_S
    s_int2 = noise.gyro_raw**2 * window / noise.rate_hz
    GM = G @ M
    s_dir2 = _direction_sigma2(fit, n_before, noise) + _direction_sigma2(fit, n_after, noise)
    C = s_dir2[:, None, None] * np.eye(2) + s_int2[:, None, None] * (GM @ np.transpose(
        GM, (0, 2, 1)))  # fmt: skip
    F = np.einsum("kai,kab->kib", Bq, np.einsum("kji,kjc->kic", R, _direction_derivatives(
        fit, up)) - _direction_derivatives(fit, p))  # fmt: skip
    return TurnRows(J, np.linalg.inv(C), F)


def design_turns(fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise) -> TurnRows:
    """:func:`turn_rows` of a design's turns."""
    if not turns:
        return TurnRows(np.zeros((0, 2, 12)), np.zeros((0, 2, 2)), np.zeros((0, 2, 12)))
    return turn_rows(
        fit, np.array([poses[t.before].up for t in turns], float),
        np.array([t.axis for t in turns], float), np.array([t.angle_rad for t in turns]),
        np.array([t.duration_s for t in turns]), np.array([poses[t.before].n for t in turns]),
        np.array([poses[t.after].n for t in turns]), noise,
    )  # fmt: skip


def gyro_information(fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise
                     ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The gyro's information on ``(b, vec M)`` (12 x 12) and its cross term with the
    accelerometer's ``theta`` (``sum J^T C^-1 F``, 12 x 12)."""
    info, cross = design_turns(fit, poses, turns, noise).information()
    info[:3, :3] += sum(p.n for p in poses) / noise.gyro_raw**2 * np.eye(3)
    return info, cross


def axes_std(M: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gains (raw units per SI unit: the row norms of ``M^-1``) and their std, and the std of
    the angles between the rows (minus 90, degrees: xy, xz, yz), from the covariance of
    ``vec(M)`` (9 x 9, row-major): the delta method."""
    S = np.linalg.inv(np.asarray(M, float))
    gains = np.linalg.norm(S, axis=1)
    s = S / gains[:, None]
    dS = -np.einsum("ik,lj->ijkl", S, S).reshape(3, 3, 9)  # d S_ij / d M_kl = -S_ik S_lj
    J = np.empty((6, 9))
    J[:3] = np.einsum("ij,ijc->ic", s, dS)  # d |S_i| = s_i . d S_i
    for row, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
        c = s[i] @ s[j]
        dc = ((s[j] - c * s[i]) @ dS[i]) / gains[i] + ((s[i] - c * s[j]) @ dS[j]) / gains[j]
        J[3 + row] = -np.degrees(1.0) * dc / np.sqrt(max(1.0 - c * c, 1e-300))
    std = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", J, cov, J), 0.0, None))
    return gains, std[:3], std[3:]


def gyro_terms(fit: Fit, info: np.ndarray, cross: np.ndarray, accel_cov: np.ndarray | None
               ) -> TermStd | None:  # fmt: skip
    """The gyro's :class:`TermStd` (None: undetermined), the accelerometer calibration's
    covariance on ``theta`` (``accel_cov``) carried in."""
    w = np.linalg.eigvalsh(info)
    if not w[0] > 1e-12 * max(w[-1], 1e-300):
        return None
    inv = np.linalg.inv(info)
    cov = inv
    if accel_cov is not None:
        H = -inv @ cross
        cov = inv + H @ accel_cov @ H.T
    gains, gain_std, angle_std = axes_std(fit.gyro_matrix, cov[3:, 3:])
    bias = np.sqrt(np.clip(np.diag(cov[:3, :3]), 0.0, None)) / gains
    return TermStd(gain=gain_std / gains, bias=bias, misalignment_deg=angle_std)


# --------------------------------------------------------------------------------------------
# A design
# --------------------------------------------------------------------------------------------


def design_std(fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise,
               accel_info: np.ndarray | None = None) -> DesignStd:  # fmt: skip
    """The std every term of both sensors would have from ``poses`` and ``turns`` at ``fit``
    (``accel_info``: the poses' information, when already summed)."""
    A = accel_information(fit, poses, noise) if accel_info is None else accel_info
    accel_cov = accel_covariance(A)
    accel = None if accel_cov is None else accel_terms(fit, A, accel_cov)
    gyro = None
    if turns and accel is not None:  # the turns are measured with the accelerometer
        info, cross = gyro_information(fit, poses, turns, noise)
        gyro = gyro_terms(fit, info, cross, accel_cov)
    return DesignStd(accel, gyro)
