"""The labelled-pose solver's placement beyond first order (eq. L6 of :mod:`.labelled`): along
the placement directions the data leave to the labels (six faces: the three strains of the
faces' frame besides its rotation), the parameters are refitted at the nodes of a fully
symmetric rule over the placement's posterior, and the spread of those refits beyond their
first-order part joins the covariance. ``st`` below is the fit's end (:class:`.labelled.
_State`: its problem, ``sol.x``, ``P = (J^T J)^-1``)."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from .gravity import _UPPER, triangular_and_rotation
from .labelled_model import Problem, sphere_exp

__all__ = ["placement_beyond_first_order", "symmetric_rule"]

#: A placement direction is label-limited (propagated beyond first order, eq. L6) where the
#: fit leaves it more than this fraction of the prior's variance.
LABEL_LIMITED = 0.01
#: Up to this many label-limited directions the fifth-degree rule (2 m^2 + 1 refits), above
#: it the third-degree one (2 m refits: the mean of a quadratic, not all of its variance).
MAX_FIFTH_DEGREE = 8
#: The gauge of the placements: a rotation of the frame and every direction together.
GAUGE_MODES = 3


def symmetric_rule(m: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Nodes (n, m) and weights (n,) of a fully symmetric rule for ``N(0, I_m)``, and the
    distance ``a`` of its axis nodes ``+-a e_i`` (nodes 1..2m, in the order +e_1, -e_1, ...).

    Up to :data:`MAX_FIFTH_DEGREE` dimensions the fifth-degree rule (exact for polynomials of
    degree 5, so for the mean and covariance of a quadratic): the centre, ``+-sqrt(3) e_i``
    and ``+-sqrt(3) e_i +- sqrt(3) e_j`` (i < j), weights ``1 + (m^2 - 7 m) / 18``,
    ``(4 - m) / 18`` and ``1 / 36`` (for m = 1 Gauss-Hermite's three points); above, the
    third-degree one (``+-sqrt(m) e_i``, weights ``1 / 2m``)."""
    if m > MAX_FIFTH_DEGREE:
        a = np.sqrt(m)
        nodes = np.vstack([np.zeros(m), *[s * a * np.eye(m)[i] for i in range(m) for s in (1, -1)]])
        return nodes, np.r_[0.0, np.full(2 * m, 0.5 / m)], a
    a = np.sqrt(3.0)
    nodes, weights = [np.zeros(m)], [1.0 + (m * m - 7 * m) / 18.0]
    for i in range(m):
        for s in (1, -1):
            nodes.append(s * a * np.eye(m)[i])
            weights.append((4 - m) / 18.0)
    for i in range(m):
        for j in range(i + 1, m):
            for si in (1, -1):
                for sj in (1, -1):
                    nodes.append(a * (si * np.eye(m)[i] + sj * np.eye(m)[j]))
                    weights.append(1.0 / 36.0)
    return np.array(nodes), np.array(weights), a


def _label_limited(st) -> tuple[np.ndarray, np.ndarray]:
    """Columns of ``x`` of the labelled placements and the label-limited directions of their
    posterior, less the gauge (eq. L6): ``(cols, V)`` with ``delta = delta_hat + V xi``,
    ``xi ~ N(0, I_m)``."""
    prob, x = st.prob, st.sol.x
    cols = (12 + 2 * prob.lab[:, None] + np.arange(2)).ravel()
    lam, V = np.linalg.eigh(st.P[np.ix_(cols, cols)])
    big = lam > LABEL_LIMITED * prob.sigma_p**2
    if big.sum() <= GAUGE_MODES:  # nothing beyond the gauge (qureshi18-like designs)
        return cols, np.zeros((len(cols), 0))
    Vb = V[:, big] * np.sqrt(lam[big])
    # The gauge (a rotation of the frame and every direction together) in these whitened
    # coordinates; (L4) holds it exactly, so it is left out.
    gauge = (V[:, big] / np.sqrt(lam[big])).T @ prob.gauge_modes(x)[cols]
    Q, _ = np.linalg.qr(gauge, mode="complete")
    return cols, Vb @ Q[:, gauge.shape[1] :]


