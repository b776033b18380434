"""The rotation of the gravity-magnitude solver's 12-parameter variant (:mod:`.gravity`):
gravity magnitude cannot see a rotation of the calibrated frame, so the variant keeps the
9-parameter solution ``M`` and adds the rotation ``R`` that best aligns the calibrated
directions with the labelled ``up`` directions (Wahba's problem), ``matrix = R M``; its
covariance from the scatter of the poses about their labels (the placement errors).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.design.poses import angle_deg
from imucal_cli.errors import DesignError

__all__ = ["LABEL_OUTLIER_DEG", "align_to_labels", "rotation_cov"]


#: A labelled pose further than this from its label (after the alignment) is left out of the
#: alignment: the label is wrong, not the placement.
LABEL_OUTLIER_DEG = 20.0


def align_to_labels(directions, up, variant):
    """Rotation (Wahba) of the calibrated directions onto the labels, its covariance and the
    angle of each pose to its label. Labels far from their pose (a wrong label) are left out
    of the alignment, so one bad label cannot rotate the frame.

    Parameters
    ----------
    directions : ndarray, shape (N, 3)
        Unit calibrated gravity directions of the poses.
    up : ndarray, shape (N, 3), or None
        Labels (NaN rows where unlabelled).
    variant : str
        ``"9"`` or ``"12"``: only the 12-parameter variant needs the rotation.

    Returns
    -------
    R : ndarray, shape (3, 3)
        Identity where fewer than two labels in different directions (variant 9).
    R_cov : ndarray, shape (3, 3), or None
        Covariance of its small-angle rotation vector, rad^2.
    up_angle : ndarray, shape (N,)
        Angle of each aligned pose to its label, degrees (NaN unlabelled).

    Raises
    ------
    DesignError
        Variant 12 without two labelled poses of different ``up``.
    """
    N = len(directions)
    up_angle = np.full(N, np.nan)
    labelled = np.zeros(N, bool) if up is None else np.isfinite(up).all(axis=1)
    if labelled.sum() < 2 or np.linalg.matrix_rank(up[labelled], tol=0.1) < 2:
        if variant == "12":
            raise DesignError(
                "the 12-parameter variant needs at least two labelled poses with different `up` "
                'directions; label the poses or use model = "9"'
            )
        return np.eye(3), None, up_angle
    use = labelled.copy()
    for _ in range(3):
        rot, _ = Rotation.align_vectors(up[use], directions[use])
        ang = angle_deg(directions @ rot.as_matrix().T, np.where(labelled[:, None], up, 1.0))
        keep = labelled & (ang <= max(LABEL_OUTLIER_DEG, 5 * np.median(ang[labelled])))
        if keep.sum() < 2 or np.linalg.matrix_rank(up[keep], tol=0.1) < 2 or (keep == use).all():
            break
        use = keep
    R = rot.as_matrix()
    aligned = directions @ R.T
    up_angle[labelled] = angle_deg(aligned[labelled], up[labelled])
    return R, rotation_cov(aligned[use], up[use]), up_angle


def rotation_cov(aligned: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Covariance (rad^2) of the small rotation aligning calibrated directions to labels.

    Each pose constrains the rotation in the two directions perpendicular to it; the scatter
    of the residual angles (placement errors) gives the per-pose variance.
    """
    e = np.cross(aligned, up)  # small-angle residual rotation vectors
    n = len(up)
    dof = max(2 * n - 3, 1)
    var = float(np.sum(e * e)) / dof
    info = sum(np.eye(3) - np.outer(u, u) for u in up)
    return var * np.linalg.pinv(info)
