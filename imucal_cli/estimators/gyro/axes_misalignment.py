"""What the per-axis model's missing misalignment does to its gains (Qureshi & Golnaraghi).

The paper's gyro model (eq. 6) is ``omega = K T_s (omega_s - B)`` with a misalignment
``T_s``; the per-axis solvers drop it (eq. 15), on the paper's finding that a single-die
gyro's misalignment is small (0.0003, section III-B). A few tenths of a degree of it still
moves the per-axis gains by about as much as their noise: each turn's axis is a degree or
two off the sensor axis it is credited to (a hand is never exact), and the integral of the
other channels leaks into its angle through the off-diagonal terms (first order in the
misalignment, different for every turn); and the angle is read about the per-axis calibrated
rotation vector, which the misalignment tilts from the true axis, so each turn's angle is
short by a part quadratic in the misalignment that is the same on every turn of one axis (it
moves the gain without showing in the residuals).

:func:`misalignment_errors` gives those angle errors, noise-free, for draws of the
misalignment at a stated RMS, on the session's own turns (their rotation vectors and the
gravity direction each starts from): the per-axis fit
(:func:`~imucal_cli.estimators.gyro.axes.fit_axis_static`, ``..._dynamic``) turns them into the
variance they add to its estimates.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.estimators.gyro.axes import ModelErrors

#: Draws of the misalignment (each with its mirror image): the variance they give has a
#: relative Monte Carlo error of about ``1 / sqrt(N)`` (6 % at 256), well under that of the
#: misalignment's own measurement.
DRAWS = 256
#: The fractional raise of a component's variance for the derivative that gives the dof.
STEP = 0.2


def misalignment_parts(m: np.ndarray, m_std: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """RMS of the rotation and the non-orthogonality in a measured misalignment ``m`` (rad),
    and the degrees of freedom of their squares.

    ``m = D^-1 M - I`` (``M_ij / M_ii`` off the diagonal) splits into its antisymmetric part, a
    rotation of the gyro from the accelerometer, and its symmetric part, the axes' departure
    from orthogonal (3 entries each). They must be told apart: eq. (15)'s gains, read as the
    turns' angles, are nearly blind to a rotation (it keeps each turn's angle) but not to
    the rest.

    The per-axis std average the misalignment's effect over its direction, at its measured
    size: what limits that size is the measurement (``m_std``), so each square's dof is
    ``2 sigma^4 / Var(sigma^2)`` with ``Var`` by the delta method over the 3 entries
    (``(4 x^2 s^2 + 2 s^4) / 9`` each): thousands where the full model measures the
    misalignment to a few percent.

    Parameters
    ----------
    m : ndarray, shape (3, 3)
        Measured misalignment (diagonal ignored), rad.
    m_std : ndarray, shape (3, 3), optional
        Its standard deviations: their share is taken out of the mean squares (default:
        exact, infinite dof).

    Returns
    -------
    sigma : ndarray, shape (2,)
        RMS of the rotation's and the non-orthogonality's off-diagonal entries, rad (0 where
        the estimation noise is larger).
    dof : ndarray, shape (2,)
        Degrees of freedom of ``sigma**2``.
    """
    m = np.asarray(m, float)
    s2 = np.zeros((3, 3)) if m_std is None else np.nan_to_num(np.asarray(m_std, float)) ** 2
    iu = np.triu_indices(3, 1)
    noise = ((s2 + s2.T) / 4)[iu]  # variance of (m_ij +- m_ji) / 2
    sigma, dof = np.zeros(2), np.full(2, np.inf)
    for c, part in enumerate(((m - m.T) / 2, (m + m.T) / 2)):
        x = part[iu]
        var = float(np.mean(x**2 - noise))
        if var <= 0:
            continue
        sigma[c] = np.sqrt(var)
        spread = float(np.sum(4 * x**2 * noise + 2 * noise**2)) / 9
        dof[c] = 2 * var**2 / spread if spread > 0 else np.inf
    return sigma, dof


def misalignment_errors(rotvec: np.ndarray, g_before: np.ndarray, sign: np.ndarray, axis: int,
                        sigma: np.ndarray, dof: np.ndarray | None = None, draws: int = DRAWS,
                        seed: int = 0) -> ModelErrors:  # fmt: skip
    """Angle errors of eq. (15) where the gyro has the misalignment of eq. (6).

    For each draw ``m`` (a rotation and a symmetric non-orthogonality, each in a random
    direction with exactly the RMS of its off-diagonal entries that ``sigma`` gives, diagonal
    zero) the gyro is ``M = D (I + m)``
    with ``D`` the per-axis gains, so a turn with rotation vector ``r`` (accelerometer frame)
    integrates to ``d = M^-1 r`` and the per-axis calibration turns it into
    ``q = D d = (I + m)^-1 r``. The angle is read as the solver reads it: about ``q``'s
    direction, from the gravity direction before the turn and the one ``r`` turns it to, times
    the axis's component (:func:`~imucal_cli.estimators.gyro.axes.rotation_angle_about_axis`);
    its error is that minus ``q_i`` (what ``k_i`` times the integral predicts, eq. 17).

    Parameters
    ----------
    rotvec : ndarray, shape (K, 3)
        Rotation vector of each turn about ``axis``, rad, accelerometer (body) frame.
    g_before : ndarray, shape (K, 3)
        Gravity direction before each turn, body frame (any units).
    sign : ndarray, shape (K,)
        +1 or -1: the labelled direction of each turn's axis.
    axis : int
        The sensor axis (0, 1, 2) the turns are about.
    sigma : ndarray, shape (2,)
        RMS of the rotation's and the non-orthogonality's off-diagonal entries, rad
        (:func:`misalignment_parts`).
    dof : ndarray, shape (2,), optional
        Degrees of freedom of each one's measured variance (default: exact).
    draws : int
        Draws (each also taken with its sign reversed).
    seed : int
        Seed of the draws (fixed: the same session gives the same std).

    Returns
    -------
    ModelErrors
        ``errors`` (3, 2 draws, K), rad: at ``sigma``, then with each component's variance
        raised by :data:`STEP`.
    """
    r = np.asarray(rotvec, float)
    u0 = np.asarray(g_before, float)
    u0 = u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    u1 = Rotation.from_rotvec(r).apply(u0, inverse=True)  # gravity turns by -r in the body
    z = np.random.default_rng(seed).standard_normal((2, draws, 3, 3))
    rot, sym = (z[0] - z[0].transpose(0, 2, 1)) / 2, (z[1] + z[1].transpose(0, 2, 1)) / 2
    off = ~np.eye(3, dtype=bool)
    sym[:, ~off] = 0.0
    # Each draw at exactly the measured RMS, in a random direction: the size is measured, the
    # direction's effect is averaged (normal draws would add the spread of the size: for an
    # effect quadratic in it, 5/3 of the mean square over 3 entries).
    rot = rot / np.sqrt(np.mean(rot[:, off] ** 2, axis=1))[:, None, None]
    sym = sym / np.sqrt(np.mean(sym[:, off] ** 2, axis=1))[:, None, None]
    sgn = np.asarray(sign, float)
    up = np.sqrt(1 + STEP)
    scales = [(1.0, 1.0), (up, 1.0), (1.0, up)]
    errors = [
        np.concatenate([_errors(s * (a * sigma[0] * rot + c * sigma[1] * sym), r, u0, u1, sgn,
                                axis) for s in (1.0, -1.0)])
        for a, c in scales
    ]  # fmt: skip
    return ModelErrors(np.array(errors), STEP,
                       np.full(2, np.inf) if dof is None else np.asarray(dof, float))


def _errors(m: np.ndarray, r: np.ndarray, u0: np.ndarray, u1: np.ndarray, sign: np.ndarray,
            i: int) -> np.ndarray:  # fmt: skip
    """(N, K) angle errors for misalignments ``m`` (N, 3, 3)."""
    eye = np.eye(3)
    q = np.einsum("nab,kb->nka", np.linalg.inv(eye + m), r)  # (N, K, 3)
    a = q / np.linalg.norm(q, axis=2, keepdims=True)
    a = a * (np.sign(q[..., i]) * sign)[..., None]
    p0 = u0 - np.sum(u0 * a, axis=2, keepdims=True) * a
    p1 = u1 - np.sum(u1 * a, axis=2, keepdims=True) * a
    angle = -np.arctan2(np.sum(a * np.cross(p0, p1), axis=2), np.sum(p0 * p1, axis=2))
    ai = np.abs(a[..., i])
    seen = sign * angle
    seen = seen + 2 * np.pi * np.round((q[..., i] / ai - seen) / (2 * np.pi))
    return seen * ai - q[..., i]
