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
deficient), the radius updated from the ratio of actual to predicted reduction, and
MINPACK's three tests (``ftol``, ``xtol``, ``gtol``). The parameter counts we solve are tens,
the residual counts up to tens of thousands: one thin SVD per Jacobian is cheap.

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


def _lm_step(s, V, c, Delta, par):
    """Moré's damped step in scaled variables, ``q = -V diag(s / (s^2 + lambda)) c``, with
    ``lambda >= 0`` such that ``||q||`` is within 10% of ``Delta`` (``lambda = 0`` when the
    Gauss-Newton step is already inside). ``par`` is the previous ``lambda`` (a start).
    Returns ``(q, lambda)``."""
    s_max = s[0] if len(s) else 0.0
    keep = s > EPS * max(len(s), 1) * max(len(c), 1) * s_max  # numerical rank
    gn = np.zeros_like(c)
    gn[keep] = c[keep] / s[keep]
    gn_norm = np.linalg.norm(gn)
    sc = s * c
    if gn_norm <= 1.1 * Delta or not np.any(sc):
        return -(V @ gn), 0.0

    def norm_and_derivative(lam):
        d = s * s + lam
        t = sc / d
        n = np.linalg.norm(t)
        return n, -float(np.sum(t * t / d)) / n  # ||q||, d||q||/dlambda

    # lambda is bracketed: below by the Newton step from 0 (full rank), above by ||A^T f||/Delta
    hi = np.linalg.norm(sc) / Delta
    lo = 0.0
    if keep.all():
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
    return -(V @ (sc / (s * s + lam))), lam


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
        fun, jacobian, x, f, D, (ftol, xtol, gtol), max_nfev
    )
    if not J_at_x:  # the Jacobian at the solution (not counted in njev, as in scipy's "lm")
        J = jacobian(x, f)
    return _result(x, f, J, nfev, njev, status)


def _iterate(fun, jacobian, x: np.ndarray, f: np.ndarray, D: np.ndarray | None, tols,
             max_nfev: int):  # fmt: skip
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
        U, s, Vt = np.linalg.svd(J / D, full_matrices=False)
        c = U.T @ f
        while True:  # until a step reduces the cost (or a test ends the solve)
            q, par = _lm_step(s, Vt.T, c, Delta, par)
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
