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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import eigvals
from scipy.optimize import least_squares
from scipy.special import chdtri

from imucal_cli.errors import DesignError

from .ellipsoid import fit_ellipsoid


@dataclass(frozen=True)
class Constraints:
    """Inner-product motion constraints ``f_i^T f_k = h_ik`` (eq. 15).

    Attributes
    ----------
    i, k : ndarray of int, shape (K,)
        Row indices into the measurement matrix ``Z``; ``i == k`` is a magnitude constraint.
    h : ndarray, shape (K,)
        The inner products, in the motion's units squared.
    """

    i: np.ndarray
    k: np.ndarray
    h: np.ndarray

    def __post_init__(self):
        for name in ("i", "k"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=int))
        object.__setattr__(self, "h", np.asarray(self.h, dtype=float))

    def __len__(self) -> int:
        return len(self.h)

    @property
    def kind(self) -> str:
        """``"magnitude-only"`` (all h equal and non-zero: eq. 29), ``"orthogonal-only"``
        (all zero: eq. 30) or ``"general"``."""
        if np.all(self.h == 0):
            return "orthogonal-only"
        if np.allclose(self.h, self.h[0]) and np.all(self.i == self.k):
            return "magnitude-only"
        return "general"


@dataclass(frozen=True)
class ScaleReference:
    """One motion of known magnitude for the global scale of orthogonality-only data (eq. 31).

    Attributes
    ----------
    w : ndarray, shape (n,)
        Integral of the bias-free measurements over the known rotation, ``sum (z - b) dt``
        (raw units x s). For a redundant unit, the integral of ``z`` and the duration ``T``.
    magnitude : float
        Its true magnitude (the rotation angle, rad).
    duration : float
        Seconds over which ``w`` was integrated (used to remove the bias term when the biases
        are estimated together with the rest).
    """

    w: np.ndarray
    magnitude: float
    duration: float = 0.0
    sigma: float | None = None  # standard deviation of the measured magnitude; default 0.1 %


@dataclass
class FactorizationResult:
    """Result of :func:`factorize` or :func:`refine`.

    Attributes
    ----------
    S : ndarray, shape (3, n)
        Sensitivity axes ``s_j`` as columns (raw units per motion unit); gains ``|s_j|``.
    b : ndarray, shape (n,)
        Biases, raw units.
    T : ndarray, shape (3, n)
        ``[S^T]^+``: motion = ``T @ (z - b)``.
    F : ndarray, shape (m, 3)
        Recovered motions (rows of ``Z``), in the frame of ``T``.
    configuration : str
        ``"redundant"`` (p = 4) or ``"triad"`` (p = 3).
    case : str
        Constraint case: ``"general"``, ``"magnitude-only"``, ``"orthogonal-only"``.
    constraint_rms : float
        RMS of ``f_i^T f_k - h_ik`` over the constraints (the paper's C_err, as an RMS).
    singular_values : ndarray
        Of ``Z`` (redundant) or ``D`` (triad), largest first: the rank evidence.
    method : str
        ``"linear"`` or ``"nonlinear"``.
    iterations, converged, message
        Of the nonlinear refinement (0, True, "" for the linear solution).
    cov : ndarray or None
        Covariance of ``(b, vec(T))`` (n + 3n); only for :func:`refine`. Rotation-gauge
        directions are removed (pseudo-inverse), so use it for rotation-invariant quantities.
    noise_scale : float
        Factor applied to ``cov`` (residual chi^2/dof when the noise was not given or the
        residuals exceed it).
    """

    S: np.ndarray
    b: np.ndarray
    T: np.ndarray
    F: np.ndarray
    configuration: str
    case: str
    constraint_rms: float
    singular_values: np.ndarray
    method: str = "linear"
    iterations: int = 0
    converged: bool = True
    message: str = ""
    cov: np.ndarray | None = None
    noise_scale: float = 1.0
    notes: list[str] = field(default_factory=list)
    fixture_tolerance: float = 0.0

    @property
    def gains(self) -> np.ndarray:
        """``|s_j|``, raw units per motion unit, shape (n,)."""
        return np.linalg.norm(self.S, axis=0)

    def angles_deg(self) -> np.ndarray:
        """Angles between sensitivity axes, degrees, shape (n, n)."""
        s = self.S / self.gains
        return np.degrees(np.arccos(np.clip(s.T @ s, -1, 1)))


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


