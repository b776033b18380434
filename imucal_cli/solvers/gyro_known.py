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
maximum-likelihood estimate (Gauss-Newton; the residuals of known turns are bilinear in
``b`` and ``M``, and the start is their closed-form least-squares solution).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import DesignError, SolverError
from imucal_cli.solvers.gyro_full import chdtri  # the full model's quantile function
from imucal_cli.solvers.gyro_model import Problem, Rotations, Stills

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
    """

    t: list[np.ndarray]
    z: list[np.ndarray]
    angle: np.ndarray
    axis: np.ndarray
    axis_sigma: np.ndarray
    angle_sigma: np.ndarray
    a: list[np.ndarray] | None = None


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
        self.target = known.angle[:, None] * known.axis
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
        return (gyro + (ang * self.known.axis_sigma[:, None, None]) ** 2 * across
                + self.known.angle_sigma[:, None, None] ** 2 * along)  # fmt: skip

    def whitening(self, x) -> np.ndarray:
        """(K, 3, 3) ``L_k^-1`` with ``L_k L_k^T`` the covariance of turn k's residual."""
        return np.linalg.inv(np.linalg.cholesky(self.covariance(x)))


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
    """Result of :func:`fit_known`: as :class:`.gyro_full.FullResult` for the shared fields."""

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

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))


class _Stacked:
    """Known turns, still periods and (optionally) gravity-referenced turns in one problem."""

    def __init__(self, known, still, gyro_sigma, rot, with_g):
        self.kp = KnownProblem(known, still, gyro_sigma, with_g)
        self.gp = None if rot is None else Problem(rot, still, gyro_sigma, g_sensitivity=with_g)
        self.still, self.with_g = still, with_g
        self.n_params = self.kp.n_params

    def freeze(self, x):
        """The noise model at ``x`` (the whitening is held fixed within one solve)."""
        self.L = self.kp.whitening(x)
        self.W = None if self.gp is None else self.gp.whitener(x)

    def _still_rows(self, x):
        b, _, G = self.kp.split(x)
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
        fk = _whiten_blocks(self.L, self.kp.residuals(x))
        Jk = _whiten_blocks(self.L, self.kp.jacobian(x))
        if self.gp is None:  # the still rows on their own
            fs, Js = self._still_rows(x)
        else:  # the gravity-referenced turns' rows, with the still rows they hold
            raw, Jraw = self.gp.residuals_and_jacobian(x)
            fs, Js = self.W(raw), self.W(Jraw)
        return np.r_[fk, fs], np.vstack([Jk, Js])


def _gauss_newton(prob: _Stacked, x: np.ndarray, max_iterations: int) -> tuple[np.ndarray, int]:
    """Damped Gauss-Newton (step halving) on the stacked whitened residuals."""
    prob.freeze(x)
    f, J = prob.f_and_J(x)
    it = 0
    while it < max_iterations:
        it += 1
        step = np.linalg.lstsq(J, -f, rcond=None)[0]
        cost = f @ f
        for _ in range(30):
            x_new = x + step
            f_new, J_new = prob.f_and_J(x_new)
            if np.all(np.isfinite(f_new)) and f_new @ f_new <= cost:
                break
            step = step / 2
        else:
            break
        x, f, J = x_new, f_new, J_new
        if np.linalg.norm(step) <= 1e-12 * max(np.linalg.norm(x), 1e-300) or cost - f @ f \
                <= 1e-14 * max(cost, 1e-300):  # fmt: skip
            break
    return x, it


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
) -> KnownResult:
    """Bias, matrix (and g-sensitivity) from turns of known angle and the still periods, with
    the gravity-referenced turns ``rot`` in the same fit when given.

    Parameters
    ----------
    known : KnownTurns
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

    Raises
    ------
    DesignError
        The turns do not determine the model.
    SolverError
        No finite solution.
    """
    if x0 is None:  # initialisation: the known turns' closed form at the still bias
        x0 = np.r_[b0, closed_form(known, b0).ravel()]
    x = np.r_[x0[:12], np.zeros(9)] if g_sensitivity else np.asarray(x0[:12], float)
    prob = _Stacked(known, still, gyro_sigma, rot, g_sensitivity)
    x, it1 = _gauss_newton(prob, x, max_iterations)  # solve: the whitened e_k and still rows
    x, it2 = _gauss_newton(prob, x, max_iterations)  # the noise model at the solution
    if not np.all(np.isfinite(x)):
        raise SolverError("the known-angle gyro fit did not converge")
    prob.freeze(x)
    f, J = prob.f_and_J(x)
    _check_determined(J, g_sensitivity)
    cov, noise_scale = _covariance(f, J, prob.kp.K, prob.n_params, rot is None)
    b, M, G = prob.kp.split(x)
    return KnownResult(
        b=b.copy(), M=M.copy(), G=G.copy() if g_sensitivity else None, cov=cov,
        chi2=float(f @ f), dof=max(len(f) - prob.n_params, 1), noise_scale=float(noise_scale),
        iterations=it1 + it2, **_turn_errors(prob.kp, known, x, f),
    )  # fmt: skip


def _check_determined(J: np.ndarray, g_sensitivity: bool) -> None:
    """Refuse a design whose whitened Jacobian leaves a combination of parameters free."""
    sv = np.linalg.svd(J, compute_uv=False)
    if sv[-1] < UNDETERMINED * sv[0]:
        what = "the g-sensitivity (hold opposite faces up) or " if g_sensitivity else ""
        raise DesignError(
            f"the turns leave {what}the gyro's matrix undetermined: turn the unit by a known "
            "angle about three different axes, or 10 or more times between still periods"
        )


def _covariance(f: np.ndarray, J: np.ndarray, K: int, n: int, known_only: bool):
    """Covariance of the parameters and the largest noise scale.  The excess of each group of
    rows (the K known turns' 3 K; the still periods and gravity-referenced turns) over its
    noise scales that group only: still periods that disagree (a drifting bias) say nothing
    about the known turns' axes."""
    groups = [slice(0, 3 * K), slice(3 * K, len(f))]
    free = [3 * K - (9 if known_only else 0), len(f) - 3 * K - (n - 9)]
    row_scale = np.ones(len(f))
    scales = []
    for sl, d in zip(groups, free, strict=True):
        c = float(f[sl] @ f[sl])
        s_ = c / d if d > 0 and c > chdtri(d, 0.01) else 1.0
        row_scale[sl] = s_
        scales.append(s_)
    Jw = J / np.sqrt(row_scale)[:, None]
    return np.linalg.inv(Jw.T @ Jw), max(scales)


def _turn_errors(kp: KnownProblem, known: KnownTurns, x: np.ndarray, f: np.ndarray) -> dict:
    """Diagnostics of each known turn: the integrated angle about (and axis off) the known
    axis, and its squared whitened residual (3 dof)."""
    integ = kp.integrated(x)
    along = np.sum(integ * known.axis, axis=1)
    cosang = np.clip(along / np.linalg.norm(integ, axis=1), -1, 1)
    fk = f[: 3 * kp.K].reshape(kp.K, 3)
    return {
        "angle_error_deg": np.degrees(along - known.angle),
        "axis_error_deg": np.degrees(np.arccos(np.abs(cosang))),
        "measured_angle_deg": np.degrees(along),
        "known_chi2": np.sum(fk**2, axis=1),
    }
