"""The guided capture's state machine: blocks and commands in, messages and segments out.

:class:`GuidedState` knows nothing of terminals.  Feed it every block of the stream
(:meth:`~GuidedState.on_block`) and every command line (:meth:`~GuidedState.on_command`); it
calls ``add_segment`` for each segment once it is final, appends what the person should be told
to :attr:`~GuidedState.messages`, and says through :meth:`~GuidedState.prompt` what the person
should do now.  A screen (:mod:`.screen`) draws that; tests read it directly.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from imucal_cli.design.poses import coverage, describe_direction
from imucal_cli.design.stillness import StillState
from imucal_cli.plans import CaptureSummary, Plan

from .direction import estimate_direction
from .keys import Command, parse_command
from .magnetic import MagCoverage
from .matching import Taken, match_hold, measure_turn, turn_warnings
from .options import GuidedOptions, Message, Prompt, detector_for, duration_text
from .samples import SampleHistory
from .words import fmt_vec, instruction

__all__ = ["GuidedOptions", "GuidedState", "Message", "Prompt"]


class GuidedState:
    """Plan progress of a guided capture (see the package notes for the behaviour).

    Parameters
    ----------
    plan : Plan
        The steps.
    opt : GuidedOptions
        The options.
    base : int
        Recorder index of the first sample the state will see.
    add_segment : callable
        ``add_segment(kind, start, stop, label=..., up=... | axis=..., angle_deg=...)``,
        called once per final segment, in time order.
    """

    def __init__(self, plan: Plan, opt: GuidedOptions, base: int, add_segment: Callable[..., None]):
        self.plan = plan
        self.steps = plan.steps
        self.o = opt
        self.add_segment = add_segment
        self.messages: list[Message] = []
        self.status = ["pending"] * len(self.steps)
        self.taken: list[Taken] = []
        self.uncommitted: Taken | None = None
        self.committed_start = -1
        self.focus: int | None = None
        self.detector = opt.detector or detector_for(plan)
        self.base = int(base)
        longest = max((s.hold_s or 0.0 for s in self.steps), default=0.0)
        self.hist = SampleHistory(self.base, keep_s=longest + 10.0 if longest else 0.0)
        self.armed = True
        self.min_start = 0
        self.holding = False
        self.rot_phase = "pre"
        self.pre_run: tuple[int, int] | None = None
        self.state: StillState | None = None
        self.last_block = None
        self.data_min = np.inf
        self.data_max = -np.inf
        self.end_reason: str | None = None
        self.serial = 0
        self.noise_told = False
        self.no_direction_told = False
        self.rotations = any(s.kind == "rotation" for s in self.steps)
        self.mag: MagCoverage | None = None  # the magnetometer's coverage, when it streams
        self.mag_told = -1  # the last tenth of coverage told
        self.mag_pending = False  # every step done; turning on for the magnetometer
        self.turn_from: int | None = None  # where the unit left the last pose taken
        self.say(self.plan_line(), "bold")

    def resume(self, done: list[tuple[str, str, np.ndarray | None]]) -> None:
        """Continue a capture: mark the steps the session already holds as done.

        ``done`` lists the session's segments in time order, ``(kind, label, mean raw accel)``
        (the mean of a static segment, else None).  A segment fulfils the first pending step of
        its kind and label; its measured direction joins the coverage and the "too close" check.
        """
        for kind, label, mean in done:
            i = next((i for i, s in enumerate(self.steps) if self.status[i] == "pending"
                      and s.kind == kind and s.label == label), None)  # fmt: skip
            if i is None:
                continue
            direction = None
            if kind == "static" and mean is not None:
                direction = estimate_direction(mean, self.o.accel_units,
                                               nominal_bias=self.o.nominal_bias,
                                               nominal_scale=self.o.nominal_scale)  # fmt: skip
            self.status[i] = "done"
            self.taken.append(Taken(i, kind, -1, -1, direction))  # in the file already
        n = sum(st == "done" for st in self.status)
        self.say(f"resumed: {n} of {len(self.steps)} steps already in the session; "
                 + ("left: " + ", ".join(self.left_labels()) if self.left_labels()
                    else "nothing left"), "bold")  # fmt: skip
        self.serial += 1
        if self.current() is None:
            self.end_reason = "every step of the plan done or skipped"

    def plan_line(self) -> str:
        """What the whole capture asks: the steps, how long each hold is and in total."""
        holds = [float(s.hold_s) if s.hold_s else self.o.hold_s
                 for s in self.steps if s.kind == "static"]  # fmt: skip
        n_turns = len(self.steps) - len(holds)
        text = f"plan {self.plan.name}: {len(holds)} poses"
        if n_turns:
            text += f" and {n_turns} turns"
        if holds:
            each = f"{holds[0]:g} s" if len(set(holds)) == 1 else "as long as each step says"
            text += (f"; hold each pose still {each} (the count starts once the unit is still): "
                     f"{duration_text(sum(holds))} of holding in all")  # fmt: skip
        return text

    # ------------------------------------------------------------------------ reading
    def say(self, text: str, style: str = "") -> None:
        self.messages.append(Message(text, style))

    def drain(self) -> list[Message]:
        """The messages since the last call."""
        out, self.messages = self.messages, []
        return out

    def hold_s(self) -> float:
        """The current step's hold (its own ``hold_s``, e.g. a still:MINUTES plan), else --hold."""
        cur = self.current()
        own = None if cur is None else self.steps[cur].hold_s
        return float(own) if own else self.o.hold_s

    def current(self) -> int | None:
        if self.focus is not None and self.status[self.focus] == "pending":
            return self.focus
        for i, st in enumerate(self.status):
            if st == "pending":
                return i
        return None

    def candidates(self) -> list[int]:
        """Pending static steps in the run of static steps that holds the current step."""
        cur = self.current()
        if cur is None or self.steps[cur].kind != "static":
            return []
        a = cur
        while a > 0 and self.steps[a - 1].kind == "static":
            a -= 1
        b = cur
        while b + 1 < len(self.steps) and self.steps[b + 1].kind == "static":
            b += 1
        out = [i for i in range(a, b + 1) if self.status[i] == "pending"]
        return sorted(out, key=lambda i: (i != cur, i))

    def is_pose(self, i: int) -> bool:
        """A static step that is a gravity pose (not just the still period of a turn)."""
        return self.steps[i].up is not None or not self.rotations

    def left_labels(self) -> list[str]:
        return [s.label for s, st in zip(self.steps, self.status, strict=True) if st == "pending"]

    def progress_text(self) -> str:
        done = sum(s == "done" for s in self.status)
        left = self.left_labels()
        text = f"done {done}/{len(self.steps)}"
        if left:
            text += "; left: " + ", ".join(left)
        return text

    def instruction_line(self, cur: int) -> str:
        step = self.steps[cur]
        text = instruction(step)
        if step.kind == "static":
            text += f" for {self.hold_s():g} s"
            if len(self.candidates()) > 1:
                text += " (or any pose left, in any order)"
        if step.kind == "rotation" and self.rot_phase == "pre":
            text = "Hold still first. " + text
        return text

    def prompt(self) -> Prompt:
        """What the person should do now."""
        cur = self.current()
        if cur is None and self.mag_pending:
            text = ("Turn the unit slowly through the field directions still missing "
                    "(q: finish now)")  # fmt: skip
            return Prompt(None, len(self.steps), "mag", text, 0.0, 0.0, self.serial)
        if cur is None:
            return Prompt(None, len(self.steps), "done", "", 0.0, 0.0, self.serial)
        step = self.steps[cur]
        if step.kind == "static":
            phase = "hold" if self.holding else ("wait" if self.armed else "move")
        else:
            phase = self.rot_phase
        text = self.instruction_line(cur)
        if phase == "move":
            text = "Turn the unit to the next pose (Enter: take this one again)"
        held = min(self.hold_elapsed(), self.hold_s()) if phase == "hold" else 0.0
        return Prompt(cur, len(self.steps), phase, text, self.hold_s(), held, self.serial)

    def hold_elapsed(self) -> float:
        st = self.state
        if st is None or st.still_start is None:
            return 0.0
        s0 = max(st.still_start + self.base, self.min_start)
        return max(0.0, self.hist.t(self.hist.end - 1) - self.hist.t(s0))

    def signal_line(self) -> list[tuple[str, str]]:
        """The live signal as ``(text, style)`` parts: accel mean, |w|, STILL/MOVING."""
        b = self.last_block
        parts: list[tuple[str, str]] = []
        if b is not None and b.accel is not None and len(b):
            a = np.asarray(b.accel, float).mean(axis=0)
            parts.append((f"accel {fmt_vec(a)}  |a| {np.linalg.norm(a):.5g}  ", ""))
        if b is not None and b.gyro is not None and len(b):
            g = np.asarray(b.gyro, float).mean(axis=0)
            parts.append((f"gyro |w| {np.linalg.norm(g):.4g}  ", ""))
        st = self.state
        if st is None or not st.noise_ready:
            parts.append(("learning the noise (keep the unit still)", "yellow"))
        elif st.still:
            parts.append((f"STILL {st.still_for_s:4.1f} s", "bold green"))
            parts.append((f" (level {st.level:.2f} < {st.threshold:.2f})", "dim"))
        else:
            parts.append(("MOVING", "bold red"))
            parts.append((f" (level {st.level:.3g} > {st.threshold:.2f})", "dim"))
        return parts

    # ------------------------------------------------------------------------ commands
    def on_command(self, line: str) -> None:
        """One command line typed by the person."""
        self.command(parse_command(line, self.plan))

    def command(self, cmd: Command) -> None:
        if cmd.action == "quit":
            self.end_reason = "finished by the person (q)"
        elif cmd.action == "skip":
            cur = self.current()
            if cur is None:
                return
            self.status[cur] = "skipped"
            self.focus = None
            self.say(f"skipped {self.steps[cur].label}", "yellow")
            self.after_step()
        elif cmd.action == "redo":
            self.redo()
        elif cmd.action == "continue":
            self.armed = True
            self.min_start = self.hist.end
            self.holding = False
            if self.current() is not None and self.steps[self.current()].kind == "rotation":
                self.rot_phase = "pre"
        elif cmd.action == "pick":
            i = cmd.step
            if self.status[i] != "pending":
                self.say(f"{self.steps[i].label} is already {self.status[i]}", "yellow")
                return
            self.focus = i
            self.rot_phase = "pre"
            self.say(f"next: {self.steps[i].label}")
        else:
            self.say(
                f"unknown command {cmd.text!r}: r redo, s skip, q finish, Enter continue, "
                "or a step number or label",
                "yellow",
            )

    def redo(self) -> None:
        t = self.uncommitted
        if t is None:
            self.say("nothing to redo (only the last step taken can be redone)", "yellow")
            return
        self.uncommitted = None
        self.taken.remove(t)
        if t.turn is not None:  # the unit left the pose before it at the same moment
            self.turn_from = t.turn[0]
        self.status[t.step] = "pending"
        self.focus = t.step
        self.armed = True
        self.min_start = self.hist.end
        self.holding = False
        self.rot_phase = "pre"
        self.say(f"redo: {self.steps[t.step].label} removed; do it again", "yellow")
        self.serial += 1

    def after_step(self) -> None:
        self.next_step()
        if self.current() is None:
            if self.mag is not None and not self.mag.done:
                self.mag_pending = True
                self.say(
                    "every step done; " + self.mag.status() + ". Keep turning the unit slowly "
                    "through the missing directions (q: finish now)",
                    "bold",
                )
                return
            self.end_reason = "every step of the plan done or skipped" + self.mag_done_text()

    def next_step(self) -> None:
        """A step was taken: the hold and the turn's tracking start again."""
        self.holding = False
        self.rot_phase = "pre"
        self.pre_run = None
        self.serial += 1

    # ------------------------------------------------------------------------ segments
    def take(self, t: Taken) -> None:
        self.commit()
        self.uncommitted = t
        self.taken.append(t)
        self.status[t.step] = "done"
        if self.focus == t.step:
            self.focus = None

    def commit(self) -> None:
        """Hand the pending step to ``add_segment`` (it can no longer be redone)."""
        t = self.uncommitted
        if t is None:
            return
        self.uncommitted = None
        if t.start < self.committed_start:  # cannot happen with holds and turns in order
            self.say(f"{self.steps[t.step].label}: out of time order, not saved", "red")
            return
        step = self.steps[t.step]
        if t.turn is not None:  # the motion that led into this pose, before it in time
            self.add_segment("rotation", *t.turn, label=f"turn to {step.label}")
        self.add_segment(t.kind, t.start, t.stop, **step.segment_attrs())
        self.committed_start = t.start

    # ------------------------------------------------------------------------ stream
    def on_block(self, block) -> None:
        """One block of samples, already in the session (indices count the recorder's)."""
        self.last_block = block
        if len(block) == 0:
            return
        if getattr(block, "mag", None) is not None:
            self.on_mag(block.mag)
            if self.end_reason is not None:
                return
        self.hist.append(block.time, block.accel, block.gyro)
        if block.accel is not None:
            self.data_min = min(self.data_min, float(np.min(block.accel)))
            self.data_max = max(self.data_max, float(np.max(block.accel)))
        st = self.detector.update(block.time, block.accel, block.gyro)
        self.state = st
        if st.noise_ready and not self.noise_told:
            self.noise_told = True
            self.tell_noise()
        for s, e in st.ended_runs:  # the detector counts from its first sample
            self.on_run_end(s + self.base, e + self.base)
            if self.end_reason is not None:
                return
        self.on_current(st)

    def on_mag(self, mag: np.ndarray) -> None:
        """Magnetometer rows: update the coverage, tell each new tenth of it, and end the
        capture once the steps are done and the magnetometer has seen enough."""
        if self.mag is None:
            self.mag = MagCoverage(self.o.mag_goal)
        self.mag.update(mag)
        if not self.mag.ready:
            return
        tenth = int(10 * self.mag.fraction)
        if tenth > self.mag_told:
            self.mag_told = tenth
            self.say(self.mag.status(), "dim")
        if self.mag_pending and self.mag.done:
            self.mag_pending = False
            self.end_reason = "every step of the plan done or skipped" + self.mag_done_text()

    def mag_done_text(self) -> str:
        """``", and the magnetometer saw 93% ..."`` with a magnetometer, else ``""``."""
        if self.mag is None:
            return ""
        return f", and the magnetometer saw {100 * self.mag.fraction:.0f}% of the field directions"

    def tell_noise(self) -> None:
        sd = self.detector.noise_std()
        parts = [f"{k} {fmt_vec(v).strip()}" for k, v in sd.items() if v is not None]
        self.say(
            "noise learned (raw units per sample): "
            + "; ".join(" ".join(p.split()) for p in parts)
            + f". Still: window RMS below {self.detector.threshold:.2f} x noise "
            f"(false alarm {self.detector.alpha:g} per window)",
            "dim",
        )

    def on_run_end(self, s: int, e: int) -> None:
        """A still run ``[s, e)`` ended: the unit moved."""
        cur = self.current()
        if cur is None:
            return
        if self.steps[cur].kind == "static":
            if self.armed:
                s0 = max(s, self.min_start)
                dur = self.hist.t(e) - self.hist.t(s0) if e > s0 else 0.0
                if dur >= self.hold_s():
                    self.hold_done(s0, e)
                elif self.holding and dur >= self.o.warn_after_s:
                    self.say("the unit moved during the hold: hold it again", "bold yellow")
            last = self.taken[-1] if self.taken else None
            if last is not None and last.kind == "static" and s <= last.start < e:
                # the still run of the pose just taken ends: a turn starts, not before the
                # pose's window ends (the run ends at the first moving window's start, which
                # a knock just after the pose was taken can put inside the window)
                self.turn_from = max(e, last.stop)
            self.holding = False
            self.armed = True  # the unit moved: the next still period is a new pose
            self.min_start = 0
        elif self.rot_phase == "pre":
            s0 = max(s, self.min_start)
            if e > s0 and self.hist.t(e) - self.hist.t(s0) >= self.o.pre_still_s:
                self.pre_run = (s0, e)
                self.rot_phase = "turning"
                self.min_start = 0
        elif self.rot_phase == "turning":
            if self.hist.t(e) - self.hist.t(s) >= self.o.settle_s:
                self.turn_done(s)

    def on_current(self, st: StillState) -> None:
        """The unit is still now (or not): start, continue or finish a hold or a turn."""
        cur = self.current()
        if cur is None or not st.still:
            return
        s = st.still_start + self.base
        if self.steps[cur].kind == "static":
            if not self.armed:
                return
            s0 = max(s, self.min_start)
            end = self.hist.end
            if end - s0 < 2:
                return
            self.holding = True
            if self.hist.t(end - 1) - self.hist.t(s0) >= self.hold_s():
                self.hold_done(s0, end)
        elif self.rot_phase == "turning":
            if self.hist.t(self.hist.end - 1) - self.hist.t(s) >= self.o.settle_s:
                self.turn_done(s)

    # ------------------------------------------------------------------------ a hold
    def hold_done(self, s0: int, e: int) -> None:
        """The unit stayed still from ``s0`` for at least ``hold_s``: take the pose."""
        t = self.hist.time[s0 - self.hist.first : e - self.hist.first]
        n = int(np.searchsorted(t, t[0] + self.hold_s() - 1e-9, side="left"))
        n = max(2, min(n if n > 0 else len(t), e - s0))
        stop = s0 + n
        self.holding = False
        self.armed = False
        accel = self.hist.rows(self.hist.accel, s0, stop)
        if accel is None:
            self.say("this session has no accelerometer: static steps cannot be taken", "red")
            return
        direction = self.direction_of(accel)
        index, refusal = self.match_pose(direction)
        if refusal:
            self.say(refusal, "bold red")
            return
        turn = None
        if self.turn_from is not None and self.turn_from < s0 and self.last_taken_static():
            turn = (self.turn_from, s0)
        self.turn_from = None
        self.take(Taken(index, "static", s0, stop, direction, turn=turn))
        where = "" if direction is None else f" (measured up {describe_direction(direction)})"
        self.say(f"recorded {self.steps[index].label}{where}{self.count_text()}", "bold green")
        self.tell_coverage()
        self.tell_left()
        self.after_step()
        if self.current() is not None and self.steps[self.current()].kind == "static":
            self.say("turn the unit to the next pose")

    def match_pose(self, direction: np.ndarray | None) -> tuple[int, str | None]:
        """The step a finished hold fulfils, and a refusal (None: accepted)."""
        return match_hold(
            direction, self.current(), self.candidates(), self.steps, self.taken_poses(),
            min_separation_deg=self.o.min_separation_deg,
            match_tolerance_deg=self.o.match_tolerance_deg, is_pose=self.is_pose,
        )  # fmt: skip

    def count_text(self) -> str:
        """`` (3 of 6)``: the steps done of the plan's."""
        return f" ({sum(st == 'done' for st in self.status)} of {len(self.steps)})"

    def view_rows(self) -> list:
        """More rows of the live view (rich renderables; none here)."""
        return []

    def direction_of(self, accel: np.ndarray) -> np.ndarray | None:
        direction = estimate_direction(
            accel.mean(axis=0),
            self.o.accel_units,
            nominal_bias=self.o.nominal_bias,
            nominal_scale=self.o.nominal_scale,
            data_min=self.data_min,
            data_max=self.data_max,
        )
        if direction is None and not self.no_direction_told:
            self.no_direction_told = True
            self.say(
                "the gravity direction cannot be estimated without a nominal bias/scale for "
                "these units or channels: poses are taken in plan order",
                "yellow",
            )
        return direction

    def last_taken_static(self) -> bool:
        """The last step taken is a static one (a turn after it is a turn between poses)."""
        return bool(self.taken) and self.taken[-1].kind == "static"

    def taken_poses(self) -> list[Taken]:
        return [
            x
            for x in self.taken
            if x.kind == "static" and x.direction is not None and self.is_pose(x.step)
        ]

    def tell_coverage(self) -> None:
        dirs = [x.direction for x in self.taken_poses()]
        if dirs:
            c = coverage(np.array(dirs))
            self.say(
                f"coverage: {100 * c.fraction:.0f}% of the sphere within {c.cap_deg:g} deg of "
                f"a pose, largest gap {c.largest_gap_deg:.0f} deg",
                "dim",
            )

    def tell_left(self) -> None:
        left = self.left_labels()
        self.say("left: " + (", ".join(left) if left else "nothing"))

    # ------------------------------------------------------------------------ a turn
    def turn_done(self, post_start: int) -> None:
        """The unit is still again after a rotation step's turn: record the turn."""
        cur = self.current()
        step = self.steps[cur]
        a, b, measured = measure_turn(
            self.hist, self.pre_run, post_start, self.detector.noise_std().get("gyro"),
            self.o.gyro_units, self.o.gyro_scale,
        )  # fmt: skip
        self.take(Taken(cur, "rotation", a, b, measured=measured))
        self.turn_from = None  # this turn is recorded as the plan's own step
        text = f"recorded {step.label} ({self.hist.t(b) - self.hist.t(a):.1f} s"
        if "angle_deg" in measured:
            text += f", {measured['angle_deg']:.0f} deg measured"
        self.say(text + ")", "bold green")
        for warning in turn_warnings(step, measured, self.o.axis_tolerance_deg):
            self.say(warning, "bold yellow")
        self.tell_left()
        self.after_step()
        # the unit is still in its new pose: a static step next may hold right away
        self.armed = True
        self.min_start = post_start

    # ------------------------------------------------------------------------ the end
    def summary(self, recorder) -> CaptureSummary:
        """Commit the last step and say what was done (``recorder``: samples, end, stats)."""
        self.commit()
        done = [self.steps[x.step].label for x in self.taken]
        skipped = [
            s.label for s, st in zip(self.steps, self.status, strict=True) if st == "skipped"
        ]
        missing = self.left_labels()
        reason = self.end_reason or getattr(recorder, "end_reason", "") or "the stream ended"
        complete = not missing and not skipped
        text = f"{len(done)} of {len(self.steps)} steps done"
        if skipped:
            text += f", {len(skipped)} skipped"
        if missing:
            text += f", {len(missing)} missing: " + ", ".join(missing)
        self.say(f"{text} ({reason})", "bold green" if complete else "bold yellow")
        if self.mag is not None:
            self.say(self.mag.status(), "bold green" if self.mag.done else "bold yellow")
        return CaptureSummary(
            complete=complete,
            done=done,
            skipped=skipped,
            missing=missing,
            end_reason=reason,
            samples=int(recorder.n_samples),
            stats=dict(getattr(recorder, "stats", {}) or {}),
        )
