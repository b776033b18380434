"""The next pose that helps most, and how long to hold the current one (issue 27 points 1, 2).

From the current pose, a person can turn the unit about one of its own axes (+X, -X, +Y, -Y,
+Z, -Z) by 45, 90, 135 or 180 degrees: 24 candidates (:func:`candidates`), of which those
about an axis within :data:`MIN_TILT_DEG` of the vertical are left out (gravity does not see
them: neither sensor learns anything).  Each candidate adds to the design a turn (the gyro's
information, :func:`~.design_information.turn_rows`) and a new still pose held for the
shortest hold (the accelerometer's, with the label's placement error, and the gyro's bias).
:func:`propose` ranks them by the design's predicted std against the targets: the worst
target's ratio first, then the sum of the squared ratios of the targets not yet met.

Before the design determines every target, no candidate's worst target is finite: the ranking
is then by the information gained overall (D-optimality: the log-determinant of both sensors'
information over a prior of a consumer part's spread, :data:`PRIOR`: biases of 50 mg and 3
deg/s, gains 3 %, axes 1 degree, the frame 2 degrees), so that the first poses are chosen for
all they will determine.  The prior only ranks: what the capture states is its refit.

How long to hold (:func:`hold_length`): holding longer shrinks what this pose's samples
determine (its mean, the gyro's bias, the directions of the turns beside it) with diminishing
returns, while the next pose costs a move.  The hold ends at the first length where a further
:data:`HOLD_STEP_S` shrinks the worst target, per second, less than the best next step would
(its improvement over the step's cost, reaction and move and the shortest hold), or less than
:data:`MIN_SHRINK_PER_S`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .information import (
    DesignStd,
    Fit,
    Noise,
    Pose,
    TermStd,
    Turn,
    accel_covariance,
    accel_terms,
    design_turns,
    gyro_terms,
    pose_information,
    turn_rows,
)

__all__ = [
    "ANGLES_DEG",
    "Candidate",
    "Proposal",
    "candidates",
    "hold_length",
    "plan_hold",
    "propose",
    "ratios",
    "score",
]

ANGLES_DEG = (45.0, 90.0, 135.0, 180.0)
"""The turns a person is asked for, degrees."""

MIN_TILT_DEG = 30.0
"""A turn about an axis this close to the vertical is not proposed, degrees."""

HOLD_STEP_S = 0.25
"""The hold's length is judged in steps of this, s."""

MIN_SHRINK_PER_S = 0.02
"""A hold goes on only while it shrinks the worst target by at least this much per second (a
fraction; below it, more samples no longer help whatever the next step would do)."""

TERMS = ("gain", "bias", "misalignment")

PRIOR = {"accel_bias_g": 0.05, "gain": 0.03, "axes_deg": 1.0, "frame_deg": 2.0,
         "gyro_bias_dps": 3.0}
"""The spread of a consumer part (1 std) the ranking assumes before the data tell."""


