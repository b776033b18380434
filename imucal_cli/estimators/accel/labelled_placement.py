"""The placement of the labelled-pose solver (:mod:`.labelled`) in two parts (issue 24.5).

A pose's true up is off its label by the face's own deviation, shared by every pose held on
that face (the face is not square to the sensor's frame: a case, a mount, a block), and by the
hold's (the table's tilt at its heading, how it sat)::

    delta_k = delta_f(k) + eta_k,  delta_f ~ N(0, sigma_f^2 I_2),  eta_k ~ N(0, sigma_h^2 I_2)

(L1b), so that the placements of the poses on one face of ``m`` poses have the covariance
``C = sigma_f^2 1 1^T + sigma_h^2 I`` (per angle). Where every label is held once the two
parts are one (``sigma_p^2 = sigma_f^2 + sigma_h^2``) and the solver keeps the single
placement; where a face is held again (MaD Lab's Ferraris session: +X four times, +Y and +Z
three times) its repeats agree to a few hundredths of a degree while the faces sit tenths off
their labels, and placements taken as independent count each repeat as a new look at its
face's deviation: the frame leans to the faces held most, and the stated std shrink as if the
repeats were independent (73 % of the 95 % intervals held the truth in simulated sessions of
that design).

Both parts are variance components of the prior rows, estimated by REML (Foerstner's
iteration, :func:`placement_parts`); each parameter's interval takes the degrees of freedom of
each part's estimate (:func:`placement_split`: the face's rests on the faces, six on a cube).
"""

from __future__ import annotations

import numpy as np

from .labelled_model import Problem

#: Placement error (RMS angle, degrees) assumed when the data cannot estimate it.
DEFAULT_PLACEMENT_DEG = 2.0
#: The placement estimate never goes below this (a perfect fixture), degrees.
MIN_PLACEMENT_DEG = 1e-3


def _blocks(prob: Problem, P: np.ndarray):
    """The labelled placements' columns of ``x``, the prior's covariance ``C`` (2L, 2L), its
    face structure ``V_f``, ``C^-1`` and the covariance of the prior rows' residuals ``Q = C -
    P_dd`` (``P`` the posterior covariance of ``x``)."""
    cols = (12 + 2 * prob.lab[:, None] + np.arange(2)).ravel()
    C, Vf = prob.placement_covariance()
    Ci = np.linalg.inv(C)
    return cols, Vf, Ci, C - P[np.ix_(cols, cols)]


def placement_parts(prob: Problem, x: np.ndarray, P: np.ndarray) -> tuple[float, float]:
    """One step of the two variance components (L1b), ``(sigma_f, sigma_h)`` rad per angle:
    each scaled by the ratio of the prior residuals' quadratic form to its expectation,
    ``(d^T C^-1 V_i C^-1 d) / tr(C^-1 V_i C^-1 Q)`` (``d`` the placements at ``x``, ``V_i``
    the face indicator or the identity); a fixed point is REML's estimate, and one component
    alone gives Helmert's ``|d|^2 / r_p``."""
    cols, Vf, Ci, Q = _blocks(prob, P)
    Cd = Ci @ x[cols]
    out = []
    for theta, V in ((prob.sigma_f**2, Vf), (prob.sigma_h**2, np.eye(len(cols)))):
        den = float(np.sum((Ci @ V @ Ci) * Q))
        out.append(theta * float(Cd @ V @ Cd) / den if den > 0 and theta > 0 else theta)
    floor = (np.radians(MIN_PLACEMENT_DEG) / np.sqrt(2)) ** 2
    return float(np.sqrt(max(out[0], floor * 1e-6))), float(np.sqrt(max(out[1], floor)))


def placement_split(prob: Problem, P: np.ndarray, T: np.ndarray):
    """Each part's share of every parameter's variance, and the degrees of freedom of each
    part's estimate: ``((v_face, nu_face), (v_hold, nu_hold))``, ``v`` shape (12,).

    The prior rows weigh the placements by ``C^-1 = C^-1 (s_f^2 V_f + s_h^2 I) C^-1``: each
    term is its part's share (``T`` the public parameters' Jacobian). A part estimated from the
    quadratic form ``q = d^T A d`` (``A = C^-1 V C^-1``) of Gaussian residuals of covariance
    ``Q`` has ``E q = tr(A Q)`` and ``var q = 2 tr(A Q A Q)``, so ``nu = tr(A Q)^2 / tr(A Q A
    Q)`` (one part alone: the prior rows' redundancy)."""
    cols, Vf, Ci, Q = _blocks(prob, P)
    G = T @ P[cols, :12].T  # the public parameters' change per unit weight of each placement
    out = []
    for theta, V in ((prob.sigma_f**2, Vf), (prob.sigma_h**2, np.eye(len(cols)))):
        A = Ci @ V @ Ci
        AQ = A @ Q
        nu = float(np.trace(AQ) ** 2 / max(np.sum(AQ * AQ.T), 1e-300))
        out.append((np.diag(G @ (theta * A) @ G.T), max(nu, 1.0)))
    return out


def part_deg(prob: Problem, sigma: float, source: str) -> float | None:
    """A part of the placement as an RMS angle, degrees; None where the placement was not
    split (no face holds two labelled poses, or it was given)."""
    if source != "estimated" or not prob.repeated or prob.sigma_f == 0.0:
        return None
    return float(np.degrees(sigma) * np.sqrt(2))


def interval_dof(parts: dict, placement_dof: float, source: str, noise_dof: float, split=None):
    """Effective degrees of freedom of each parameter's variance (Satterthwaite): the
    measurement part rests on ``noise_dof``, the placement part on the prior's redundancy, or,
    split into its face and hold parts (:func:`placement_split`), each on its own (the
    second-order part shared in their proportion).

    Parameters
    ----------
    parts : dict
        The covariance by where it comes from (:attr:`.labelled.LabelledResult.cov_parts`):
        ``"measurement"``, ``"placement"``, ``"placement_second_order"``, (12, 12) each.
    placement_dof : float
        Redundancy of the prior rows.
    source : str
        Where the placement came from: only an ``"estimated"`` one is uncertain.
    noise_dof : float
        Degrees of freedom of the pooled noise estimate.
    split : tuple, optional
        :func:`placement_split`'s ``((v_face, nu_face), (v_hold, nu_hold))``.

    Returns
    -------
    ndarray, shape (12,)
        At least 1; ``inf`` where the variance is known.
    """
    v_meas = np.diag(parts["measurement"])
    v_place = np.diag(parts["placement"]) + np.diag(parts["placement_second_order"])
    with np.errstate(divide="ignore", invalid="ignore"):
        if split is None:
            nu_p = placement_dof if source == "estimated" else np.inf
            spread = v_place**2 / nu_p
        else:
            (v_f, nu_f), (v_h, nu_h) = split
            k = np.where(v_f + v_h > 0, v_place / (v_f + v_h), 1.0)
            spread = (k * v_f) ** 2 / nu_f + (k * v_h) ** 2 / nu_h
        t_dof = (v_meas + v_place) ** 2 / (spread + v_meas**2 / noise_dof)
    return np.where(np.isfinite(t_dof), np.maximum(t_dof, 1.0), np.inf)
