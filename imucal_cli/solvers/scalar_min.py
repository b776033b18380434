"""Bounded minimisation of a function of one variable (numpy-free, no scipy.optimize).

Brent's ``localmin`` (Brent 1973, ch. 5; Forsythe, Malcolm & Moler 1977, ``fmin``): golden
section steps, parabolic interpolation through the three best points when it is safe. What
``scipy.optimize.minimize_scalar(method="bounded")`` does, without its 0.4 s import.
"""

from __future__ import annotations

import math
from collections.abc import Callable

GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))
SQRT_EPS = math.sqrt(2.2e-16)


def minimize_bounded(
    f: Callable[[float], float], a: float, b: float, xatol: float = 1e-5, max_fev: int = 500
) -> tuple[float, float, int]:
    """A local minimum of ``f`` on ``[a, b]`` to about ``xatol``.

    Returns ``(x, f(x), evaluations)``.
    """
    v = w = x = a + GOLDEN * (b - a)
    fv = fw = fx = f(x)
    d = e = 0.0
    n = 1
    while n < max_fev:
        m = 0.5 * (a + b)
        tol = SQRT_EPS * abs(x) + xatol / 3.0
        if abs(x - m) <= 2.0 * tol - 0.5 * (b - a):
            break
        golden = True
        if abs(e) > tol:  # try a parabola through x, w, v
            r = (x - w) * (fx - fv)
            q = (x - v) * (fx - fw)
            p = (x - v) * q - (x - w) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = abs(q)
            e_prev, e = e, d
            if abs(p) < abs(0.5 * q * e_prev) and q * (a - x) < p < q * (b - x):
                d = p / q
                golden = False
                u = x + d
                if u - a < 2.0 * tol or b - u < 2.0 * tol:
                    d = tol if m >= x else -tol
        if golden:
            e = (a if x >= m else b) - x
            d = GOLDEN * e
        u = x + (d if abs(d) >= tol else (tol if d >= 0 else -tol))
        fu = f(u)
        n += 1
        if fu <= fx:
            if u >= x:
                a = x
            else:
                b = x
            v, fv, w, fw, x, fx = w, fw, x, fx, u, fu
        else:
            if u < x:
                a = u
            else:
                b = u
            if fu <= fw or w == x:
                v, fv, w, fw = w, fw, u, fu
            elif fu <= fv or v == x or v == w:
                v, fv = u, fu
    return x, fx, n
