"""Factorization-based calibration (Hwangbo & Kanade, sections II-IV).

Each of the n sensor elements of a unit follows the affine model ``z = f^T s_j + b_j`` (eq. 2),
so m motions give the measurement matrix

    Z = [F 1] [S; b^T] = F_b S_b        (m x n) = (m x p)(p x n),          (3)-(5)

with ``F`` the motions (m x 3), ``S = [s_1 ... s_n]`` the sensitivity axes (3 x n) and ``b`` the
biases. A rank-p SVD of ``Z`` gives ``F_b`` and ``S_b`` up to an invertible p x p matrix ``A``
(eqs. 7-12); inner-product constraints between the true motions, ``f_i^T f_k = h_ik`` (eq. 15),
fix ``A`` up to a rotation (the metric upgrade):

* redundant units (n >= 4, p = 4): ``a4`` from eq. (18), ``Q = A13 A13^T`` from the linear
  system (20)-(22), ``C = chol(Q0)``, ``u = C^-1 q1`` (23)-(26);
* triads (n = p = 3): biases known beforehand (eq. 14 for accelerometers, still periods for
  gyroscopes), ``D = Z - b`` (eq. 13) and ``A = chol(Q)`` (27)-(28);
* magnitude-only constraints: ``q = q_p + alpha q_n`` with alpha from the quartic
  ``det Q(alpha) = 0`` (eqs. 24, 29); orthogonality-only: ``q = beta q_n`` with beta from one
  known rotation (eqs. 30-31).

:func:`refine` then minimises the constraint errors over every parameter, biases included
(section IV-C), weighted so that it is the first-order maximum-likelihood estimate.

Motions are in the units of ``h`` (gravity-normalised for accelerometers: ``h_ii = 1``; rad/s
for gyroscopes). The calibration is ``f = T (z - b)`` with ``T = [S^T]^+`` (3 x n).

This module holds the linear solution (:func:`factorize`) and the rotation gauge (:func:`align`);
the inputs and result are :mod:`.factorization_model`'s, :func:`refine`
:mod:`.factorization_refine`'s (all importable from here).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigvals

from imucal_cli.errors import DesignError
from imucal_cli.estimators.ellipsoid import fit_ellipsoid
from imucal_cli.estimators.factorization_model import (
    Constraints,
    FactorizationResult,
    ScaleReference,
    constraint_rms,
    right_handed,
)
from imucal_cli.estimators.factorization_refine import estimate_fixture_tolerance, refine

__all__ = [
    "Constraints",
    "FactorizationResult",
    "ScaleReference",
    "align",
    "estimate_fixture_tolerance",
    "factorize",
    "refine",
]


# --------------------------------------------------------------------------- linear algebra


def _ell(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Rows ``l(x, y)`` with ``l(x, y) . q = x^T Q y`` for symmetric Q (footnotes 1-2).

    ``q`` holds the upper-triangular entries of Q in ``np.triu_indices(p)`` order.
    x, y : (K, p) -> (K, p(p+1)/2).
    """
    p = x.shape[1]
    r, c = np.triu_indices(p)
    return np.where(r == c, x[:, r] * y[:, c], x[:, r] * y[:, c] + x[:, c] * y[:, r])


def _sym(q: np.ndarray, p: int) -> np.ndarray:
    Q = np.zeros((p, p))
    r, c = np.triu_indices(p)
    Q[r, c] = q
    Q[c, r] = q
    return Q