def _prior(fit: Fit) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal prior information on the accelerometer's ``theta = (B, K, r)`` and the gyro's
    ``(b, vec M)`` (:data:`PRIOR`)."""
    theta = fit.theta()
    k = np.abs(theta[3:6])  # K's diagonal, raw -> m/s^2 per raw unit
    sa = 1.0 / k  # raw units per m/s^2
    std_a = np.r_[PRIOR["accel_bias_g"] * fit.gravity * sa, PRIOR["gain"] * k,
                  np.radians(PRIOR["axes_deg"]) * k[[0, 0, 1]], np.full(3, PRIOR["frame_deg"])]
    M = np.asarray(fit.gyro_matrix, float)
    scale = float(np.mean(np.abs(np.diag(M))))
    std_g = np.r_[np.full(3, np.radians(PRIOR["gyro_bias_dps"]) / scale),
                  np.where(np.eye(3).ravel() > 0, PRIOR["gain"] * scale,
                           np.radians(PRIOR["axes_deg"]) * scale)]  # fmt: skip
    return np.diag(1.0 / std_a**2), np.diag(1.0 / std_g**2)


@dataclass(frozen=True)
class Candidate:
    """A turn about the unit's own ``axis`` (a unit vector along one of its axes) by
    ``angle_deg`` (right hand), taking the gravity direction from ``up_before`` to
    ``up_after`` (both in the unit's frame)."""

    axis: np.ndarray
    angle_deg: float
    up_before: np.ndarray
    up_after: np.ndarray


@dataclass(frozen=True)
class Proposal:
    """A candidate, the std the design would then have, and its :func:`score`."""

    candidate: Candidate
    predicted: DesignStd
    score: tuple[float, float]


def candidates(up: np.ndarray, min_tilt_deg: float = MIN_TILT_DEG) -> list[Candidate]:
    """The turns a person can be asked for from the pose whose gravity direction (in the
    unit's frame) is ``up``."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    out = []
    for k in range(3):
        for sign in (1.0, -1.0):
            axis = sign * np.eye(3)[k]
            tilt = np.degrees(np.arccos(np.clip(abs(axis @ up), 0.0, 1.0)))
            if tilt < min_tilt_deg:
                continue
            for angle in ANGLES_DEG:
                if angle == 180.0 and sign < 0:  # the same pose as +180 about +axis
                    continue
                R = Rotation.from_rotvec(np.radians(angle) * axis).as_matrix()
                out.append(Candidate(axis, angle, up, R.T @ up))
    return out


def ratios(std: DesignStd, limits: dict[tuple[str, str], float]) -> dict[tuple[str, str], float]:
    """Each limited term's worst std over its limit (``inf`` while undetermined); ``limits``
    in :class:`TermStd` units (gain relative, bias SI, misalignment deg)."""
    out = {}
    for (sensor, term), limit in limits.items():
        terms: TermStd | None = getattr(std, sensor)
        if terms is None:
            out[(sensor, term)] = np.inf
            continue
        values = {"gain": terms.gain, "bias": terms.bias, "misalignment": terms.misalignment_deg}
        out[(sensor, term)] = float(np.max(values[term])) / limit
    return out


def score(r: dict[tuple[str, str], float]) -> tuple[float, float]:
    """``(worst ratio, sum of the squared finite ratios above 1)``: smaller is better."""
    worst = max(r.values(), default=0.0)
    rest = sum(x * x for x in r.values() if np.isfinite(x) and x > 1.0)
    return worst, rest


class _Base:
    """The design's information, summed once for many additions: each pose's accelerometer
    information, the turns' gyro information, the still samples."""

    def __init__(self, fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise):
        self.fit, self.poses, self.turns, self.noise = fit, poses, turns, noise
        self.P = pose_information(fit, poses, noise) if poses else np.zeros((0, 12, 12))
        self.A = self.P.sum(axis=0) if poses else np.zeros((12, 12))
        self.I, self.X = design_turns(fit, poses, turns, noise).information()
        self.n_still = sum(p.n for p in poses)
        self.prior = _prior(fit)

    def std(self, A: np.ndarray, info: np.ndarray, cross: np.ndarray, n_turns: int,
            n_still: int) -> DesignStd:  # fmt: skip
        """Both sensors' :class:`TermStd` from these sums."""
        cov = accel_covariance(A)
        accel = None if cov is None else accel_terms(self.fit, A, cov)
        gyro = None
        if accel is not None and n_turns:
            info = info.copy()
            info[:3, :3] += n_still / self.noise.gyro_raw**2 * np.eye(3)
            gyro = gyro_terms(self.fit, info, cross, cov)
        return DesignStd(accel, gyro)

    def gained(self, A: np.ndarray, info: np.ndarray, n_still: int) -> float:
        """The information over the prior, both sensors: ``log det(I + P) - log det(P)``."""
        prior_a, prior_g = self.prior
        info = info.copy()
        info[:3, :3] += n_still / self.noise.gyro_raw**2 * np.eye(3)
        out = 0.0
        for I, P in ((A, prior_a), (info, prior_g)):
            d = 1.0 / np.sqrt(np.diag(P))
            out += float(np.linalg.slogdet(d[:, None] * (I + P) * d)[1])
        return out

    def now(self) -> DesignStd:
        return self.std(self.A, self.I, self.X, len(self.turns), self.n_still)

    def with_last_held(self, n: int) -> DesignStd:
        """The design with its last pose held ``n`` samples (its turn in, recomputed)."""
        last = self.poses[-1]
        pose = Pose(last.up, int(n), last.placement_deg)
        A = self.A - self.P[-1] + pose_information(self.fit, [pose], self.noise)[0]
        info, cross = self.I, self.X
        into = [t for t in self.turns if t.after == len(self.poses) - 1]
        if into:
            held = [*self.poses[:-1], pose]
            old = design_turns(self.fit, self.poses, into, self.noise).information()
            new = design_turns(self.fit, held, into, self.noise).information()
            info, cross = info - old[0] + new[0], cross - old[1] + new[1]
        return self.std(A, info, cross, len(self.turns), self.n_still - last.n + int(n))

    def with_steps(self, cands: list[Candidate], hold_n: int, move_s: float,
                   placement_deg: float) -> list[tuple[DesignStd, float]]:  # fmt: skip
        """The design after each candidate (the turn, then a new pose held ``hold_n``): its
        std and its information gained (:meth:`gained`)."""
        if not cands:
            return []
        last = self.poses[-1]
        new = [Pose(c.up_after, hold_n, placement_deg) for c in cands]
        P = pose_information(self.fit, new, self.noise)
        k = len(cands)
        rows = turn_rows(self.fit, np.tile(last.up, (k, 1)), np.array([c.axis for c in cands]),
                         np.radians([c.angle_deg for c in cands]), np.full(k, move_s),
                         np.full(k, last.n), np.full(k, hold_n), self.noise)  # fmt: skip
        JW = np.einsum("kai,kab->kib", rows.J, rows.W)
        dI = np.einsum("kib,kbj->kij", JW, rows.J)
        dX = np.einsum("kib,kbj->kij", JW, rows.F)
        n = self.n_still + hold_n
        return [(self.std(self.A + P[i], self.I + dI[i], self.X + dX[i], len(self.turns) + 1, n),
                 self.gained(self.A + P[i], self.I + dI[i], n)) for i in range(k)]  # fmt: skip


def propose(fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise,
            limits: dict[tuple[str, str], float], *, hold_n: int, move_s: float = 1.5,
            placement_deg: float = np.inf) -> list[Proposal]:  # fmt: skip
    """Every candidate from the last pose, best first (see the module notes).

    Parameters
    ----------
    fit, poses, turns, noise
        The design so far at the current fit (the last pose is where the unit is).
    limits : dict
        ``(sensor, term)`` -> the target in :class:`TermStd` units.
    hold_n : int
        Samples of the shortest hold (the new pose's).
    move_s : float
        How long a turn takes, s.
    placement_deg : float
        The new pose's label error (``inf``: the accelerometer fit uses no labels).
    """
    if not poses:
        return []
    base = _Base(fit, poses, turns, noise)
    determined = np.isfinite(score(ratios(base.now(), limits))[0])
    cands = candidates(poses[-1].up)
    out = []
    for c, (std, gained) in zip(cands, base.with_steps(cands, hold_n, move_s, placement_deg),
                                strict=True):  # fmt: skip
        worst, rest = score(ratios(std, limits))
        key = (worst, rest) if determined or np.isfinite(worst) else (np.inf, -gained)
        out.append(Proposal(c, std, key))
    out.sort(key=lambda p: p.score)
    return out


def hold_length(fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise,
                limits: dict[tuple[str, str], float], *, min_n: int, max_n: int,
                step_gain: float, step_s: float) -> int:  # fmt: skip
    """How many samples to hold the last pose (between ``min_n`` and ``max_n``).

    ``step_gain`` is how much the best next step would shrink the worst target (log of the
    ratio before over after, from :func:`propose`), ``step_s`` what it costs (s): the hold
    goes on while a further :data:`HOLD_STEP_S` shrinks the worst target faster per second,
    and stops at once when every target is met.
    """
    dn = max(1, int(round(HOLD_STEP_S * noise.rate_hz)))
    per_s = max(max(step_gain, 0.0) / max(step_s, 1e-9), MIN_SHRINK_PER_S)
    n = int(min_n)
    base = _Base(fit, poses, turns, noise)
    worst = score(ratios(base.with_last_held(n), limits))[0]
    while n < max_n:
        if worst <= 1.0:
            return n
        nxt = score(ratios(base.with_last_held(n + dn), limits))[0]
        if not np.isfinite(worst) or not np.isfinite(nxt):
            return n  # more of this pose cannot determine what is missing: move on
        if np.log(worst / nxt) / HOLD_STEP_S <= per_s:
            return n
        n, worst = n + dn, nxt
    return int(max_n)


def plan_hold(fit: Fit, poses: list[Pose], turns: list[Turn], noise: Noise,
              limits: dict[tuple[str, str], float], *, min_n: int, max_n: int, move_s: float,
              step_s: float, placement_deg: float = np.inf) -> int:  # fmt: skip
    """How many samples to hold the last pose, the pose in progress (:func:`hold_length`),
    against the best next step from it after the shortest hold (:func:`propose`)."""
    held = [*poses[:-1], Pose(poses[-1].up, int(min_n), poses[-1].placement_deg)]
    now = score(ratios(_Base(fit, held, turns, noise).now(), limits))[0]
    best = propose(fit, held, turns, noise, limits, hold_n=int(min_n), move_s=move_s,
                   placement_deg=placement_deg)  # fmt: skip
    after = best[0].score[0] if best else np.inf
    if np.isfinite(now) and np.isfinite(after) and after > 0:
        gain = float(np.log(now / after))
    else:
        gain = np.inf if np.isfinite(after) or not np.isfinite(now) else 0.0
    return hold_length(fit, poses, turns, noise, limits, min_n=min_n, max_n=max_n,
                       step_gain=gain, step_s=step_s)  # fmt: skip
