"""The start of the labelled-pose solver (:mod:`.labelled`): with every placement ``delta_k =
0`` the model (L2) is linear in the bias and sensitivity, one least-squares solve over the
labelled poses (no nominal sensitivity needed; issue 10.1); and the labels that start
contradicts (a pose labelled with the wrong face; issue 10.6)."""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import DesignError

__all__ = ["contradicted_labels", "init_linear"]


def init_linear(a_mean: np.ndarray, up: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form start: (L2) with every ``delta = 0`` is linear in ``(B, S)``.

    Parameters
    ----------
    a_mean : ndarray, shape (N, 3)
        Pose means, raw units.
    up : ndarray, shape (N, 3)
        Labels (NaN rows where unlabelled; those poses are not used).
    g : float
        Gravity, m/s^2.

    Returns
    -------
    B : ndarray, shape (3,)
    S : ndarray, shape (3, 3)
        Raw units per m/s^2.

    Raises
    ------
    DesignError
        The labelled directions do not span the affine space ``[1, up]`` (fewer than four
        labels not in one plane): bias and sensitivity cannot be told apart.
    """
    lab = np.isfinite(up).all(axis=1)
    X = np.column_stack([np.ones(lab.sum()), g * up[lab]])  # a_k^T = [1, g up_k^T] [B; S^T]
    if np.linalg.matrix_rank(X, tol=1e-6 * g) < 4:
        raise DesignError(
            f"{int(lab.sum())} labelled poses whose up directions lie in one plane cannot tell "
            "bias from sensitivity"
        )
    sol, *_ = np.linalg.lstsq(X, a_mean[lab], rcond=None)
    return sol[0], sol[1:].T


def contradicted_labels(
    a_mean: np.ndarray, up: np.ndarray, g: float, limit_deg: float = 20.0, max_fraction=0.25
) -> list[tuple[int, float]]:
    """Labelled poses whose reading contradicts their label (issue 10.6: a pose labelled with
    the wrong face): each labelled pose is predicted by the linear start (:func:`init_linear`)
    of the others; the pose furthest from its label, if further than ``limit_deg``, is taken
    out and the test repeated (at most ``max_fraction`` of the labels).

    Returns
    -------
    list of (index, angle_deg)
        The contradicted poses and the angle between their measured and labelled up.
    """
    up = np.array(up, dtype=float)
    found: list[tuple[int, float]] = []
    n_lab = int(np.isfinite(up).all(axis=1).sum())
    while len(found) < max(1, int(max_fraction * n_lab)):
        lab = np.flatnonzero(np.isfinite(up).all(axis=1))
        worst, worst_angle = -1, limit_deg
        for k in lab:
            others = up.copy()
            others[k] = np.nan
            try:
                B, S = init_linear(a_mean, others, g)
                u = np.linalg.solve(S, a_mean[k] - B)
            except (DesignError, np.linalg.LinAlgError):
                continue
            cos = float(u @ up[k] / max(np.linalg.norm(u), 1e-300))
            angle = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
            if angle > worst_angle:
                worst, worst_angle = int(k), angle
        if worst < 0:
            break
        found.append((worst, worst_angle))
        up[worst] = np.nan
    return found
