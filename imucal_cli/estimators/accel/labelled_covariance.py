"""The parameters of the labelled-pose solver (:mod:`.labelled`) at the fit's end and their
covariance by where it comes from: the measurement and first-order placement parts of (L4),
the curvature of the sensitivities and angles in ``K`` (second order) and the placement beyond
first order (L6, :mod:`.labelled_beyond`). ``st`` below is the fit's end (:class:`.labelled.
_State`: its problem, ``sol.x``, ``P = (J^T J)^-1``, whitened Jacobian ``J``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .gravity import _UPPER
from .labelled_beyond import placement_beyond_first_order
from .labelled_model import axes, public_from_theta, second_order

if TYPE_CHECKING:
    from .labelled import _State

__all__ = ["covariance_parts", "public_of_normalised"]


def public_of_normalised(offset: np.ndarray, scale: float):
    """The map from normalised ``x`` (n, 12) (bias, ``K`` upper and ``r`` rad, in the fit's
    raw coordinates ``(raw - offset) / scale``) to :data:`.labelled.PARAM_NAMES` (n, 12)."""

    def public(v):  # public parameters of normalised x (n, 12): (B raw, K raw, r deg) first
        v = np.atleast_2d(v)
        return public_from_theta(
            np.concatenate([offset + scale * v[:, :3], v[:, 3:9] / scale,
                            np.degrees(v[:, 9:12])], axis=1)
        )  # fmt: skip

    return public


def covariance_parts(
    st: _State, public, T: np.ndarray, beyond_first_order: bool
) -> tuple[np.ndarray, dict, int]:
    """The public parameters at the fit's end, their covariance by where it comes from and the
    number ``m`` of label-limited placement directions propagated (eq. L6).

    Parameters
    ----------
    st : _State
        The fit's end.
    public : callable
        :func:`public_of_normalised` of the fit's normalisation.
    T : ndarray, shape (12, 12)
        ``public``'s Jacobian at ``st.sol.x[:12]``.
    beyond_first_order : bool
        Whether to propagate the label-limited placement through refits (L6); without it
        (many poses: :data:`.labelled.DENSE_MAX_POSES`) ``m = 0``.

    Returns
    -------
    params : ndarray, shape (12,)
    parts : dict
        ``"measurement"``, ``"placement"`` (first order: the two sum to ``T P T^T``, (L4)) and
        ``"placement_second_order"``, (12, 12) each, public units squared.
    m : int
    """
    prob, x12 = st.prob, st.sol.x[:12]
    n_meas = 3 * prob.N
    Pt = st.P[:, :12]
    Jm, Jp = st.J[:n_meas], st.J[n_meas:]
    parts = {
        "measurement": T @ (Pt.T @ Jm.T @ Jm @ Pt) @ T.T,
        "placement": T @ (Pt.T @ Jp.T @ Jp @ Pt) @ T.T,  # the two sum to T P T^T
    }
    # Second order: the sensitivities and angles are curved functions of K, whose cross-axis
    # terms the labels (not the data) fix on six faces: add that variance (unless the
    # placement's propagation (L6) below, which includes it, runs). Its mean is not removed
    # (module notes: removing it biased the saved gains).
    axes_of = lambda k: axes(_matrices(k))  # noqa: E731
    _, extra2 = second_order(axes_of, x12[3:9], st.P[3:9, 3:9], many=True)
    params = public(x12)[0]
    extra, m = (placement_beyond_first_order(st, public, params) if beyond_first_order
                else (np.zeros((12, 12)), 0))  # fmt: skip
    if m == 0:
        extra[3:9, 3:9] += extra2
    parts["placement_second_order"] = extra
    return params, parts, m


def _matrices(k: np.ndarray) -> np.ndarray:
    """``K^-1`` of each row of upper-triangle entries ``k`` (n, 6): (n, 3, 3)."""
    K = np.zeros((len(k), 3, 3))
    K[:, _UPPER[0], _UPPER[1]] = k
    return np.linalg.inv(K)
