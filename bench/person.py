"""A simulated person following ``imucal capture``'s guide, in this process (issue 27).

The same :class:`~imucal_cli.simulate.live.LiveUnit` and :class:`~imucal_cli.simulate.live.
Person` as ``imucal simulate --serve --person``, and the same guided state machine and screen
as ``imucal capture --until`` (plain lines), joined without the pseudo-terminal: blocks of
samples go to the state, the lines the screen prints go to the person.  Time is the device's,
and the capture's own computing takes as long in it as it does on this computer, as at the
bench: its planning delays what it prints by the time it took, and a refit answers as many
seconds of device time after it was asked as it ran (:class:`_Refits`; the capture runs it in
a thread beside the stream).  The stream itself runs 50-300 times faster than the device's
clock, so a refit left in a thread here answered 5-30 s of device time later instead of a
tenth of a second: with a pose every 4 s each answer was about steps already redone, and how
long a fixed plan took depended on the machine's load.  Tests of many seeds and the tuning
of the bench use it; the bench itself measures through the virtual port
(:mod:`bench.adaptive`).
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, field

import numpy as np
from rich.console import Console

from imucal_cli.calibrate.refit import refit
from imucal_cli.capture.guided import AdaptiveOptions, AdaptiveState, GuidedOptions, Refit
from imucal_cli.capture.guided.screen import Screen
from imucal_cli.formats.columns import SampleBlock
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Segment, Session, utc_now_iso
from imucal_cli.formats.targets import Targets, parse_until
from imucal_cli.plans import Plan
from imucal_cli.simulate.live import LiveUnit, Person

#: The issue's targets: gains 0.05 %, bias 0.5 mg and 0.01 deg/s, misalignment 0.05 deg.
ISSUE_TARGETS = ("accel.gain=0.05%,accel.bias=0.5mg,accel.misalignment=0.05deg,"
                 "gyro.gain=0.05%,gyro.bias=0.01deg/s,gyro.misalignment=0.05deg")


@dataclass
class _Recorder:
    """What the guided state needs of a recorder: sample count and segments."""

    n_samples: int = 0
    segments: list = field(default_factory=list)
    end_reason: str = ""
    stats: dict = field(default_factory=dict)

    def add_segment(self, kind, start, stop, **attrs):
        attrs.pop("extra", None)
        self.segments.append(Segment(f"{len(self.segments):04d}", kind, int(start), int(stop),
                                     **attrs))  # fmt: skip


@dataclass
class Outcome:
    """One capture by the simulated person: ``seconds`` of device time to "done" (None: the
    targets were not met within the limit), the session recorded, the truth, the lines."""

    seconds: float | None
    session: Session
    truth: object
    lines: list[str]
    poses: int
    turns: int
    refit_s: float
    unit: LiveUnit | None = None
    refits: list[tuple[float, float]] = field(default_factory=list)
    """Each refit's device time asked and answered, s."""


class _Answer:
    """A refit's result, ready ``at`` seconds of device time (``clock()``)."""

    def __init__(self, clock, at: float, value) -> None:
        self.clock, self.at, self.value = clock, at, value

    def done(self) -> bool:
        return self.clock() >= self.at

    def result(self):
        return self.value


class _Refits:
    """The capture's refit worker on the device's clock (what the guided state needs of its
    thread pool: ``submit`` and ``shutdown``): a refit runs at once, in this thread, and its
    answer is ready as many seconds of device time after it was asked as it took on this
    computer.  Without it, the stream, simulated much faster than real time, ran on while a
    refit ran in its thread, and every refit seemed to take 50-300 times longer than it does
    at the bench."""

    def __init__(self, clock) -> None:
        self.clock = clock
        self.spent = 0.0  # s of computing in refits, not the screen's (the person's lag)
        self.log: list[tuple[float, _Answer]] = []

    def submit(self, fn, *args) -> _Answer:
        tic = time.perf_counter()
        value = fn(*args)
        took = time.perf_counter() - tic
        self.spent += took
        answer = _Answer(self.clock, self.clock() + took, value)
        self.log.append((self.clock(), answer))
        return answer

    def shutdown(self, wait: bool = True) -> None:
        pass


def follow(seed: int, targets: Targets | str = ISSUE_TARGETS, *, rate_hz: float = 100.0,
           plan: Plan | None = None, min_hold_s: float = 0.5, max_s: float = 240.0,
           chunk_s: float = 0.05, cfg: Config | None = None,
           person: dict | None = None, stamp: bool = False, propose: bool = True,
           keep: bool = False) -> Outcome:  # fmt: skip
    """Run a capture with ``targets`` by the simulated person on part ``seed`` (``plan``:
    its steps first; ``propose``: then the guide's proposals, else the capture ends with the
    plan; ``keep``: the outcome keeps the part's true inputs)."""
    if isinstance(targets, str):
        targets = parse_until(targets)
    cfg = cfg or Config()
    unit = LiveUnit(seed, rate_hz=rate_hz, keep=keep)
    who = Person(unit, np.random.default_rng([seed, 27]), **(person or {}))
    rec = _Recorder()
    opt = GuidedOptions(hold_s=min_hold_s, accel_units="counts", gyro_units="counts")
    adaptive = AdaptiveOptions(targets, refit=lambda s: Refit(*refit(s, cfg)),
                               min_hold_s=min_hold_s, propose=propose)  # fmt: skip
    state = AdaptiveState(plan, opt, 0, rec.add_segment, adaptive)
    refits = state.pool = _Refits(lambda: unit.k / rate_hz)
    out = io.StringIO()
    screen = Screen(Console(file=out, width=200, force_terminal=False, color_system=None))
    screen.start(state)
    seen = 0
    chunk = max(1, int(round(chunk_s * rate_hz)))
    lines: list[str] = []
    while unit.k < max_s * rate_hz and state.end_reason is None:
        t, a, g = unit.samples(chunk)
        rec.n_samples += chunk
        tic, spent = time.perf_counter(), refits.spent
        state.on_block(SampleBlock(time=t, accel=a, gyro=g))
        screen.show(state)
        lag = int((time.perf_counter() - tic - (refits.spent - spent)) * rate_hz)
        text = out.getvalue()
        new = text[seen:].splitlines()
        seen = len(text)
        for line in new:
            lines.append(f"[{unit.k / rate_hz:6.2f}] {line}" if stamp else line)
            who.read(line, at=unit.k + lag)
    summary = state.summary(rec)
    screen.print_messages(state)
    lines += out.getvalue()[seen:].splitlines()
    n = unit.k
    session = Session(time=np.arange(n) / rate_hz, accel=np.asarray(state.hist.accel),
                      gyro=np.asarray(state.hist.gyro), temperature=None,
                      segments=sorted(rec.segments, key=lambda s: s.start),
                      created=utc_now_iso(), source="simulator", sample_rate_hz=rate_hz,
                      accel_units="counts", gyro_units="counts")  # fmt: skip
    seconds = (state.done_time - state.first_time) if summary.complete else None
    poses = sum(1 for x in state.taken if x.kind == "static")
    turns = sum(1 for x in state.taken if x.turn is not None)
    asked = [(at, answer.at) for at, answer in refits.log]
    return Outcome(seconds, session, unit.truth(), lines, poses, turns, state.refit_s, unit, asked)
