"""Which step of a plan each still period and each motion of a recording is (unattended
capture, :mod:`.unattended`).

Seeing a plan
-------------
A **still period** is seen when it lasted at least ``min_still_s`` and was followed by motion
(or by the end of the recording); while recording, the still period in progress counts once it
has lasted ``min_still_s + FINAL_HOLD_EXTRA_S``, so the recording can stop in the last pose.
Every second the still periods since the last confirmed one are searched again.

- A static step with ``up`` is seen when a still period's mean accelerometer direction lies
  within :data:`MATCH_DEG` of its ``up`` and of no other step's.  This needs raw data centred
  on zero (counts of a signed ADC, g, m/s^2): when the still periods' mean magnitudes differ by
  more than :data:`MAX_MAGNITUDE_RATIO` (an unsigned ADC, a large bias) directions are not
  used, and static steps are counted instead (as many still periods as static steps).
- Static steps without ``up`` are counted.
- A static step with its own ``hold_s`` (the ``still:MINUTES`` plan) needs a still period at
  least that long: while recording, the shortest still period that counts is the plan's
  longest ``hold_s`` (so a still plan records its full duration).
- A rotation step is seen in the motion between two still periods when the gyroscope's
  integrated rotation (bias from the neighbouring still periods) points along its ``axis``
  within :data:`MATCH_DEG` (either sign when the plan leaves the angle free) and, when the step
  has an ``angle_deg`` and directions are usable, the turn by that angle takes the still
  direction before onto the one after within :data:`MATCH_DEG`.  Without a gyroscope, rotation
  steps are counted as motions between still periods.

A plan with rotation steps is performed in its order (each turn starts from the pose before
it): the still periods and the motions between them are aligned with the steps in plan order
(:func:`_match_in_order`, an edit distance that sees as many steps as possible; a pause within
a turn or the move to the next block's face is passed over), with the fits above; a pose plan
is matched in any order as above.

A segment is labelled by the step it matches where the data checked the match (a direction, an
axis), or where the order alone fixes it: between two checked still periods (or a checked one
and an end of the recording) as many still periods as the plan has static steps there
(:func:`order_fixed`; the unlabelled poses and sweeps of a re-mounted unit, plan
``hwangbo-iron``). Otherwise a step is only counted and its segment left unlabelled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.plans import Plan, Step

MATCH_DEG = 20.0
"""A still direction or rotation axis matches a step within this angle, degrees."""

MAX_MAGNITUDE_RATIO = 1.2
"""Still periods whose mean accel magnitudes differ by more than this ratio are not centred
data: their directions are not matched to ``up`` vectors."""


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


@dataclass
class Still:
    start: int
    stop: int
    mean_accel: np.ndarray | None
    mean_gyro: np.ndarray | None


@dataclass
class Matches:
    """Which step (index into plan.steps) each still period and each motion matched."""

    still: list[int | None]
    motion: list[int | None]  # motion i is between still i and i + 1
    directions_used: bool
    ordered: bool = False  # aligned in plan order: every step seen is matched
    checked: set | None = None  # ordered: (0 still / 1 motion, index) the data checked


def _directions_usable(stills: list[Still]) -> bool:
    norms = [np.linalg.norm(s.mean_accel) for s in stills if s.mean_accel is not None]
    if not norms or min(norms) <= 0:
        return False
    return max(norms) / min(norms) <= MAX_MAGNITUDE_RATIO


def _match_still(
    step_ups: list[tuple[int, np.ndarray]], direction: np.ndarray, used: set[int]
) -> int | None:
    """The first labelled step in plan order, not taken by an earlier still, whose ``up`` is
    within :data:`MATCH_DEG`; a still on a face already taken (the still after a turn on the
    table) is left for the plan's unlabelled steps."""
    close = [i for i, up in step_ups if i not in used and _angle_deg(direction, up) <= MATCH_DEG]
    if close:
        used.add(close[0])
    return close[0] if close else None


def _motion_rotvec(
    time: np.ndarray, gyro: np.ndarray, before: Still, after: Still
) -> tuple[np.ndarray, np.ndarray] | None:
    """Integrated bias-free gyro over the motion between two still periods (raw units * s),
    and the principal axis of its rate (unit, signed like the integral): the axis of a sweep
    that ends where it began, whose integral is nearly zero."""
    if before.mean_gyro is None or after.mean_gyro is None or after.start <= before.stop:
        return None
    bias = 0.5 * (before.mean_gyro + after.mean_gyro)
    a, b = before.stop, after.start
    dt = np.diff(time[a - 1 : b + 1])
    g = gyro[a:b] - bias
    rv = (g * 0.5 * (dt[:-1] + dt[1:])[:, None]).sum(axis=0)
    if not np.linalg.norm(rv) > 0 or g.shape[1] != 3:
        return None
    axis = np.linalg.eigh(g.T @ g)[1][:, -1]
    return rv, axis * (1.0 if axis @ rv >= 0 else -1.0)


