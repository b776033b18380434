"""How a labelled-pose fit (:mod:`.labelled`) follows each pose's mean reading: what a set of
IMUs held in the same poses needs for the rotations between their calibrations
(``docs/imu-set.md``, eq. R3; issue 28). Computed only where a set asks for it: a fit of one
IMU never does.

The fit minimises ``|r(x)|^2 / 2`` over ``x = (theta, delta)`` (eq. L3), its measurement rows
``r_k = W_k (a_k - prediction_k) / (scale s)``. A change ``da_k`` of pose k's mean moves the
optimum, the labels' prior held, by (the implicit function theorem at the optimum)::

    dx = -(J^T J + sum_i r_i d^2 r_i / dx^2)^-1 J_k^T (d r_k / d a_k) da_k,          (L7)

``J_k`` pose k's rows of the Jacobian. The residuals' curvature is not Gauss-Newton's to leave
out here: along the frame's rotation only the labels hold the fit, as weakly as the curvature
of the predictions times residuals of the noise's size, so leaving it out misstates how the
frame follows the noise by a part that grows with the placement. ``sum_k L_k cov_k L_k^T`` is
the measurement part of the parameters' covariance (``cov_parts["measurement"]``, times
``noise_scale``) and ``L_k cov_k`` their covariance with pose k's mean.
"""

from __future__ import annotations

import numpy as np

from .labelled import DENSE_MAX_POSES, LabelledResult

__all__ = ["pose_response"]

#: Step of the central differences of the Jacobian (normalised coordinates, all O(1)).
CURVATURE_STEP = 1e-6


def pose_response(res: LabelledResult) -> np.ndarray:
    """``L_k = d params / d a_k`` (12, N, 3), eq. L7: each of :data:`.labelled.PARAM_NAMES`'
    first-order change per raw unit of each pose's mean reading, the placement's prior held,
    at the fit's end (above :data:`.labelled.DENSE_MAX_POSES` poses without the residuals'
    curvature).

    Raises
    ------
    ValueError
        ``res`` does not carry its fit's end (``res.fit`` is None).
    """
    if res.fit is None:
        raise ValueError("the labelled result carries no fit to differentiate")
    st, T, scale = res.fit.state, res.fit.T, res.fit.scale
    prob, x, r = st.prob, st.sol.x, st.r
    hess = st.J.T @ st.J
    if prob.N <= DENSE_MAX_POSES:
        curv = np.empty((len(x), len(x)))
        h = CURVATURE_STEP
        for j in range(len(x)):
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            curv[:, j] = (prob.jacobian(xp) - prob.jacobian(xm)).T @ r / (2 * h)
        hess = hess + (curv + curv.T) / 2
    n_meas = 3 * prob.N
    JmW = st.J[:n_meas].reshape(prob.N, 3, -1)  # rows of pose k
    dr_da = prob.W / (prob.meas_scale * scale)  # (N, 3, 3): d r_k / d a_k, raw units
    g = np.einsum("nrc,nrj->cnj", JmW, dr_da).reshape(len(x), -1)
    dx_da = -np.linalg.solve(hess, g)[:12].reshape(12, prob.N, 3)
    L = np.einsum("pk,knj->pnj", T, dx_da)
    runs = res.fit.runs
    if runs is None:
        return L
    # holds fitted as one run (:mod:`.labelled_holds`): d a_run / d a_k = C_run C_k^-1
    return np.einsum("pnj,njk->pnk", L[:, runs.index], runs.weights)
