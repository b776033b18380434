"""The nonlinear refinement of a factorization (Hwangbo & Kanade section IV-C;
:mod:`.factorization`): every parameter, biases included, fitted to the motion-constraint errors
weighted as the first-order maximum-likelihood estimate (:func:`refine`), its sandwich
covariance, and the fixture's tolerance estimated from the data
(:func:`estimate_fixture_tolerance`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.special import chdtri

from imucal_cli.estimators.factorization_model import (
    Constraints,
    FactorizationResult,
    ScaleReference,
    constraint_rms,
    right_handed,
)

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
        constraint_rms=constraint_rms(F, constraints), singular_values=initial.singular_values,
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
    T, S, _ = right_handed(T, S, np.zeros((0, 3)))
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