def _axis_checkable(step: Step) -> bool:
    """A rotation step whose axis the gyro can check: it has one, in the sensor's own frame
    (mounting 1, where the unit is square in the fixture)."""
    return step.axis is not None and (step.mounting or 1) == 1


def _motion_fits(step: Step, motion: tuple[np.ndarray, np.ndarray], before: Still,
                 after: Still, use_directions: bool) -> bool:  # fmt: skip
    """Whether a motion between two still periods is the rotation ``step`` (its axis checkable):
    its axis within :data:`MATCH_DEG` (either sign for a turn of any angle or a sweep: the
    principal axis of the rate), and a turn of known angle taking the direction before onto
    the one after."""
    rotvec, principal = motion
    if step.angle_deg is None:  # a turn of any angle, or a sweep back and forth
        angle = _angle_deg(principal, step.axis)
        return min(angle, 180.0 - angle) <= MATCH_DEG
    ok = _angle_deg(rotvec * np.sign(step.angle_deg), step.axis) <= MATCH_DEG
    if ok and use_directions and before.mean_accel is not None:
        turn = Rotation.from_rotvec(np.radians(step.angle_deg) * np.asarray(step.axis))
        predicted = turn.inv().apply(before.mean_accel)
        ok = _angle_deg(predicted, after.mean_accel) <= MATCH_DEG
    return ok


def _match_motion(
    steps: list[tuple[int, Step]], motion: tuple[np.ndarray, np.ndarray], before: Still,
    after: Still, use_directions: bool, used: set[int], after_step: int | None,
) -> int | None:  # fmt: skip
    """The first rotation step in plan order, not matched yet, that the motion fits; right
    after a still matched to step j, only step j + 1 (the plan's turn after that pose)."""
    close = []
    for i, step in steps:
        if i in used or not _axis_checkable(step):
            continue
        if after_step is not None and i != after_step + 1:
            continue
        if _motion_fits(step, motion, before, after, use_directions):
            close.append(i)
    if close:
        used.add(close[0])
    return close[0] if close else None


#: A match the data check (a still's direction on a step's ``up``, a motion's axis on a step's
#: ``axis``) outweighs one that is only counted, when both see as many steps.
_CHECKED = 1.001


