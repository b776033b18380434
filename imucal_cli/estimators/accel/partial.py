"""The gravity-magnitude fit of a design that cannot fix the whole model (issue 27.3): a
maximum a posteriori fit with a Gaussian prior on every parameter.

Qureshi & Golnaraghi's magnitude equations (III-A, eq. 4: ``|h_k| = g``) are written in the
report's parameters ``p = (b_x, b_y, b_z, s_x, s_y, s_z, a_xy, a_xz, a_yz)``: bias (raw),
sensitivities (raw units per m/s^2) and angles between the sensitivity axes minus 90 deg.  The
sensitivity matrix ``S`` (rows: the axes) enters the magnitude only through its Gram matrix
``G = S S^T``, ``G_ii = s_i^2``, ``G_ij = s_i s_j cos(90 deg + a_ij)``::

    |h_k|^2 = (a_k - b)^T G^-1 (a_k - b)                                   (eq. 4, any frame)

so the fit needs no gauge; the section's matrix is the upper-triangular ``M`` with
``M^T M = G^-1`` (the gravity solver's gauge, eq. 3).

A few poses about one axis do not determine all nine parameters.  With the prior
``p ~ N(p0, diag(sigma0^2))`` (nominal values, or an earlier calibration) the fit minimises

    sum_k ((|h_k| - g) / sigma_k)^2 + sum_i ((p_i - p0_i) / sigma0_i)^2

(``sigma_k``: the magnitude's noise from the pose mean's covariance), and the posterior
covariance is ``(J^T J)^-1`` of the whitened residuals at the solution (data and prior rows):
the std of a parameter the poses do not see is its prior std, never a smaller one.  In
units of the prior (``z = (p - p0) / sigma0``) the prior is the identity, so the posterior
``(I + F)^-1`` (``F``: the data's Fisher information) shares ``F``'s eigenvectors: a
direction of eigenvalue ``lambda`` keeps ``1 / sqrt(1 + lambda)`` of its prior std.

The rule (:data:`MEASURED_RATIO`): a parameter is **measured** when its posterior std is below
half its prior std (the data carry at least 3 times the prior's information on it), else
**assumed**.  A combination of assumed parameters the data still determine (a direction of
``F`` with ``lambda > 3``) is listed with its posterior std.

An assumed parameter's value is the prior's, moved only by what the data say of the
combinations it enters (by less than its prior std; not at all when the data carry no
information on it).  Holding the assumed ones exactly at the prior instead and refitting the
others (their std carrying the held ones' prior, Schmidt's consider covariance) was tried:
where a determined combination mixes measured and assumed parameters (poses tilted about one
axis) the measured ones must then absorb the prior's error alone: on a simulated vehicle log
the magnitudes missed gravity by 13 times their noise, b_x moved by 1,460 counts and the
measured std grew 20-45 fold (b_x 5,500 counts against 121), so the joint posterior is what
is stated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

__all__ = ["MEASURED_RATIO", "NAMES", "PartialResult", "Prior", "fit_partial", "gram",
           "matrix_of", "suggest"]  # fmt: skip

NAMES = ("b_x", "b_y", "b_z", "s_x", "s_y", "s_z", "a_xy", "a_xz", "a_yz")
PAIRS = ((0, 1), (0, 2), (1, 2))

MEASURED_RATIO = 0.5
"""A parameter is measured when its posterior std is below this fraction of its prior std."""

#: The same rule for a direction of the information: ``1 / sqrt(1 + lambda) < 0.5``.
DETERMINED_EIGENVALUE = 1.0 / MEASURED_RATIO**2 - 1.0


@dataclass(frozen=True)
class Prior:
    """A Gaussian prior on the parameters :data:`NAMES`: ``mean`` (9,), ``std`` (9,) in the
    parameters' units, and where it comes from (words for the report)."""

    mean: np.ndarray
    std: np.ndarray
    source: str


