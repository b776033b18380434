"""A virtual IMU held by a simulated person who follows the guide (``imucal simulate --serve
--person``, issue 27).

:class:`LiveUnit` is one simulated part (the part, pose and noise generators of a seed, as
every simulator draws them) whose samples are made as the stream needs them: the unit lies
still, or turns as it is told (a smootherstep turn about a fixed axis, from its attitude to the
target, :meth:`~imucal_cli.simulate.motion.Timeline.move`), then lies still again.  The earth
rate and linear accelerations are left out, as in every simulator.

:class:`Person` reads what the guide prints (``imucal capture``'s lines, plain: one per
instruction) and does it as a person would:

- ``step N: Turn about +X by 90 degrees ...``: a turn about the unit's own axis by that angle;
- ``step N: Put face -Y up ...`` / ``Put edge +X-Z up ...``: the smallest turn that puts it up;
- ``Put the unit in a new orientation ...`` (unlabelled poses, ``random:N``): a turn of 45 to
  180 degrees about a random axis;
- after a **reaction time** (uniform in ``reaction_s``), in a **move** of uniform
  ``move_s`` seconds, ending with a **placement error**: the unit comes to rest tilted from
  the intended pose by a random horizontal rotation of RMS ``jitter_deg`` (2 degrees by hand);
- the person reads the first instruction after each pose the guide recorded (``recorded
  ...``): the guide's ``next: ...`` proposal, a ``step N: ...`` line, or a plan's ``left:
  ...`` list (its first pose); other lines, and instructions repeated before the next
  recorded pose, are ignored (a terminal's live view shows the current step again and
  again, the step just recorded among them); when the guide refuses a hold (too close to a
  pose taken, matching no step), the person does the last instruction again.

The person starts with the unit on face +Z (placed with the same error and a random heading).
Words a person follows are the contract: :func:`parse_instruction` reads exactly what
:func:`imucal_cli.capture.guided.words.turn_instruction` and the plan steps' instructions say
(a test holds them together).
"""

from __future__ import annotations

import re
import sys
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.model.calibration import Calibration
from imucal_cli.simulate import device, pseudo_terminal
from imucal_cli.simulate.motion import EZ, Timeline, place, placement_tilts
from imucal_cli.simulate.sensor import G0, Imu, draw_part
from imucal_cli.simulate.served_lines import format_lines as device_format

__all__ = ["Instruction", "LiveLines", "LiveUnit", "Person", "follow_stdin", "format_lines",
           "parse_instruction"]

_TURN = re.compile(r"Turn about ([+-])([XYZ]) by (-?\d+(?:\.\d+)?) degrees")
_PUT = re.compile(r"Put (?:face|edge) ([+-][XYZ](?:[+-][XYZ])?) up")
_NEW = re.compile(r"Put the unit in a new orientation")
_REFUSED = ("turn the unit to another face or edge", "put the unit on one of the poses left")
"""The guide's words when it did not take a hold: the person tries again."""
_STEP = re.compile(r"^\s*(?:\[)?(?:step (\d+)|next:|left:)")


@dataclass(frozen=True)
class Instruction:
    """What the guide asked: a ``turn`` about the unit's ``axis`` by ``angle_deg``, to
    ``put`` the unit with ``up`` (its frame) up, or a ``random`` new orientation; ``step``
    its number (0: a ``next:`` or ``left:`` line)."""

    step: int
    kind: str
    axis: np.ndarray | None = None
    angle_deg: float = 0.0
    up: np.ndarray | None = None


def parse_instruction(line: str) -> Instruction | None:
    """The instruction of one of the guide's lines (``step N: ...``), or None."""
    m = _STEP.match(line)
    if not m:
        return None
    step = int(m.group(1) or 0)
    if line.lstrip().startswith("left:"):  # a plan's steps left: the first is next
        first = line.split(":", 1)[1].split(",")[0].strip()
        line = ("Put the unit in a new orientation" if re.match(r"pose \d+$", first)
                else "Put " + first)
    turn = _TURN.search(line)
    if turn:
        axis = np.zeros(3)
        axis["XYZ".index(turn.group(2))] = 1.0 if turn.group(1) == "+" else -1.0
        return Instruction(step, "turn", axis=axis, angle_deg=float(turn.group(3)))
    if _NEW.search(line):
        return Instruction(step, "random")
    put = _PUT.search(line)
    if put:
        up = np.zeros(3)
        text = put.group(1)
        for sign, name in zip(text[::2], text[1::2], strict=True):
            up["XYZ".index(name)] = 1.0 if sign == "+" else -1.0
        return Instruction(step, "put", up=up / np.linalg.norm(up))
    return None


