"""Which poses disagree with the rest: deletion diagnostics of a weighted least-squares fit.

For a fit with whitened residuals ``r`` (unit variance when the weights are right) and
Jacobian ``J`` at the solution, deleting the rows ``k`` of one pose changes the parameters by
(to first order, exact for a linear model)::

    dx_k = P J_k^T (I - H_kk)^+ r_k,       P = (J^T J)^-1,  H_kk = J_k P J_k^T,

and lowers the sum of squares by the pose's studentized statistic::

    T_k = r_k^T (I - H_kk)^+ r_k  ~  chi^2(rank(I - H_kk))   if the pose agrees with the rest.

``T_k`` is tested against the measured noise, scaled by ``s^2``, an estimate of the residual
variance (>= 1) so that a recording whose noise is a little above what its holds show
(correlated noise, a slightly nonlinear part) does not flag every pose, while one bad pose
cannot hide. ``s^2`` is the smaller of two estimates: the median of ``T_k`` over the median of
``chi^2(rank_k)``, which one bad pose of ordinary leverage does not move; and the variance
left once the worst pose is deleted, ``(chi^2 - T_max) / (dof - rank_max)``, for a bad pose
of high leverage (a bumped edge pose of Qureshi's 18) that drags the fit and with it every
other pose's ``T_k``. The threshold is Bonferroni over the poses.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.special import chdtrc, chdtri

#: Family-wise probability of flagging a pose of a good session.
OUTLIER_ALPHA = 1e-3


@dataclass(frozen=True)
class Deletion:
    """Deletion diagnostics of every pose.

    Attributes
    ----------
    dx : ndarray, shape (N, p)
        Change of the parameter vector when the pose is left out.
    T : ndarray, shape (N,)
        Studentized statistic (chi^2 drop when the pose is left out), in units of the
        measured noise.
    rank : ndarray of int, shape (N,)
        Its degrees of freedom (0: the pose cannot be checked: nothing else determines it).
    chi2 : float
        The whole fit's sum of squared whitened residuals (NaN: not known).
    dof : int
        Its degrees of freedom (equations minus parameters).
    """

    dx: np.ndarray
    T: np.ndarray
    rank: np.ndarray
    chi2: float = float("nan")
    dof: int = 0


def deletion(J: np.ndarray, r: np.ndarray, groups: list[np.ndarray], P: np.ndarray) -> Deletion:
    """Deletion diagnostics (module docstring) of the row groups of a whitened fit."""
    N, p = len(groups), J.shape[1]
    whole = dict(chi2=float(r @ r), dof=len(r) - p)
    sizes = np.array([len(g) for g in groups], dtype=int)
    if N and np.all(sizes == sizes[0]):
        return replace(_deletion_batched(J, r, np.array(groups), P), **whole)
    dx = np.zeros((N, p))
    T = np.zeros(N)
    rank = np.zeros(N, dtype=int)
    for size in np.unique(sizes):  # the groups of each size at once
        which = np.flatnonzero(sizes == size)
        if size == 0:
            continue
        part = _deletion_batched(J, r, np.array([groups[k] for k in which]), P)
        dx[which], T[which], rank[which] = part.dx, part.T, part.rank
    return Deletion(dx, T, rank, **whole)


def _deletion_batched(J: np.ndarray, r: np.ndarray, idx: np.ndarray, P: np.ndarray) -> Deletion:
    """:func:`deletion` for groups of equal size, all at once (idx: (N, L) row indices)."""
    Jg = J[idx]  # (N, L, p)
    L = idx.shape[1]
    JgP = Jg @ P.T  # (P J_k^T)^T
    A = np.eye(L) - JgP @ np.swapaxes(Jg, 1, 2)  # I - H_kk, transposed (symmetrised below)
    w, V = np.linalg.eigh(0.5 * (A + np.swapaxes(A, 1, 2)))
    keep = w > 1e-8
    z = np.einsum("nij,ni->nj", V, r[idx])
    zw = np.where(keep, z / np.where(keep, w, 1.0), 0.0)
    T = np.sum(z * zw, axis=1)
    dx = np.einsum("nip,ni->np", JgP, np.einsum("nij,nj->ni", V, zw))  # P J_k^T V (z / w)
    return Deletion(dx, T, keep.sum(axis=1))


def noise_excess(d: Deletion) -> float:
    """Robust factor by which the residual variance exceeds the measured noise (>= 1): the
    smaller of the median of ``T_k`` over the median of ``chi^2(rank_k)`` and, where the
    fit's ``chi2`` and ``dof`` are known, the variance left without the worst pose (module
    docstring)."""
    T, rank = d.T, d.rank
    ok = rank > 0
    if ok.sum() < 3:
        return 1.0
    medians = chdtri(rank[ok].astype(float), 0.5)
    s2 = float(np.median(T[ok]) / np.median(medians))
    worst = int(np.argmax(np.where(ok, T, -np.inf)))
    rest_dof = d.dof - int(rank[worst])
    if np.isfinite(d.chi2) and rest_dof > 0:
        s2 = min(s2, max(d.chi2 - float(T[worst]), 0.0) / rest_dof)
    return float(max(1.0, s2))


def flag(d: Deletion, alpha: float = OUTLIER_ALPHA) -> np.ndarray:
    """Poses whose statistic exceeds the Bonferroni threshold, worst first (indices)."""
    ok = d.rank > 0
    if not ok.any():
        return np.zeros(0, dtype=int)
    limit = np.full(len(d.T), np.inf)
    limit[ok] = chdtri(d.rank[ok].astype(float), alpha / ok.sum())
    ratio = d.T / (noise_excess(d) * limit)
    bad = np.flatnonzero(ratio > 1.0)
    return bad[np.argsort(-ratio[bad])]


def significance(d: Deletion, k: int) -> float:
    """Family-wise p-value of pose ``k``'s statistic among the poses that can be checked
    (Bonferroni), against the noise scaled by :func:`noise_excess`; a pose that cannot be
    checked (rank 0: flagged for another reason) is tested as one degree of freedom."""
    n = int(np.sum(d.rank > 0)) or 1
    rank = max(int(d.rank[k]), 1)
    return float(min(1.0, n * chdtrc(rank, d.T[k] / noise_excess(d))))