@dataclass(frozen=True)
class PartialResult:
    """The maximum a posteriori fit (module notes).

    Attributes
    ----------
    params, cov : ndarray, shapes (9,), (9, 9)
        The estimate of :data:`NAMES` and its posterior covariance.
    prior : Prior
    ratio : ndarray, shape (9,)
        Posterior std over prior std of each parameter.
    measured : ndarray of bool, shape (9,)
        ``ratio < MEASURED_RATIO``.
    combinations : list of (ndarray (9,), float, float)
        Determined directions that involve assumed parameters: the coefficients ``c`` of
        ``c . p`` (parameters' units; 1 for the parameter it weighs most in units of the
        prior std), its value and its std.
    bias : ndarray (3,)
        Raw units.
    matrix : ndarray (3, 3)
        Upper triangular, ``calibrated = matrix @ (raw - bias)``.
    residuals : ndarray (N,)
        ``|h_k| - g``, m/s^2.
    sigmas : ndarray (N,)
        Each magnitude's noise, m/s^2.
    chi2 : float
        The data's part of the weighted sum of squares.
    iterations, nfev : int
    converged : bool
    message : str
    """

    params: np.ndarray
    cov: np.ndarray
    prior: Prior
    ratio: np.ndarray
    measured: np.ndarray
    combinations: list
    bias: np.ndarray
    matrix: np.ndarray
    residuals: np.ndarray
    sigmas: np.ndarray
    chi2: float
    iterations: int
    nfev: int
    converged: bool
    message: str

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


def gram(p: np.ndarray) -> np.ndarray:
    """``G = S S^T`` of the sensitivities and angles in ``p`` (module notes), (3, 3)."""
    s = np.asarray(p[3:6], float)
    G = np.diag(s**2)
    for (i, j), a in zip(PAIRS, p[6:9], strict=True):
        G[i, j] = G[j, i] = s[i] * s[j] * np.cos(np.radians(90.0 + a))
    return G


def matrix_of(p: np.ndarray) -> np.ndarray:
    """The upper-triangular ``M`` with ``M^T M = G^-1`` (eq. 3's gauge)."""
    L = np.linalg.cholesky(np.linalg.inv(gram(p)))
    return L.T


def _magnitudes(p: np.ndarray, a_mean: np.ndarray) -> np.ndarray:
    d = a_mean - p[:3]
    return np.sqrt(np.einsum("ki,ij,kj->k", d, np.linalg.inv(gram(p)), d))


def _sigmas(p: np.ndarray, a_mean: np.ndarray, cov_mean: np.ndarray) -> np.ndarray:
    """The magnitude's noise per pose: ``u^T M C_k M^T u``, ``u`` the calibrated direction."""
    M = matrix_of(p)
    h = (a_mean - p[:3]) @ M.T
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    w = u @ M
    return np.sqrt(np.einsum("ki,kij,kj->k", w, cov_mean, w))


def fit_partial(a_mean: np.ndarray, cov_mean: np.ndarray, g: float, prior: Prior,
                max_iterations: int = 200) -> PartialResult:  # fmt: skip
    """The maximum a posteriori gravity-magnitude fit of ``a_mean`` (N, 3) raw pose means
    with covariances ``cov_mean`` (N, 3, 3), local gravity ``g`` (m/s^2), under ``prior``.

    The weights are the magnitudes' noise at the prior mean, then again at the solution (a
    second pass).  Returns a :class:`PartialResult`.
    """
    a_mean = np.asarray(a_mean, float)
    p0, s0 = np.asarray(prior.mean, float), np.asarray(prior.std, float)
    sig = _sigmas(p0, a_mean, cov_mean)

    def residuals(z):
        p = p0 + s0 * z
        return np.r_[(_magnitudes(p, a_mean) - g) / sig, z]

    z = np.zeros(9)
    for _ in range(2):
        sol = least_squares(residuals, z, method="lm", max_nfev=max_iterations * 10,
                            x_scale=np.ones(9))  # fmt: skip
        z = sol.x
        sig = _sigmas(p0 + s0 * z, a_mean, cov_mean)
    sol = least_squares(residuals, z, method="lm", max_nfev=max_iterations * 10)
    z = sol.x
    J = sol.jac
    post = s0[:, None] * np.linalg.inv(J.T @ J) * s0  # the joint posterior
    ratio = np.sqrt(np.clip(np.diag(post), 0.0, None)) / s0
    measured = ratio < MEASURED_RATIO
    Jd = J[: len(a_mean)]
    combos = _combinations(Jd, measured, p0 + s0 * z, post, s0)
    p = p0 + s0 * z
    res = _magnitudes(p, a_mean) - g
    return PartialResult(
        params=p, cov=(post + post.T) / 2, prior=prior, ratio=ratio, measured=measured,
        combinations=combos, bias=p[:3].copy(), matrix=matrix_of(p), residuals=res,
        sigmas=sig, chi2=float(np.sum((res / sig) ** 2)), iterations=int(sol.nfev),
        nfev=int(sol.nfev), converged=bool(sol.success), message=str(sol.message),
    )  # fmt: skip


