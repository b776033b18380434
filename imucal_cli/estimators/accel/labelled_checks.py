"""The labels of the labelled-pose solver (:mod:`.labelled`) checked against its fit: each
labelled pose's prior rows (their residuals, redundancy, the poses they are tied to) and the
groups of poses whose placement disagrees with the others' (a label off by degrees: the unit on
a wedge, the wrong face named; issue 24.6)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.special import chdtrc, fdtrc

from .labelled_placement import DEFAULT_PLACEMENT_DEG

if TYPE_CHECKING:
    from .labelled import LabelledResult


def placement_rows(J: np.ndarray, r: np.ndarray, N: int, labelled: np.ndarray) -> dict:
    """Each labelled pose's prior rows (L3): their squared residuals ``|delta_k|^2 /
    sigma_p^2`` and redundancy (``1 - h`` summed over its two rows: 0 where the labels alone
    fix the pose's direction, 2 where the data do), and the poses whose placement residuals
    are tied to its own (the correlation of the rows' residuals, ``I - H``, at least
    :data:`TIED`: opposite faces of six, whose disagreement the fit shares between them);
    NaN or empty for unlabelled poses. ``J``, ``r``: the fit's whitened Jacobian and residuals
    at its end (``3 N`` measurement rows, then two prior rows per labelled pose)."""
    e = r[3 * N :].reshape(-1, 2)
    Q, _ = np.linalg.qr(J)
    Qp = Q[3 * N :]
    C = np.eye(len(Qp)) - Qp @ Qp.T  # covariance of the prior rows' residuals (unit noise)
    L = len(e)
    sq = np.full(N, np.nan)
    red = np.full(N, np.nan)
    lab = np.flatnonzero(labelled)
    sq[lab] = np.sum(e**2, axis=1)
    red[lab] = np.clip(np.diag(C), 0, 1).reshape(L, 2).sum(axis=1)
    d = np.sqrt(np.clip(np.diag(C), 1e-300, None))
    R = np.abs(C / np.outer(d, d)).reshape(L, 2, L, 2).max(axis=(1, 3))
    tied = [[] for _ in range(N)]
    for i, k in enumerate(lab):
        tied[k] = [int(lab[j]) for j in np.flatnonzero(R[i] >= TIED) if j != i]
    return {"placement_sq": sq, "placement_redundancy": red, "placement_tied": tied}


#: Placement residuals of two poses correlated at least this much are one group: the fit
#: cannot tell which of them is off.
TIED = 0.5
#: A group whose placement test against the rest's spread reaches only this family-wise
#: p-value is named when it also sits off by more than a hand placement allows.
MARGINAL = 0.05


def placement_outliers(res: LabelledResult, *, alpha: float = 0.01,
                       min_redundancy: float = 0.3,
                       min_deg: float = 3.0) -> list[tuple[list[int], float]]:
    """Groups of poses whose placement disagrees with the others' (a label off by degrees:
    the unit on a wedge, the wrong face named), worst first, with their family-wise p-values.

    A labelled pose and the poses tied to it (:data:`TIED`; one pose where the design can
    attribute the disagreement, both faces of a pair on six faces) are tested against the
    placement spread of the rest (Helmert, without the group's rows): ``F = (S_G / R_G) /
    (S_rest / R_rest)`` with ``S`` the squared prior residuals and ``R`` their redundancy,
    against ``F(R_G, R_rest)``, Bonferroni over the groups; where that test is marginal (the
    rest's spread rests on few equations: 4 on six faces), up to :data:`MARGINAL`, the group
    is also named when it sits off its labels by more than a hand placement
    (:data:`DEFAULT_PLACEMENT_DEG` RMS) allows at ``alpha``. Where the config states the
    placement (``[accel.labelled] placement_deg``) it is trusted: ``S_G`` against
    ``chi^2(R_G)``. A group whose rows are nearly all
    leverage (redundancy below ``min_redundancy``) cannot be judged: the design cannot
    tell. A group whose placement comes to less than ``min_deg`` (the root sum of its poses'
    squared angles to their labels) is not named however well the rest sits: a degree is a
    hand's placement, not a wrong label (MaD Lab's session B: its +-Z faces 0.7 deg off where
    the others sit within 0.1)."""
    sq, red, tied = res.placement_sq, res.placement_redundancy, res.placement_tied
    lab = np.flatnonzero(np.isfinite(sq))
    if len(lab) < 3 or res.placement_dof < 2:
        return []
    S, R = float(np.nansum(sq)), res.placement_dof
    given = res.placement_source == "config"  # the stated placement: trusted, a chi^2 test
    groups = sorted({tuple(sorted({int(k), *tied[k]})) for k in lab})
    out = []
    for grp in groups:
        idx = list(grp)
        S_G, R_G = float(np.sum(sq[idx])), float(np.sum(red[idx]))
        R_rest = R - R_G
        if R_G < min_redundancy or (not given and (R_rest < 1 or S - S_G <= 0)):
            continue
        n = len(groups)
        if given:
            p = min(float(chdtrc(R_G, S_G)) * n, 1.0)
        else:
            p = min(float(fdtrc(R_G, R_rest, (S_G / R_G) / ((S - S_G) / R_rest))) * n, 1.0)
            # the rest's spread rests on few equations (six faces: 4): a group off by more
            # than a hand placement allows (DEFAULT_PLACEMENT_DEG) is named at MARGINAL
            hand = S_G * (res.placement_deg / DEFAULT_PLACEMENT_DEG) ** 2
            if p >= alpha and p < MARGINAL and float(chdtrc(R_G, hand)) * n < alpha:
                p = alpha * 0.999
        size = float(np.sqrt(np.nansum(res.up_angle_deg[idx] ** 2)))
        if p < alpha and size >= min_deg:
            out.append((idx, p))
    return sorted(out, key=lambda gp: gp[1])
