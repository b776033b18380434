"""Guided capture: tell the person at the bench what to do, and record it when it is done.

:func:`run_guided` consumes :meth:`Recorder.blocks() <imucal_cli.capture.recorder.Recorder.blocks>`
(every block is already in the session file when it arrives) and, for each step of a
:class:`~imucal_cli.plans.Plan`:

static step
    says what to do (``Put face +Z up and hold still``), shows the live signal and STILL/MOVING;
    as soon as the :class:`~imucal_cli.solvers.stillness.StillnessDetector` calls the unit
    still, the hold starts by itself and runs ``hold_s`` seconds under a progress bar.  Motion
    during the hold restarts it with a warning.  The finished hold is matched by its gravity
    direction to the nearest static step of the plan not yet taken (any order), refused when
    it is within ``min_separation_deg`` of a pose already taken, and the coverage of the sphere
    and the steps left are shown.  After a pose the next hold waits for the unit to move.
rotation step
    says ``Turn about +X by 90 degrees, then hold still``; waits for a still period, detects
    the start and end of the turn from the gyro (:func:`~imucal_cli.solvers.stillness.motion_span`)
    and records a ``rotation`` segment spanning it, with the plan's ``axis`` and ``angle_deg``.

Commands (a line each, from a :class:`KeySource`): ``r`` redo the last step taken, ``s`` skip
the current step, ``q`` finish now, Enter continue (take the next hold where the unit is now,
without waiting for it to move), a number or a step label picks the step to do next.

Segments reach the recorder only when they are final: the last step taken stays pending (so
that ``r`` can drop it) until the next one is taken or the capture ends; segments are therefore
added once, in time order, as :class:`~imucal_cli.formats.session.SessionWriter` requires.

Output works in a terminal (a :class:`rich.live.Live` display refreshed ``refresh_hz`` times a
second, events printed above it) and without one (tests, logs: plain lines, one per event or
change of instruction, nothing per block).
"""

from __future__ import annotations

import queue
import re
import sys
import threading
import time as _time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from rich.console import Console, Group
from rich.live import Live
from rich.progress_bar import ProgressBar
from rich.table import Table
from rich.text import Text

from imucal_cli.plans import CaptureSummary, Plan, Step
from imucal_cli.solvers.poses import angle_deg, coverage, describe_direction, unit
from imucal_cli.solvers.stillness import (
    StillnessDetector,
    StillState,
    integrate_rate,
    motion_span,
    rate_to_deg_s,
)

__all__ = [
    "Command",
    "KeySource",
    "ScriptedKeys",
    "StdinKeys",
    "estimate_direction",
    "instruction",
    "parse_command",
    "run_guided",
]

ADC_WORDS = (8, 10, 12, 14, 16, 18, 20, 24, 32)
"""Standard ADC word lengths, bits (for the mid-scale of an unsigned ADC)."""

HISTORY_SAMPLES = 200_000
"""Samples kept in memory for holds and turns (about half an hour at 100 Hz)."""


# --------------------------------------------------------------------------------------------
# Commands and key sources
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Command:
    """A parsed command line.

    Attributes
    ----------
    action : str
        ``"continue"`` (empty line), ``"redo"`` (``r``), ``"skip"`` (``s``), ``"quit"``
        (``q``), ``"pick"`` (a step number, 1-based, or a step label) or ``"unknown"``.
    step : int or None
        For ``"pick"``: the step index (0-based).
    text : str
        The line as typed.
    """

    action: str
    step: int | None = None
    text: str = ""


def parse_command(text: str, plan: Plan) -> Command:
    """Parse one command line against ``plan``.

    ``r``/``redo``, ``s``/``skip``, ``q``/``quit``, empty: continue; ``3``: step 3 (1-based);
    otherwise a step label, exact (case-insensitive) or the only label that contains ``text``.
    """
    raw = text
    t = " ".join(str(text).split()).lower()
    if t == "":
        return Command("continue", text=raw)
    for action in ("redo", "skip", "quit"):
        if t in (action, action[0]):
            return Command(action, text=raw)
    if t.isdigit():
        i = int(t) - 1
        if 0 <= i < len(plan.steps):
            return Command("pick", i, raw)
        return Command("unknown", text=raw)
    labels = [s.label.lower() for s in plan.steps]
    exact = [i for i, lab in enumerate(labels) if lab == t]
    hits = exact or [i for i, lab in enumerate(labels) if t in lab]
    if len(hits) == 1 or (exact and hits):
        return Command("pick", hits[0], raw)
    return Command("unknown", text=raw)


