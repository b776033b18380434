"""Unattended capture (``imucal capture --no-prompt``): no keyboard, the motion tells all.

:func:`run_unattended` records until ``duration_s`` has passed since the first sample, or until
every step of the plan has been seen in the motion itself, then segments the whole recording
with :func:`imucal_cli.design.segmentation.find_static` / ``find_rotations`` and adds the
segments to the session.

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

The segments written are the offline result; their labels, ``up``, ``axis`` and ``angle_deg``
come from the step they match unambiguously as above, else they are left unlabelled.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.design.segmentation import find_rotations, find_static
from imucal_cli.errors import InputError
from imucal_cli.formats.columns import SampleBlock
from imucal_cli.plans import CaptureSummary, Plan, Step

from .targets_watch import TargetWatcher

__all__ = [
    "FINAL_HOLD_EXTRA_S",
    "MATCH_DEG",
    "MAX_MAGNITUDE_RATIO",
    "run_unattended",
    "segment_recording",
]

MATCH_DEG = 20.0
"""A still direction or rotation axis matches a step within this angle, degrees."""

MAX_MAGNITUDE_RATIO = 1.2
"""Still periods whose mean accel magnitudes differ by more than this ratio are not centred
data: their directions are not matched to ``up`` vectors."""

FINAL_HOLD_EXTRA_S = 1.0
"""The still period in progress counts, while recording, once it lasted ``min_still_s`` plus
this."""

CHECK_EVERY_S = 1.0
"""How often the plan is checked while recording, s."""


# --------------------------------------------------------------------------------------------
# Growing arrays
# --------------------------------------------------------------------------------------------


class _Buffer:
    """The samples recorded so far, in arrays that grow by doubling."""

    def __init__(self) -> None:
        self.n = 0
        self._arrays: dict[str, np.ndarray | None] = {}

    def add(self, block: SampleBlock) -> None:
        k = len(block)
        if k == 0:
            return
        parts = {"time": block.time, "accel": block.accel, "gyro": block.gyro}
        if not self._arrays:
            for name, a in parts.items():
                self._arrays[name] = None if a is None else np.empty((1024,) + a.shape[1:])
        for name, a in parts.items():
            store = self._arrays[name]
            if store is None:
                continue
            if self.n + k > len(store):
                bigger = np.empty((max(2 * len(store), self.n + k),) + store.shape[1:])
                bigger[: self.n] = store[: self.n]
                self._arrays[name] = store = bigger
            store[self.n : self.n + k] = a
        self.n += k

    def get(self, name: str) -> np.ndarray | None:
        a = self._arrays.get(name)
        return None if a is None else a[: self.n]


# --------------------------------------------------------------------------------------------
# Matching still periods and motions to plan steps
# --------------------------------------------------------------------------------------------


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


@dataclass
class _Still:
    start: int
    stop: int
    mean_accel: np.ndarray | None
    mean_gyro: np.ndarray | None


@dataclass
class _Matches:
    """Which step (index into plan.steps) each still period and each motion matched."""

    still: list[int | None]
    motion: list[int | None]  # motion i is between still i and i + 1
    directions_used: bool
    ordered: bool = False  # aligned in plan order: every step seen is matched
    checked: set | None = None  # ordered: (0 still / 1 motion, index) the data checked


def _directions_usable(stills: list[_Still]) -> bool:
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
    time: np.ndarray, gyro: np.ndarray, before: _Still, after: _Still
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


def _motion_fits(step: Step, motion: tuple[np.ndarray, np.ndarray], before: _Still,
                 after: _Still, use_directions: bool) -> bool:  # fmt: skip
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
    steps: list[tuple[int, Step]], motion: tuple[np.ndarray, np.ndarray], before: _Still,
    after: _Still, use_directions: bool, used: set[int], after_step: int | None,
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


def _match_in_order(plan: Plan, stills: list[_Still], time: np.ndarray,
                    gyro: np.ndarray | None, use_directions: bool) -> _Matches:  # fmt: skip
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
    return _Matches(still, motion, use_directions, ordered=True, checked=checked)


def _match(plan: Plan, stills: list[_Still], time: np.ndarray, gyro: np.ndarray | None) -> _Matches:
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
    return _Matches(still, motion, use_directions)


def _progress(plan: Plan, stills: list[_Still], matches: _Matches, has_gyro: bool):
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


def _stills(ranges, accel, gyro) -> list[_Still]:
    """Still periods with their means, from ``(start, stop)`` pairs."""
    out = []
    for a, b in ranges:
        a, b = int(a), int(b)
        out.append(
            _Still(
                a, b,
                None if accel is None else accel[a:b].mean(axis=0),
                None if gyro is None else gyro[a:b].mean(axis=0),
            )
        )  # fmt: skip
    return out


# --------------------------------------------------------------------------------------------
# Offline segmentation
# --------------------------------------------------------------------------------------------


@dataclass
class SegmentPlanEntry:
    """A segment to add: kind, half-open samples and the matched step (or None)."""

    kind: str
    start: int
    stop: int
    step: Step | None


def segment_recording(
    time: np.ndarray,
    accel: np.ndarray | None,
    gyro: np.ndarray | None,
    plan: Plan | None,
    *,
    min_still_s: float = 1.0,
) -> tuple[list[SegmentPlanEntry], list[str], list[str]]:
    """Segment a whole recording and match it to a plan (see the module notes).

    Returns
    -------
    segments : list of SegmentPlanEntry
        Static and rotation segments in time order.
    done, missing : list of str
        Labels of the plan's steps seen and not seen (empty without a plan).
    """
    if len(time) < 2:
        return [], [], [] if plan is None else [s.label for s in plan.steps]
    static = find_static(time, accel, gyro, min_still_s=min_still_s)
    if accel is None:  # static segments need accel: keep the still periods for rotations only
        static_for_segments = []
    else:
        static_for_segments = static
    rotations = find_rotations(time, gyro, static) if gyro is not None and static else []
    stills = _stills([(iv.start, iv.stop) for iv in static], accel, gyro)
    done: list[str] = []
    missing: list[str] = []
    still_steps: list[Step | None] = [None] * len(stills)
    motion_by_start: dict[int, Step | None] = {}
    if plan is not None:
        matches = _match(plan, stills, time, gyro)
        done, missing = _progress(plan, stills, matches, gyro is not None)
        # a segment is labelled by the step the data checked (a direction, an axis); a step
        # only counted leaves its segment unlabelled
        told = (lambda kind, k: True) if not matches.ordered else (
            lambda kind, k: (kind, k) in matches.checked)  # fmt: skip
        still_steps = [None if i is None or not told(0, k) else plan.steps[i]
                       for k, i in enumerate(matches.still)]  # fmt: skip
        for k, (before, m) in enumerate(zip(stills[:-1], matches.motion, strict=True)):
            motion_by_start[before.stop] = None if m is None or not told(1, k) else plan.steps[m]
    entries = [
        SegmentPlanEntry("static", s.start, s.stop, step)
        for s, step in zip(stills, still_steps, strict=True)
        if static_for_segments
    ]
    for iv in rotations:
        entries.append(
            SegmentPlanEntry("rotation", int(iv.start), int(iv.stop),
                             motion_by_start.get(int(iv.start)))
        )  # fmt: skip
    entries.sort(key=lambda e: (e.start, e.stop))
    return entries, done, missing


# --------------------------------------------------------------------------------------------
# The mode
# --------------------------------------------------------------------------------------------


class _PlanWatcher:
    """Online: are all steps of the plan seen yet?  Re-searches from the last confirmed still."""

    def __init__(self, plan: Plan, min_still_s: float) -> None:
        self.plan = plan
        holds = [s.hold_s for s in plan.steps if s.kind == "static" and s.hold_s]
        self.min_still_s = max([min_still_s, *holds])
        self.closed: list[_Still] = []
        self.missing = [s.label for s in plan.steps]

    def update(self, buffer: _Buffer) -> bool:
        time, accel, gyro = buffer.get("time"), buffer.get("accel"), buffer.get("gyro")
        n = len(time)
        base = self.closed[-1].start if self.closed else 0
        if n - base < 10:
            return False
        try:
            found = find_static(
                time[base:],
                None if accel is None else accel[base:],
                None if gyro is None else gyro[base:],
                min_still_s=self.min_still_s,
            )
        except InputError:
            return False
        rate = (n - base - 1) / (time[-1] - time[base]) if time[-1] > time[base] else 0.0
        margin = max(2, int(0.5 * rate))
        ongoing = None
        for iv in found:
            a, b = base + int(iv.start), base + int(iv.stop)
            if self.closed and a < self.closed[-1].stop:
                continue  # the last confirmed still period, found again
            if b < n - margin:
                self.closed.extend(_stills([(a, b)], accel, gyro))
            else:
                ongoing = (a, b)
        stills = list(self.closed)
        if ongoing is not None:
            a, b = ongoing
            if time[b - 1] - time[a] >= self.min_still_s + FINAL_HOLD_EXTRA_S:
                stills.extend(_stills([(a, b)], accel, gyro))
        if not stills:
            return False
        matches = _match(self.plan, stills, time, gyro)
        _, self.missing = _progress(self.plan, stills, matches, gyro is not None)
        return not self.missing


def run_unattended(
    recorder,
    plan: Plan | None,
    duration_s: float | None = None,
    *,
    min_still_s: float = 1.0,
    on_status: Callable[[str], None] | None = None,
    done_before: list[str] | None = None,
    targets=None,
    refit: Callable | None = None,
    gravity: float = 9.80665,
) -> CaptureSummary:
    """Record without a keyboard, then segment the recording; see the module notes.

    Parameters
    ----------
    recorder : Recorder
        Not started yet; the caller closes it afterwards.
    plan : Plan or None
        Steps to see; None records for ``duration_s`` only.
    duration_s : float, optional
        Stop this long after the first sample (at the latest).
    min_still_s : float
        Shortest still period that counts, s.
    on_status : callable, optional
        Called with progress messages.
    done_before : list of str, optional
        Continuing a capture (``recorder.resumed_from`` samples already in the session): the
        labels of the steps its segments already hold; only the other steps are looked for,
        and the new segments follow the old samples.
    targets, refit, gravity
        Accuracy targets (:class:`~imucal_cli.formats.targets.Targets`) and the refit of the
        recording so far (:class:`~imucal_cli.capture.targets_watch.TargetWatcher`): the
        recording stops once every target is met, which is then what ``complete`` means.

    Returns
    -------
    CaptureSummary
        ``complete``: with a plan, every step seen in the segmented recording; without one,
        the recording ran for ``duration_s``.
    """
    if plan is None and duration_s is None and not targets:
        raise ValueError("run_unattended needs a plan, a duration or targets")
    say = on_status or (lambda message: None)
    before = list(done_before or [])
    if plan is not None and before:
        before, plan = _left_to_do(plan, before, say)
        if not plan.steps:
            return CaptureSummary(complete=True, done=before, skipped=[], missing=[],
                                  end_reason="every step of the plan was already in the session",
                                  samples=recorder.n_samples, stats=recorder.stats)  # fmt: skip
    base = int(getattr(recorder, "resumed_from", 0))  # the new segments follow the old
    watcher = None
    if targets:
        watcher = TargetWatcher(targets, refit, lambda t, a, g: [
            (e.kind, e.start, e.stop, _attrs(e.step)) for e in segment_recording(
                t, a, g, plan, min_still_s=min_still_s)[0]],
            units=(getattr(recorder, "accel_units", None), getattr(recorder, "gyro_units", None)),
            gravity=gravity)  # fmt: skip
    buffer, reached_duration = _record(recorder, plan, duration_s, min_still_s, say, watcher)
    done: list[str] = []
    missing: list[str] = [] if plan is None else [s.label for s in plan.steps]
    time, accel, gyro = buffer.get("time"), buffer.get("accel"), buffer.get("gyro")
    if time is not None and len(time) >= 2:
        entries, done, missing = segment_recording(time, accel, gyro, plan, min_still_s=min_still_s)
        for e in entries:
            attrs = {} if e.step is None else e.step.segment_attrs()
            recorder.add_segment(e.kind, base + e.start, base + e.stop, **attrs)
    complete = not missing if plan is not None else reached_duration
    if watcher is not None:  # with targets: every target met (the plan, if any, aside)
        if time is not None and len(time) >= 10:
            watcher.n_still = -1  # the whole recording, once more, as it is segmented
            watcher.update(time, accel, gyro, say)
        complete = watcher.met
        missing = [s.describe() for s in watcher.statuses if not s.met]
    return CaptureSummary(
        complete=complete,
        done=[label for label in before if plan is None or label not in missing] + done,
        skipped=[],
        missing=missing,
        end_reason=recorder.end_reason,
        samples=recorder.n_samples,
        stats=recorder.stats,
        targets=[] if watcher is None else list(watcher.statuses),
    )


def _attrs(step: Step | None) -> dict:
    """A segment's attributes from the plan step it matches (none: ``{}``)."""
    if step is None:
        return {}
    attrs = step.segment_attrs()
    attrs.pop("extra", None)
    return attrs