def _solve_q(L: np.ndarray, h: np.ndarray, case: str, p: int) -> tuple[np.ndarray, list[str]]:
    """Solve ``L q = h`` for Q (eqs. 22, 28), with the special cases of section III-C."""
    nq = p * (p + 1) // 2
    notes: list[str] = []
    if case == "orthogonal-only":
        _, sv, Vt = np.linalg.svd(L, full_matrices=True)
        q = Vt[-1]  # eq. (30): q = beta q_n, beta = 1 for now
        Q = _sym(q, p)
        if np.trace(Q) < 0:
            Q = -Q
        notes.append("orthogonality-only constraints: global scale from the reference (eq. 31)")
        return Q, notes
    if case == "magnitude-only" and p == 4:
        # L loses one rank (eq. 29): q = q_p + alpha q_n, alpha from det Q(alpha) = 0 (eq. 24).
        U, sv, Vt = np.linalg.svd(L, full_matrices=False)
        keep = nq - 1
        q_p = Vt[:keep].T @ ((U[:, :keep].T @ h) / sv[:keep])
        q_n = Vt[-1]
        Qp, Qn = _sym(q_p, p), _sym(q_n, p)
        alphas = eigvals(Qp, -Qn)  # (Qp + alpha Qn) v = 0; inf where Qn is singular
        best = None
        for a in alphas:
            if not np.isfinite(a) or abs(a.imag) > 1e-9 * max(1.0, abs(a.real)):
                continue
            Q = Qp + a.real * Qn
            ev = np.linalg.eigvalsh(Q)  # ascending; a valid Q is PSD of rank 3
            score = np.min(ev[1:]) / np.max(ev)
            if score > 0 and (best is None or score > best[0]):
                best = (score, Q)
        if best is None:
            raise DesignError(
                "magnitude-only constraints left the metric upgrade without a valid solution "
                "(no real root of eq. 24 gives a positive Q); capture more orientations"
            )
        notes.append("magnitude-only constraints: alpha from the quartic of eq. (24)")
        return best[1], notes
    q, *_ = np.linalg.lstsq(L, h, rcond=None)
    return _sym(q, p), notes


def _check_constraint_rank(L: np.ndarray, case: str, p: int) -> None:
    nq = p * (p + 1) // 2
    need = nq - (1 if case in ("orthogonal-only",) or (case == "magnitude-only" and p == 4) else 0)
    sv = np.linalg.svd(L, compute_uv=False)
    rank = int(np.sum(sv > 1e-9 * sv[0])) if len(sv) else 0
    if rank < need:
        what = (
            "orthogonal pairs of motions (turns about at least three mutually orthogonal axes)"
            if case == "orthogonal-only"
            else "orientations spread over the sphere (faces and edges of the block)"
        )
        raise DesignError(
            f"the motion constraints are not independent enough: rank {rank} of the {need} the "
            f"metric upgrade needs (p = {p}); capture more {what}"
        )


def factorize(
    Z: np.ndarray,
    constraints: Constraints,
    *,
    bias: np.ndarray | None = None,
    scale_reference: ScaleReference | None = None,
    linear: str = "paper",
) -> FactorizationResult:
    """The linear factorization method (sections II-III).

    ``linear="paper"`` follows the paper step by step. ``linear="subspace"`` (redundant units
    only) first finds the 3-D affine subspace the measurements lie in (an SVD of the centred
    ``Z``: the rank constraint of eq. 8 applied to the affine model), then solves the triad
    problem inside it: biases from the magnitude constraints (an algebraic ellipsoid fit, the
    redundant counterpart of eq. 14) or from ``bias``, and ``A = chol(Q)`` (eqs. 27-28). It
    avoids the noise-sensitive root of eq. (24) and is, on static designs, as accurate as the
    nonlinear refinement.

    Parameters
    ----------
    Z : ndarray, shape (m, n)
        Measurement matrix: one motion per row (a sample or a pose mean), raw units.
    constraints : Constraints
        ``f_i^T f_k = h_ik`` between rows of ``Z``.
    bias : ndarray, shape (n,), optional
        Required for a triad (n = 3): the biases from eq. (14) or still periods. Ignored for
        redundant units, whose biases are estimated with everything else.
    scale_reference : ScaleReference, optional
        Required for orthogonality-only constraints: one motion of known magnitude (eq. 31).

    Returns
    -------
    FactorizationResult
        ``T`` in a canonical frame (rotation not yet resolved: see :func:`align`).

    Raises
    ------
    DesignError
        Rank-deficient ``Z``, too few independent constraints, a triad without biases,
        orthogonality-only data without a scale reference.
    """
    Z = np.asarray(Z, dtype=float)
    m, n = Z.shape
    case = constraints.kind
    if n < 3:
        raise DesignError(f"a unit needs at least 3 sensor elements, this one has {n}")
    if case == "orthogonal-only" and scale_reference is None:
        raise DesignError(
            "orthogonality-only constraints fix the gains only up to one global scale; add one "
            "rotation of known angle (a ruler-guided 90-degree turn, `angle_deg`)"
        )
    if linear not in ("paper", "subspace"):
        raise ValueError(f"linear must be 'paper' or 'subspace', not {linear!r}")
    if linear == "subspace" and n >= 4:
        return _factorize_subspace(Z, constraints, bias, scale_reference)
    if n >= 4:
        F, S, b, sv, notes = _factorize_redundant(Z, constraints)
        configuration = "redundant"
    else:
        F, S, b, sv, notes = _factorize_triad(Z, constraints, bias)
        configuration = "triad"

    T = np.linalg.pinv(S.T)
    if case == "orthogonal-only":
        beta = _reference_scale(T, b, scale_reference)  # eq. (31)
        T, S, F = T * beta, S / beta, F * beta
    T, S, F = right_handed(T, S, F)
    return FactorizationResult(
        S=S,
        b=b,
        T=T,
        F=F,
        configuration=configuration,
        case=case,
        constraint_rms=constraint_rms(F, constraints),
        singular_values=sv,
        notes=notes,
    )


