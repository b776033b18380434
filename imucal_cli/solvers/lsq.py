"""Levenberg-Marquardt for the small dense least-squares problems of the solvers (numpy only).

``least_squares(fun, x0, jac=...)`` minimises ``0.5 * sum(fun(x)**2)`` and returns an
:class:`LsqResult` with the fields the solvers read from ``scipy.optimize.least_squares``
(``x, fun, jac, cost, nfev, njev, status, message, success, optimality``), so that the
calibrate, import and report paths do not import ``scipy.optimize`` (about 0.4 s and 80 MiB
of start-up, more than a whole calibration).

The method is Moré's (1978) trust-region Levenberg-Marquardt, as in MINPACK's ``lmder``
(what ``least_squares(method="lm")`` calls): variables scaled by ``D = 1 / x_scale`` or by
the Jacobian's column norms (``x_scale="jac"``, MINPACK's ``mode=1``), the damping ``lambda``
found so that the scaled step ``||D p||`` meets the trust radius (Moré's eqs. 3.5-5.5, here
on the SVD of ``J D^-1``, which also gives the minimum-norm step when ``J`` is rank
deficient; or, for a Jacobian with per-block nuisance columns (``blocks``), on the Schur
complement of the normal equations where ``J`` is well-conditioned), the radius updated
from the ratio of actual to predicted reduction, and MINPACK's three tests (``ftol``,
``xtol``, ``gtol``). The parameter counts we solve are tens, the residual counts up to tens
of thousands: one thin SVD per Jacobian is cheap.

Status codes are scipy's: ``0`` iteration limit, ``1`` gtol, ``2`` ftol, ``3`` xtol,
``4`` ftol and xtol; ``-1`` improper input.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

EPS = np.finfo(float).eps

MESSAGES = {
    -1: "Improper input parameters status returned from `leastsq`",
    0: "The maximum number of function evaluations is exceeded.",
    1: "`gtol` termination condition is satisfied.",
    2: "`ftol` termination condition is satisfied.",
    3: "`xtol` termination condition is satisfied.",
    4: "Both `ftol` and `xtol` termination conditions are satisfied.",
}


@dataclass
class LsqResult:
    """The solution, with the fields of ``scipy.optimize.OptimizeResult`` the solvers read.

    ``x`` (n,), ``fun`` (m,) residuals at ``x``, ``jac`` (m, n) Jacobian at ``x``,
    ``cost = 0.5 * fun @ fun``, ``optimality = max |jac.T @ fun|``, ``nfev``/``njev``
    evaluations of ``fun``/``jac`` by the iteration (finite-difference evaluations and the
    final Jacobian at ``x`` not counted),
    ``status`` (scipy's codes), ``message``, ``success = status > 0``.
    """

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    cost: float
    nfev: int
    njev: int
    status: int
    message: str
    success: bool
    optimality: float


def _dense(J) -> np.ndarray:
    """A Jacobian as a dense float array (a ``scipy.sparse`` one is densified: n is small)."""
    if hasattr(J, "toarray"):
        J = J.toarray()
    return np.atleast_2d(np.asarray(J, dtype=float))


def _forward_difference(fun: Callable, x: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Jacobian by forward differences, with scipy's ``"2-point"`` step (sqrt(eps) relative)."""
    sign = np.where(x >= 0, 1.0, -1.0)
    h = np.sqrt(EPS) * sign * np.maximum(1.0, np.abs(x))
    h = (x + h) - x  # representable steps
    J = np.empty((len(f), len(x)))
    for j in range(len(x)):
        xj = x.copy()
        xj[j] += h[j]
        J[:, j] = (np.asarray(fun(xj), float) - f) / h[j]
    return J


class _SvdSteps:
    """Damped steps ``q(lambda) = -(A^T A + lambda I)^-1 A^T f`` of the scaled Jacobian
    ``A = J D^-1`` from its thin SVD ``A = U diag(s) V^T``: ``q = -V diag(s / (s^2 + lambda))
    c``, ``c = U^T f`` (Moré's eqs. 3.5-5.5; the minimum-norm step when ``A`` is rank
    deficient)."""

    def __init__(self, A: np.ndarray, f: np.ndarray):
        U, self.s, Vt = np.linalg.svd(A, full_matrices=False)
        self.V = Vt.T
        self.c = U.T @ f
        self.sc = self.s * self.c  # A^T f in the basis V

    def gauss_newton(self) -> tuple[np.ndarray, float, bool]:
        """The undamped step, its norm and whether ``A`` has full (numerical) rank."""
        s, c = self.s, self.c
        s_max = s[0] if len(s) else 0.0
        keep = s > EPS * max(len(s), 1) * max(len(c), 1) * s_max  # numerical rank
        gn = np.zeros_like(c)
        gn[keep] = c[keep] / s[keep]
        return -(self.V @ gn), float(np.linalg.norm(gn)), bool(keep.all())

    def gradient(self) -> tuple[float, bool]:
        """``||A^T f||`` and whether ``A^T f`` is nonzero."""
        return float(np.linalg.norm(self.sc)), bool(np.any(self.sc))

    def norm_and_derivative(self, lam: float) -> tuple[float, float]:
        """``||q(lambda)||`` and its derivative in ``lambda``."""
        d = self.s * self.s + lam
        t = self.sc / d
        n = np.linalg.norm(t)
        return n, -float(np.sum(t * t / d)) / n

    def step(self, lam: float) -> np.ndarray:
        return -(self.V @ (self.sc / (self.s * self.s + lam)))


class _BlockSteps:
    """:class:`_SvdSteps`' damped steps from the normal equations, for a Jacobian whose
    columns after the first ``n0`` come in groups of ``b`` that share no row (per-pose
    nuisance parameters): ``N = A^T A = [[U, W], [W^T, V]]`` with ``V`` block diagonal, and
    each step eliminates those blocks (the Schur complement, an ``n0 x n0`` solve)::

        (U + lambda I - W (V + lambda I)^-1 W^T) q_0 = -g_0 + W (V + lambda I)^-1 g_V,
        q_V = -(V + lambda I)^-1 (g_V + W^T q_0),            g = A^T f.

    Only for a well-conditioned ``A`` (:meth:`usable`), whose steps the normal equations give
    to rounding noise; the iteration's fixed point, ``A^T f = 0``, is the same."""

    #: Largest ``tr(N) tr(N^-1)`` (a bound on cond(A)^2) accepted: cond(A) <= 1e6.
    MAX_COND2 = 1e12

    def __init__(self, A: np.ndarray, f: np.ndarray, blocks: tuple[int, int]):
        n0, b = blocks
        self.n0, self.b = n0, b
        self.nb = (A.shape[1] - n0) // b
        N = A.T @ A
        self.trace = float(np.trace(N))
        self.U = N[:n0, :n0]
        self.W = N[:n0, n0:]
        ar = np.arange(self.nb)
        self.V = N[n0:, n0:].reshape(self.nb, b, self.nb, b)[ar, :, ar, :]  # (nb, b, b)
        self.Wb = self.W.reshape(n0, self.nb, b).transpose(1, 0, 2)  # (nb, n0, b)
        self.g = A.T @ f
        self._lam: float | None = None

    def _factor(self, lam: float) -> None:
        """``(V + lambda I)^-1`` and the Schur complement's Cholesky factor at ``lam``."""
        if self._lam == lam:
            return
        self.Vinv = np.linalg.inv(self.V + lam * np.eye(self.b))
        Z = (self.Wb @ self.Vinv).transpose(1, 0, 2).reshape(self.n0, -1)  # W (V + lam)^-1
        self.Z = Z
        self.L = np.linalg.cholesky(self.U - Z @ self.W.T + lam * np.eye(self.n0))
        self._lam = lam

    def _solve(self, r: np.ndarray, lam: float) -> np.ndarray:
        """``(N + lambda I)^-1 r``."""
        self._factor(lam)
        r0, rV = r[: self.n0], r[self.n0 :]
        y = rV.reshape(self.nb, self.b)
        rhs = r0 - self.Z @ rV
        q0 = np.linalg.solve(self.L.T, np.linalg.solve(self.L, rhs))
        qV = np.einsum("kij,kj->ki", self.Vinv, y - (self.Wb.transpose(0, 2, 1) @ q0))
        return np.concatenate([q0, qV.ravel()])

    def usable(self) -> bool:
        """Whether ``N`` is positive definite with ``tr(N) tr(N^-1) <= MAX_COND2``
        (``tr(N^-1) = tr(S^-1) + tr(V^-1) + tr(S^-1 Z Z^T)``, ``S`` the Schur complement,
        ``Z = W V^-1``)."""
        if not np.all(np.isfinite(self.g)) or self.trace <= 0:
            return False
        try:
            self._factor(0.0)
        except np.linalg.LinAlgError:
            return False
        Linv = np.linalg.inv(self.L)
        Sinv = Linv.T @ Linv
        tr_inv = np.trace(Sinv) + np.trace(self.Vinv, axis1=1, axis2=2).sum()
        tr_inv += float(np.sum(Sinv * (self.Z @ self.Z.T)))
        return bool(np.all(np.linalg.eigvalsh(self.V) > 0)) and (
            0 < self.trace * tr_inv <= self.MAX_COND2
        )

    def gauss_newton(self) -> tuple[np.ndarray, float, bool]:
        q = -self._solve(self.g, 0.0)
        return q, float(np.linalg.norm(q)), True

    def gradient(self) -> tuple[float, bool]:
        return float(np.linalg.norm(self.g)), bool(np.any(self.g))

    def norm_and_derivative(self, lam: float) -> tuple[float, float]:
        q = self._solve(self.g, lam)
        n = np.linalg.norm(q)
        return n, -float(q @ self._solve(q, lam)) / n

    def step(self, lam: float) -> np.ndarray:
        return -self._solve(self.g, lam)


def _steps(A: np.ndarray, f: np.ndarray, blocks: tuple[int, int] | None):
    """The damped steps of ``A``: by blocks where given and well-conditioned, else the SVD."""
    if blocks is not None:
        steps = _BlockSteps(A, f, blocks)
        if steps.usable():
            return steps
    return _SvdSteps(A, f)


def _lm_step(steps, Delta, par):
    """Moré's damped step in scaled variables (``steps``: :class:`_SvdSteps` or
    :class:`_BlockSteps`), with ``lambda >= 0`` such that ``||q||`` is within 10% of
    ``Delta`` (``lambda = 0`` when the Gauss-Newton step is already inside). ``par`` is the
    previous ``lambda`` (a start). Returns ``(q, lambda)``."""
    gn, gn_norm, full_rank = steps.gauss_newton()
    grad, nonzero = steps.gradient()
    if gn_norm <= 1.1 * Delta or not nonzero:
        return gn, 0.0
    norm_and_derivative = steps.norm_and_derivative
    # lambda is bracketed: below by the Newton step from 0 (full rank), above by ||A^T f||/Delta
    hi = grad / Delta
    lo = 0.0
    if full_rank:
        n0, d0 = norm_and_derivative(0.0)
        lo = max(0.0, -(n0 - Delta) / Delta * n0 / d0)
    lam = par if lo < par < hi else max(lo, 1e-3 * hi)
    if lam <= 0.0:
        lam = 1e-3 * hi
    for _ in range(30):
        n, dn = norm_and_derivative(lam)
        if abs(n - Delta) <= 0.1 * Delta:
            break
        if n > Delta:
            lo = max(lo, lam)
        else:
            hi = min(hi, lam)
        lam = lam + (1.0 / n - 1.0 / Delta) * n * n / dn  # Newton on 1/||q|| - 1/Delta (eq. 5.5)
        if not lo < lam < hi:
            lam = max(np.sqrt(lo * hi), 1e-3 * hi)
    return steps.step(lam), lam


def least_squares(
    fun: Callable[[np.ndarray], np.ndarray],
    x0,
    jac: Callable[[np.ndarray], np.ndarray] | None = None,
    *,
    x_scale="jac",
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    gtol: float = 1e-8,
    max_nfev: int | None = None,
    blocks: tuple[int, int] | None = None,
) -> LsqResult:
    """Minimise ``0.5 * ||fun(x)||^2`` by Levenberg-Marquardt.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> ndarray (m,)``, the residuals, m >= n.
    x0 : array_like, shape (n,)
        Start.
    jac : callable, optional
        ``jac(x) -> ndarray (m, n)`` (dense or scipy.sparse); omitted: forward differences.
    x_scale : "jac" or float or array_like (n,)
        Characteristic size of each variable (the trust region is ``||p / x_scale|| <=
        Delta``); ``"jac"`` scales by the Jacobian's column norms, updated as they grow.
    ftol, xtol, gtol : float
        MINPACK's tests: relative reduction of the cost (actual and predicted) below ``ftol``;
        trust radius below ``xtol * ||D x||``; largest cosine between ``fun`` and a column of
        ``jac`` below ``gtol``.
    max_nfev : int, optional
        Limit on evaluations of ``fun`` (default ``100 n``, scipy's for ``"lm"``).
    blocks : (n0, b), optional
        The Jacobian's columns after the first ``n0`` come in groups of ``b`` that share no
        row (e.g. per-pose nuisance parameters): the damped steps are then solved by
        eliminating those groups (a Schur complement, :class:`_BlockSteps`) instead of an SVD
        of the whole Jacobian, unless it is ill-conditioned. Same iterates to rounding noise.

    Returns
    -------
    LsqResult
    """
    x = np.array(x0, dtype=float).ravel()
    n = len(x)
    if max_nfev is None:
        max_nfev = 100 * n
    f = np.asarray(fun(x), dtype=float).ravel()

    def jacobian(x, f):
        return _dense(jac(x)) if jac is not None else _forward_difference(fun, x, f)

    by_jac = isinstance(x_scale, str)
    if by_jac and x_scale != "jac":
        raise ValueError(f"x_scale must be 'jac' or numbers, not {x_scale!r}")
    D = None if by_jac else 1.0 / np.broadcast_to(np.asarray(x_scale, float), (n,)).copy()
    if len(f) < n or (D is not None and not np.all(np.isfinite(D) & (D > 0))):
        return _result(x, f, np.full((len(f), n), np.nan), 1, 0, -1)
    x, f, J, J_at_x, nfev, njev, status = _iterate(
        fun, jacobian, x, f, D, (ftol, xtol, gtol), max_nfev, blocks
    )
    if not J_at_x:  # the Jacobian at the solution (not counted in njev, as in scipy's "lm")
        J = jacobian(x, f)
    return _result(x, f, J, nfev, njev, status)


def _iterate(fun, jacobian, x: np.ndarray, f: np.ndarray, D: np.ndarray | None, tols,
             max_nfev: int, blocks: tuple[int, int] | None = None):  # fmt: skip
    """Moré's iteration from ``x`` (``fun(x) = f``; ``D`` None: scaled by the Jacobian's
    column norms, MINPACK's mode 1): a Jacobian and its SVD, then damped steps in the trust
    region until one reduces the cost, until a test ends the solve.  Returns ``x, f``, the
    last Jacobian and whether it is at ``x``, the evaluation counts and the status."""
    ftol, xtol, gtol = tols
    by_jac = D is None
    nfev, njev = 1, 0
    fnorm = np.linalg.norm(f)
    par, Delta, xnorm = 0.0, 0.0, 0.0
    first = True
    while True:
        J, J_at_x = jacobian(x, f), True
        njev += 1
        col = np.linalg.norm(J, axis=0)
        if by_jac:  # MINPACK mode 1: the column norms, never decreasing
            scale_now = np.where(col > 0, col, 1.0)
            D = scale_now if first else np.maximum(D, scale_now)
        if first:
            xnorm = np.linalg.norm(D * x)
            Delta = 100.0 * xnorm if xnorm > 0 else 100.0
        g = J.T @ f
        if fnorm == 0 or np.max(np.abs(g) / np.where(col > 0, col, np.inf)) <= gtol * fnorm:
            return x, f, J, J_at_x, nfev, njev, 1
        steps = _steps(J / D, f, blocks)
        while True:  # until a step reduces the cost (or a test ends the solve)
            q, par = _lm_step(steps, Delta, par)
            p = q / D
            pnorm = np.linalg.norm(q)
            if first:
                Delta = min(Delta, pnorm)
            x_new = x + p
            f_new = np.asarray(fun(x_new), dtype=float).ravel()
            nfev += 1
            fnorm_new = np.linalg.norm(f_new) if np.all(np.isfinite(f_new)) else np.inf
            actred = 1.0 - (fnorm_new / fnorm) ** 2 if 0.1 * fnorm_new < fnorm else -1.0
            prered, dirder = _predicted(J, p, pnorm, par, fnorm)
            ratio = actred / prered if prered != 0 else 0.0
            Delta, par = _new_radius(ratio, actred, dirder, (fnorm_new, fnorm), Delta, pnorm, par)
            accepted = ratio >= 1e-4
            if accepted:
                x, f, fnorm, J_at_x = x_new, f_new, fnorm_new, False
                xnorm = np.linalg.norm(D * x)
            first = False
            status = _status(actred, prered, ratio, Delta <= xtol * xnorm, ftol, nfev, max_nfev)
            if status is not None:
                return x, f, J, J_at_x, nfev, njev, status
            if accepted:
                break


def _predicted(J: np.ndarray, p: np.ndarray, pnorm: float, par: float,
               fnorm: float) -> tuple[float, float]:  # fmt: skip
    """Moré's predicted relative reduction of the cost by the step ``p`` (``pnorm`` its
    scaled length, ``par`` its damping) and the directional derivative, as MINPACK's lmder."""
    t1 = np.linalg.norm(J @ p) / fnorm
    t2 = np.sqrt(par) * pnorm / fnorm
    return t1 * t1 + 2.0 * t2 * t2, -(t1 * t1 + t2 * t2)


def _new_radius(ratio: float, actred: float, dirder: float, norms: tuple[float, float],
                Delta: float, pnorm: float, par: float) -> tuple[float, float]:  # fmt: skip
    """The trust radius and damping after a step, from the ratio of actual to predicted
    reduction (lmder): shrunk when it is at most 1/4, doubled when at least 3/4 (or
    undamped); ``norms``: the residual norms after and before the step."""
    fnorm_new, fnorm = norms
    if ratio <= 0.25:  # shrink the trust region
        temp = 0.5 if actred >= 0 else 0.5 * dirder / (dirder + 0.5 * actred)
        if 0.1 * fnorm_new >= fnorm or temp < 0.1:
            temp = 0.1
        Delta = temp * min(Delta, pnorm / 0.1)
        par /= temp
    elif par == 0 or ratio >= 0.75:
        Delta = pnorm / 0.5
        par *= 0.5
    return Delta, par


def _status(actred: float, prered: float, ratio: float, x_ok: bool, ftol: float, nfev: int,
            max_nfev: int) -> int | None:  # fmt: skip
    """MINPACK's tests after a step: scipy's status (2 ftol, 3 xtol, 4 both, 0 the
    evaluations used up), or None to go on."""
    f_ok = abs(actred) <= ftol and prered <= ftol and 0.5 * ratio <= 1
    if f_ok or x_ok:
        return 4 if (f_ok and x_ok) else (2 if f_ok else 3)
    if nfev >= max_nfev:
        return 0
    return None


def _result(x, f, J, nfev, njev, status) -> LsqResult:
    return LsqResult(
        x=x,
        fun=f,
        jac=J,
        cost=0.5 * float(f @ f),
        nfev=nfev,
        njev=njev,
        status=status,
        message=MESSAGES[status],
        success=status > 0,
        optimality=float(np.max(np.abs(J.T @ f))) if J.size else 0.0,
    )