def _left_to_do(plan: Plan, before: list[str], say) -> tuple[list[str], Plan]:
    """Continuing a capture: the labels of ``before`` that are steps of ``plan`` (each step
    once), and the plan of the steps left."""
    left, matched = list(plan.steps), []
    for label in before:
        i = next((i for i, s in enumerate(left) if s.label == label), None)
        if i is not None:
            matched.append(left.pop(i).label)
    say(f"resumed: {len(matched)} steps already in the session, {len(left)} left")
    return matched, Plan(plan.name, tuple(left))


def _record(recorder, plan: Plan | None, duration_s: float | None, min_still_s: float, say,
            targets: TargetWatcher | None = None):  # fmt: skip
    """Record until ``duration_s`` of device time after the first sample, or until every step
    of ``plan`` is seen (checked every :data:`CHECK_EVERY_S`), or the recorder ends; returns
    the samples and whether the duration was reached."""
    buffer = _Buffer()
    watcher = None if plan is None else _PlanWatcher(plan, min_still_s)
    first = None
    last_check = _time.monotonic()
    reached_duration = False
    reported: list[str] | None = None
    met = False
    for block in recorder.blocks():
        now = _time.monotonic()
        if len(block):
            buffer.add(block)
            if first is None:
                first = float(block.time[0])
        if first is None:
            continue
        # the duration in device time: a backlog read at once or a busy host cuts nothing short
        recorded = float(buffer.get("time")[-1]) - first
        if duration_s is not None and recorded >= duration_s and not reached_duration:
            reached_duration = True
            say(f"{duration_s:g} s recorded")
            recorder.stop()
        due = now - last_check >= CHECK_EVERY_S
        if due:
            last_check = now
        if targets is not None and due and not met:
            if targets.update(buffer.get("time"), buffer.get("accel"), buffer.get("gyro"), say):
                met = True
                say("every target met")
                recorder.stop()
        if watcher is not None and due:
            if watcher.update(buffer):
                say("every step of the plan was seen")
                recorder.stop()
            elif watcher.missing != reported:
                reported = watcher.missing
                n_done = len(plan.steps) - len(watcher.missing)
                say(f"{n_done} of {len(plan.steps)} steps seen")
    return buffer, reached_duration