def _factorize_redundant(Z: np.ndarray, constraints: Constraints):
    """Section III-A, a redundant unit (n >= 4): rank-4 factorization of ``Z`` (eqs. 7-9),
    then the metric upgrade ``A`` from the constraints (eqs. 16-26). Returns ``(F, S, b,
    singular values, notes)``."""
    m, _ = Z.shape
    case = constraints.kind
    p = 4
    U, sv, Vt = np.linalg.svd(Z, full_matrices=False)
    if m < p or sv[p - 1] <= 1e-9 * sv[0]:
        raise DesignError(
            f"the measurement matrix Z has rank {int(np.sum(sv > 1e-9 * sv[0]))}, below the "
            f"{p} of the affine model: capture motions in more directions"
        )
    # Rank-p truncation and the canonical factors (eqs. 7-9).
    F_hat = U[:, :p] * np.sqrt(sv[:p])
    S_hat = np.sqrt(sv[:p])[:, None] * Vt[:p]
    a4 = np.linalg.pinv(F_hat) @ np.ones(m)  # eq. (18)
    L = _ell(F_hat[constraints.i], F_hat[constraints.k])  # eqs. (20)-(22)
    _check_constraint_rank(L, case, p)
    Q, notes = _solve_q(L, constraints.h, case, p)
    Q0, q1 = Q[:3, :3], Q[:3, 3]  # eq. (23)
    try:
        C = np.linalg.cholesky(Q0)  # eq. (25)
    except np.linalg.LinAlgError:
        raise DesignError(
            "the metric upgrade failed (Q0 is not positive definite): the constraints are "
            "too noisy or too few; capture more orientations"
        ) from None
    u = np.linalg.solve(C, q1)  # eq. (26)
    A = np.zeros((p, p))
    A[:3, :3] = C
    A[3, :3] = u
    A[:, 3] = a4  # A = [A13 | a4], eq. (16)
    F_b = F_hat @ A  # eq. (11)
    S_b = np.linalg.solve(A, S_hat)  # eq. (12)
    F, S, b = F_b[:, :3], S_b[:3], S_b[3]
    return F, S, b, sv, notes


