"""Sigma-point propagation of an accelerometer calibration's covariance into a gyro fit.

The gyro's turns are measured against gravity directions from the calibrated accelerometer,
so the gyro estimate ``x_hat(theta)`` is a function of the accelerometer's parameters
``theta`` (bias and matrix). To first order its covariance from ``theta``'s is ``A C A^T``
(``A = d x_hat / d theta``, :func:`imucal_cli.estimators.gyro.full.accel_sensitivity`). Where the
turns barely determine the gyro and the accelerometer is poorly known (the 5 moves between six
faces, each near 180 degrees, measured with an accelerometer known to about 0.7 degree) the
solution moves far enough that its Jacobian changes on the way: the first order understates
the spread (issue 10: a gain 129 % off, stated to 36 %).

Then the accelerometer's part is computed by refitting the gyro at sigma points (the unscented
transform, Julier & Uhlmann): ``theta = theta_hat +- sqrt(n + lambda) l_k`` with ``l_k`` the
columns of a square root of ``C``, ``n + lambda = 3`` (for a Gaussian ``theta`` the choice that
gives the exact second moment of a function quadratic along each column: ``kappa = 3 - n``).
The moment is taken about the estimate the fit reports, ``x_hat(theta_hat)`` (not the sigma
points' mean): it holds the nonlinear shift too, and the centre point's weight drops out::

    C_x = 1 / (2 (n + lambda)) sum_k sum_+- (x(theta_hat +- sqrt(n + lambda) l_k) - x_hat)
                                             (x(...) - x_hat)^T

Linear ``x`` gives ``A C A^T`` exactly. Only the accelerometer directions that matter are
refitted: the square root's columns are rotated (SVD of the whitened ``A L``) so that each moves
the gyro independently, measured in the gyro's own noise std; those that move it by less than
that std (:data:`GATE`) keep their first-order part, by the argument of point 1 below.

When the first order is doubtful, measurably (:func:`propagate`):

1. the accelerometer moves the gyro by at least :data:`GATE` (one) of the gyro's own noise std
   in some direction (first order, one accelerometer std). Below that the first order is kept
   without a refit: the accelerometer's effect is smaller than the noise's, whose curvature
   along the same solution every stated std already neglects;
2. one Gauss-Newton step from the first-order prediction at each sigma point (``step``: one
   evaluation of the turns each, where a refit makes five or six) changes some std by more
   than :data:`PRECHECK` (a quarter of the tolerance below). The step is the refit to second
   order (it estimates the refits' change within a few % of itself: 1e-4 to 1e-3 on the clean
   designs, 4-9 % against 4-8.5 % on six faces' seeds that stay linear, 0.2 to 85 where they do
   not); below :data:`PRECHECK` the first order is clearly adequate and kept without refits;
3. the sigma points change the std of some linear combination of the gyro's parameters (a
   parameter, a gain, a rate in any direction: the generalised eigenvalues of the two total
   covariances) by more than :data:`LINEAR_TOLERANCE` (10 %), or a refit fails. Otherwise the
   first-order covariance is kept as it was (the refits only checked it).

Clean designs stay linear by far (``free:12``, the Xsens recording: std changes of 1e-4 to
1e-3 where the check runs; ``qureshi18``, ``random:20``, ``qureshi-axes``: no check, the
accelerometer moves the gyro by 0.1-0.7 of its noise); the six faces' 5 moves change some
combination by 10 % to 80 times (a parameter's std by up to 5.7 times, seed 9).

Sigma points are themselves an approximation: second order along each direction, no cross
terms between directions (an error that is 1.5 std along several directions at once can move
a gain further than either alone). So the covariance stated is never below the first order in
any combination (:func:`envelope`), and the pipeline warns where the two differ by more than
half (the std are then only a rough guide).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: Sigma points at +-sqrt(n + lambda) = sqrt(3) std along each column (kappa = 3 - n).
SIGMA_SPREAD = np.sqrt(3.0)
#: The first order is kept without a refit when the accelerometer moves the gyro by less than
#: this many of its noise std in every direction (less than the noise itself).
GATE = 1.0
#: Sigma points that change no std (of any combination of the parameters) by more than this
#: share keep the first order.
LINEAR_TOLERANCE = 0.1
#: A Gauss-Newton step from the first-order prediction at every sigma point that changes no
#: std by more than this share (a quarter of :data:`LINEAR_TOLERANCE`: the step estimates the
#: refits' change to a few % of itself) keeps the first order without refits.
PRECHECK = LINEAR_TOLERANCE / 4


MEANING = ("how the accelerometer calibration's covariance was carried into the gyro's: "
           "first order (linear), or by refitting the gyro at sigma points where the first "
           "order is doubtful; effect: largest movement of the gyro by one accelerometer std, "
           "in the gyro's own noise std")


@dataclass
class SigmaPropagation:
    """The accelerometer's part of a gyro covariance and how it was obtained.

    Attributes
    ----------
    cov : ndarray (p, p)
        Covariance of the gyro parameters from the accelerometer's: the first order, or the
        second moment of the sigma points about the estimate, in every direction at least the
        first order (:func:`envelope`).
    linear : ndarray (p, p)
        The first-order ``A C A^T``.
    method : str
        ``"first order"`` or ``"sigma points"``.
    reason : str
        Why (the criterion and its value).
    effect : float
        Largest movement of the gyro by one accelerometer std, in the gyro's noise std (first
        order).
    nonlinearity : float or None
        The largest relative change of any std (of any linear combination of the gyro's
        parameters: a gain, a rate) from the first order to the sigma points (None: not
        checked).
    refits, failed : int
        Gyro refits made, and those that did not converge (or left turns unexplained).
    directions : int
        Accelerometer directions refitted at sigma points.
    """

    cov: np.ndarray
    linear: np.ndarray
    method: str
    reason: str
    effect: float | None
    nonlinearity: float | None = None
    refits: int = 0
    failed: int = 0
    directions: int = 0
    std_ratio: tuple[float, float] | None = None

    def summary(self) -> dict:
        out = {"method": self.method, "meaning": MEANING, "reason": self.reason,
               "effect": self.effect,
               "nonlinearity": self.nonlinearity, "refits": self.refits,
               "failed": self.failed, "directions": self.directions}  # fmt: skip
        if self.std_ratio is not None:
            out["std_ratio_to_first_order"] = list(self.std_ratio)
        return out


def square_root(C: np.ndarray) -> np.ndarray:
    """``L`` (m, r) with ``L L^T = C`` (symmetric positive semi-definite, any scaling of its
    parameters: eigen-decomposed after scaling to unit diagonal); columns of zero variance
    (a gauge the solver fixes) dropped."""
    C = (np.asarray(C, float) + np.asarray(C, float).T) / 2
    d = np.sqrt(np.clip(np.diag(C), 0, None))
    d_safe = np.where(d > 0, d, 1.0)
    w, V = np.linalg.eigh(C / np.outer(d_safe, d_safe))
    keep = w > 1e-12 * max(w.max(), 0.0)
    return d_safe[:, None] * V[:, keep] * np.sqrt(w[keep])


def _whitener(cov_noise: np.ndarray) -> np.ndarray:
    """``W`` with ``W cov W^T = I`` (inverse Cholesky factor after scaling)."""
    d = np.sqrt(np.diag(cov_noise))
    Lc = np.linalg.cholesky(cov_noise / np.outer(d, d))
    return np.linalg.solve(Lc, np.diag(1 / d))


def propagate(
    x_hat: np.ndarray,
    theta_hat: np.ndarray,
    C: np.ndarray,
    A: np.ndarray,
    cov_noise: np.ndarray,
    refit: Callable[[np.ndarray, np.ndarray], np.ndarray | None],
    step: Callable[[np.ndarray, np.ndarray], np.ndarray | None] | None = None,
) -> SigmaPropagation:
    """The accelerometer's part of the gyro covariance, by first order or sigma points.

    Parameters
    ----------
    x_hat : ndarray (p,)
        The gyro fit.
    theta_hat, C : ndarray (m,), (m, m)
        The accelerometer calibration's parameters and their covariance.
    A : ndarray (p, m)
        ``d x_hat / d theta`` (first order).
    cov_noise : ndarray (p, p)
        The gyro's own covariance (the accelerometer taken as exact): the scale of "matters".
    refit : callable
        ``refit(theta, x_start)``: the gyro refitted with the accelerometer at ``theta``,
        started from ``x_start`` (the first-order prediction), or None when it does not
        converge.
    step : callable, optional
        ``step(theta, x_start)``: one Gauss-Newton step of that refit from ``x_start`` (None
        when it leaves a turn unexplained). Given, the sigma points are first estimated by it
        and refitted only when the estimate changes some std by more than :data:`PRECHECK`.
    """
    linear = A @ C @ A.T
    L = square_root(C)
    if L.shape[1] == 0:
        return SigmaPropagation(linear, linear, "first order", "no accelerometer covariance",
                                0.0)  # fmt: skip
    try:
        W = _whitener(cov_noise)
    except np.linalg.LinAlgError:  # a gyro covariance not positive definite: nothing to scale by
        return SigmaPropagation(linear, linear, "first order", "the gyro's own covariance is "
                                "singular: no scale for a check", None)  # fmt: skip
    _, s, Vt = np.linalg.svd(W @ A @ L, full_matrices=False)
    D = L @ Vt.T  # accelerometer directions, each at one std, moving the gyro independently
    effect = float(s[0])
    if effect < GATE:
        return SigmaPropagation(linear, linear, "first order",
                                f"one accelerometer std moves the gyro by at most {effect:.2g} "
                                f"of its noise std (below {GATE:g})", effect)  # fmt: skip
    if step is not None:
        cov, n, failed, used = _sigma_moment(x_hat, theta_hat, A, D, s, step)
        lo, hi, change = _std_change(cov_noise, linear, cov)
        if change <= PRECHECK and not failed:
            return SigmaPropagation(linear, linear, "first order",
                                    f"a Gauss-Newton step from the first-order prediction at "
                                    f"{n} sigma points (no refit) changes no std by more than "
                                    f"{100 * change:.2g} % (refitted above "
                                    f"{100 * PRECHECK:g} %)", effect, change, 0, 0, used,
                                    (lo, hi))  # fmt: skip
    cov, refits, failed, used = _sigma_moment(x_hat, theta_hat, A, D, s, refit)
    lo, hi, change = _std_change(cov_noise, linear, cov)
    if change <= LINEAR_TOLERANCE and not failed:
        return SigmaPropagation(linear, linear, "first order",
                                f"refits at {refits} sigma points change no std by more than "
                                f"{100 * change:.2g} % (at most {100 * LINEAR_TOLERANCE:g} %)",
                                effect, change, refits, failed, used, (lo, hi))  # fmt: skip
    why = (f"refits at {refits} sigma points change the std of combinations of the parameters "
           f"by a factor {lo:.2g} to {hi:.2g} (beyond {100 * LINEAR_TOLERANCE:g} %)"
           + (f"; {failed} refit(s) did not converge" if failed else ""))  # fmt: skip
    total = envelope(cov_noise + linear, cov_noise + cov)
    return SigmaPropagation(total - cov_noise, linear, "sigma points", why, effect, change,
                            refits, failed, used, (lo, hi))  # fmt: skip


def _sigma_moment(x_hat, theta_hat, A, D, s, solve):
    """Second moment about ``x_hat`` of the gyro solved (``solve(theta, x_start)``) at the
    sigma points of the directions ``D`` that move it by at least :data:`GATE` (``s``), the
    first order along the others. Returns it, the solves made, those that failed (None) and
    the directions solved."""
    h = SIGMA_SPREAD
    cov = np.zeros((len(x_hat), len(x_hat)))
    solves = failed = used = 0
    for k in range(len(s)):
        g = A @ D[:, k]
        if s[k] < GATE:  # moves the gyro by less than its noise: first order, as the gate
            cov += np.outer(g, g)
            continue
        used += 1
        got = [solve(theta_hat + sign * h * D[:, k], x_hat + sign * h * g) for sign in (1, -1)]
        solves += 2
        failed += sum(p is None for p in got)
        got = [p for p in got if p is not None]
        if not got:  # neither side converged: the first order is all there is
            cov += np.outer(g, g)
        for p in got:
            d = p - x_hat
            cov += np.outer(d, d) / (len(got) * h**2)
    return (cov + cov.T) / 2, solves, failed, used


def envelope(first: np.ndarray, other: np.ndarray) -> np.ndarray:
    """The covariance that states, for every linear combination of the parameters, the larger
    of its variances under ``first`` and ``other`` along their common eigenbasis (generalised
    eigenvalues below one raised to one). Sigma points are themselves approximate (second
    order along each column, no cross terms): where they find less spread than the first
    order, the smaller figure is not a safe statement."""
    W = _whitener(first)
    lam, U = np.linalg.eigh(W @ other @ W.T)
    Wi = np.linalg.inv(W)
    out = Wi @ (U * np.maximum(lam, 1.0)) @ U.T @ Wi.T
    return (out + out.T) / 2


def _std_change(
    cov_noise: np.ndarray, linear: np.ndarray, cov: np.ndarray
) -> tuple[float, float, float]:
    """:func:`std_ratio` of the total covariance with the accelerometer's part ``cov`` to that
    with its first-order part ``linear``, and the largest relative change of a std."""
    lo, hi = std_ratio(cov_noise + linear, cov_noise + cov)
    return lo, hi, max(hi - 1, 1 - lo)


def std_ratio(first: np.ndarray, other: np.ndarray) -> tuple[float, float]:
    """Smallest and largest ratio of the std of any linear combination of the parameters
    (a gain, a rate in any direction) under covariance ``other`` to that under ``first``:
    square roots of the generalised eigenvalues."""
    W = _whitener(first)
    lam = np.linalg.eigvalsh(W @ other @ W.T)
    return float(np.sqrt(max(lam[0], 0.0))), float(np.sqrt(max(lam[-1], 0.0)))