class KeySource(Protocol):
    """Where commands come from.  ``get()`` never blocks: one command line, or None."""

    def get(self) -> str | None:
        """The next command line (without its newline), or None when there is none."""
        ...


class StdinKeys:
    """Command lines from a text stream (stdin), read by a background thread.

    Works with a terminal (type a command, then Enter) and with a pipe.  The thread is a
    daemon: it never keeps the program alive.

    Parameters
    ----------
    stream : text file, optional
        Default ``sys.stdin``.
    """

    def __init__(self, stream=None) -> None:
        self._stream = sys.stdin if stream is None else stream
        self._queue: queue.SimpleQueue[str] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._read, name="imucal-keys", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        try:
            for line in self._stream:
                self._queue.put(line.rstrip("\r\n"))
        except (OSError, ValueError):
            pass

    def get(self) -> str | None:
        """The next line typed, or None."""
        try:
            return self._queue.get_nowait()
        except queue.Empty:
            return None


class ScriptedKeys:
    """Commands for tests, released in order, each when its condition holds.

    Parameters
    ----------
    items : iterable
        Each item is a command string (released on the next :meth:`get`), or a pair
        ``(condition, command)``: ``condition`` an int (released once ``n_samples()`` reaches
        it) or a callable returning True when the command is due.
    n_samples : callable, optional
        Current sample count (e.g. ``lambda: recorder.n_samples``); needed for int conditions.

    Attributes
    ----------
    released : list of str
        The commands handed out so far.
    """

    def __init__(
        self,
        items: Iterable[str | tuple[int | Callable[[], bool], str]],
        *,
        n_samples: Callable[[], int] | None = None,
    ) -> None:
        self._items = list(items)
        self._n_samples = n_samples
        self.released: list[str] = []

    def get(self) -> str | None:
        """The next command if its condition holds, else None."""
        if not self._items:
            return None
        item = self._items[0]
        if isinstance(item, str):
            due, command = True, item
        else:
            cond, command = item
            if callable(cond):
                due = bool(cond())
            else:
                if self._n_samples is None:
                    raise ValueError("ScriptedKeys: int conditions need n_samples")
                due = self._n_samples() >= int(cond)
        if not due:
            return None
        self._items.pop(0)
        self.released.append(command)
        return command

    @property
    def pending(self) -> int:
        """Commands not yet released."""
        return len(self._items)


# --------------------------------------------------------------------------------------------
# Gravity direction of a hold without a calibration
# --------------------------------------------------------------------------------------------


def _adc_mid_scale(data_min: float, data_max: float, mean: np.ndarray) -> float | None:
    """Mid-scale of an unsigned ADC, or None when the data look signed (see
    :func:`estimate_direction`)."""
    if data_min < 0:
        return None
    for bits in ADC_WORDS:
        if data_max <= 2**bits - 1:
            if np.all(mean >= 2 ** (bits - 2)):
                return float(2 ** (bits - 1))
            return None
    return None


def estimate_direction(
    mean: np.ndarray,
    units: str | None,
    *,
    nominal_bias=None,
    nominal_scale=None,
    data_min: float | None = None,
    data_max: float | None = None,
) -> np.ndarray | None:
    """Unit gravity ("up") direction of a hold from its raw mean, without a calibration.

    ``up = unit(M @ (mean - b))``: the raw mean minus a nominal zero-g offset ``b``, mapped by a
    nominal matrix ``M`` onto the fixture axes.  The offset and scale errors of a MEMS part
    (a few % and tens of mg) tilt this direction by a few degrees at most, far less than the
    45 degrees between the poses of a plan, which is all the matching needs.

    - ``b`` is ``nominal_bias`` when given (one number or one per channel).  Otherwise 0 for
      ``g``, ``m/s^2`` and signed ``counts``; for ``counts`` from an unsigned ADC, mid-scale
      ``2^(bits-1)``: the data are taken as unsigned when every sample seen so far is >= 0
      (``data_min``) and every channel's mean is above a quarter of the smallest standard word
      that holds ``data_max`` (a signed part lying flat reads about 0 on two axes).  For ``V``
      (analog parts sit at an unknown mid-supply) no default exists: None is returned.
    - ``M`` is ``nominal_scale``: None (identity; needs 3 channels), one number or one per
      channel (a diagonal), or a 3 x n matrix (redundant units: n channels onto 3 axes).

    Parameters
    ----------
    mean : ndarray, shape (n,)
        Mean raw accel of the hold.
    units : str or None
        Raw accel units (``counts``, ``V``, ``g``, ``m/s^2``).
    nominal_bias, nominal_scale : optional
        See above.
    data_min, data_max : float, optional
        Smallest and largest raw accel value seen so far (default: those of ``mean``).

    Returns
    -------
    ndarray, shape (3,), or None
        None when the direction cannot be estimated (``V`` without a nominal bias, more than
        3 channels without a matrix, a zero vector).
    """
    m = np.asarray(mean, dtype=float).reshape(-1)
    n = len(m)
    if nominal_bias is not None:
        b = np.broadcast_to(np.asarray(nominal_bias, float), (n,))
    elif units == "V":
        return None
    elif units in (None, "counts"):
        lo = float(m.min()) if data_min is None else float(data_min)
        hi = float(m.max()) if data_max is None else float(data_max)
        mid = _adc_mid_scale(lo, hi, m)
        b = np.zeros(n) if mid is None else np.full(n, mid)
    else:
        b = np.zeros(n)
    x = m - b
    if nominal_scale is None:
        if n != 3:
            return None
        v = x
    else:
        s = np.asarray(nominal_scale, dtype=float)
        if s.ndim == 2:
            if s.shape != (3, n):
                return None
            v = s @ x
        else:
            if n != 3:
                return None
            v = x / np.broadcast_to(s, (3,))
    if not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        return None
    return unit(v[None, :])[0]