def _factorize_triad(Z: np.ndarray, constraints: Constraints, bias):
    """Section III-B, a triad (n = 3): the biases first (eq. 14, given), the bias-free
    measurements factorized (eq. 13) and upgraded by ``A = chol(Q)`` (eqs. 27-28). Returns
    ``(F, S, b, singular values, notes)``."""
    m, _ = Z.shape
    case = constraints.kind
    p = 3
    if bias is None:
        raise DesignError(
            "a triad needs its biases first (eq. 14): capture at least one pair of opposite "
            "poses (a face up and the same face down), or still periods for a gyroscope"
        )
    b = np.asarray(bias, dtype=float)
    D = Z - b  # eq. (13)
    U, sv, Vt = np.linalg.svd(D, full_matrices=False)
    if m < p or sv[p - 1] <= 1e-9 * sv[0]:
        raise DesignError(
            "the bias-free measurements span fewer than 3 directions: capture motions along "
            "every axis"
        )
    F_hat = U * np.sqrt(sv)
    S_hat = np.sqrt(sv)[:, None] * Vt
    L = _ell(F_hat[constraints.i], F_hat[constraints.k])  # eqs. (27)-(28)
    _check_constraint_rank(L, case, p)
    Q, notes = _solve_q(L, constraints.h, case, p)
    try:
        A = np.linalg.cholesky(Q)  # A = chol(Q), up to a rotation
    except np.linalg.LinAlgError:
        raise DesignError(
            "the metric upgrade failed (Q is not positive definite): the constraints are too "
            "noisy or too few; capture more orientations"
        ) from None
    F = F_hat @ A
    S = np.linalg.solve(A, S_hat)
    return F, S, b, sv, notes


def _factorize_subspace(Z, constraints, bias, scale_reference) -> FactorizationResult:
    """Redundant unit: the affine 3-D subspace first, then the triad method inside it."""

    z_bar = Z.mean(axis=0)
    _, sv, Vt = np.linalg.svd(Z - z_bar, full_matrices=False)
    if len(Z) < 4 or sv[2] <= 1e-9 * sv[0]:
        raise DesignError(
            "the measurements span fewer than 3 directions: capture motions along every axis"
        )
    V3 = Vt[:3].T  # (n, 3): the span of the sensitivity axes
    Y = (Z - z_bar) @ V3  # subspace coordinates, (m, 3)
    if bias is not None:
        c = V3.T @ (np.asarray(bias, float) - z_bar)
    else:
        mag = (constraints.i == constraints.k) & (constraints.h > 0)
        rows = constraints.i[mag]
        if len(np.unique(rows)) < 9 or not np.allclose(constraints.h[mag], constraints.h[mag][0]):
            raise DesignError(
                "the biases of a redundant unit need at least 9 motions of one known magnitude "
                "(static orientations under gravity), or still periods (gyroscopes)"
            )
        c = fit_ellipsoid(Y[rows], np.sqrt(constraints.h[mag][0])).bias
    tri = factorize(
        Y, constraints, bias=c, scale_reference=_project_reference(scale_reference, V3, z_bar)
    )
    T = tri.T @ V3.T
    b = z_bar + V3 @ c
    S = np.linalg.pinv(T).T
    return FactorizationResult(
        S=S,
        b=b,
        T=T,
        F=tri.F,
        configuration="redundant",
        case=tri.case,
        constraint_rms=tri.constraint_rms,
        singular_values=sv,
        notes=tri.notes + ["linear solution in the subspace of the sensitivity axes"],
    )


def _project_reference(ref, V3, z_bar):
    if ref is None:
        return None
    w = np.asarray(ref.w, float) - ref.duration * z_bar * (ref.duration > 0)
    return ScaleReference(V3.T @ w, ref.magnitude, ref.duration, ref.sigma)


def _reference_scale(T: np.ndarray, b: np.ndarray, ref: ScaleReference) -> float:
    """Factor making the reference motion's magnitude right (eq. 31)."""
    w = np.asarray(ref.w, float) - ref.duration * b * (ref.duration > 0)
    mag = np.linalg.norm(T @ w)
    if mag == 0:
        raise DesignError("the known-angle rotation shows no motion in the measurements")
    return ref.magnitude / mag


# --------------------------------------------------------------------------- rotation gauge


def align(result: FactorizationResult, R: np.ndarray) -> FactorizationResult:
    """The same calibration expressed in a rotated frame: ``T -> R T``, ``S -> R S``."""
    out = FactorizationResult(**{**result.__dict__})
    out.T, out.S, out.F = R @ result.T, R @ result.S, result.F @ R.T
    if result.cov is not None:
        n = len(result.b)
        J = np.zeros((n + 3 * n, n + 3 * n))
        J[:n, :n], J[n:, n:] = np.eye(n), np.kron(R, np.eye(n))  # block diagonal
        out.cov = J @ result.cov @ J.T
    return out