def _combinations(Jd: np.ndarray, measured: np.ndarray, p: np.ndarray, post: np.ndarray,
                  s0: np.ndarray) -> list:  # fmt: skip
    """Determined directions of the data's information ``F = Jd^T Jd`` (prior units) that
    involve assumed parameters (module notes), with their value and posterior std."""
    F = Jd.T @ Jd
    lam, V = np.linalg.eigh((F + F.T) / 2)
    combos = []
    for k in np.flatnonzero(lam > DETERMINED_EIGENVALUE):
        v = V[:, k]  # v . z, i.e. c . p with c = v / sigma0
        if np.max(np.abs(v[~measured]), initial=0.0) < 0.1:
            continue  # a direction of measured parameters: they are listed themselves
        lead = int(np.argmax(np.abs(v)))  # the parameter it weighs most (prior units)
        c = v / s0
        c = c / c[lead]
        combos.append((c, float(c @ p), float(np.sqrt(c @ post @ c))))
    return combos


def _pose_row(p0: np.ndarray, s0: np.ndarray, z: np.ndarray, a: np.ndarray, sig: float
              ) -> np.ndarray:  # fmt: skip
    """d((|h| - g) / sigma) / dz of one more pose whose mean raw reading is ``a`` (3,)."""
    out = np.empty(9)
    for i in range(9):
        dz = np.zeros(9)
        dz[i] = 1e-6
        hi = _magnitudes(p0 + s0 * (z + dz), a[None])[0]
        lo = _magnitudes(p0 + s0 * (z - dz), a[None])[0]
        out[i] = (hi - lo) / (2e-6 * sig)
    return out


def suggest(result: PartialResult, g: float, candidates: dict[str, np.ndarray], sigma: float,
            most: int = 6) -> list[str]:  # fmt: skip
    """The poses (names of ``candidates``: calibrated unit up directions) that would measure
    the assumed parameters, chosen one at a time (greedy): each the one after which the
    most parameters are measured (ties: the largest gain in information, log det); at most
    ``most``, none when every parameter is measured.  ``sigma``: one more pose's magnitude
    noise, m/s^2."""
    p0, s0 = result.prior.mean, result.prior.std
    z = (result.params - p0) / s0
    H = np.linalg.inv(result.cov / np.outer(s0, s0))  # posterior information, prior units
    S = np.linalg.inv(result.matrix)
    rows = {name: _pose_row(p0, s0, z, S @ (g * np.asarray(u, float)) + result.bias, sigma)
            for name, u in candidates.items()}  # fmt: skip
    chosen: list[str] = []
    while len(chosen) < most and not np.all(np.diag(np.linalg.inv(H)) < MEASURED_RATIO**2):
        best, key = None, None
        for name, j in rows.items():
            Hc = H + np.outer(j, j)
            k = (int(np.sum(np.diag(np.linalg.inv(Hc)) < MEASURED_RATIO**2)),
                 float(np.linalg.slogdet(Hc)[1]))  # fmt: skip
            if key is None or k > key:
                best, key = name, k
        chosen.append(best)
        H = H + np.outer(rows[best], rows[best])
    return chosen