# --------------------------------------------------------------------------------------------
# Words
# --------------------------------------------------------------------------------------------


def instruction(step: Step) -> str:
    """What the person is told for a step: ``"Put face +Z up and hold still"``,
    ``"Turn about +X by 90 degrees, then hold still"``."""
    label = step.label.strip()
    if step.kind == "rotation":
        if step.axis is not None:
            text = f"Turn about {describe_direction(np.asarray(step.axis, float))}"
            if step.angle_deg is not None:
                text += f" by {step.angle_deg:g} degrees"
            return text + ", then hold still"
        return label[:1].upper() + label[1:] + ", then hold still"
    low = label.lower()
    if low.startswith(("face ", "edge ")):
        return f"Put {label} and hold still"
    if re.fullmatch(r"pose \d+", low):
        return f"Put the unit in a new orientation ({label}) and hold still"
    if step.up is not None:
        return f"Put the unit {label} ({describe_direction(np.asarray(step.up))} up) and hold still"
    text = label[:1].upper() + label[1:]
    return text if "still" in low else text + " and hold still"


def _fmt_vec(v: np.ndarray) -> str:
    return " ".join(f"{x:9.4g}" for x in np.asarray(v, float))


# --------------------------------------------------------------------------------------------
# The run
# --------------------------------------------------------------------------------------------


class _History:
    """The recent samples, indexed by recorder sample index."""

    def __init__(self, first: int, keep_s: float = 0.0) -> None:
        self.first = first
        self.keep_s = keep_s  # never drop samples younger than this (a long hold), s
        self.time = np.empty(0)
        self.accel: np.ndarray | None = None
        self.gyro: np.ndarray | None = None

    def append(self, time, accel, gyro) -> None:
        self.time = np.concatenate([self.time, np.asarray(time, float)])
        if accel is not None:
            a = np.asarray(accel, float)
            self.accel = a if self.accel is None else np.concatenate([self.accel, a])
        if gyro is not None:
            g = np.asarray(gyro, float)
            self.gyro = g if self.gyro is None else np.concatenate([self.gyro, g])
        drop = len(self.time) - HISTORY_SAMPLES
        if drop > 0 and self.keep_s > 0:
            young = int(np.searchsorted(self.time, self.time[-1] - self.keep_s, side="left"))
            drop = min(drop, young)
        if drop > 0:
            self.first += drop
            self.time = self.time[drop:]
            self.accel = None if self.accel is None else self.accel[drop:]
            self.gyro = None if self.gyro is None else self.gyro[drop:]

    @property
    def end(self) -> int:
        return self.first + len(self.time)

    def t(self, index: int) -> float:
        i = min(max(index - self.first, 0), len(self.time) - 1)
        return float(self.time[i])

    def rows(self, arr: np.ndarray | None, start: int, stop: int) -> np.ndarray | None:
        if arr is None:
            return None
        return arr[max(start - self.first, 0) : max(stop - self.first, 0)]


@dataclass
class _Taken:
    step: int
    kind: str
    start: int
    stop: int
    direction: np.ndarray | None = None
    measured: dict = field(default_factory=dict)