def _refit_iterative(prob: Problem, x: np.ndarray, free: np.ndarray) -> np.ndarray:
    """``x`` with its ``free`` coordinates refitted to the measurements (the others held), by
    Levenberg-Marquardt from ``x``."""
    n_meas = 3 * prob.N

    def whole(v):
        y = x.copy()
        y[free] = v
        return y

    sol = least_squares(
        lambda v: prob.residuals(whole(v))[:n_meas],
        x[free],
        jac=lambda v: prob.jacobian(whole(v))[:n_meas][:, free],
        method="lm",
        x_scale=1.0,
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=50,
    )
    return whole(sol.x)


def _refit_linear(prob: Problem, X: np.ndarray) -> np.ndarray:
    """:func:`_refit_iterative` of ``(B, K, phi)`` with every direction held, at each row of ``X``
    (n, len(x)). The prediction (L2) is then linear in ``B`` and ``M' = g K^-1 R(phi)^T``::

        W_k (a_k - o_k) = W_k B + W_k M' u_k,      (o_k: the marginalisation's offset)

    one weighted linear least-squares solve (QR) per row; ``R K = g M'^-1`` gives ``K`` and
    ``phi`` back (as :func:`triangular_and_rotation`). NaN rows where that lands on another
    branch than the row (signs of ``K``'s diagonal, the rotation vector's wrap): those are
    for the iterative refit."""
    n, N = len(X), prob.N
    u, _ = sphere_exp(np.tile(prob.u0, (n, 1)), np.tile(prob.T, (n, 1, 1)),
                      X[:, 12:].reshape(n * N, 2))  # fmt: skip
    D = np.zeros((n, N, 3, 12))  # d prediction / d [B | M' row-major], per pose
    D[..., :3] = np.eye(3)
    for i in range(3):
        D[:, :, i, 3 + 3 * i : 6 + 3 * i] = u.reshape(n, N, 3)
    A = np.einsum("kij,nkjc->nkic", prob.W, D).reshape(n, 3 * N, 12)
    y = np.einsum("kij,kj->ki", prob.W, prob.a_n - prob.offset).ravel()
    Q, R = np.linalg.qr(A)
    sol = np.linalg.solve(R, np.swapaxes(Q, 1, 2) @ y[:, None])[..., 0]
    K, Qm = triangular_and_rotation(prob.g * np.linalg.inv(sol[:, 3:].reshape(n, 3, 3)))
    phi = Rotation.from_matrix(Qm).as_rotvec()
    out = X.copy()
    out[:, :3], out[:, 3:9], out[:, 9:12] = sol[:, :3], K[:, _UPPER[0], _UPPER[1]], phi
    other = np.any(np.sign(out[:, 3:6]) != np.sign(X[:, 3:6]), axis=1)  # K's diagonal
    other |= np.linalg.norm(phi - X[:, 9:12], axis=1) > 1
    out[other] = np.nan
    return out


def placement_beyond_first_order(st, public, p_hat: np.ndarray):
    """Eq. (L6): the parameters' covariance from the label-limited placement beyond (L4)'s
    first order, (12, 12), and the number of directions propagated. Each node of
    :func:`symmetric_rule` holds the labelled placements there and refits the rest (bias,
    matrix and the unlabelled poses' directions) to the measurements."""
    prob, x = st.prob, st.sol.x
    cols, V = _label_limited(st)
    m = V.shape[1]
    if m == 0:
        return np.zeros((12, 12)), 0
    held = np.zeros(len(x), bool)
    held[cols] = True
    free = np.flatnonzero(~held)
    nodes, w, a = symmetric_rule(m)
    X = np.tile(x, (len(nodes), 1))
    X[:, cols] += nodes @ V.T
    Y = _refit_linear(prob, X) if len(free) == 12 else np.full(X.shape, np.nan)
    for i in np.flatnonzero(~np.isfinite(Y).all(axis=1)):  # not linear: iteratively
        Y[i] = _refit_iterative(prob, X[i], free)
    Y = public(Y[:, :12]) - p_hat
    G = (Y[1 : 2 * m + 1 : 2] - Y[2 : 2 * m + 1 : 2]) / (2 * a)  # first order, (m, 12)
    extra = (Y * w[:, None]).T @ Y - G.T @ G
    ev, U = np.linalg.eigh((extra + extra.T) / 2)
    return (U * np.clip(ev, 0, None)) @ U.T, m
