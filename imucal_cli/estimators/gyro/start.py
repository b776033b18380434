"""Start values of the full gyro model that need no nominal sensitivity (issue 10.1).

The full model ``omega = M (z - b)`` is fitted by Gauss-Newton from a start; a start 40 % off in
scale falls into another minimum. This module finds the start from the data alone:

1. **Bias**: the still periods' gyro means (closed form).
2. **Scale** ``lambda`` (rad/s per raw unit): a turn that gravity sees by an angle ``alpha_k``
   (between the still directions before and after) turned at least that much, so
   ``lambda >= alpha_k / |x_k|`` with ``x_k`` the bias-free raw integral, with equality for a
   fixed-axis turn about a horizontal axis. Hand turns about many axes put the upper quantile
   of these ratios near ``lambda``: that is the first estimate. A turn about a fixed axis
   integrates to its angle, but a tumble through many attitudes (a magnetometer plan's moves)
   does not: its raw integral can be far shorter than the way it turned, and its ratio far
   above ``lambda`` (a qureshi18 --mag session, seed 7338: 0.2-5 lambda, the upper quantile 1.8
   lambda, the search below never reached lambda and the fit ended at 1/30 of the gains).
   The raw path ``P_k = integral |z - b| dt`` bounds ``lambda`` from below for any turn
   (``lambda >= alpha_k / P_k``), so the orientations are also scored, and the scale
   searched, down to that bound.
3. **Orientation** of the gyro triad in the accelerometer's frame, among the 48 signed
   permutations (a gyro mounted with axes swapped or reversed, or left-handed). For
   ``M = lambda R0`` every rotation is a conjugate, ``R_k(lambda R0) = R0 R_k(+-lambda I) R0^T``
   (``-`` for a reflection), so two integrations score all 48 by the gravity mismatch
   ``sum_k |R_k^T u_before - u_after|^2``.
4. **Scale refined** for the best orientations: a grid over ``[0.7, 3] lambda`` (from 0.9 of
   the path's bound where that is lower) then a bounded scalar search of the same mismatch.

Every integration here is coarse (one rotation per block of samples, about 25 per second).
The starts, best first, go to the Gauss-Newton fit (:func:`imucal_cli.estimators.gyro.full`),
which tries the next one when a start ends in a fit that does not explain the turns.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import permutations, product

import numpy as np
from scipy.optimize import minimize_scalar

from imucal_cli.errors import DesignError
from imucal_cli.estimators.gyro.integration import Stack, compose_ends, quat_to_matrix

#: Turns that gravity sees by less than this carry no scale information for the start.
MIN_SEEN_DEG = 10.0
#: Upper quantile of the seen-angle / integral ratios taken as the first scale.
SCALE_QUANTILE = 0.9
#: Bracket of the scale search, relative to the first scale.
SCALE_BRACKET = (0.7, 3.0)
#: The coarse integrator of the start composes blocks of samples at about this rate.
COARSE_RATE_HZ = 25.0
#: Scales integrated together by the coarse integrator (the turns repeated once per scale) up
#: to this many samples in all: one pass for several where per-pass costs dominate (short
#: recordings), bounded memory where the samples do (thousands of turns).
BATCH_SAMPLES = 1 << 18


@dataclass
class Start:
    """A start of the full model: ``M = scale * orientation``."""

    M: np.ndarray
    scale: float
    orientation: np.ndarray
    mismatch: float  # sum over turns of |predicted - measured gravity direction|^2
    given: str | None = None  # how a start not found here was chosen

    @property
    def describe(self) -> str:
        if self.given:
            return self.given
        o = self.orientation
        if np.allclose(o, np.eye(3)):
            axes = "gyro axes along the accelerometer's"
        else:
            names = [("-" if o[i, j] < 0 else "+") + "xyz"[j] for i in range(3)
                     for j in range(3) if o[i, j]]  # fmt: skip
            axes = "accelerometer x, y, z measured by gyro channels " + ", ".join(names)
        return f"start: scale {self.scale:.6g} rad/s per raw unit, {axes}"


def signed_permutations() -> np.ndarray:
    """The 48 signed permutation matrices (24 rotations first, then 24 reflections)."""
    mats = []
    for perm in permutations(range(3)):
        for signs in product((1, -1), repeat=3):
            m = np.zeros((3, 3))
            m[np.arange(3), perm] = signs
            mats.append(m)
    mats.sort(key=lambda m: -np.linalg.det(m))
    return np.array(mats)


class _Turns:
    """What the start needs of each turn: the bias-free raw integral, the unit gravity
    directions before and after, and a coarse integrator.

    The coarse integrator composes one rotation per block of samples (the block's raw
    integral, scaled): exact for a turn about a fixed axis, and within a fraction of a degree
    for hand turns, enough to find the start at a fraction of the cost of a full integration.
    """

    def __init__(self, t, z, g_before, g_after, b0, clock):
        full = Stack.of(t)  # every turn's samples end to end
        h = clock * np.diff(full.t)
        inside = full.pos[1:] > 0  # the interval from row i to i + 1 lies within a turn
        dt = np.median(np.diff(full.t)[inside])
        m = max(1, int(round(1 / (COARSE_RATE_HZ * max(clock * dt, 1e-12)))))
        # Each interval's trapezoid integral of the bias-free rate (zero across two turns).
        d = np.concatenate(z).astype(float) - np.asarray(b0, float)
        inc = np.zeros_like(d)
        inc[:-1] = h[:, None] * (d[:-1] + d[1:]) / 2
        inc[:-1][~inside] = 0.0
        last = full.stop[full.seg] - 1 == np.arange(len(full.t))
        keep = np.flatnonzero((full.pos % m == 0) | last)  # every m-th row and the last one
        # The raw integral of each block: from the kept row before to this one, 0 at the first.
        steps = np.zeros((len(keep), 3))
        steps[1:] = np.add.reduceat(inc, keep, axis=0)[:-1]
        steps[full.pos[keep] == 0] = 0.0
        self.x = np.add.reduceat(inc, full.start, axis=0)  # (K, 3): each turn's raw integral
        # each turn's raw path: the length of the way its raw integral went
        self.path = np.add.reduceat(np.linalg.norm(inc, axis=1), full.start)
        n_kept = np.bincount(full.seg[keep], minlength=len(t))
        coarse_t = np.split(full.t[keep], np.cumsum(n_kept)[:-1])
        self.stack = Stack.of(coarse_t)
        self.coarse_t, self._stacks = coarse_t, {1: self.stack}
        self.steps = np.ascontiguousarray(steps.T)  # (3, n_coarse): raw integral of each block
        self.u0 = g_before / np.linalg.norm(g_before, axis=1, keepdims=True)
        self.u1 = g_after / np.linalg.norm(g_after, axis=1, keepdims=True)

    def rotations(self, scale: float) -> np.ndarray:
        """(K, 3, 3) rotations of the turns with ``M = scale * I``."""
        return self.rotations_at([scale])[0]

    def rotations_at(self, scales) -> np.ndarray:
        """(S, K, 3, 3) rotations of the turns with ``M = scale * I`` for each of ``S``
        scales, integrated together (the turns repeated once per scale: one pass for several,
        up to :data:`BATCH_SAMPLES` coarse samples at a time)."""
        per = max(1, BATCH_SAMPLES // len(self.stack.t))
        out = []
        for i in range(0, len(scales), per):
            part = scales[i : i + per]
            if len(part) not in self._stacks:  # at most BATCH_SAMPLES rows each
                self._stacks[len(part)] = Stack.of(self.coarse_t * len(part))
            stack = self._stacks[len(part)]
            phi = np.concatenate([s * self.steps for s in part], axis=1)
            out.append(quat_to_matrix(compose_ends(stack, phi)).reshape(len(part), -1, 3, 3))
        return np.concatenate(out)

    def mismatch(self, R: np.ndarray, O: np.ndarray) -> np.ndarray:
        """Gravity mismatch of each orientation ``O`` (n, 3, 3) given the turns' rotations
        ``R`` integrated with ``det(O) * scale``: shape (n,)."""
        # Stacked matrix products (an einsum of these shapes took 4 times as long).
        v = self.u0 @ O  # (n, K, 3): O^T u0
        v = (v[:, :, None, :] @ R)[:, :, 0]  # R^T O^T u0
        p = v @ O.transpose(0, 2, 1)  # O R^T O^T u0
        return np.sum((p - self.u1) ** 2, axis=(1, 2))


def first_scale(turns: _Turns) -> float:
    """Scale from the angles gravity sees against the raw integrals (step 2)."""
    seen = np.arccos(np.clip(np.sum(turns.u0 * turns.u1, axis=1), -1, 1))
    raw = np.linalg.norm(turns.x, axis=1)
    ok = (seen > np.radians(MIN_SEEN_DEG)) & (raw > 0)
    if not ok.any():
        raise DesignError(
            f"no rotation turns the gravity direction by {MIN_SEEN_DEG:g} degrees or more: the "
            "accelerometer cannot see the turns; turn the unit about horizontal axes"
        )
    return float(np.quantile(seen[ok] / raw[ok], SCALE_QUANTILE))


def lowest_scale(turns: _Turns) -> float:
    """The largest ``alpha_k / P_k`` (module notes, step 2): no scale below it turns every
    turn by the angle gravity sees (inf when no turn is seen)."""
    seen = np.arccos(np.clip(np.sum(turns.u0 * turns.u1, axis=1), -1, 1))
    ok = (seen > np.radians(MIN_SEEN_DEG)) & (turns.path > 0)
    return float(np.max(seen[ok] / turns.path[ok])) if ok.any() else np.inf


def start_values(
    t: list[np.ndarray],
    z: list[np.ndarray],
    g_before: np.ndarray,
    g_after: np.ndarray,
    b0: np.ndarray,
    *,
    clock: float = 1.0,
    n_best: int = 3,
) -> Iterator[Start]:
    """Starts of the full model from the data alone, best first (computed as they are asked
    for: the scale is refined for an orientation only when its start is wanted).

    Parameters
    ----------
    t, z : list of ndarray (n_k,), (n_k, 3)
        Sample times (s) and raw gyro samples of each turn.
    g_before, g_after : ndarray (K, 3)
        Calibrated accelerometer means of the still periods before and after each turn.
    b0 : ndarray (3,)
        Gyro bias, raw units (the still periods' means).
    clock : float
        Factor on every time interval.
    n_best : int
        How many distinct orientations to offer.

    Yields
    ------
    Start
        By increasing gravity mismatch of the orientation at the first scale.
    """
    turns = _Turns(t, z, g_before, g_after, b0, clock)
    lam = first_scale(turns)
    low = min(0.9 * lowest_scale(turns), lam * SCALE_BRACKET[0])  # 0.9: unequal gains, noise
    O = signed_permutations()
    proper = np.linalg.det(O) > 0
    score = np.full(len(O), np.inf)
    factors = [1.0, 1.4, 2.0]  # the first scale is about a lower bound: look a little above
    if low < lam * SCALE_BRACKET[0]:  # tumbles: down to the path's bound, steps of 1.4
        n = int(np.ceil(np.log(lam * SCALE_BRACKET[0] / low) / np.log(1.4)))
        factors += list(np.geomspace(low / lam, SCALE_BRACKET[0], n + 1)[:-1])
    trials = [(sign * f * lam, which) for f in factors
              for sign, which in ((1.0, proper), (-1.0, ~proper))]  # fmt: skip
    for R, (_, which) in zip(turns.rotations_at([s for s, _ in trials]), trials, strict=True):
        score[which] = np.minimum(score[which], turns.mismatch(R, O[which]))
    for i in np.argsort(score)[:n_best]:
        scale, mismatch = _refine_scale(turns, O[i], lam, low)
        yield Start(scale * O[i], scale, O[i], mismatch)


def _refine_scale(turns: _Turns, O: np.ndarray, lam: float, low: float
                  ) -> tuple[float, float]:  # fmt: skip
    """Scale minimising the gravity mismatch for orientation ``O`` (step 4), searched from
    ``low`` (at most the bracket's lower end) up to the bracket's upper end."""
    sign = np.sign(np.linalg.det(O))

    def cost(log_scale):
        return float(turns.mismatch(turns.rotations(sign * np.exp(log_scale)), O[None])[0])

    lo, hi = np.log(min(low, lam * SCALE_BRACKET[0])), np.log(lam * SCALE_BRACKET[1])
    # 9 points over the bracket (steps of 1.2), as many more below it
    grid = np.linspace(lo, hi, max(9, int(np.ceil((hi - lo) / np.log(1.2))) + 1))
    R = turns.rotations_at(sign * np.exp(grid))  # the grid integrated at once
    values = [float(turns.mismatch(Rg, O[None])[0]) for Rg in R]
    i = int(np.argmin(values))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    sol = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 2e-3})
    best = (sol.x, sol.fun) if sol.fun <= values[i] else (grid[i], values[i])
    return float(np.exp(best[0])), float(best[1])
