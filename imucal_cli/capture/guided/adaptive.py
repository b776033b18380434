"""Guided capture until accuracy targets are met (``imucal capture --until``, issue 27).

:class:`AdaptiveState` is the guided state machine (:class:`~.state.GuidedState`) with
targets (:mod:`imucal_cli.formats.targets`):

- **refit after every step**: the session so far (:func:`~.design.session_so_far`) goes through
  the calibrate step (the ``refit`` callable: the solvers as ``imucal calibrate`` runs them),
  in a thread beside the stream (a refit takes a few tenths of a second, the person turns
  meanwhile); each target's current std is told against it, and when every one is met the
  capture says "done" and ends (the time it states is the end of the hold that met them);
- **the next pose that helps most**: without a plan (or once its steps are done) the next step
  is proposed from the Fisher information at the refit (:func:`~imucal_cli.planning.next_pose.
  propose`): the turn about one of the unit's axes, and the pose it leads to, that shrinks the
  worst target most, in words (:func:`~.words.turn_instruction`); the live view's coverage map
  marks it ``*``;
- **holds end by themselves**: when a hold starts, its length is planned
  (:func:`~imucal_cli.planning.next_pose.plan_hold`): at least ``min_hold_s``, and on while
  more samples of it shrink the worst target faster than the next step would;
- a hold that is not the pose proposed is recorded as the pose it is (any still pose informs
  the fit); ``s`` skips a proposal (the next best is proposed), ``r`` redoes, ``q`` finishes.

The predictions of the information are scaled, target by target, to what the last refit
stated (its std over the prediction for the same design): the refit's noise level and the
accelerometer calibration's share of the gyro's std then carry into the planning.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from rich.table import Table
from rich.text import Text

from imucal_cli.design.poses import angle_deg
from imucal_cli.formats.session import Session
from imucal_cli.formats.targets import Targets, TargetStatus, brief, measure
from imucal_cli.model.calibration import Calibration
from imucal_cli.planning.information import DesignStd, design_std
from imucal_cli.planning.next_pose import Proposal, plan_hold, propose, ratios
from imucal_cli.plans import CaptureSummary, Plan, Step
from imucal_cli.use.report.coverage_map import coverage_map

from .design import Design, design, limits, session_so_far
from .matching import Taken
from .options import GuidedOptions, Prompt
from .state import GuidedState
from .words import NAMED_WITHIN_DEG, instruction, pose_name, turn_instruction

__all__ = ["AdaptiveOptions", "AdaptiveState", "Refit", "first_step"]


@dataclass(frozen=True)
class Refit:
    """What refitting the session so far gave: the calibration (None: nothing calibrated
    yet) and, per sensor, why it is not calibrated (``{"gyro": "..."}``)."""

    calibration: Calibration | None
    notes: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class AdaptiveOptions:
    """How a capture with targets runs.

    Attributes
    ----------
    targets : Targets
        What to capture until.
    refit : callable
        ``refit(session) -> Refit``: the calibrate step on the session so far.
    min_hold_s, max_hold_s : float
        The shortest and the longest hold, s.
    move_s : float
        How long a proposed turn takes, s, from the end of a hold to the start of the next
        (reading, turning, settling: the window the calibrate step integrates the turn over).
    step_s : float
        What one more step costs: reading, turning, settling and the shortest hold, s.
    placement_deg : float
        RMS error of a hand placement on a named pose (the labels' prior, while the
        accelerometer's solver uses labels).
    gravity : float
        Local gravity, m/s^2.
    propose : bool
        Once the plan's steps are done (or without a plan), propose the next pose, and plan
        each hold's length; False: a fixed plan, each hold ``min_hold_s``, ending with its last
        step, targets met or not (or earlier, when they are met).
    """

    targets: Targets
    refit: Callable[[Session], Refit]
    min_hold_s: float = 1.0
    max_hold_s: float = 30.0
    move_s: float = 2.5
    step_s: float = 4.0
    placement_deg: float = 2.0
    gravity: float = 9.80665
    propose: bool = True


def first_step() -> Step:
    """Where a capture without a plan begins: on a face."""
    return Step("static", "face +Z up", up=np.array([0.0, 0.0, 1.0]))


def _named(direction: np.ndarray) -> tuple[str, np.ndarray | None]:
    """A measured pose's label and its ``up`` when it is a face or an edge, else ``("pose",
    None)`` (no label: its direction enters by its magnitude only)."""
    name = pose_name(direction)
    if name.startswith(("face ", "edge ")):
        axes = name.split()[1]
        up = np.zeros(3)
        for sign, axis in zip(axes[::2], axes[1::2], strict=True):
            up["XYZ".index(axis)] = 1.0 if sign == "+" else -1.0
        return name, up / np.linalg.norm(up)
    return "pose", None


class AdaptiveState(GuidedState):
    """The guided state machine with targets (see the module notes).

    Parameters
    ----------
    plan : Plan or None
        Steps to go through first (None: the guide proposes every pose after the first).
    opt : GuidedOptions
    base : int
    add_segment : callable
        As for :class:`GuidedState`.
    adaptive : AdaptiveOptions
    """

    def __init__(self, plan: Plan | None, opt: GuidedOptions, base: int,
                 add_segment: Callable[..., None], adaptive: AdaptiveOptions) -> None:  # fmt: skip
        self.a = adaptive
        self.given_plan = plan
        self.statuses: list[TargetStatus] = []
        self.refit_result: Refit | None = None
        self.proposals: dict[int, Proposal] = {}
        self.skipped_here: set[tuple] = set()
        self.hold_plan: float | None = None
        self.factors: dict[tuple[str, str], float] = {}
        self.met = False
        self.checking = False  # targets met on a refit without the last steps: refit them
        self.version = 0  # of the steps taken: a take or a redo changes it
        self.fresh = False
        self.pool: ThreadPoolExecutor | None = None
        self.pending: Future | None = None
        self.queued: tuple[Session, int] | None = None  # the session and its version
        self.refits = 0
        self.refit_s = 0.0
        self.first_time: float | None = None
        self.done_time: float | None = None
        super().__init__(plan or Plan("until", (first_step(),)), opt, base, add_segment)
        self.steps = list(self.steps)
        self.statuses = measure(None, self.a.targets)

    # ------------------------------------------------------------------------ words
    def plan_line(self) -> str:
        first = (f"plan {self.given_plan.name} first, then " if self.given_plan is not None
                 else "")  # fmt: skip
        return (f"capture until every target is met (1 std, worst axis): "
                f"{self.a.targets.describe()}; {first}the guide proposes the pose that helps "
                f"most; each hold ends by itself (at least {self.a.min_hold_s:g} s)")

    def instruction_line(self, cur: int) -> str:
        if cur in self.proposals:
            c = self.proposals[cur].candidate
            return turn_instruction(c.axis, c.angle_deg, c.up_after)
        step = self.steps[cur]
        if step.kind == "static" and not step.hold_s:
            return instruction(step) + " (the hold ends by itself)"
        return super().instruction_line(cur)

    def count_text(self) -> str:
        return f" (pose {sum(1 for t in self.taken if t.kind == 'static')})"

    def tell_left(self) -> None:
        if self.given_plan is not None and any(st == "pending" for st in self.status):
            super().tell_left()

    def progress_text(self) -> str:
        return f"std/target: {brief(self.statuses)}"

    def prompt(self) -> Prompt:
        if self.met:  # done: nothing more to do (a proposal made meanwhile is void)
            return Prompt(None, 0, "done", "", 0.0, 0.0, self.serial)
        if self.checking and self.current() is None:
            return Prompt(None, 0, "check", "Hold still: the targets are checked with the last "
                          "steps", 0.0, 0.0, self.serial)  # fmt: skip
        p = super().prompt()
        return Prompt(p.step, 0, p.phase, p.text, p.hold_s, p.held_s, p.serial)

    # ------------------------------------------------------------------------ the hold
    def hold_s(self) -> float:
        cur = self.current()
        own = None if cur is None else self.steps[cur].hold_s
        if own:
            return float(own)
        if not self.a.propose and self.given_plan is not None:
            return self.a.min_hold_s
        if self.holding and self.state is not None and self.state.still_start is not None:
            if self.hold_plan is None:
                self.hold_plan = self._plan_hold()
            return self.hold_plan
        return self.a.min_hold_s

    def _hold_start(self) -> int:
        return max(self.state.still_start + self.base, self.min_start)

    def _plan_hold(self) -> float:
        """The length of the hold that starts now (see the module notes), s."""
        s0 = self._hold_start()
        turn = None
        if self.turn_from is not None and self.turn_from < s0 and self.last_taken_static():
            turn = (self.turn_from, s0)
        d = self.design(current=(s0, self.hist.end), current_turn=turn)
        rate = d.noise.rate_hz
        min_n = max(2, int(math.ceil(self.a.min_hold_s * rate)))
        max_n = max(min_n, int(self.a.max_hold_s * rate))
        n = plan_hold(d.fit, d.poses, d.turns, d.noise, self.limits(), min_n=min_n,
                      max_n=max_n, move_s=self.a.move_s, step_s=self.a.step_s,
                      placement_deg=self.placement())  # fmt: skip
        return n / rate

    def on_run_end(self, s: int, e: int) -> None:
        super().on_run_end(s, e)
        if not self.holding:
            self.hold_plan = None

    def match_pose(self, direction: np.ndarray | None) -> tuple[int, str | None]:
        """A proposed step (or the first) takes any still pose: the one asked for under its
        label, another as the face or edge it is, or unlabelled."""
        cur = self.current()
        if cur is None or direction is None or not (cur in self.proposals or
                                                    self.given_plan is None):  # fmt: skip
            return super().match_pose(direction)
        step = self.steps[cur]
        if step.up is not None and angle_deg(direction, np.asarray(step.up, float)) \
                <= self.o.match_tolerance_deg:  # fmt: skip
            return cur, None
        label, up = _named(direction)
        off = (angle_deg(direction, up) if up is not None else math.inf)
        if off > NAMED_WITHIN_DEG + self.o.match_tolerance_deg:
            label, up = "pose", None
        if label == "pose":
            label = f"pose {sum(1 for t in self.taken if t.kind == 'static') + 1}"
        self.say(f"not the pose asked for ({step.label}): recorded as {label}", "yellow")
        self.steps[cur] = Step("static", label, up=up)
        self.proposals.pop(cur, None)
        self.plan = Plan(self.plan.name, tuple(self.steps))
        return cur, None

    def take(self, t: Taken) -> None:
        super().take(t)
        self.version += 1
        self.fresh = True
        self.skipped_here.clear()

    def redo(self) -> None:
        n = len(self.taken)
        super().redo()
        if len(self.taken) < n:  # a step removed: refits of the session with it are stale
            self.version += 1

    # ------------------------------------------------------------------------ after a step
    def after_step(self) -> None:
        if self.fresh:
            self.fresh = False
            self.request_refit()
        self.hold_plan = None
        if self.met:
            return
        if self.checking and self.current() is None:  # no proposal, no end while checking
            self.next_step()
            return
        if self.current() is None and (self.a.propose or self.given_plan is None):
            self.add_proposal()
        super().after_step()

    def command(self, cmd) -> None:
        if cmd.action == "skip":
            cur = self.current()
            if cur is not None and cur in self.proposals:
                c = self.proposals[cur].candidate
                self.skipped_here.add((tuple(np.round(c.axis, 6)), c.angle_deg))
        super().command(cmd)

    def request_refit(self) -> None:
        """Refit the session so far in the refit thread (after the one running, if any)."""
        if self.hist.accel is None:
            return
        session = session_so_far(self.hist, self.taken, self.steps,
                                 accel_units=self.o.accel_units, gyro_units=self.o.gyro_units,
                                 gravity=self.a.gravity)  # fmt: skip
        job = (session, self.version)
        if self.pending is not None:
            self.queued = job  # the newest waits; an older one waiting is dropped
            return
        if self.pool is None:
            self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="imucal-refit")
        self.pending = self.pool.submit(self._timed_refit, *job)

    def _timed_refit(self, session: Session, version: int) -> tuple[Refit, float, float, int]:
        started = _time.perf_counter()
        result = self.a.refit(session)
        return result, _time.perf_counter() - started, float(session.time[-1]), version

    def poll_refit(self, wait: bool = False) -> None:
        """Take a finished refit's result (``wait``: every refit asked for)."""
        while self.pending is not None and (wait or self.pending.done()):
            result, took, last, version = self.pending.result()
            self.pending = None
            if self.queued is not None:
                job, self.queued = self.queued, None
                self.pending = self.pool.submit(self._timed_refit, *job)
            self.refit_s += took
            self.refits += 1
            self.apply_refit(result, last, version)

    def apply_refit(self, result: Refit, last: float, version: int | None = None) -> None:
        """Tell each target's std against it; "done" when every one is met on a refit of
        the steps as they are now (``version``: of the steps the refitted session holds;
        None: as now). Targets met on a refit of other steps (the person goes on while a refit
        runs, or redid a step) are checked first: the session saved, every step in it, is
        the one that must meet them (no new proposal meanwhile; if it misses one, the guide
        goes on)."""
        if self.met:
            return
        self.refit_result = result
        self.statuses = measure(result.calibration, self.a.targets, result.notes)
        met = all(s.met for s in self.statuses)
        self._update_factors()
        stale = version is not None and version != self.version
        if met and stale:
            if not self.checking:
                self.say("every target met without the last steps; refitting with them", "dim")
            self.checking = True
            self._refit_now()
            return
        self.met = met
        if met:
            self._done(last)
            return
        self.say(f"std/target now: {brief(self.statuses)}", "dim")
        if not self.checking:
            return
        if stale:  # the steps as they are now are refitted next
            self._refit_now()
            return
        self.checking = False  # the check failed: the guide goes on
        if self.end_reason is None and self.current() is None:
            if self.a.propose or self.given_plan is None:
                self.add_proposal()
            else:  # a fixed plan's steps all taken: it ends as without targets
                GuidedState.after_step(self)

    def _refit_now(self) -> None:
        """A refit of the steps as they are now, unless one is running or waiting."""
        if self.pending is None and self.queued is None:
            self.request_refit()

    def _done(self, last: float) -> None:
        self.done_time = last
        took = "" if self.first_time is None else \
            f" after {self.done_time - self.first_time:.1f} s"  # fmt: skip
        self.say(f"done: every target met{took} (std/target: {brief(self.statuses)})",
                 "bold green")
        if self.end_reason is None:
            self.holding = False
            self.serial += 1
            self.end_reason = "every target met"

    def on_block(self, block) -> None:
        if self.first_time is None and len(block):
            self.first_time = float(block.time[0])
        self.poll_refit()
        if self.end_reason is None:
            super().on_block(block)

    # ------------------------------------------------------------------------ the design
    def placement(self) -> float:
        """The labels' placement error as the accelerometer's solver uses them (``inf``: the
        gravity-magnitude solver, no labels)."""
        cal = None if self.refit_result is None else self.refit_result.calibration
        sec = None if cal is None else cal.accel
        if sec is None:
            return self.a.placement_deg
        if sec.solver != "labelled":
            return math.inf
        return float((sec.placement.rms_deg if sec.placement is not None else None)
                     or self.a.placement_deg)

    def design(self, current=None, current_turn=None) -> Design:
        cal = None if self.refit_result is None else self.refit_result.calibration
        statics = [t for t in self.taken if t.kind == "static"]
        labelled = [self.steps[t.step].up is not None for t in statics]
        sd = self.detector.noise_std()
        fallback = tuple(float(np.mean(v)) if v is not None else 1.0
                         for v in (sd.get("accel"), sd.get("gyro")))  # fmt: skip
        return design(self.hist, self.taken, cal, gravity=self.a.gravity,
                      placement_deg=self.placement(), labelled=labelled,
                      nominal_bias=self.o.nominal_bias, fallback_noise=fallback,
                      current=current, current_turn=current_turn)  # fmt: skip

    def limits(self) -> dict[tuple[str, str], float]:
        """The targets in the information's units, each divided by how much the last refit's
        std exceeded the information's prediction."""
        return {k: v / self.factors.get(k, 1.0) for k, v in limits(self.a.targets).items()}

    def _update_factors(self) -> None:
        d = self.design()
        if not d.poses:
            return
        predicted: DesignStd = design_std(d.fit, d.poses, d.turns, d.noise)
        base = limits(self.a.targets)
        r = ratios(predicted, base)
        for s in self.statuses:
            key = (s.target.sensor, s.target.term)
            if s.std is None or not np.isfinite(r.get(key, np.inf)) or r[key] <= 0:
                continue
            self.factors[key] = float(np.clip(s.ratio / r[key], 0.3, 5.0))

    def add_proposal(self) -> None:
        """Append the next step: the candidate that shrinks the worst target most."""
        d = self.design()
        if not d.poses:
            self.steps.append(first_step())
            self.status.append("pending")
            self.plan = Plan(self.plan.name, tuple(self.steps))
            return
        rate = d.noise.rate_hz
        props = propose(d.fit, d.poses, d.turns, d.noise, self.limits(),
                        hold_n=max(2, int(math.ceil(self.a.min_hold_s * rate))),
                        move_s=self.a.move_s, placement_deg=self.placement())  # fmt: skip
        props = [p for p in props
                 if (tuple(np.round(p.candidate.axis, 6)), p.candidate.angle_deg)
                 not in self.skipped_here] or props  # fmt: skip
        best = props[0]
        c = best.candidate
        self.steps.append(Step("static", pose_name(c.up_after), up=c.up_after))
        self.status.append("pending")
        self.proposals[len(self.steps) - 1] = best
        self.plan = Plan(self.plan.name, tuple(self.steps))
        self.say("next: " + turn_instruction(c.axis, c.angle_deg, c.up_after)
                 + self._why(best), "bold")

    def _why(self, best: Proposal) -> str:
        """`` (the worst target, accel misalignment: 0.12 -> 0.07 deg predicted)``."""
        worst = max(self.statuses, key=lambda s: s.ratio, default=None)
        if worst is None:
            return ""
        t = worst.target
        after = ratios(best.predicted, self.limits()).get((t.sensor, t.term), math.inf)
        if worst.std is None:
            state = "not determined yet" + (", determined after it" if np.isfinite(after)
                                            else "")  # fmt: skip
            return f" (the worst target, {t.sensor} {t.term}: {state})"
        predicted = after * t.value
        return (f" (the worst target, {t.sensor} {t.term}: {worst.std:.2g} -> "
                f"{predicted:.2g} {t.unit} predicted)")

    # ------------------------------------------------------------------------ the view
    def view_rows(self) -> list:
        """The targets against their std, and the coverage map with the next pose (``*``)."""
        table = Table(box=None, padding=(0, 1), show_header=True, header_style="dim")
        for name in ("target", "std now", "limit", ""):
            table.add_column(name, justify="right" if name in ("std now", "limit") else "left")
        for s in self.statuses:
            t = s.target
            std = "-" if s.std is None else f"{s.std:.2g} {t.unit}"
            table.add_row(f"{t.sensor} {t.term}", std, f"{t.value:.2g} {t.unit}",
                          Text("met", style="green") if s.met else Text("not yet", "yellow"))
        rows: list = [table]
        d = self.design()
        marks = []
        cur = self.current()
        if cur is not None and cur in self.proposals:
            marks = [self.proposals[cur].candidate.up_after]
        if d.poses:
            lines = coverage_map([p.up for p in d.poses], marks=marks)
            legend = "o pose held, * next pose" if marks else "o pose held"
            rows.append(Text("\n".join([*lines[:-1], f"{lines[-1].strip()}; {legend}"]),
                             style="cyan"))  # fmt: skip
        return rows

    # ------------------------------------------------------------------------ the end
    def summary(self, recorder) -> CaptureSummary:
        """Commit the last step and say what was reached (``complete``: every target met)."""
        self.poll_refit(wait=True)
        if self.pool is not None:
            self.pool.shutdown()
        self.commit()
        done = [self.steps[x.step].label for x in self.taken]
        missing = [s.describe() for s in self.statuses if not s.met]
        reason = self.end_reason or getattr(recorder, "end_reason", "") or "the stream ended"
        n_poses = sum(1 for t in self.taken if t.kind == "static")
        n_turns = sum(1 for t in self.taken if t.turn is not None or t.kind == "rotation")
        head = f"{n_poses} poses and {n_turns} turns, {self.refits} refits"
        if self.met:
            self.say(f"{head}: every target met ({reason})", "bold green")
        else:
            self.say(f"{head}; targets not met ({reason}): {brief(self.statuses)}",
                     "bold yellow")
        return CaptureSummary(complete=self.met, done=done, skipped=[], missing=missing,
                              end_reason=reason, samples=int(recorder.n_samples),
                              stats=dict(getattr(recorder, "stats", {}) or {}),
                              targets=list(self.statuses))  # fmt: skip