def _match_in_order(plan: Plan, stills: list[Still], time: np.ndarray,
                    gyro: np.ndarray | None, use_directions: bool) -> Matches:  # fmt: skip
    """A plan with turns, performed in its order (each turn starts from the pose before it):
    the still periods and the motions between them, in time order, aligned with the steps in
    plan order so that as many steps as possible are seen (dynamic programming, as in an edit
    distance).  A still period fits a static step with ``up`` when its direction is within
    :data:`MATCH_DEG` of it (any still when directions are not usable: counted), and any
    static step without ``up``; a motion fits a rotation step whose axis it matches
    (:func:`_motion_fits`), or any rotation step the gyro cannot check.  A still period or a
    motion the plan has no step for (a pause within a turn, the move to the next block's
    face) is passed over, and so is a step not seen."""
    steps = plan.steps
    n, m = len(stills), len(steps)
    n_items = 2 * n - 1  # still 0, motion 0, still 1, ..., still n - 1
    fit = np.zeros((max(n_items, 0), m))
    static = np.array([s.kind == "static" for s in steps], bool)
    if n and static.any():
        fit[0::2, static] = 1.0  # counted
        ups = [j for j, s in enumerate(steps) if s.kind == "static" and s.up is not None]
        means = [st.mean_accel for st in stills]
        if ups and use_directions and all(a is not None for a in means):
            d = np.array(means) / np.linalg.norm(means, axis=1, keepdims=True)
            u = np.array([steps[j].up for j in ups], float)
            cos = d @ (u / np.linalg.norm(u, axis=1, keepdims=True)).T
            near = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) <= MATCH_DEG
            fit[0::2, ups] = np.where(near, _CHECKED, 0.0)
    turns = [j for j, s in enumerate(steps) if s.kind == "rotation"]
    for k, (before, after) in enumerate(zip(stills[:-1], stills[1:], strict=True)):
        mv = None if gyro is None else _motion_rotvec(time, gyro, before, after)
        for j in turns:
            if gyro is None or not _axis_checkable(steps[j]):
                fit[2 * k + 1, j] = 1.0
            elif mv is not None and _motion_fits(steps[j], mv, before, after, use_directions):
                fit[2 * k + 1, j] = _CHECKED
    best = np.zeros((n_items + 1, m + 1))
    for t in range(1, n_items + 1):  # best[t, j] = max(skip item, skip step, match)
        pair = np.where(fit[t - 1] > 0, best[t - 1, :-1] + fit[t - 1], -1.0)
        best[t, 1:] = np.maximum.accumulate(np.maximum(best[t - 1, 1:], pair))
    still: list[int | None] = [None] * n
    motion: list[int | None] = [None] * max(n - 1, 0)
    checked: set[tuple[int, int]] = set()
    t, j = n_items, m
    while t > 0 and j > 0:  # back from the end: a match where it made the score
        f = fit[t - 1, j - 1]
        if f and best[t, j] == best[t - 1, j - 1] + f:
            (still if (t - 1) % 2 == 0 else motion)[(t - 1) // 2] = j - 1
            if f == _CHECKED:
                checked.add(((t - 1) % 2, (t - 1) // 2))
            t, j = t - 1, j - 1
        elif best[t, j] == best[t - 1, j]:
            t -= 1
        else:
            j -= 1
    return Matches(still, motion, use_directions, ordered=True, checked=checked)


def match_plan(
    plan: Plan, stills: list[Still], time: np.ndarray, gyro: np.ndarray | None
) -> Matches:
    use_directions = _directions_usable(stills)
    steps = plan.steps
    if any(s.kind == "rotation" for s in steps):
        return _match_in_order(plan, stills, time, gyro, use_directions)
    step_ups = [(i, s.up) for i, s in enumerate(steps) if s.kind == "static" and s.up is not None]
    used: set[int] = set()
    still = [
        _match_still(step_ups, s.mean_accel, used)
        if use_directions and s.mean_accel is not None
        else None
        for s in stills
    ]
    rot_steps = [(i, s) for i, s in enumerate(plan.steps) if s.kind == "rotation"]
    motion: list[int | None] = []
    used_turns: set[int] = set()
    for k, (before, after) in enumerate(zip(stills[:-1], stills[1:], strict=True)):
        mv = None if gyro is None else _motion_rotvec(time, gyro, before, after)
        motion.append(
            None
            if mv is None
            else _match_motion(rot_steps, mv, before, after, use_directions, used_turns, still[k])
        )
    return Matches(still, motion, use_directions)


def plan_progress(plan: Plan, stills: list[Still], matches: Matches, has_gyro: bool):
    """Return (done, missing): step labels of the plan seen and not seen, in plan order."""
    seen = set(i for i in matches.still + matches.motion if i is not None)
    if matches.ordered:
        done = [s.label for i, s in enumerate(plan.steps) if i in seen]
        return done, [s.label for i, s in enumerate(plan.steps) if i not in seen]
    statics = [i for i, s in enumerate(plan.steps) if s.kind == "static"]
    rotations = [i for i, s in enumerate(plan.steps) if s.kind == "rotation"]
    # Steps that can only be counted: static steps without up (or when directions are not
    # usable), rotation steps without an axis the gyro can check (or without a gyro).
    counted_static = [i for i in statics if plan.steps[i].up is None or not matches.directions_used]
    spare_stills = sum(1 for m in matches.still if m is None)
    for i in counted_static[:spare_stills]:
        seen.add(i)
    counted_rot = [i for i in rotations if not _axis_checkable(plan.steps[i]) or not has_gyro]
    spare_motions = sum(1 for m in matches.motion if m is None)
    for i in counted_rot[:spare_motions]:
        seen.add(i)
    done = [s.label for i, s in enumerate(plan.steps) if i in seen]
    missing = [s.label for i, s in enumerate(plan.steps) if i not in seen]
    return done, missing


def still_means(ranges, accel, gyro) -> list[Still]:
    """Still periods with their means, from ``(start, stop)`` pairs."""
    out = []
    for a, b in ranges:
        a, b = int(a), int(b)
        out.append(
            Still(
                a, b,
                None if accel is None else accel[a:b].mean(axis=0),
                None if gyro is None else gyro[a:b].mean(axis=0),
            )
        )  # fmt: skip
    return out


def order_fixed(plan: Plan, matches: Matches) -> set[tuple[int, int]]:
    """The matches of an ordered alignment that the order alone fixes, as ``(0 still / 1
    motion, index)``: the still periods between two checked ones (or a checked one and an end
    of the recording), each matched, as many as the plan's static steps between those two
    steps, and the motions matched between them.  One still period more or fewer there (a
    pause, a pose left out) and none of that stretch is fixed."""
    if not matches.ordered:
        return set()
    n = len(matches.still)
    anchors = [k for k in range(n) if (0, k) in (matches.checked or set())]
    if not anchors:  # nothing the data checked to count from (directions not usable)
        return set()
    static = [j for j, s in enumerate(plan.steps) if s.kind == "static"]
    fixed: set[tuple[int, int]] = set()
    for a, b in zip([-1, *anchors], [*anchors, n], strict=True):
        lo = -1 if a < 0 else matches.still[a]
        hi = len(plan.steps) if b == n else matches.still[b]
        inside = range(a + 1, b)
        if any(matches.still[k] is None for k in inside):
            continue
        if len(inside) != sum(1 for j in static if lo < j < hi):
            continue
        fixed.update((0, k) for k in inside)
        fixed.update((1, k) for k in range(max(a, 0), min(b, n - 1))
                     if matches.motion[k] is not None)  # fmt: skip
    return fixed
