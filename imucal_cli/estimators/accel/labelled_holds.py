"""Holds that are one placement, for the labelled-pose solver (:mod:`.labelled`; issue 24.6).

A turn on the table about the vertical (a Ferraris capture's 360-degree turns) leaves the
unit's gravity where it was in its own frame: the hold before the turn and the hold after
it see the same up, one draw of the placement (L1b), not two. Taken as two holds on one face,
their agreement reads as a hold part far smaller than the repeats of a face otherwise show,
the face part takes the rest, and the frame's std shrink: over 140 simulated Ferraris
captures the frame's rotation ``r`` was covered by 88-92 % of its 95 % intervals (RMS
error/std 1.12-1.23).

Consecutive labelled holds with the same label whose mean readings agree within their
noise (``d^T (C_k + C_run)^-1 d`` against ``chi^2(3)`` at :data:`ONE_PLACEMENT_ALPHA`,
``d`` the hold's mean minus the run's so far) are one run; the fit takes each run as one pose:
the information-weighted mean ``a_run = C_run sum_k C_k^-1 a_k``, ``C_run = (sum_k
C_k^-1)^-1`` (the pooled noise over all their samples), and every hold gets its run's results
back (:func:`expand`). Holds placed again by hand sit a placement apart (degrees against the
noise's hundredths): they stay apart.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.special import chdtrc

from imucal_cli.design.outliers import Deletion

#: Two holds whose means differ by a chi^2(3) this improbable were placed apart.
ONE_PLACEMENT_ALPHA = 1e-3


@dataclass(frozen=True)
class Runs:
    """Consecutive holds taken as one placement.

    Attributes
    ----------
    index : ndarray of int, shape (N,)
        Run of each hold.
    a_mean : ndarray, shape (R, 3)
        Each run's mean raw reading, raw units.
    cov_mean : ndarray, shape (R, 3, 3)
        Its covariance, raw units^2.
    up : ndarray, shape (R, 3)
        Its label (NaN unlabelled).
    weights : ndarray, shape (N, 3, 3)
        ``d a_run / d a_k = C_run C_k^-1`` of each hold.
    """

    index: np.ndarray
    a_mean: np.ndarray
    cov_mean: np.ndarray
    up: np.ndarray
    weights: np.ndarray

    @property
    def merged(self) -> bool:
        """Whether some run holds more than one hold."""
        return len(self.a_mean) < len(self.index)


def one_placement_runs(a_mean: np.ndarray, cov_mean: np.ndarray, up: np.ndarray,
                       alpha: float = ONE_PLACEMENT_ALPHA) -> Runs:
    """The runs of ``N`` holds in time order (module docstring): ``a_mean`` (N, 3) raw units,
    ``cov_mean`` (N, 3, 3) raw units^2, ``up`` (N, 3) labels (NaN rows unlabelled)."""
    a_mean, cov_mean, up = (np.asarray(v, float) for v in (a_mean, cov_mean, up))
    try:
        info = np.linalg.inv(cov_mean)
    except np.linalg.LinAlgError:  # a noiseless axis: each hold its own (the fit says why)
        n = len(a_mean)
        return Runs(np.arange(n), a_mean, cov_mean, up, np.broadcast_to(np.eye(3), (n, 3, 3)))
    index = np.zeros(len(a_mean), dtype=int)
    runs: list[list[int]] = []
    for k in range(len(a_mean)):
        last = runs[-1] if runs else None
        if last is not None and np.isfinite(up[k]).all() and np.allclose(up[k], up[last[0]]):
            C = np.linalg.inv(info[last].sum(axis=0))
            m = C @ np.einsum("nij,nj->i", info[last], a_mean[last])
            d = a_mean[k] - m
            if chdtrc(3, float(d @ np.linalg.solve(cov_mean[k] + C, d))) >= alpha:
                last.append(k)
                index[k] = len(runs) - 1
                continue
        runs.append([k])
        index[k] = len(runs) - 1
    C_run = np.array([np.linalg.inv(info[r].sum(axis=0)) for r in runs])
    a_run = np.array([C @ np.einsum("nij,nj->i", info[r], a_mean[r])
                      for C, r in zip(C_run, runs, strict=True)])  # fmt: skip
    weights = np.einsum("nij,njk->nik", C_run[index], info)
    return Runs(index, a_run, C_run, up[[r[0] for r in runs]], weights)


def expand(res, runs: Runs, a_mean: np.ndarray, g: float):
    """The labelled result ``res`` of the runs, for each of the ``N`` holds: the run's
    direction, label angle, deletion statistics (leaving a hold out is tested as leaving its
    run out) and held-out residual; its own calibrated mean's residuals; the placement's prior
    rows on the run's first hold (its other holds 0, tied to it)."""
    idx = runs.index
    h = (np.asarray(a_mean, float) - res.bias) @ res.matrix.T
    u = res.directions[idx]
    first = np.array([np.flatnonzero(idx == r)[0] for r in range(len(runs.a_mean))])
    is_first = np.zeros(len(idx), bool)
    is_first[first] = True
    members = [np.flatnonzero(idx == r).tolist() for r in range(len(first))]

    def spread(v):  # the run's value on its first hold, 0 on the others (NaN unlabelled)
        return np.where(is_first | ~np.isfinite(v[idx]), v[idx], 0.0)

    tied = [sorted({*members[idx[k]], *(m for t in res.placement_tied[idx[k]]
                                        for m in members[t])} - {k})
            for k in range(len(idx))]  # fmt: skip
    d = res.deletion
    return replace(
        res,
        residuals=np.linalg.norm(h, axis=1) - g,
        residual_vectors=h - g * u,
        directions=u,
        up_angle_deg=res.up_angle_deg[idx],
        residual_loo=res.residual_loo[idx],
        deletion=Deletion(d.dx[idx], d.T[idx], d.rank[idx], d.chi2, d.dof),
        placement_sq=spread(res.placement_sq),
        placement_redundancy=spread(res.placement_redundancy),
        placement_tied=tied,
        fit=None if res.fit is None else replace(res.fit, runs=runs),
    )