class LiveUnit:
    """One simulated part, its samples made on demand (see the module notes).

    Parameters
    ----------
    seed : int
        The part, its placements and its noise (three generators, as every simulator).
    rate_hz, units, accel_noise, gyro_noise, gravity
        As ``imucal simulate``.
    jitter_deg : float
        RMS placement error of the first pose.
    keep : bool
        Keep the true inputs handed out (:attr:`inputs`: specific force and rate, for tests
        that draw the noise again over the same motion).
    """

    def __init__(self, seed: int, *, rate_hz: float = 100.0, units: str = "counts",
                 accel_noise: float = 0.01, gyro_noise: float = 0.005,
                 gravity: float = G0, jitter_deg: float = 2.0,
                 keep: bool = False) -> None:  # fmt: skip
        self.imu: Imu
        self.imu, pose_ss, noise_ss = draw_part(seed, units, accel_noise, gyro_noise)
        self.prng = np.random.default_rng(pose_ss)
        self.nrng = np.random.default_rng(noise_ss)
        self.rate_hz, self.gravity = float(rate_hz), float(gravity)
        self.att = place(self.prng, EZ, jitter_deg)  # attitude at the end of what is queued
        self.k = 0  # samples handed out
        self.moves: deque[tuple[int, Rotation, int]] = deque()  # (start sample, target, n)
        self._force = np.empty((0, 3))
        self._rate = np.empty((0, 3))
        self._end_att = self.att  # attitude after the queued true inputs
        self.keep = keep
        self._kept: list[tuple[np.ndarray, np.ndarray]] = []

    @property
    def up(self) -> np.ndarray:
        """The body's up direction once every move queued is done."""
        return self.att.inv().apply(EZ)

    def move_to(self, start: int, target: Rotation, seconds: float) -> None:
        """Turn to ``target`` (body -> world) starting at sample ``start``, in ``seconds``
        (about the fixed axis of the smallest rotation)."""
        n = max(2, int(round(seconds * self.rate_hz)) - 1)
        self.moves.append((max(int(start), self.k), target, n))
        self.att = target

    def turn(self, start: int, axis: np.ndarray, angle: float, seconds: float) -> None:
        """Turn about the body ``axis`` (unit) by ``angle`` rad (any, a full turn too),
        starting at sample ``start``, in ``seconds``."""
        n = max(2, int(round(seconds * self.rate_hz)) - 1)
        axis = np.asarray(axis, float) / np.linalg.norm(axis)
        self.moves.append((max(int(start), self.k), (axis, float(angle)), n))
        self.att = self.att * Rotation.from_rotvec(angle * axis)

    def _extend(self, need: int) -> None:
        """Make the true inputs up to ``need`` samples past those handed out."""
        while len(self._force) < need:
            at = self.k + len(self._force)
            if self.moves and self.moves[0][0] <= at:
                _, target, n = self.moves.popleft()
                tl = Timeline(self.rate_hz, self.gravity, self._end_att)
                if isinstance(target, Rotation):
                    tl.move(target, n)
                else:  # (axis, angle): a turn by that angle, whole turns included
                    tl.smooth_turn(target[0], target[1], n)
                force, rate = tl.arrays()
                self._end_att = tl.att
            else:
                until = self.moves[0][0] if self.moves else at + need
                m = max(1, min(until, self.k + need) - at)
                force = np.broadcast_to(self._end_att.inv().apply(self.gravity * EZ), (m, 3))
                rate = np.zeros((m, 3))
            self._force = np.concatenate([self._force, force])
            self._rate = np.concatenate([self._rate, rate])

    def samples(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The next ``n`` samples: time (s), raw accel, raw gyro."""
        self._extend(n)
        force, self._force = self._force[:n], self._force[n:]
        rate, self._rate = self._rate[:n], self._rate[n:]
        if self.keep:
            self._kept.append((force, rate))
        raw = self.imu.sample({"accel": force, "gyro": rate}, self.nrng)
        t = (self.k + np.arange(n)) / self.rate_hz
        self.k += n
        return t, raw["accel"], raw["gyro"]

    @property
    def inputs(self) -> dict[str, np.ndarray]:
        """The true specific force (m/s^2) and rate (rad/s) handed out (``keep``)."""
        if not self._kept:
            return {"accel": np.empty((0, 3)), "gyro": np.empty((0, 3))}
        return {"accel": np.concatenate([f for f, _ in self._kept]),
                "gyro": np.concatenate([r for _, r in self._kept])}  # fmt: skip

    def truth(self) -> Calibration:
        """The part's true calibration (its accel and gyro sections)."""
        sections = self.imu.truth_sections({})
        return Calibration(accel=sections["accel"], gyro=sections["gyro"])


class Person:
    """Follows the guide's instructions with a :class:`LiveUnit` (see the module notes).

    Parameters
    ----------
    unit : LiveUnit
    rng : numpy.random.Generator
        The person's own draws (reaction, move time, placement error).
    reaction_s, move_s : tuple of float
        Uniform ranges, s.
    jitter_deg : float
        RMS placement error of every pose, degrees.
    """

    def __init__(self, unit: LiveUnit, rng: np.random.Generator, *,
                 reaction_s: tuple[float, float] = (0.5, 1.0),
                 move_s: tuple[float, float] = (1.0, 2.0),
                 jitter_deg: float = 2.0) -> None:  # fmt: skip
        self.unit, self.rng = unit, rng
        self.reaction_s, self.move_s, self.jitter_deg = reaction_s, move_s, jitter_deg
        self.ready = True  # the next instruction is to be done (after a pose was recorded)
        self.last: Instruction | None = None
        self.step = 0  # the step number of the latest instruction read
        self.recorded_step = -1  # the step that was current when a pose was recorded
        self.moves = 0

    def read(self, line: str, at: int | None = None) -> Instruction | None:
        """One line of the guide's output, read when the unit had made ``at`` samples
        (default: now); an instruction is done (a move queued), other lines ignored."""
        if line.lstrip().startswith("recorded "):
            self.ready = True
            self.recorded_step = self.step
            return None
        refused = any(words in line for words in _REFUSED)
        ins = self.last if refused else parse_instruction(line)
        if ins is None:
            return None
        if ins.step:
            self.step = ins.step
        if not (self.ready or refused) or (ins.step and ins.step == self.recorded_step):
            return None  # not the next instruction: one done, or the step just recorded
        self.ready = False
        self.last = ins
        at = self.unit.k if at is None else at
        target = self.target(ins)
        if target is None:
            return ins
        start = at + int(round(self.rng.uniform(*self.reaction_s) * self.unit.rate_hz))
        seconds = float(self.rng.uniform(*self.move_s))
        if isinstance(target, Rotation):
            self.unit.move_to(start, target, seconds)
        else:  # a whole turn (or more) about an axis: it ends where it began
            self.unit.turn(start, *target, seconds=seconds * abs(target[1]) / np.pi)
        self.moves += 1
        return ins

    def target(self, ins: Instruction):
        """Where the unit should end (body -> world), the placement error included; None:
        it is there already; ``(axis, angle)``: a turn of a whole turn or more about the body
        axis, back onto the same face (against the ruler: no new placement)."""
        att = self.unit.att
        if ins.kind == "turn" and abs(ins.angle_deg) >= 270.0:  # back where it began
            return ins.axis, np.radians(ins.angle_deg)
        if ins.kind == "turn":
            ideal = att * Rotation.from_rotvec(np.radians(ins.angle_deg) * ins.axis)
        elif ins.kind == "random":
            axis = self.rng.standard_normal(3)
            angle = np.radians(self.rng.uniform(45.0, 180.0))
            ideal = att * Rotation.from_rotvec(angle * axis / np.linalg.norm(axis))
        else:
            now = att.inv().apply(EZ)
            if np.degrees(np.arccos(np.clip(now @ ins.up, -1.0, 1.0))) < 3 * self.jitter_deg:
                return None
            turn, _ = Rotation.align_vectors(now[None, :], ins.up[None, :])
            ideal = att * turn
        tilt = placement_tilts(self.rng, self.jitter_deg, 1)[0]
        return Rotation.from_rotvec(tilt) * ideal


# --------------------------------------------------------------------------------------------
# Serving: imucal simulate --serve --person
# --------------------------------------------------------------------------------------------


class LiveLines:
    """The data lines of a :class:`LiveUnit`, made as the virtual port asks for them (the
    sequence :func:`imucal_cli.simulate.device.serve` streams); ``read(line)`` hands a line of
    the guide to the :class:`Person` (from another thread: a lock keeps the two in order)."""

    CHUNK = 5
    """Samples made at a time."""

    def __init__(self, unit: LiveUnit, person: Person, temperature: bool = True,
                 say=None, counts: bool = True) -> None:  # fmt: skip
        self.unit, self.person, self.temperature = unit, person, temperature
        self.counts = counts
        self.say = say or (lambda message: None)
        self.lock = threading.Lock()
        self.first = 0
        self.lines: list[bytes] = []
        self.sent = 0  # the last index asked for

    def __len__(self) -> int:
        return sys.maxsize

    def __getitem__(self, k: int) -> bytes:
        with self.lock:
            self.sent = k
            while k >= self.first + len(self.lines):
                self.first += len(self.lines)
                t, a, g = self.unit.samples(self.CHUNK)
                self.lines = format_lines(t, a, g, self.temperature, self.counts)
            return self.lines[k - self.first]

    def read(self, line: str) -> None:
        with self.lock:
            ins = self.person.read(line, at=self.sent + 1)
            if ins is not None and self.person.moves and self.unit.moves:
                start, _, n = self.unit.moves[-1]
                what = (f"turn about {_axis_name(ins.axis)} by {ins.angle_deg:g} deg"
                        if ins.kind == "turn" else "put " + _axis_name(ins.up) + " up")
                self.say(f"person: {what}, from t = {start / self.unit.rate_hz:.2f} s, "
                         f"{(n + 1) / self.unit.rate_hz:.2f} s")


def _axis_name(v: np.ndarray) -> str:
    return "".join(f"{'+' if x > 0 else '-'}{'XYZ'[i]}" for i, x in enumerate(v) if abs(x) > 1e-9)


def format_lines(time, accel, gyro, temperature: bool, counts: bool = True) -> list[bytes]:
    """``t,ax,ay,az,gx,gy,gz[,temp]`` lines, as the plan device prints them."""
    return device_format(time, accel, gyro, temperature, counts)


def follow_stdin(lines: LiveLines, stream=None) -> threading.Thread:
    """Read the guide's lines from ``stream`` (stdin) into ``lines`` in a daemon thread."""
    stream = sys.stdin if stream is None else stream

    def run() -> None:
        try:
            for line in stream:
                lines.read(line.rstrip("\n"))
        except (OSError, ValueError):
            pass

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def serve_person(*, seed: int = 0, rate_hz: float = 100.0, baud: int = 115200,
                 units: str = "counts", accel_noise: float = 0.01, jitter_deg: float = 2.0,
                 temperature: bool = True, duration_s: float | None = None,
                 wait_reader_s: float | None = None, announce=print, status=None,
                 stream=None) -> device.ServeResult:  # fmt: skip
    """Stream a :class:`LiveUnit` held by a :class:`Person` who reads the guide from
    ``stream`` (stdin) on a new pseudo-terminal, until the reader closes it, ``duration_s``
    or a signal (as :func:`imucal_cli.simulate.device.serve`)."""
    device._check_line(rate_hz, baud, None)
    say = status or (lambda message: None)
    unit = LiveUnit(seed, rate_hz=rate_hz, units=units, accel_noise=accel_noise,
                    jitter_deg=jitter_deg)  # fmt: skip
    who = Person(unit, np.random.default_rng([int(seed), 27]), jitter_deg=jitter_deg)
    lines = LiveLines(unit, who, temperature, say, counts=units == "counts")
    fields = "t,ax,ay,az,gx,gy,gz" + (",temp" if temperature else "")
    header = (f"# imucal virtual IMU: a person following the guide, {rate_hz:g} Hz, {units}, "
              f"columns {fields}, seed {seed}\n").encode()  # fmt: skip
    schedule = device._Schedule(len(lines), [], loop=False, step=False, next_pose=None,
                                say=say, rate_hz=rate_hz)  # fmt: skip
    stop = {"kind": None}
    with pseudo_terminal.stop_on_signals(stop):
        port = pseudo_terminal.Port()
        try:
            announce(port.path)
            say(f"a person holds the unit (part of seed {seed}) at {rate_hz:g} Hz, {baud} baud "
                f"on {port.path}, following the guide read on stdin; waiting for a reader")
            follow_stdin(lines, stream)
            line = device._Line(port.master, port.poller, stop, lines, rate_hz, baud,
                                schedule=schedule, duration_s=duration_s, garbage=False,
                                stall_after_s=None, vanish_after_s=None, malformed_every=None,
                                rng=np.random.default_rng(seed + 1))  # fmt: skip
            return device._stream(port, line, header, stop, wait_reader_s, say)
        finally:
            port.close()
