"""Unattended capture (``imucal capture --no-prompt``): no keyboard, the motion tells all.

:func:`run_unattended` records until ``duration_s`` has passed since the first sample, or until
every step of the plan has been seen in the motion itself, then segments the whole recording
with :func:`imucal_cli.design.segmentation.find_static` / ``find_rotations`` and adds the
segments to the session.

The still periods and motions are matched to the plan's steps by :mod:`.plan_match` (its notes
say how).

The segments written are the offline result; their labels, ``up``, ``axis`` and ``angle_deg``
come from the step they match unambiguously as above, else they are left unlabelled.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imucal_cli.design.segmentation import find_rotations, find_static
from imucal_cli.errors import InputError
from imucal_cli.formats.columns import SampleBlock
from imucal_cli.plans import CaptureSummary, Plan, Step

from .plan_match import (
    MATCH_DEG,
    MAX_MAGNITUDE_RATIO,
    Still,
    match_plan,
    order_fixed,
    plan_progress,
    still_means,
)
from .targets_watch import TargetWatcher

__all__ = [
    "FINAL_HOLD_EXTRA_S",
    "MATCH_DEG",
    "MAX_MAGNITUDE_RATIO",
    "run_unattended",
    "segment_recording",
]

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
    stills = still_means([(iv.start, iv.stop) for iv in static], accel, gyro)
    done: list[str] = []
    missing: list[str] = []
    still_steps: list[Step | None] = [None] * len(stills)
    motion_by_start: dict[int, Step | None] = {}
    if plan is not None:
        matches = match_plan(plan, stills, time, gyro)
        done, missing = plan_progress(plan, stills, matches, gyro is not None)
        # a segment is labelled by the step the data checked (a direction, an axis) or the
        # order fixed; a step only counted leaves its segment unlabelled
        sure = (matches.checked or set()) | order_fixed(plan, matches)
        told = (lambda kind, k: True) if not matches.ordered else (
            lambda kind, k: (kind, k) in sure)  # fmt: skip
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
        self.closed: list[Still] = []
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
                self.closed.extend(still_means([(a, b)], accel, gyro))
            else:
                ongoing = (a, b)
        stills = list(self.closed)
        if ongoing is not None:
            a, b = ongoing
            if time[b - 1] - time[a] >= self.min_still_s + FINAL_HOLD_EXTRA_S:
                stills.extend(still_means([(a, b)], accel, gyro))
        if not stills:
            return False
        matches = match_plan(self.plan, stills, time, gyro)
        _, self.missing = plan_progress(self.plan, stills, matches, gyro is not None)
        return not self.missing


def run_unattended(
    recorder,
    plan: Plan | None,
    duration_s: float | None = None,
    *,
    min_still_s: float = 1.0,
    on_status: Callable[[str], None] | None = None,
    done_before: list[str | None] | None = None,
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
    done_before : list of str or None, optional
        Continuing a capture (``recorder.resumed_from`` samples already in the session): the
        labels of the steps its segments already hold, None for each unlabelled static
        segment (a pose the first capture counted: it fills a pose step without ``up`` of a
        plan of poses, ``random:N``); only the other steps are looked for, and the new
        segments follow the old samples.
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
    before = [label for label in done_before or [] if label is not None]
    if plan is not None and done_before:
        before, plan = _left_to_do(plan, list(done_before), say)
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


def _left_to_do(plan: Plan, before: list[str | None], say) -> tuple[list[str], Plan]:
    """Continuing a capture: the labels of ``before`` that are steps of ``plan`` (each step
    once), and the plan of the steps left.  In a plan of poses (no turns, matched in any
    order) each unlabelled still period of ``before`` (None) fills a pose step without ``up``,
    as the capture that recorded it counted it; a plan with turns is matched in its order, so
    an unlabelled period there is not taken as any step."""
    left, matched = list(plan.steps), []
    for label in before:
        i = next((i for i, s in enumerate(left) if label is not None and s.label == label), None)
        if i is not None:
            matched.append(left.pop(i).label)
    if all(s.kind == "static" for s in plan.steps):
        for _ in range(sum(label is None for label in before)):
            i = next((i for i, s in enumerate(left) if s.up is None), None)
            if i is None:
                break
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