class _Guided:
    def __init__(self, recorder, plan: Plan, console: Console, keys: KeySource, opt: dict):
        self.rec = recorder
        self.plan = plan
        self.steps = plan.steps
        self.console = console
        self.keys = keys
        self.o = opt
        self.status = ["pending"] * len(self.steps)
        self.taken: list[_Taken] = []
        self.uncommitted: _Taken | None = None
        self.committed_start = -1
        self.focus: int | None = None
        self.detector = opt["detector"] or StillnessDetector()
        self.base = int(recorder.n_samples)
        longest = max((s.hold_s or 0.0 for s in self.steps), default=0.0)
        self.hist = _History(self.base, keep_s=longest + 10.0 if longest else 0.0)
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
        self.terminal = bool(console.is_terminal)
        self.live: Live | None = None
        self.last_render = 0.0
        self.plain_key: tuple | None = None
        self.noise_told = False
        self.no_direction_told = False
        self.rotations = any(s.kind == "rotation" for s in self.steps)

    def hold_s(self) -> float:
        """The current step's hold (its own ``hold_s``, e.g. a still:MINUTES plan), else --hold."""
        cur = self.current()
        own = None if cur is None else self.steps[cur].hold_s
        return float(own) if own else self.o["hold_s"]

    # ---------------------------------------------------------------- output
    def say(self, text: str, style: str | None = None) -> None:
        target = self.live.console if self.live is not None else self.console
        target.print(Text(text, style=style or ""), highlight=False)

    def plain_status(self) -> None:
        """Plain mode: print the instruction once per change of what the person should do."""
        cur = self.current()
        if cur is None:
            return
        step = self.steps[cur]
        if step.kind == "static":
            phase = "hold" if self.holding else ("wait" if self.armed else "move")
        else:
            phase = self.rot_phase
        key = (cur, phase)
        if key == self.plain_key:
            return
        self.plain_key = key
        if phase == "move":
            return  # the message after the pose already says to turn the unit
        if phase == "hold":
            self.say(f"still: holding {self.hold_s():g} s ...")
        elif phase == "turning":
            self.say("turning ...")
        else:
            self.say(f"step {cur + 1}/{len(self.steps)}: {self.instruction_line(cur)}", "bold")

    def instruction_line(self, cur: int) -> str:
        step = self.steps[cur]
        text = instruction(step)
        if step.kind == "static" and len(self.candidates()) > 1:
            text += " (or any pose left, in any order)"
        if step.kind == "rotation" and self.rot_phase == "pre":
            text = "Hold still first. " + text
        return text

    def render(self):
        cur = self.current()
        rows = Table.grid(padding=(0, 1))
        rows.add_column()
        if cur is not None:
            step = self.steps[cur]
            head = f"[step {cur + 1}/{len(self.steps)}] {self.instruction_line(cur)}"
            if step.kind == "static" and not self.armed:
                head = "Turn the unit to the next pose (Enter: take this one again)"
            rows.add_row(Text(head, style="bold"))
        rows.add_row(self.signal_text())
        if self.holding and self.state is not None:
            done = min(self.hold_elapsed(), self.hold_s())
            bar = Table.grid(padding=(0, 1))
            bar.add_row(
                ProgressBar(total=self.hold_s(), completed=done, width=40),
                Text(f"{done:.1f}/{self.hold_s():g} s"),
            )
            rows.add_row(bar)
        rows.add_row(Text(self.progress_text(), style="dim"))
        rows.add_row(Text("commands: r redo, s skip, q finish, Enter continue", style="dim"))
        return Group(rows)

    def signal_text(self) -> Text:
        b = self.last_block
        t = Text()
        if b is not None and b.accel is not None and len(b):
            a = np.asarray(b.accel, float).mean(axis=0)
            t.append(f"accel {_fmt_vec(a)}  |a| {np.linalg.norm(a):.5g}  ")
        if b is not None and b.gyro is not None and len(b):
            g = np.asarray(b.gyro, float).mean(axis=0)
            t.append(f"gyro |w| {np.linalg.norm(g):.4g}  ")
        st = self.state
        if st is None or not st.noise_ready:
            t.append("learning the noise (keep the unit still)", style="yellow")
        elif st.still:
            t.append(f"STILL {st.still_for_s:4.1f} s", style="bold green")
            t.append(f" (level {st.level:.2f} < {st.threshold:.2f})", style="dim")
        else:
            t.append("MOVING", style="bold red")
            t.append(f" (level {st.level:.3g} > {st.threshold:.2f})", style="dim")
        return t

    def progress_text(self) -> str:
        done = sum(s == "done" for s in self.status)
        left = self.left_labels()
        text = f"done {done}/{len(self.steps)}"
        if left:
            text += "; left: " + ", ".join(left)
        return text

    def left_labels(self) -> list[str]:
        return [s.label for s, st in zip(self.steps, self.status, strict=True) if st == "pending"]

    def refresh(self, force: bool = False) -> None:
        if self.live is not None:
            now = _time.monotonic()
            if force or now - self.last_render >= 1.0 / self.o["refresh_hz"]:
                self.last_render = now
                self.live.update(self.render(), refresh=True)
        else:
            self.plain_status()

    # ---------------------------------------------------------------- plan state
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

    # ---------------------------------------------------------------- commands
    def poll_keys(self) -> None:
        while True:
            line = self.keys.get()
            if line is None:
                return
            self.command(parse_command(line, self.plan))
            if self.end_reason is not None:
                return

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
        self.status[t.step] = "pending"
        self.focus = t.step
        self.armed = True
        self.min_start = self.hist.end
        self.holding = False
        self.rot_phase = "pre"
        self.say(f"redo: {self.steps[t.step].label} removed; do it again", "yellow")
        self.plain_key = None

    def after_step(self) -> None:
        self.holding = False
        self.rot_phase = "pre"
        self.pre_run = None
        self.plain_key = None
        if self.current() is None:
            self.end_reason = "every step of the plan done or skipped"

    # ---------------------------------------------------------------- segments
    def take(self, t: _Taken) -> None:
        self.commit()
        self.uncommitted = t
        self.taken.append(t)
        self.status[t.step] = "done"
        if self.focus == t.step:
            self.focus = None

    def commit(self) -> None:
        t = self.uncommitted
        if t is None:
            return
        self.uncommitted = None
        if t.start < self.committed_start:  # cannot happen with holds and turns in order
            self.say(f"{self.steps[t.step].label}: out of time order, not saved", "red")
            return
        step = self.steps[t.step]
        if t.kind == "static":
            self.rec.add_segment(
                "static",
                t.start,
                t.stop,
                label=step.label,
                up=None if step.up is None else np.asarray(step.up, float),
            )
        else:
            self.rec.add_segment(
                "rotation",
                t.start,
                t.stop,
                label=step.label,
                axis=None if step.axis is None else np.asarray(step.axis, float),
                angle_deg=step.angle_deg,
            )
        self.committed_start = t.start

    # ---------------------------------------------------------------- stream
    def on_block(self, block) -> None:
        self.last_block = block
        if len(block) == 0:
            return
        self.hist.append(block.time, block.accel, block.gyro)
        if block.accel is not None:
            self.data_min = min(self.data_min, float(np.min(block.accel)))
            self.data_max = max(self.data_max, float(np.max(block.accel)))
        st = self.detector.update(block.time, block.accel, block.gyro)
        # the detector counts from the first sample it saw: shift to recorder indices
        shift = self.base
        self.state = st
        if st.noise_ready and not self.noise_told:
            self.noise_told = True
            self.tell_noise()
        for s, e in st.ended_runs:
            self.on_run_end(s + shift, e + shift)
            if self.end_reason is not None:
                return
        self.on_current(st, shift)

    def tell_noise(self) -> None:
        sd = self.detector.noise_std()
        parts = [f"{k} {_fmt_vec(v).strip()}" for k, v in sd.items() if v is not None]
        self.say(
            "noise learned (raw units per sample): "
            + "; ".join(" ".join(p.split()) for p in parts)
            + f". Still: window RMS below {self.detector.threshold:.2f} x noise "
            f"(false alarm {self.detector.alpha:g} per window)",
            "dim",
        )

    def hold_elapsed(self) -> float:
        st = self.state
        if st is None or st.still_start is None:
            return 0.0
        s0 = max(st.still_start + self.base, self.min_start)
        return max(0.0, self.hist.t(self.hist.end - 1) - self.hist.t(s0))

    def on_run_end(self, s: int, e: int) -> None:
        cur = self.current()
        if cur is None:
            return
        step = self.steps[cur]
        if step.kind == "static":
            if self.armed:
                s0 = max(s, self.min_start)
                dur = self.hist.t(e) - self.hist.t(s0) if e > s0 else 0.0
                if dur >= self.hold_s():
                    self.hold_done(s0, e)
                elif self.holding and dur >= self.o["warn_after_s"]:
                    self.say("the unit moved during the hold: hold it again", "bold yellow")
            self.holding = False
            self.armed = True  # the unit moved: the next still period is a new pose
            self.min_start = 0
        else:
            if self.rot_phase == "pre":
                s0 = max(s, self.min_start)
                if e > s0 and self.hist.t(e) - self.hist.t(s0) >= self.o["pre_still_s"]:
                    self.pre_run = (s0, e)
                    self.rot_phase = "turning"
                    self.min_start = 0
            elif self.rot_phase == "turning":
                if self.hist.t(e) - self.hist.t(s) >= self.o["settle_s"]:
                    self.turn_done(s)

    def on_current(self, st: StillState, shift: int) -> None:
        cur = self.current()
        if cur is None or not st.still:
            return
        s = st.still_start + shift
        step = self.steps[cur]
        if step.kind == "static":
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
            if self.hist.t(self.hist.end - 1) - self.hist.t(s) >= self.o["settle_s"]:
                self.turn_done(s)

    # ---------------------------------------------------------------- a hold
    def hold_done(self, s0: int, e: int) -> None:
        """The unit stayed still from ``s0`` for at least ``hold_s``: take the pose."""
        t = self.hist.time[s0 - self.hist.first : e - self.hist.first]
        n = int(np.searchsorted(t, t[0] + self.hold_s() - 1e-9, side="left"))
        n = max(2, min(n if n > 0 else len(t), e - s0))
        stop = s0 + n
        self.holding = False
        self.armed = False
        accel = self.hist.rows(self.hist.accel, s0, stop)
        cur = self.current()
        if accel is None:
            self.say("this session has no accelerometer: static steps cannot be taken", "red")
            return
        direction = estimate_direction(
            accel.mean(axis=0),
            self.o["accel_units"],
            nominal_bias=self.o["nominal_bias"],
            nominal_scale=self.o["nominal_scale"],
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
        index, refusal = self.match(direction, cur)
        if refusal:
            self.say(refusal, "bold red")
            return
        self.take(_Taken(index, "static", s0, stop, direction))
        n_done = sum(st == "done" for st in self.status)
        where = "" if direction is None else f" (measured up {describe_direction(direction)})"
        self.say(
            f"recorded {self.steps[index].label}{where} ({n_done} of {len(self.steps)})",
            "bold green",
        )
        dirs = [
            x.direction
            for x in self.taken
            if x.kind == "static" and x.direction is not None and self.is_pose(x.step)
        ]
        if dirs:
            c = coverage(np.array(dirs))
            self.say(
                f"coverage: {100 * c.fraction:.0f}% of the sphere within {c.cap_deg:g} deg of "
                f"a pose, largest gap {c.largest_gap_deg:.0f} deg",
                "dim",
            )
        left = self.left_labels()
        self.say("left: " + (", ".join(left) if left else "nothing"))
        self.after_step()
        if self.current() is not None and self.steps[self.current()].kind == "static":
            self.say("turn the unit to the next pose")

    def match(self, direction: np.ndarray | None, cur: int) -> tuple[int, str | None]:
        """The step a hold fulfils, or a refusal message."""
        cands = self.candidates()
        if not cands:
            return cur, None
        if direction is None:
            return cands[0], None
        min_sep = self.o["min_separation_deg"]
        taken = [
            x
            for x in self.taken
            if x.kind == "static" and x.direction is not None and self.is_pose(x.step)
        ]
        close = [
            (float(angle_deg(direction, x.direction)), x)
            for x in taken
            if float(angle_deg(direction, x.direction)) < min_sep
        ]
        close.sort(key=lambda ax: ax[0])
        labelled = [i for i in cands if self.steps[i].up is not None]
        best, best_angle = None, np.inf
        for i in labelled:
            a = float(angle_deg(direction, np.asarray(self.steps[i].up, float)))
            if a < best_angle:
                best, best_angle = i, a

        def too_close() -> str:
            ang, x = close[0]
            return (
                f"too close to {self.steps[x.step].label}, already taken ({ang:.0f} deg "
                f"apart): turn the unit to another face or edge"
            )

        if best is not None and best_angle <= self.o["match_tolerance_deg"]:
            up = np.asarray(self.steps[best].up, float)
            repeat = any(
                self.steps[x.step].up is not None
                and float(angle_deg(up, np.asarray(self.steps[x.step].up, float))) < min_sep
                for _, x in close
            )
            if close and not repeat:
                return best, too_close()
            return best, None
        if close and self.is_pose(cands[0]):
            return cands[0], too_close()
        unlabelled = [i for i in cands if self.steps[i].up is None]
        if unlabelled:
            return unlabelled[0], None
        near = f"{self.steps[best].label}, {best_angle:.0f} deg away" if best is not None else ""
        return cands[0], (
            f"this pose (up {describe_direction(direction)}) matches no step left "
            f"(nearest: {near}; tolerance {self.o['match_tolerance_deg']:g} deg): "
            "put the unit on one of the poses left"
        )

    # ---------------------------------------------------------------- a turn
    def turn_done(self, post_start: int) -> None:
        cur = self.current()
        step = self.steps[cur]
        pre_s, pre_e = self.pre_run
        a, b = pre_e, post_start
        measured: dict = {}
        gyro = self.hist.gyro
        sd = self.detector.noise_std().get("gyro")
        if gyro is not None and sd is not None:
            n_rest = max(2, pre_e - pre_s)
            lo = max(pre_e - n_rest, self.hist.first)
            rest = self.hist.rows(gyro, lo, pre_e).mean(axis=0)
            w0 = max(pre_s, self.hist.first)
            w1 = self.hist.end
            span = motion_span(self.hist.rows(gyro, w0, w1), rest, sd)
            if span is not None:
                a, b = w0 + span[0], w0 + span[1]
            t = self.hist.rows(self.hist.time[:, None], w0, w1)[:, 0]
            vec = integrate_rate(t, self.hist.rows(gyro, w0, w1), rest, a - w0, b - w0)
            factor = rate_to_deg_s(self.o["gyro_units"], self.o["gyro_scale"])
            measured["integral"] = vec
            if factor is not None and np.linalg.norm(vec) > 0:
                measured["angle_deg"] = float(np.linalg.norm(vec) * factor)
        if b <= a:
            a, b = pre_e, max(post_start, pre_e + 1)
        self.take(_Taken(cur, "rotation", a, b, measured=measured))
        dur = self.hist.t(b) - self.hist.t(a)
        text = f"recorded {step.label} ({dur:.1f} s"
        if "angle_deg" in measured:
            text += f", {measured['angle_deg']:.0f} deg measured"
        self.say(text + ")", "bold green")
        vec = measured.get("integral")
        if vec is not None and len(vec) == 3 and np.linalg.norm(vec) > 0:
            if step.axis is not None:
                axis = np.asarray(step.axis, float)
                off = float(angle_deg(vec, axis))
                if min(off, 180.0 - off) > self.o["axis_tolerance_deg"]:
                    self.say(
                        f"the turn looks like it was about {describe_direction(vec)}, not "
                        f"{describe_direction(axis)}: r redoes it",
                        "bold yellow",
                    )
            want, got = step.angle_deg, measured.get("angle_deg")
            if want is not None and got is not None and abs(got - abs(want)) > 20.0:
                self.say(
                    f"turned {got:.0f} deg, the plan says {abs(want):g}: r redoes it",
                    "bold yellow",
                )
        left = self.left_labels()
        self.say("left: " + (", ".join(left) if left else "nothing"))
        self.after_step()
        # the unit is still in its new pose: a static step next may hold right away
        self.armed = True
        self.min_start = post_start

    # ---------------------------------------------------------------- loop
    def run(self) -> CaptureSummary:
        gen = self.rec.blocks(self.o["tick_s"])
        live = None
        if self.terminal:
            live = Live(
                self.render(),
                console=self.console,
                auto_refresh=False,
                transient=False,
                redirect_stdout=False,
                redirect_stderr=False,
            )
            live.start()
            self.live = live
        try:
            self.refresh(force=True)
            for block in gen:
                self.on_block(block)
                if self.end_reason is None:
                    self.poll_keys()
                if self.end_reason is not None:
                    break
                self.refresh()
        finally:
            gen.close()
            if self.end_reason is not None:
                self.rec.stop()
            if live is not None:
                self.live.update(self.render(), refresh=True)
                live.stop()
                self.live = None
        self.commit()
        return self.summary()

    def summary(self) -> CaptureSummary:
        done = [self.steps[x.step].label for x in self.taken]
        skipped = [
            s.label for s, st in zip(self.steps, self.status, strict=True) if st == "skipped"
        ]
        missing = self.left_labels()
        reason = self.end_reason or getattr(self.rec, "end_reason", "") or "the stream ended"
        complete = not missing and not skipped
        stats = dict(getattr(self.rec, "stats", {}) or {})
        text = f"{len(done)} of {len(self.steps)} steps done"
        if skipped:
            text += f", {len(skipped)} skipped"
        if missing:
            text += f", {len(missing)} missing: " + ", ".join(missing)
        self.say(f"{text} ({reason})", "bold green" if complete else "bold yellow")
        return CaptureSummary(
            complete=complete,
            done=done,
            skipped=skipped,
            missing=missing,
            end_reason=reason,
            samples=int(self.rec.n_samples),
            stats=stats,
        )


def run_guided(
    recorder,
    plan: Plan,
    *,
    console: Console,
    keys: KeySource,
    hold_s: float = 2.0,
    min_separation_deg: float = 15.0,
    nominal_bias=None,
    nominal_scale=None,
    refresh_hz: float = 10.0,
    match_tolerance_deg: float = 20.0,
    accel_units: str | None = None,
    gyro_units: str | None = None,
    gyro_scale: float | None = None,
    detector: StillnessDetector | None = None,
    warn_after_s: float = 0.5,
    pre_still_s: float = 0.5,
    settle_s: float = 0.5,
    axis_tolerance_deg: float = 30.0,
    tick_s: float = 0.1,
) -> CaptureSummary:
    """Guide a person through ``plan`` while ``recorder`` records; return what was done.

    Parameters
    ----------
    recorder : Recorder
        Provides ``blocks(tick_s)``, ``n_samples``, ``add_segment(...)``, ``stop()``,
        ``end_reason``, ``stats`` and, optionally, ``accel_units``/``gyro_units``.  Blocks must
        be yielded after they were appended (segment indices count the recorder's samples).
    plan : Plan
        The steps (static and rotation).
    console : rich.console.Console
        Where to talk.  A terminal gets a live display; anything else plain lines.
    keys : KeySource
        Commands: ``r`` redo, ``s`` skip, ``q`` finish, Enter continue, a step number or label.
    hold_s : float
        Length of each static hold, s; a step's own ``hold_s`` (the ``still:MINUTES`` plan)
        takes precedence.
    min_separation_deg : float
        A pose closer than this to one already taken is refused (unless the plan itself asks
        for that direction again).
    nominal_bias, nominal_scale : optional
        How a raw accel mean becomes a gravity direction (see :func:`estimate_direction`).
    refresh_hz : float
        Live display refresh rate (terminal only).
    match_tolerance_deg : float
        A hold is matched to the nearest pending static step whose ``up`` is within this angle.
    accel_units, gyro_units : str, optional
        Raw units; default the recorder's.
    gyro_scale : float, optional
        Raw gyro units per rad/s, to show measured turn angles for ``counts``/``V``.
    detector : StillnessDetector, optional
        Default ``StillnessDetector()`` (0.25 s windows, false alarm 1e-4 per window).
    warn_after_s : float
        A hold interrupted by motion after this long is reported ("moved during the hold");
        shorter still moments are handling.
    pre_still_s, settle_s : float
        A turn needs the unit still this long before it, and counts as ended when the unit is
        still again this long.
    axis_tolerance_deg : float
        Warn when a turn's measured axis is further than this from the plan's.
    tick_s : float
        Passed to ``recorder.blocks``.

    Returns
    -------
    CaptureSummary
        ``complete`` iff no step is missing or skipped; ``done`` in the order taken.
    """
    if not hold_s > 0:
        raise ValueError(f"hold_s must be > 0, got {hold_s!r}")
    opt = {
        "hold_s": float(hold_s),
        "min_separation_deg": float(min_separation_deg),
        "nominal_bias": nominal_bias,
        "nominal_scale": nominal_scale,
        "refresh_hz": max(float(refresh_hz), 0.1),
        "match_tolerance_deg": float(match_tolerance_deg),
        "accel_units": accel_units
        if accel_units is not None
        else _recorder_attr(recorder, "accel_units"),
        "gyro_units": gyro_units
        if gyro_units is not None
        else _recorder_attr(recorder, "gyro_units"),
        "gyro_scale": gyro_scale,
        "detector": detector,
        "warn_after_s": float(warn_after_s),
        "pre_still_s": float(pre_still_s),
        "settle_s": float(settle_s),
        "axis_tolerance_deg": float(axis_tolerance_deg),
        "tick_s": float(tick_s),
    }
    return _Guided(recorder, plan, console, keys, opt).run()


def _recorder_attr(recorder, name: str) -> str | None:
    return getattr(recorder, name, None)