def _constraint_rms(F: np.ndarray, c: Constraints) -> float:
    e = np.sum(F[c.i] * F[c.k], axis=1) - c.h
    return float(np.sqrt(np.mean(e * e)))


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
    T, S, F = _right_handed(T, S, F)
    return FactorizationResult(
        S=S,
        b=b,
        T=T,
        F=F,
        configuration=configuration,
        case=case,
        constraint_rms=_constraint_rms(F, constraints),
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


def _right_handed(T, S, F):
    """Resolve the reflection that inner products cannot see: the first three channels form a
    right-handed set (``det T[:, :3] > 0``), as on every standard IMU."""
    if np.linalg.det(T[:, :3]) < 0:
        flip = np.diag([1.0, 1.0, -1.0])
        return flip @ T, flip @ S, F @ flip
    return T, S, F


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


# --------------------------------------------------------------------------- refinement


def _gauge_free_inverse(J: np.ndarray, gauge: int) -> np.ndarray:
    """``(J^T J)^+`` without the ``gauge`` directions the data cannot see (the rotation of the
    frame): columns scaled to unit norm first, so that only those directions, and not merely
    small parameters, are dropped."""
    d = np.linalg.norm(J, axis=0)
    d[d == 0] = 1.0
    w, V = np.linalg.eigh((J / d).T @ (J / d))
    keep = np.arange(len(w)) >= gauge  # eigenvalues ascending: the gauge ones come first
    inv = (V[:, keep] / w[keep]) @ V[:, keep].T
    return inv / np.outer(d, d)


def _unpack(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    return x[:n], x[n:].reshape(3, n)


def refine(
    Z: np.ndarray,
    constraints: Constraints,
    initial: FactorizationResult,
    *,
    sigma: np.ndarray | float | None = None,
    scale_reference: ScaleReference | None = None,
    zero_motion: tuple[np.ndarray, np.ndarray] | None = None,
    row_owner: np.ndarray | None = None,
    fixture_tolerance: float | None = 0.0,
    max_iterations: int = 200,
) -> FactorizationResult:
    """Nonlinear refinement of every parameter together, biases included (section IV-C).

    Minimises the motion-constraint errors ``f_i^T f_k - h_ik`` with ``f_i = T (z_i - b)``,
    each divided by its first-order standard deviation, plus (for n > 3) the part of each
    ``z_i - b`` outside the span of the sensitivity axes, which the constraints cannot see but
    the affine model predicts to be noise.

    One row of ``Z`` often enters many constraints (a labelled pose with every other one), so
    the residuals are correlated; the covariance of the result accounts for that (a sandwich
    estimator built from how every residual depends on every noise source), so the reported
    uncertainty stays honest whatever the constraint set.

    Parameters
    ----------
    Z, constraints
        As for :func:`factorize`.
    initial : FactorizationResult
        The linear solution.
    sigma : float or ndarray (m,), optional
        Noise standard deviation of each row of ``Z`` (raw units, per channel; a pose mean's
        is the sample noise / sqrt(samples)). Omitted: equal weights, noise estimated from the
        residuals.
    scale_reference : ScaleReference, optional
        The known-magnitude motion (needed for orthogonality-only data).
    zero_motion : (ndarray (r, n), ndarray (r,)), optional
        Readings with no motion at all (a gyroscope held still) and their noise: each says
        ``z = b`` up to noise, which ties the biases to the still data while they are refined.
    row_owner : ndarray of int (m,), optional
        The physical pose of each row (several samples of one pose share its placement error).
    fixture_tolerance : float or None
        RMS angle (rad) by which a labelled direction may differ from the true one (a block
        placed by hand, an iron that is not perfectly square). It weakens the constraints
        between different poses accordingly; 0 trusts the fixture exactly, as the paper does;
        None estimates it from the data (the part of the cross-constraint errors that the
        noise does not explain, by the method of moments) and refines again with it.

    Returns
    -------
    FactorizationResult
        ``method="nonlinear"``, with ``cov`` of ``(b, vec(T))``.
    """
    if fixture_tolerance is None:
        return _refine_with_estimated_tolerance(
            Z, constraints, initial, sigma=sigma, scale_reference=scale_reference,
            zero_motion=zero_motion, row_owner=row_owner, max_iterations=max_iterations,
        )  # fmt: skip
    prob = _Refinement(Z, constraints, sigma, scale_reference, zero_motion, row_owner,
                       fixture_tolerance)  # fmt: skip
    sol = _solve(prob, initial, max_iterations)  # IV-C: the weighted constraint errors
    cov, noise_scale = _sandwich_covariance(sol.jac, sol.fun, prob.noise_jacobian(sol.x),
                                            sigma is None)  # fmt: skip
    b, T, S, cov = _handed(sol.x, prob.n, cov)
    F = (prob.Z - b) @ T.T  # eq. (13): the motions the refined calibration sees
    return FactorizationResult(
        S=S, b=b, T=T, F=F, configuration=initial.configuration, case=initial.case,
        constraint_rms=_constraint_rms(F, constraints), singular_values=initial.singular_values,
        method="nonlinear", iterations=int(sol.nfev), converged=sol.status > 0,
        message=str(sol.message), cov=cov, noise_scale=float(noise_scale),
        notes=list(initial.notes), fixture_tolerance=float(fixture_tolerance),
    )  # fmt: skip


def _refine_with_estimated_tolerance(Z, constraints, initial, **options) -> FactorizationResult:
    """:func:`refine` with ``fixture_tolerance=None``: refine trusting the fixture, estimate its
    tolerance from that fit's cross-constraint errors (:func:`estimate_fixture_tolerance`),
    and refine again from there with it."""
    first = refine(Z, constraints, initial, fixture_tolerance=0.0, **options)
    tol = estimate_fixture_tolerance(Z, constraints, first, options["sigma"],
                                     options["row_owner"])  # fmt: skip
    result = refine(Z, constraints, first, fixture_tolerance=tol, **options)
    result.notes.append(f"fixture tolerance estimated from the data: {np.degrees(tol):.3f} deg")
    return result


def _solve(prob: _Refinement, initial: FactorizationResult, max_iterations: int):
    """Levenberg-Marquardt on ``prob``'s residuals from the linear solution ``initial``, the
    parameters ``(b, vec(T))`` scaled to O(1): biases by the raw spread, T by its size."""
    n = prob.n
    x0 = np.concatenate([initial.b, initial.T.ravel()])
    x_scale = np.concatenate(
        [np.full(n, np.std(prob.Z) + 1e-12), np.full(3 * n, np.abs(initial.T).max())]
    )
    return least_squares(prob.residuals, x0, method="lm", x_scale=x_scale, xtol=1e-12,
                         ftol=1e-12, gtol=1e-12, max_nfev=max_iterations)  # fmt: skip


def _handed(x: np.ndarray, n: int, cov: np.ndarray):
    """``b``, ``T``, ``S = pinv(T)^T`` and ``cov`` of the refined parameters ``x``, with the
    channels made right-handed (the row of T flipped, and its covariance)."""
    b, T = _unpack(x, n)
    S = np.linalg.pinv(T).T
    if np.linalg.det(T[:, :3]) < 0:  # right-handed channels; flip the cov of the flipped row
        flip = np.r_[np.ones(n + 2 * n), -np.ones(n)]
        cov = cov * np.outer(flip, flip)
    T, S, _ = _right_handed(T, S, np.zeros((0, 3)))
    return b, T, S, cov


def _sandwich_covariance(J: np.ndarray, r: np.ndarray, C: np.ndarray, noise_unknown: bool):
    """Covariance of the refined ``(b, vec(T))`` (section IV-C's residuals are correlated: one
    row of ``Z`` enters many constraints): ``A^+ J^T (C C^T) J A^+`` with ``C`` how each
    residual depends on each noise source; scaled by chi^2 over its expected value when the
    noise is unknown, or clearly above the given noise. Returns ``(cov, noise_scale)``."""
    A_inv = _gauge_free_inverse(J, gauge=3)
    JC = J.T @ C
    cov = A_inv @ (JC @ JC.T) @ A_inv
    # Expected chi^2 of correlated residuals: trace((I - H) C C^T), H the hat matrix.
    H = J @ A_inv @ J.T
    dof = max(float(np.sum(C * C) - np.sum((H @ C) * C)), 1.0)
    chi2 = float(r @ r)
    if noise_unknown:
        noise_scale = chi2 / dof  # estimated from the residuals
    else:  # noise given: inflate only when the residuals are clearly larger than it
        noise_scale = chi2 / dof if chi2 > chdtri(dof, 0.01) else 1.0
    return noise_scale * cov, noise_scale


class _Refinement:
    """The residuals of section IV-C and how they depend on every noise source (for
    :func:`refine`): constraint errors ``(f_i^T f_k - h_ik) / sd``, the part of each
    ``z_i - b`` outside the span of the axes (n > 3), still readings and the scale reference."""

    def __init__(self, Z, constraints, sigma, scale_reference, zero_motion, row_owner,
                 fixture_tolerance):  # fmt: skip
        Z = np.asarray(Z, float)
        m, n = Z.shape
        self.Z, self.m, self.n = Z, m, n
        self.sig = np.ones(m) if sigma is None else np.broadcast_to(np.asarray(sigma, float),
                                                                      (m,))  # fmt: skip
        self.owner = np.arange(m) if row_owner is None else np.asarray(row_owner, int)
        self.rows = np.unique(np.r_[constraints.i, constraints.k])
        self.redundant = n > 3
        self.ci, self.ck, self.h = constraints.i, constraints.k, constraints.h
        self.same = self.ci == self.ck
        self.tol = fixture_tolerance
        self.jitter = (~self.same) & (self.owner[self.ci] != self.owner[self.ck]) & (
            fixture_tolerance > 0
        )
        self.Z0 = self.s0 = None
        if zero_motion is not None:
            self.Z0 = np.asarray(zero_motion[0], float)
            self.s0 = np.asarray(zero_motion[1], float)
        self.ref, self.ref_sigma = scale_reference, None
        if scale_reference is not None:
            self.ref_sigma = scale_reference.sigma or 1e-3 * abs(scale_reference.magnitude)

    def parts(self, x):
        b, T = _unpack(x, self.n)
        D = self.Z - b
        F = D @ T.T
        G = F @ T  # rows: T^T f_i, the gradient of f_i . (anything) with respect to z_i
        dot = np.sum(F[self.ci] * F[self.ck], axis=1)
        ci, ck, sig = self.ci, self.ck, self.sig
        var = sig[ci] ** 2 * np.sum(G[ck] ** 2, 1) + sig[ck] ** 2 * np.sum(G[ci] ** 2, 1)
        # d|f|^2 = 2 f.T dz
        var = np.where(self.same, 4 * sig[ci] ** 2 * np.sum(G[ci] ** 2, 1), var)
        cross = np.cross(F[ci], F[ck])
        var = var + np.where(self.jitter, self.tol**2 * np.sum(cross**2, 1), 0.0)
        return b, T, D, F, G, cross, np.sqrt(np.maximum(var, 1e-300)), dot

    def residuals(self, x):
        b, T, D, F, G, cross, sd, dot = self.parts(x)
        out = [(dot - self.h) / sd]
        if self.redundant:
            P = np.linalg.pinv(T) @ T  # orthogonal projector onto the span of the axes
            out.append(((D[self.rows] - D[self.rows] @ P.T) / self.sig[self.rows, None]).ravel())
        if self.Z0 is not None:
            out.append(((self.Z0 - b) / self.s0[:, None]).ravel())
        if self.ref is not None:
            w = np.asarray(self.ref.w, float) - self.ref.duration * b
            out.append(
                np.atleast_1d((np.linalg.norm(T @ w) - self.ref.magnitude) / self.ref_sigma)
            )
        return np.concatenate(out)

    def noise_jacobian(self, x) -> np.ndarray:
        """d residuals / d (every noise source, in units of its standard deviation)."""
        b, T, D, F, G, cross, sd, dot = self.parts(x)
        m, n = self.m, self.n
        poses = np.unique(self.owner)
        pose_col = {p: k for k, p in enumerate(poses)}
        n_res = len(self.residuals(x))
        n_noise = (m * n + 3 * len(poses) + (0 if self.Z0 is None else self.Z0.size)
                   + (self.ref_sigma is not None))  # fmt: skip
        C = np.zeros((n_res, n_noise))
        K = len(self.h)
        for j in range(K):
            i, k = self.ci[j], self.ck[j]
            if i == k:
                C[j, i * n : (i + 1) * n] += 2 * self.sig[i] * G[i] / sd[j]
                continue
            C[j, i * n : (i + 1) * n] += self.sig[i] * G[k] / sd[j]
            C[j, k * n : (k + 1) * n] += self.sig[k] * G[i] / sd[j]
            if self.jitter[j]:
                base = m * n
                pi, pk = pose_col[self.owner[i]], pose_col[self.owner[k]]
                amp = self.tol / np.sqrt(2)
                C[j, base + 3 * pi : base + 3 * pi + 3] += amp * cross[j] / sd[j]
                C[j, base + 3 * pk : base + 3 * pk + 3] -= amp * cross[j] / sd[j]
        r0 = K
        if self.redundant:
            P = np.linalg.pinv(T) @ T
            for row in self.rows:
                C[r0 : r0 + n, row * n : (row + 1) * n] = np.eye(n) - P
                r0 += n
        c0 = m * n + 3 * len(poses)
        if self.Z0 is not None:
            C[r0 : r0 + self.Z0.size, c0 : c0 + self.Z0.size] = np.eye(self.Z0.size)
            r0 += self.Z0.size
            c0 += self.Z0.size
        if self.ref_sigma is not None:
            C[r0, c0] = 1.0
        return C



def estimate_fixture_tolerance(
    Z: np.ndarray,
    constraints: Constraints,
    result: FactorizationResult,
    sigma: np.ndarray | float | None,
    row_owner: np.ndarray | None,
) -> float:
    """RMS placement error (rad) of the labelled directions, by the method of moments.

    Each cross constraint between two poses errs by the noise (known) plus
    ``omega . (f_i x f_k)`` from the placement errors ``omega`` of both poses; the excess of
    the squared errors over the noise, per unit of ``|f_i x f_k|^2``, estimates the squared
    tolerance. Returns 0 when the noise explains everything.
    """
    m, n = Z.shape
    sig = np.ones(m) if sigma is None else np.broadcast_to(np.asarray(sigma, float), (m,))
    owner = np.arange(m) if row_owner is None else np.asarray(row_owner, int)
    ci, ck, h = constraints.i, constraints.k, constraints.h
    sel = (ci != ck) & (owner[ci] != owner[ck])
    if not sel.any():
        return 0.0
    F = (Z - result.b) @ result.T.T
    G = F @ result.T
    e = np.sum(F[ci] * F[ck], axis=1) - h
    noise = sig[ci] ** 2 * np.sum(G[ck] ** 2, 1) + sig[ck] ** 2 * np.sum(G[ci] ** 2, 1)
    cross2 = np.sum(np.cross(F[ci], F[ck]) ** 2, axis=1)
    excess = np.sum(e[sel] ** 2 - noise[sel]) / max(np.sum(cross2[sel]), 1e-300)
    return float(np.sqrt(excess)) if excess > 0 else 0.0
