"""Gyroscope calibration from turns of a known angle (issue 9.3), alone or with turns that
gravity measures.

A turn of known angle ``theta_k`` about a fixed axis ``n_k`` (unit, in the calibrated
accelerometer's frame) integrates to ``integral omega dt = theta_k n_k`` whatever its rate
profile (Ferraris et al.'s rotation test, the 360-degree turns of MaD Lab's Ferraris sessions).
With ``omega = M (z - b - G a)``:

    e_k = M (Z_k - b T_k - G A_k) - theta_k n_k,     Z_k = integral z dt, A_k = integral a dt

three residuals per turn (trapezoid integrals over the turn's samples; ``T_k`` its duration).
The axis ``n_k`` need not come from an accelerometer: a turn about an axis fixed in the body
(a unit turned flat on a table about a labelled face's normal) has the same body axis for the
whole turn, so ``integral omega dt = theta_k n_k`` holds in the frame of the labels, and three
such turns about independent axes determine ``M``, the still periods ``b``.
A turn about the vertical is one that gravity cannot see, but its axis is measured all the
same: the accelerometer reads gravity along it for the whole turn. Each residual's noise is
the integrated gyro noise (``M`` times ``sigma sqrt(sum dt^2)`` per raw axis), the angle's own
uncertainty along ``n_k`` (a hand turn back onto the same face is good to about a degree) and
the axis' uncertainty across it (``theta_k`` times its direction std).

The still periods tie the bias (and the g-sensitivity ``G`` when asked: still periods with
opposite faces up see it as a bias that changes sign). Turns between still periods whose
angle is not known (:mod:`.gyro_model`) join the same fit: their whitened residuals and
Jacobian are stacked with these, so that a session with both uses all of its turns in one
maximum-likelihood estimate (Levenberg-Marquardt; the residuals of known turns are bilinear in
``b`` and ``M``, and the start is their closed-form least-squares solution).

**Excess scatter of the turns measured by gravity** (issue 24.5). Their stated noise (the
still periods' gravity directions, the integrated gyro noise: hundredths of a degree) holds
for the simulator's turns; a hand pick-up, flip and put-down on a real part misses its
predicted direction by tenths of a degree for reasons the linear model does not hold (MaD
Lab's Ferraris session: 0.56 deg per turn, 33 times that noise, about any axis, no rate,
sign or g-sensitivity pattern). Weighted by their stated noise, nine such turns outweigh
three known turns a hundred to one and pull the gains off the known angles by a percent. Each
turn's residual is therefore given an excess ``tau`` per tangent component, the same for all,
estimated from their own scatter (variance-component estimation, Helmert/Förstner: ``tau^2``
such that their whitened chi^2 equals their redundancy ``n_g - tr(H_gg)``), zero when the
stated noise explains them. The fit, its covariance and the per-turn statistics all use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.linalg import block_diag
from scipy.optimize import brentq, least_squares
from scipy.special import chdtri, gammaincinv

from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.gyro.full import _diagonal_blocks
from imucal_cli.estimators.gyro.known_turns import (
    _DenseWhitener,
    accel_blocks,
    accel_factor,
    gravity_statistics,
)
from imucal_cli.estimators.gyro.model import (
    Problem,
    Rotations,
    Stills,
    Whitener,
    rounding_parameter_covariance,
)
from imucal_cli.numerics.banded import BandedWhitener

#: A design whose whitened Jacobian has a singular value below this fraction of the largest
#: leaves a combination of the parameters undetermined.
UNDETERMINED = 1e-8


@dataclass
class KnownTurns:
    """Turns of known angle.

    Attributes
    ----------
    t : list of ndarray (n_k,)
        Sample times, s.
    z : list of ndarray (n_k, 3)
        Raw gyro samples.
    angle : ndarray (K,)
        Known angle of each turn, rad (signed: right-handed about ``axis``).
    axis : ndarray (K, 3)
        Unit axis of each turn in the calibrated accelerometer's frame, or, without an
        accelerometer calibration, in the frame of the labels (a turn about a body-fixed
        labelled axis integrates to ``theta_k n_k`` whatever the unit's attitude).
    axis_sigma : ndarray (K,)
        Std of each axis' direction, per tangent component, rad.
    angle_sigma : ndarray (K,)
        Std of each known angle, rad.
    a : list of ndarray (n_k, 3), optional
        Calibrated accelerometer samples, m/s^2 (the g-sensitivity term only).
    labelled : ndarray (K,) of bool, optional
        Which axes are labels (fixed to the labels' frame) rather than measured by the
        accelerometer (in its frame). None: none is.
    frame : ndarray (K, 3, m), optional
        How each axis, as the calibrated accelerometer's frame sees it, moves along each
        square-root direction of that calibration's covariance (the columns of the still
        periods' ``accel_dirs``): a labelled axis is fixed to the labels, and the frame the
        accelerometer estimates is turned from theirs by its error (``phi_j x n_k``, see
        :mod:`imucal_cli.estimators.accel.frame`); zero for an axis the accelerometer
        measures (it turns with the frame). None: no such part.
    """

    t: list[np.ndarray]
    z: list[np.ndarray]
    angle: np.ndarray
    axis: np.ndarray
    axis_sigma: np.ndarray
    angle_sigma: np.ndarray
    a: list[np.ndarray] | None = None
    labelled: np.ndarray | None = None
    frame: np.ndarray | None = None


def _integrals(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Trapezoid integral of (n, 3) samples over times (n,)."""
    h = np.diff(t)
    return ((v[1:] + v[:-1]) * h[:, None]).sum(axis=0) / 2


class KnownProblem:
    """Residuals, Jacobian and noise of known-angle turns (and, alone, of the still periods)."""

    def __init__(self, known: KnownTurns, still: Stills, gyro_sigma: float,
                 g_sensitivity: bool = False):  # fmt: skip
        self.known, self.still, self.with_g = known, still, g_sensitivity
        self.n_params = 21 if g_sensitivity else 12
        self.Z = np.array([_integrals(t, z) for t, z in zip(known.t, known.z, strict=True)])
        self.T = np.array([t[-1] - t[0] for t in known.t])
        if g_sensitivity:
            if known.a is None:
                raise ValueError("the g-sensitivity term needs the turns' accelerometer samples")
            self.A = np.array([_integrals(t, a) for t, a in zip(known.t, known.a, strict=True)])
        else:
            self.A = np.zeros_like(self.Z)
        # The integral is theta_k along the true axis, off n_k by the axis' error eps (std
        # axis_sigma per tangent component): along n_k, theta_k cos|eps|, on average
        # theta_k (1 - axis_sigma^2). Against theta_k itself the gains came out too large by
        # that much (2 deg RMS axes: +0.06 %, 2 std of a turntable's known angles).
        self.target = known.angle[:, None] * known.axis * (1 - known.axis_sigma**2)[:, None]
        # Integrated white gyro noise per raw axis: sigma * sqrt(sum of squared trapezoid
        # weights) ~ sigma sqrt(T dt).
        self.int_noise = np.array([
            gyro_sigma * np.sqrt(np.sum(_weights(t) ** 2)) for t in known.t
        ])  # fmt: skip
        self.K = len(known.t)

    def split(self, x):
        G = x[12:21].reshape(3, 3) if self.with_g else np.zeros((3, 3))
        return x[:3], x[3:12].reshape(3, 3), G

    def integrated(self, x) -> np.ndarray:
        """``integral omega dt`` of each turn under ``x`` (K, 3), rad."""
        b, M, G = self.split(x)
        return (self.Z - self.T[:, None] * b - self.A @ G.T) @ M.T

    def residuals(self, x) -> np.ndarray:
        return (self.integrated(x) - self.target).ravel()

    def jacobian(self, x) -> np.ndarray:
        b, M, G = self.split(x)
        w = self.Z - self.T[:, None] * b - self.A @ G.T  # (K, 3) bias-free raw integrals
        J = np.zeros((self.K, 3, self.n_params))
        J[:, :, :3] = -self.T[:, None, None] * M
        for i in range(3):
            J[:, i, 3 + 3 * i : 6 + 3 * i] = w
        if self.with_g:  # d e / d G[r, j] = -M[:, r] A_k[j]
            J[:, :, 12:] = -np.einsum("ir,kj->kirj", M, self.A).reshape(self.K, 3, 9)
        return J.reshape(3 * self.K, self.n_params)

    def covariance(self, x) -> np.ndarray:
        """(K, 3, 3) noise covariance of each turn's residual."""
        _, M, _ = self.split(x)
        n = self.known.axis
        across = np.eye(3) - np.einsum("ki,kj->kij", n, n)
        along = np.einsum("ki,kj->kij", n, n)
        gyro = (M @ M.T)[None] * self.int_noise[:, None, None] ** 2
        ang = self.known.angle[:, None, None]
        s2 = self.known.axis_sigma[:, None, None] ** 2
        # along: the stated angle's error and the axis error's cos|eps| about its mean (the
        # variance of theta |eps|^2 / 2, |eps|^2 / s2 chi^2 with 2 dof: (theta s2)^2)
        return (gyro + ang**2 * s2 * across
                + (self.known.angle_sigma[:, None, None] ** 2 + (ang * s2) ** 2) * along)

    def whitening(self, x) -> np.ndarray:
        """(K, 3, 3) ``L_k^-1`` with ``L_k L_k^T`` the covariance of turn k's residual."""
        return np.linalg.inv(np.linalg.cholesky(self.covariance(x)))

    def frame_factor(self) -> np.ndarray | None:
        """(K, 3, m): each residual's change along each square-root direction of the
        accelerometer calibration's covariance (the target ``theta_k n_k`` seen from the frame
        it estimates: ``theta_k dn_k``), None without :attr:`KnownTurns.frame`. Its outer
        product couples the known turns (one frame for all) and, through the shared columns,
        the turns gravity measures."""
        if self.known.frame is None:
            return None
        return self.known.angle[:, None, None] * self.known.frame

    def marginal(self, x) -> np.ndarray:
        """(K, 3, 3) covariance of each turn's residual alone, the frame's part with it."""
        F = self.frame_factor()
        C = self.covariance(x)
        return C if F is None else C + np.einsum("kam,kbm->kab", F, F)


def _weights(t: np.ndarray) -> np.ndarray:
    h = np.diff(t)
    w = np.zeros(len(t))
    w[:-1] += h / 2
    w[1:] += h / 2
    return w


def _whiten_blocks(L: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Apply (K, 3, 3) blocks to stacked rows ``a`` (3K,) or (3K, n)."""
    K = len(L)
    if a.ndim == 1:
        return np.einsum("kij,kj->ki", L, a.reshape(K, 3)).ravel()
    return np.einsum("kij,kjn->kin", L, a.reshape(K, 3, -1)).reshape(3 * K, -1)


def closed_form(known: KnownTurns, b: np.ndarray) -> np.ndarray:
    """``M`` minimising ``sum |M (Z_k - b T_k) - theta_k n_k|^2`` (the Ferraris solution when
    there are three turns about independent axes).

    Raises
    ------
    DesignError
        The turns' axes do not span three dimensions.
    """
    Z = np.array([_integrals(t, z) for t, z in zip(known.t, known.z, strict=True)])
    T = np.array([t[-1] - t[0] for t in known.t])
    W = (Z.reshape(-1, 3) - T[:, None] * b).T  # (3, K)
    Y = (known.angle[:, None] * known.axis).T  # (3, K)
    sv = np.linalg.svd(W, compute_uv=False) if len(known.t) >= 3 else np.zeros(1)
    if len(known.t) < 3 or sv[-1] < 1e-6 * sv[0]:
        raise DesignError(
            f"{len(known.t)} turn(s) of known angle cannot determine the gyro's matrix: turn "
            "the unit by a known angle about three different axes (e.g. 360 degrees about each "
            "face's vertical, as the Ferraris protocol does)"
        )
    return Y @ W.T @ np.linalg.inv(W @ W.T)


@dataclass
class KnownResult:
    """Result of :func:`fit_known`: as :class:`.gyro_full.FullResult` for the shared fields.

    The per-turn arrays are in the order of the known turns (``known_*``, ``angle_*``,
    ``axis_*``, ``measured_*``) and of the gravity-referenced turns (``gravity_*``, empty
    without them)."""

    b: np.ndarray
    M: np.ndarray
    G: np.ndarray | None
    cov: np.ndarray
    chi2: float
    dof: int
    noise_scale: float
    iterations: int
    angle_error_deg: np.ndarray  # integrated angle minus the known angle, each known turn
    axis_error_deg: np.ndarray  # angle between the integrated and the known axis
    measured_angle_deg: np.ndarray
    known_chi2: np.ndarray  # each known turn's squared whitened residual (3 dof)
    angle_sigma_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))  # std along
    known_redundancy: float = 0.0  # the known rows' redundancy, 3 K - tr(H_kk)
    tau: float = 0.0  # excess std of a gravity-referenced turn per tangent component, rad
    gravity_chi2: np.ndarray = field(default_factory=lambda: np.zeros(0))  # 2 dof, with tau
    gravity_chi2_stated: np.ndarray = field(default_factory=lambda: np.zeros(0))  # tau = 0
    gravity_residual_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gravity_angle_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gravity_sigma_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))  # with tau
    gravity_redundancy: float = 0.0

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))

    @property
    def gravity_level(self) -> float:
        """The gravity-referenced turns' robust RMS ratio to their stated noise (the full
        model's level: ``sqrt(median chi^2 / median of chi^2_2)``), 0 without them."""
        if not len(self.gravity_chi2_stated):
            return 0.0
        return float(np.sqrt(np.median(self.gravity_chi2_stated) / CHI2_2_MEDIAN))


#: Median of chi^2 with 2 and 3 degrees of freedom.
CHI2_2_MEDIAN = float(2 * gammaincinv(1.0, 0.5))  # chi^2(k)'s median: 2 P^-1(k/2, 1/2)
CHI2_3_MEDIAN = float(2 * gammaincinv(1.5, 0.5))


class _Stacked:
    """Known turns, still periods and (optionally) gravity-referenced turns in one problem;
    ``tau`` the excess std of each gravity-referenced turn's residual per tangent component
    (rad, see the module notes)."""

    def __init__(self, known, still, gyro_sigma, rot, with_g, tau: float = 0.0,
                 accel_dirs: np.ndarray | None = None):  # fmt: skip
        self.kp = KnownProblem(known, still, gyro_sigma, with_g) if len(known.t) else None
        self.gp = None if rot is None else Problem(rot, still, gyro_sigma, g_sensitivity=with_g)
        self.still, self.with_g, self.tau = still, with_g, float(tau)
        self.accel_dirs = accel_dirs
        self.n_params = 21 if with_g else 12
        self.n_known = 3 * len(known.t)

    def split(self, x):
        G = x[12:21].reshape(3, 3) if self.with_g else np.zeros((3, 3))
        return x[:3], x[3:12].reshape(3, 3), G

    def freeze(self, x):
        """The noise model at ``x`` (the whitening is held fixed within one solve)."""
        self.joint = self._joint_whitener(x)
        if self.joint is None:  # known turns and turns between still periods apart
            self.L = None if self.kp is None else self.kp.whitening(x)
            self.W = None if self.gp is None else self._gravity_whitener(x)

    def _joint_whitener(self, x) -> _DenseWhitener | None:
        """With labelled axes the frame's part couples every known turn and, through the
        accelerometer calibration's error they share, the turns gravity measures: their rows
        are whitened together (known turns first, then the turns between still periods)."""
        Fk = None if self.kp is None else self.kp.frame_factor()
        if Fk is None:
            return None
        Ck = block_diag(*self.kp.covariance(x))
        Fk = Fk.reshape(3 * self.kp.K, -1)
        if self.gp is None:
            return _DenseWhitener(Ck + Fk @ Fk.T)
        Fg = (np.zeros((2 * self.gp.K, Fk.shape[1])) if self.accel_dirs is None
              else accel_factor(self.gp, x, self.accel_dirs).reshape(2 * self.gp.K, -1))
        F = np.vstack([Fk, Fg])
        return _DenseWhitener(block_diag(Ck, self.gravity_covariance(x).toarray()) + F @ F.T)

    def gravity_covariance(self, x) -> sparse.csr_array:
        """Covariance of the gravity-referenced turns' residuals with the excess ``tau``."""
        C = self.gp.rotation_covariance(x)
        if self.tau <= 0:
            return C
        return C + self.tau**2 * sparse.eye_array(C.shape[0], format="csr")

    def _gravity_whitener(self, x) -> Whitener:
        if self.accel_dirs is None:
            return Whitener(BandedWhitener(self.gravity_covariance(x)), self.gp)
        F = accel_factor(self.gp, x, self.accel_dirs).reshape(2 * self.gp.K, -1)
        return Whitener(_DenseWhitener(self.gravity_covariance(x).toarray() + F @ F.T), self.gp)

    def _still_rows(self, x):
        b, _, G = self.split(x)
        # without the g-sensitivity term the still periods' gravity is not used (it may be
        # unknown: no accelerometer calibration, turns about labelled axes)
        g_term = self.still.g @ G.T if self.with_g else 0.0
        r = ((self.still.z_mean - b - g_term) / self.still.z_sigma[:, None]).ravel()
        P = len(self.still.z_mean)
        J = np.zeros((3 * P, self.n_params))
        J[:, :3] = -np.repeat(1 / self.still.z_sigma, 3)[:, None] * np.tile(np.eye(3), (P, 1))
        if self.with_g:
            for r_ in range(3):
                J[r_::3, 12 + 3 * r_ : 15 + 3 * r_] = -self.still.g / self.still.z_sigma[:, None]
        return r, J

    def f_and_J(self, x):
        if self.joint is not None:
            return self._joint_f_and_J(x)
        if self.kp is None:
            fk, Jk = np.zeros(0), np.zeros((0, self.n_params))
        else:
            fk = _whiten_blocks(self.L, self.kp.residuals(x))
            Jk = _whiten_blocks(self.L, self.kp.jacobian(x))
        if self.gp is None:  # the still rows on their own
            fs, Js = self._still_rows(x)
        else:  # the gravity-referenced turns' rows, with the still rows they hold
            raw, Jraw = self.gp.residuals_and_jacobian(x)
            fs, Js = self.W(raw), self.W(Jraw)
        return np.r_[fk, fs], np.vstack([Jk, Js])

    def _joint_f_and_J(self, x):
        """:meth:`f_and_J` with the rows :meth:`_joint_whitener` couples."""
        rk, Jk = self.kp.residuals(x), self.kp.jacobian(x)
        if self.gp is None:
            fs, Js = self._still_rows(x)
            return np.r_[self.joint(rk), fs], np.vstack([self.joint(Jk), Js])
        raw, Jraw = self.gp.residuals_and_jacobian(x)
        n = 2 * self.gp.K
        sigma = np.repeat(self.still.z_sigma, 3)
        f = np.r_[self.joint(np.r_[rk, raw[:n]]), raw[n:] / sigma]
        J = np.vstack([self.joint(np.vstack([Jk, Jraw[:n]])), Jraw[n:] / sigma[:, None]])
        return f, J

    def estimate_tau(self, x) -> float:
        """``tau`` from the gravity-referenced turns' scatter at ``x`` (module notes): their
        chi^2 with the excess equal to their redundancy. The redundancy is taken at the
        current ``tau``, each turn's own 2 x 2 noise block for the chi^2 (the correlation
        through a shared still period is small beside an excess that matters), that block
        with the accelerometer calibration's part (:func:`accel_blocks`): scatter that its
        uncertainty explains is no excess (its effect on the gyro is propagated apart)."""
        self.freeze(x)
        f, J = self.f_and_J(x)
        K = self.gp.K
        rows = slice(self.n_known, self.n_known + 2 * K)
        q, _ = np.linalg.qr(J)
        redundancy = 2 * K - float(np.sum(q[rows] ** 2))
        raw, _ = self.gp.residuals_and_jacobian(x)
        r = raw[: 2 * K].reshape(K, 2)
        blocks = _diagonal_blocks(self.gp.rotation_covariance(x), K)
        blocks = blocks + accel_blocks(self.gp, x, self.accel_dirs)
        lam, V = np.linalg.eigh(blocks)  # (K, 2), (K, 2, 2)
        w = np.einsum("kij,ki->kj", V, r) ** 2  # squared residual along each eigenvector

        def excess(t2):
            return float(np.sum(w / (lam + t2))) - redundancy

        if redundancy <= 0.5 or excess(0.0) <= 0:
            return 0.0
        hi = max(float(np.sum(w)) / max(redundancy, 1e-9), 1e-30)
        while excess(hi) > 0:
            hi *= 4
        return float(np.sqrt(brentq(excess, 0.0, hi, xtol=1e-30, rtol=1e-10)))


def _solve_frozen(prob: _Stacked, x: np.ndarray, max_iterations: int) -> tuple[np.ndarray, int]:
    """Levenberg-Marquardt on the stacked whitened residuals, the noise model held at ``x``;
    the solution and the Jacobians evaluated."""
    prob.freeze(x)
    last: dict = {}

    def both(v):
        key = v.tobytes()
        if key not in last:
            last.clear()
            last[key] = prob.f_and_J(v)
        return last[key]

    f, J = both(x)
    if len(f) < len(x):  # fewer equations than parameters
        _check_determined(np.vstack([J, np.zeros((len(x) - len(f), len(x)))]), prob.with_g)
    sol = least_squares(lambda v: both(v)[0], x, jac=lambda v: both(v)[1], method="lm",
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12,
                        max_nfev=max_iterations)  # fmt: skip
    return sol.x, int(sol.njev or 0)


def fit_known(
    known: KnownTurns,
    still: Stills,
    gyro_sigma: float,
    b0: np.ndarray,
    *,
    rot: Rotations | None = None,
    x0: np.ndarray | None = None,
    g_sensitivity: bool = False,
    max_iterations: int = 50,
    tau: float | None = None,
    accel_dirs: np.ndarray | None = None,
) -> KnownResult:
    """Bias, matrix (and g-sensitivity) from turns of known angle and the still periods, with
    the gravity-referenced turns ``rot`` in the same fit when given.

    Parameters
    ----------
    known : KnownTurns
        Turns of known angle (may be empty when ``rot`` and ``x0`` are given).
    still : Stills
        The still periods (bias; with ``rot``, also the gravity directions of its turns).
    gyro_sigma : float
        Per-sample gyro noise, raw units.
    b0 : ndarray (3,)
        Initial bias (the still periods' mean).
    rot : Rotations, optional
        Turns between still periods whose angle gravity measures (:mod:`.gyro_model`).
    x0 : ndarray (12,), optional
        Start ``(b, M row-major)``; default the closed form of the known turns.
    g_sensitivity : bool
        Fit ``G`` (needs still periods in several orientations, e.g. opposite faces up).
    tau : float, optional
        Excess std of each gravity-referenced turn per tangent component (rad); default:
        estimated from their scatter (module notes).
    accel_dirs : ndarray (P, 3, m), optional
        How the still periods' calibrated gravity vectors move with the accelerometer
        calibration's error: column j is their change along the j-th square-root direction of
        its covariance (m/s^2). The turns' residuals then count its part of their scatter as
        noise, not excess (:func:`accel_blocks`).

    Raises
    ------
    DesignError
        The turns do not determine the model.
    SolverError
        No finite solution.
    """
    if not len(known.t) and (rot is None or x0 is None):
        raise DesignError("no turn of known angle to fit")
    if x0 is None:  # initialisation: the known turns' closed form at the still bias
        x0 = np.r_[b0, closed_form(known, b0).ravel()]
    x = np.r_[x0[:12], np.zeros(9)] if g_sensitivity else np.asarray(x0[:12], float)
    prob = _Stacked(known, still, gyro_sigma, rot, g_sensitivity, tau=tau or 0.0,
                    accel_dirs=accel_dirs)  # fmt: skip
    x, it = _solve(prob, x, max_iterations, estimate_tau=rot is not None and tau is None)
    if not np.all(np.isfinite(x)):
        raise SolverError("the known-angle gyro fit did not converge")
    prob.freeze(x)
    f, J = prob.f_and_J(x)
    _check_determined(J, g_sensitivity)
    cov, noise_scale, redundancy = _covariance(f, J, prob.n_known)
    cov = cov + rounding_parameter_covariance(J, still)  # the rounding the still means share
    b, M, G = prob.split(x)
    return KnownResult(
        b=b.copy(), M=M.copy(), G=G.copy() if g_sensitivity else None, cov=cov,
        chi2=float(f @ f), dof=max(len(f) - prob.n_params, 1), noise_scale=float(noise_scale),
        iterations=it, known_redundancy=redundancy[0], tau=prob.tau,
        **_turn_errors(prob, known, x), **_gravity_turns(prob, x, J),
    )  # fmt: skip


#: Rounds of (estimate the excess, refit) at most.
TAU_ITERATIONS = 8


def _solve(prob: _Stacked, x: np.ndarray, max_iterations: int, estimate_tau: bool):
    """Solved twice (the noise model at the solution), then, with ``estimate_tau``, the
    excess of the turns between still periods and the fit in turn until they agree."""
    x, it = _solve_frozen(prob, x, max_iterations)  # solve: the whitened e_k and still rows
    x, it2 = _solve_frozen(prob, x, max_iterations)  # the noise model at the solution
    it += it2
    if not estimate_tau or not np.all(np.isfinite(x)):
        return x, it
    for _ in range(TAU_ITERATIONS):
        new = prob.estimate_tau(x)
        done = abs(new - prob.tau) <= 1e-3 * max(new, prob.tau, 1e-12)
        prob.tau = new
        if done:
            break
        x, it2 = _solve_frozen(prob, x, max_iterations)
        it += it2
    return x, it


def _check_determined(J: np.ndarray, g_sensitivity: bool) -> None:
    """Refuse a design whose whitened Jacobian leaves a combination of parameters free."""
    sv = np.linalg.svd(J, compute_uv=False)
    if sv[-1] < UNDETERMINED * sv[0]:
        what = "the g-sensitivity (hold opposite faces up) or " if g_sensitivity else ""
        raise DesignError(
            f"the turns leave {what}the gyro's matrix undetermined: turn the unit by a known "
            "angle about three different axes, or 10 or more times between still periods"
        )


def _redundancy(J: np.ndarray, rows: slice) -> float:
    """``n - tr(H)`` of a group of whitened rows (``H`` the hat matrix of ``J``)."""
    q, _ = np.linalg.qr(J)
    n = len(range(*rows.indices(len(J))))
    return float(n - np.sum(q[rows] ** 2))


def _covariance(f: np.ndarray, J: np.ndarray, n_known: int):
    """Covariance of the parameters, the largest noise scale, and each group's redundancy.
    The excess of each group of rows (the known turns' ``n_known``; the still periods and
    gravity-referenced turns) over its noise, measured against the group's redundancy,
    scales that group only: still periods that disagree (a drifting bias) say nothing about
    the known turns' axes."""
    groups = [slice(0, n_known), slice(n_known, len(f))]
    row_scale = np.ones(len(f))
    scales, redundancy = [], []
    for sl in groups:
        d = _redundancy(J, sl)
        c = float(f[sl] @ f[sl])
        s_ = c / d if d > 0.5 and c > chdtri(d, 0.01) else 1.0
        row_scale[sl] = s_
        scales.append(s_)
        redundancy.append(d)
    Jw = J / np.sqrt(row_scale)[:, None]
    return np.linalg.inv(Jw.T @ Jw), max(scales), redundancy


def _turn_errors(prob: _Stacked, known: KnownTurns, x: np.ndarray) -> dict:
    """Diagnostics of each known turn: the integrated angle about (and axis off) the known
    axis, its std along the axis (the stated angle error and the integrated gyro noise), and
    its squared whitened residual (3 dof)."""
    kp = prob.kp
    if kp is None:
        empty = np.zeros(0)
        return {"angle_error_deg": empty, "axis_error_deg": empty, "measured_angle_deg": empty,
                "known_chi2": empty, "angle_sigma_deg": empty}  # fmt: skip
    integ = kp.integrated(x)
    along = np.sum(integ * known.axis, axis=1)
    cosang = np.clip(along / np.linalg.norm(integ, axis=1), -1, 1)
    r = kp.residuals(x).reshape(kp.K, 3)
    r_white = np.linalg.solve(kp.marginal(x), r[..., None])[..., 0]  # each turn alone
    M = x[3:12].reshape(3, 3)
    gyro_along = kp.int_noise * np.linalg.norm(known.axis @ M, axis=1)
    return {
        "angle_error_deg": np.degrees(along - known.angle),
        "axis_error_deg": np.degrees(np.arccos(np.abs(cosang))),
        "measured_angle_deg": np.degrees(along),
        "known_chi2": np.einsum("ki,ki->k", r, r_white),
        "angle_sigma_deg": np.degrees(np.sqrt(known.angle_sigma**2 + gyro_along**2)),
    }


def _gravity_turns(prob: _Stacked, x: np.ndarray, J: np.ndarray) -> dict:
    """Diagnostics of each gravity-referenced turn (:func:`gravity_statistics`) and the
    group's redundancy."""
    if prob.gp is None:
        return {}
    rows = slice(prob.n_known, prob.n_known + 2 * prob.gp.K)
    return {**gravity_statistics(prob.gp, x, prob.tau, prob.accel_dirs),
            "gravity_redundancy": _redundancy(J, rows)}  # fmt: skip
