"""A virtual serial IMU: ``imucal simulate --serve`` streams a simulated IMU on a pseudo-terminal.

:func:`serve` opens a pseudo-terminal pair, announces the device path of its slave side, waits
for a reader to open it, and writes the text lines of a simulated IMU performing a plan in real
time, ``t,ax,ay,az,gx,gy,gz,temp`` (``t`` in seconds, raw counts; the redundant unit of
``hk-redundant``: ``t,ax,ay,az,a4,temp``), so that ``imucal capture --port PATH`` reads it
through the real tty layer.

- Every plan of the registry and every plan file plays
  :func:`imucal_cli.simulate.play.simulate_plan`: the same seed and options give the same
  samples as ``imucal simulate`` writes to a file; its static segments are the holds.
- A pseudo-terminal has no baud rate: the bytes are paced to ``baud / 10`` bytes per second
  (8N1), so a stream too fast for the baud rate falls behind as it would on a real line.
- With a magnetometer (``plan_options["mag"]``, ``imucal simulate --serve --mag``) a pose
  plan is played as ``imucal simulate --mag`` writes it (tumbles between the holds) and each
  line carries ``mx,my,mz`` after the gyro: the same part, samples and truth as the file.
- The first line is a comment ``# imucal virtual IMU ...``; then data lines: numbers
  (``protocol="lines"``), or as the Arduino sketches print them (:data:`SERVE_PROTOCOLS`):
  MotionCal's ``Raw:ax,ay,az,gx,gy,gz,mx,my,mz`` (the magnetometer: a 48 uT field at 60
  degrees inclination seen through the unit's tilt, the heading fixed, 10 counts per uT as
  MotionCal's sketches scale it, plus a hard iron of :data:`HARD_IRON_COUNTS`) and i2cdevlib's
  ``a/g:\tax\tay\taz\tgx\tgy\tgz``, counts without a time.
- Faults for tests: ``garbage`` (random bytes at the same byte rate, as a wrong baud rate
  shows), ``stall_after_s`` (stop sending, keep the port open), ``vanish_after_s`` (close the
  pseudo-terminal: the device is unplugged), ``malformed_every`` (every N-th line loses fields).

The stream starts when a reader opens the port and has flushed its input (pyserial does when it
configures the port: the pseudo-terminal's packet mode shows it; a reader that never flushes
waits at most :data:`.pseudo_terminal.FLUSH_WAIT_S`), and ends after the plan (or after
``duration_s``, with ``loop`` repeating the plan), when the reader closes the port, or on
SIGINT/SIGTERM.  Before the
port closes the reader is given time to read every byte sent (at most :data:`DRAIN_MAX_S`), and
what it did not read is not counted as sent: the count is right however loaded the machine.

Pacing: by default the device walks its plan on a timer (each pose held ``hold_s``, then the
next).  ``next_pose`` (a callable, e.g. Enter typed in the device's own terminal) moves on at
once, cutting the current hold short; with ``step`` every hold lasts until ``next_pose`` says
so (the still samples keep coming, the time keeps increasing), as a person at the bench would.

The lines themselves are :mod:`.served_lines`'s; the pseudo-terminal and the signals that stop a
serve, :mod:`.pseudo_terminal`'s.
"""

from __future__ import annotations

import os
import select
import threading
import time as _time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.plans import Plan, find_plan, load_plan
from imucal_cli.simulate.imu_set import served_set, set_columns, set_lines
from imucal_cli.simulate.magnetometer import simulate_mag
from imucal_cli.simulate.play import simulate_plan
from imucal_cli.simulate.pseudo_terminal import SETTLE_S, Port, asked_to_stop, stop_on_signals
from imucal_cli.simulate.served_lines import (
    HARD_IRON_COUNTS,
    SERVE_PROTOCOLS,
    damaged,
    line_columns,
    protocol_lines,
)
from imucal_cli.simulate.steps import simulate_steps

__all__ = [
    "HARD_IRON_COUNTS",
    "SERVE_PROTOCOLS",
    "SETTLE_S",
    "Hold",
    "ServeResult",
    "plan_motion",
    "serve",
    "stream_arrays",
    "stream_with_holds",
]

DRAIN_MAX_S = 10.0
"""Longest wait, at the end, for the reader to read what was sent, s."""

@dataclass(frozen=True)
class Hold:
    """A still pose of the stream: samples ``[start, stop)`` and what the pose is."""

    start: int
    stop: int
    label: str


@dataclass
class ServeResult:
    """What :func:`serve` did.

    Attributes
    ----------
    path : str
        The slave device path.
    lines : int
        Data lines written completely to the port (malformed ones included).
    malformed : int
        Of those, lines written malformed on purpose.
    garbage_bytes : int
        Random bytes written in ``garbage`` mode.
    seconds : float
        Streaming time.
    end : str
        ``"plan"``, ``"duration"``, ``"signal"``, ``"cancelled"``, ``"reader-closed"``,
        ``"vanished"``, ``"no-reader"``.
    """

    path: str
    lines: int = 0
    malformed: int = 0
    garbage_bytes: int = 0
    seconds: float = 0.0
    end: str = ""


# --------------------------------------------------------------------------------------------
# The motion
# --------------------------------------------------------------------------------------------


def plan_motion(
    plan: Plan, *, seed: int = 0, rate_hz: float = 100.0, hold_s: float = 2.0,
    move_s: float = 1.5, units: str = "counts",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Time (N,), raw accel (N, 3) and raw gyro (N, 3) of the virtual IMU going through a
    :class:`~imucal_cli.plans.Plan`: a registry plan (by its name) as ``imucal simulate`` plays
    it, any other step by step (:func:`imucal_cli.simulate.steps.simulate_steps`).
    """
    try:
        spec, _ = find_plan(plan.name)
    except InputError:
        spec = None
    if spec is not None and load_plan(plan.name) == plan:
        return stream_arrays(
            plan.name, seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s
        )
    session, _ = simulate_steps(
        plan, seed=seed, rate_hz=rate_hz, hold_s=hold_s, move_s=move_s, units=units
    )
    return session.time, session.accel, session.gyro


def stream_arrays(
    plan: str, *, seed: int = 0, rate_hz: float | None = 100.0, hold_s: float | None = 2.0,
    units: str = "counts", move_s: float = 1.5, **options,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:  # fmt: skip
    """Time (N,), raw accel (N, na) and raw gyro (N, 3) (None without one) of one pass through
    ``plan``, as :func:`imucal_cli.simulate.play.simulate_plan` simulates it (``options``: its
    other options).

    Raises
    ------
    InputError
        Unknown plan or bad options.
    """
    time, accel, gyro, _ = stream_with_holds(
        plan, seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s, **options
    )
    return time, accel, gyro


def stream_with_holds(
    plan: str, *, seed: int = 0, rate_hz: float | None = 100.0, hold_s: float | None = 2.0,
    units: str = "counts", move_s: float = 1.5, **options,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[Hold]]:  # fmt: skip
    """As :func:`stream_arrays`, plus the still poses (:class:`Hold`, in time order): the
    session's static segments, a still run across two of them one hold, the lead the first."""
    session, holds = _served_session(plan, seed=seed, rate_hz=rate_hz, hold_s=hold_s,
                                     units=units, move_s=move_s, **options)  # fmt: skip
    return session.time, session.accel, session.gyro, holds


def _served_session(plan: str, *, mag: dict | None = None, **options):
    """The session :func:`~imucal_cli.simulate.play.simulate_plan` simulates for ``plan``
    (its device times, and temperatures where a ramp was asked for; with ``mag``, the options
    of :func:`~imucal_cli.simulate.magnetometer.simulate_mag`: the pose plan with a
    magnetometer, tumbling between the holds, as ``imucal simulate --mag`` writes it; with
    ``imus`` > 1, a set of several IMUs or one of its IMUs), and its holds."""
    imus, member = options.pop("imus", None), options.pop("serve_imu", None)
    if imus is not None and imus > 1:  # several IMUs (issue 28): a set, or one of its IMUs
        session, _ = served_set(plan, imus, member, **options)
    elif mag is None:
        session, _ = simulate_plan(plan, **options)
    else:
        keep = ("seed", "rate_hz", "hold_s", "units", "move_s", "accel_noise", "jitter_deg")
        given = {k: v for k, v in options.items() if k in keep and v is not None}
        session, _ = simulate_mag(plan, **mag, **given)
    holds: list[Hold] = []
    for i, seg in enumerate(session.static_segments()):
        start, label = seg.start, seg.label or f"pose {i + 1}"
        if holds and holds[-1].stop == start:  # the same pose still: one hold
            start = holds.pop().start
        holds.append(Hold(start, seg.stop, label))
    if holds:  # the lead is the first pose held a little longer
        holds[0] = Hold(0, holds[0].stop, holds[0].label)
    return session, holds


# --------------------------------------------------------------------------------------------
# Serving
# --------------------------------------------------------------------------------------------


def serve(
    plan: str = "six", rate_hz: float = 100.0, baud: int = 115200, *, seed: int = 0,
    hold_s: float | None = 2.0, move_s: float = 1.5, units: str = "counts",
    plan_options: dict | None = None, temperature: bool = True, loop: bool = False,
    duration_s: float | None = None, wait_reader_s: float | None = None, garbage: bool = False,
    stall_after_s: float | None = None, vanish_after_s: float | None = None,
    malformed_every: int | None = None, step: bool = False,
    next_pose: Callable[[], bool] | None = None, announce: Callable[[str], None] = print,
    status: Callable[[str], None] | None = None, protocol: str = "lines",
    cancel: threading.Event | None = None,
) -> ServeResult:  # fmt: skip
    """Stream a simulated IMU on a new pseudo-terminal until the plan ends; see the module notes.

    Parameters
    ----------
    plan : str
        A plan name or TOML file (see :func:`imucal_cli.plans.load_plan`).
    rate_hz : float
        Sample rate, Hz.
    baud : int
        Emulated baud rate: at most ``baud / 10`` bytes per second.
    seed, hold_s, units
        As for ``imucal simulate``.
    move_s : float
        Duration of each move between poses, s.
    plan_options : dict, optional
        More options of :func:`imucal_cli.simulate.play.simulate_plan` (``still_s``,
        ``rotations_per_axis``, ``mountings``, ...; ``temperature``, a
        :class:`~imucal_cli.simulate.temperature.Ramp`: the printed temperature follows it, a
        warm-up; ``clock_scale``: the part's clock runs fast or slow, its time stamps say so
        while the lines go out in true time; ``mag``: the options of
        :func:`imucal_cli.simulate.magnetometer.simulate_mag` (a pose plan with a
        magnetometer, tumbling between the holds: ``mx,my,mz`` after the gyro).
    temperature : bool
        Print the temperature field (the last field of a line).
    loop : bool
        Repeat the plan (time keeps increasing) until ``duration_s`` or a signal.
    duration_s : float, optional
        Stop streaming after this long, s.
    wait_reader_s : float, optional
        Give up when no reader opened the port within this long (default: wait forever).
    garbage, stall_after_s, vanish_after_s, malformed_every
        The test faults of the module notes: send random bytes instead of lines; stop sending
        after ``stall_after_s`` but keep the port open (until a signal or the reader closes
        it); close the pseudo-terminal after ``vanish_after_s``; send every N-th data line
        with two fields missing.
    step, next_pose
        The pacing of the module notes: ``next_pose()``, polled for each line, True moves on
        to the next pose now (e.g. Enter was typed); with ``step`` every pose is held until
        it does (not on a timer).
    announce, status : callable
        Called once with the slave device path, before anything else; called with progress
        messages (optional).
    protocol : str
        What a data line is (:data:`SERVE_PROTOCOLS`): ``lines`` (``t,ax,...``), ``motioncal``
        or ``i2cdevlib`` (see the module notes; ``temperature`` does not apply).
    cancel : threading.Event, optional
        Set by the caller (serving in another thread, where no signal reaches it): the serve
        ends at its next step, ``end`` ``"cancelled"``, having counted what the reader got.

    Returns
    -------
    ServeResult
    """
    _check_line(rate_hz, baud, malformed_every)
    say = status or (lambda message: None)
    lines, schedule, fields = _plan_lines(
        plan, protocol, seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s,
        plan_options=plan_options or {}, temperature=temperature, loop=loop, step=step,
        next_pose=next_pose, say=say,
    )  # fmt: skip
    _warn_if_too_fast(lines, rate_hz, baud, say)
    header = (f"# imucal virtual IMU: plan {plan}, {rate_hz:g} Hz, {units}, "
              f"columns {fields}, seed {seed}\n").encode()  # fmt: skip
    stop = {"kind": None, "cancel": cancel}
    with stop_on_signals(stop):
        port = Port()
        try:
            announce(port.path)
            say(f"serving plan {plan} at {rate_hz:g} Hz, {baud} baud on {port.path}; "
                "waiting for a reader")  # fmt: skip
            line = _Line(
                port.master, port.poller, stop, lines, rate_hz, baud, schedule=schedule,
                duration_s=duration_s, garbage=garbage, stall_after_s=stall_after_s,
                vanish_after_s=vanish_after_s, malformed_every=malformed_every,
                rng=np.random.default_rng(seed + 1), timed=protocol == "lines",
                clock_scale=(plan_options or {}).get("clock_scale") or 1.0,
            )  # fmt: skip
            return _stream(port, line, header, stop, wait_reader_s, say)
        finally:
            port.close()


def _plan_lines(plan: str, protocol: str, *, seed: int, rate_hz: float, hold_s: float | None,
                units: str, move_s: float, plan_options: dict, temperature: bool, loop: bool,
                step: bool, next_pose, say) -> tuple[list[bytes], _Schedule, str]:  # fmt: skip
    """The plan's data lines, the schedule that hands them out, and what a line holds.  A
    temperature ramp (``plan_options["temperature"]``: a warm-up) is printed as the part's
    temperature; a clock error (``clock_scale``) as the device's own time stamps; a
    magnetometer (``plan_options["mag"]``) as ``mx,my,mz`` after the gyro."""
    session, holds = _served_session(
        plan, seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s,
        **plan_options,
    )  # fmt: skip
    time, accel, gyro, mag = session.time, session.accel, session.gyro, session.mag
    if temperature and session.temperature is not None:
        temperature = session.temperature
    lines = protocol_lines(protocol, time, accel, gyro, temperature, units, mag, session.mag_units)
    if session.imus:  # several IMUs on one line (issue 28)
        lines = set_lines(session, temperature, units == "counts")
    schedule = _Schedule(len(lines), holds, loop=loop, step=step, next_pose=next_pose, say=say,
                         rate_hz=rate_hz)  # fmt: skip
    with_temp = temperature is not None and temperature is not False
    fields = (line_columns(accel, gyro, with_temp, mag) if protocol == "lines"
              else f"{protocol} lines")  # fmt: skip
    if session.imus:
        fields = set_columns(session, with_temp)
    return lines, schedule, fields


#: Baud rates serial ports and USB bridges commonly offer, 8N1.
STANDARD_BAUDS = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600, 1000000, 2000000)


def _warn_if_too_fast(lines: list[bytes], rate_hz: float, baud: int, say) -> None:
    """Say so when the lines need more bytes per second than ``baud`` carries (8N1: a tenth
    of it): the stream then falls behind the plan as the queue grows, and a capture without
    a time column would stamp the samples at the slower rate they arrive."""
    if not lines:
        return
    size = float(np.mean([len(x) for x in lines[:2000]]))
    need = size * rate_hz * 10.0
    if need > baud:
        enough = next((b for b in STANDARD_BAUDS if b >= need), None)
        fix = f"--baud {enough}" if enough else "a faster line"
        say(f"warning: lines of {size:.0f} bytes at {rate_hz:g} Hz need {need:,.0f} baud; at "
            f"{baud} the stream runs at {100 * baud / need:.0f} % of the plan's pace and falls "
            f"behind: pass {fix}, or a lower --rate")  # fmt: skip


def _check_line(rate_hz: float, baud: int, malformed_every: int | None) -> None:
    """Refuse a rate, baud rate or fault period the line cannot have."""
    if not rate_hz > 0:
        raise InputError(f"rate must be > 0 Hz, got {rate_hz:g}")
    if not isinstance(baud, int) or baud <= 0:
        raise InputError(f"baud rate must be a positive integer, got {baud!r}")
    if malformed_every is not None and malformed_every < 1:
        raise InputError(f"--malformed-every must be >= 1, got {malformed_every}")


def _stream(port: Port, line: _Line, header: bytes, stop: dict, wait_reader_s: float | None,
            say: Callable[[str], None]) -> ServeResult:  # fmt: skip
    """Wait for a reader, then run the line until it ends; count what the reader got."""
    result = ServeResult(path=port.path)
    result.end = port.wait_for_reader(stop, wait_reader_s)
    if result.end:
        return result
    line.run(header, result)
    if result.end in ("plan", "duration", "signal", "cancelled", "vanished"):
        line.tally(result, unread=port.drain(DRAIN_MAX_S))
    say(
        f"sent {result.lines} lines ({result.malformed} malformed) in "
        f"{result.seconds:.1f} s; end: {result.end}"
    )
    return result


def _mirrored(h: Hold, r: int) -> int:
    """The ``r``-th sample (from 0) of a paused hold replayed: backwards from its last sample
    to its first, then forwards, and so on, so that what drifts in a hold (a warm-up's
    temperature and biases) turns back smoothly instead of jumping to its start."""
    n = h.stop - h.start
    if n < 2:
        return h.start
    m = r % (2 * (n - 1))
    return h.stop - 2 - m if m < n - 1 else h.start + 1 + m - (n - 1)


class _Schedule:
    """Which sample of the pass goes out next: the plan in order, holds cut short when
    ``next_pose()`` says so, or (``step``) extended until it does by replaying the hold's own
    samples (mirrored, :func:`_mirrored`); the time of every line is ``k / rate`` for the k-th
    line sent."""

    def __init__(self, n: int, holds: list[Hold], *, loop: bool, step: bool, next_pose,
                 say, rate_hz: float) -> None:  # fmt: skip
        self.n, self.holds, self.loop, self.step = n, holds, loop, step
        self.next_pose = next_pose or (lambda: False)
        self.say, self.rate_hz = say, rate_hz
        self.i = 0  # next sample of the pass
        self.k = 0  # lines handed out
        self.replay = 0  # samples replayed in the current paused hold
        self.paused: Hold | None = None
        self.done = False

    def _hold_at(self, i: int) -> Hold | None:
        return next((h for h in self.holds if h.start <= i < h.stop), None)

    def next_index(self) -> int | None:
        """The sample of the pass to send next (None: the plan is over)."""
        if self.next_pose():
            self._advance()
        if self.paused is not None:
            self.replay += 1
            return _mirrored(self.paused, self.replay - 1)
        if self.i >= self.n:
            if not self.loop:
                self.done = True
                return None
            self.i = 0
        h = self._hold_at(self.i)
        if h is not None and self.i == h.start:
            self._announce(h)
        index = self.i
        self.i += 1
        if self.step and h is not None and self.i == h.stop:
            self.paused, self.replay = h, 0  # hold until told to move on
        return index

    def _advance(self) -> None:
        """Move on now: leave a paused hold, or cut the current one short."""
        if self.paused is not None:
            self.paused = None
            return
        h = self._hold_at(self.i)
        if h is not None:
            self.i = h.stop

    def _announce(self, h: Hold) -> None:
        n = self.holds.index(h) + 1
        held_s = (h.stop - h.start) / self.rate_hz  # the first: with the lead before it
        until = ("until Enter here" if self.step
                 else f"{held_s:.3g} s, then the next (Enter here: now)")  # fmt: skip
        self.say(f"pose {n}/{len(self.holds)}: {h.label}: held {until}")


class _Line:
    """The serial line: queues lines (or garbage) as their time comes, paced to the baud
    rate, writes them to the master side, and counts what was written completely."""

    def __init__(
        self, master: int, poller, stop: dict, lines: list[bytes], rate_hz: float, baud: int,
        *, schedule: _Schedule, duration_s, garbage: bool, stall_after_s, vanish_after_s,
        malformed_every, rng: np.random.Generator, timed: bool = True,
        clock_scale: float = 1.0,
    ) -> None:  # fmt: skip
        self.master, self.poller, self.stop, self.lines = master, poller, stop, lines
        self.rate_hz, self.baud, self.schedule, self.garbage = rate_hz, baud, schedule, garbage
        self.duration_s, self.stall_after_s = duration_s, stall_after_s
        self.vanish_after_s, self.malformed_every, self.rng = vanish_after_s, malformed_every, rng
        self.timed = timed  # a line starts with its time (rewritten for a replayed sample)
        self.clock_scale = clock_scale  # device seconds per true second of the part's clock
        self.out = bytearray()
        self.queued_bytes = 0  # bytes put into `out` (paced by the baud rate)
        self.line_ends: list[tuple[int, bool]] = []  # (byte offset after the line, malformed)
        self.garbage_bytes = 0
        self.written_total = 0  # bytes the master took

    def why_end(self, now: float) -> str:
        """Why streaming ends now, or ""."""
        if asked_to_stop(self.stop):
            return asked_to_stop(self.stop)
        if any(ev & select.POLLHUP for _, ev in self.poller.poll(0)):
            return "reader-closed"
        if self.vanish_after_s is not None and now >= self.vanish_after_s:
            return "vanished"
        if self.duration_s is not None and now >= self.duration_s:
            return "duration"
        if self.schedule.done and not self.out:
            return "plan"
        return ""

    def queue(self, now: float, budget: float) -> None:
        """Queue what is due at ``now`` within ``budget`` bytes."""
        if self.garbage:
            k = int(budget)
            junk = self.rng.integers(128, 256, k, dtype=np.uint8)
            junk[self.rng.random(k) < 1 / 64] = ord("\n")
            self.out += junk.tobytes()
            self.queued_bytes += k
            self.garbage_bytes += k
            return
        due = int(now * self.rate_hz) + 1
        while self.schedule.k < due and budget > 0:
            i = self.schedule.next_index()
            if i is None:
                break
            k = self.schedule.k
            self.schedule.k += 1
            line = self.lines[i]
            if i != k and self.timed:  # a later pass, a cut or a paused hold: time goes on
                stamp = k * self.clock_scale / self.rate_hz  # the part's clock
                line = b"%.4f," % stamp + line.split(b",", 1)[1]
            every = self.malformed_every
            bad = every is not None and k % every == every - 1
            if bad:
                line = damaged(line)
            self.out += line
            self.queued_bytes += len(line)
            budget -= len(line)
            self.line_ends.append((self.queued_bytes, bad))

    def run(self, header: bytes, result: ServeResult) -> None:
        """Stream until the end; fill ``result`` (lines, malformed, garbage, seconds, end)."""
        os.set_blocking(self.master, False)
        self.out += header
        self.queued_bytes = len(header)
        t0 = _time.monotonic()
        written_total = 0
        while True:
            now = _time.monotonic() - t0
            end = self.why_end(now)
            if end:
                break
            stalled = self.stall_after_s is not None and now >= self.stall_after_s
            budget = now * self.baud / 10.0 - self.queued_bytes
            if not stalled and budget > 0:
                self.queue(now, budget)
            if self.out:
                try:
                    written = os.write(self.master, self.out)
                except BlockingIOError:
                    written = 0
                except OSError:  # the reader's side is gone
                    end = "reader-closed"
                    break
                del self.out[:written]
                written_total += written
            _time.sleep(0.004)
        self.written_total = written_total
        self.tally(result)
        result.garbage_bytes = self.garbage_bytes
        result.seconds = _time.monotonic() - t0
        result.end = end

    def tally(self, result: ServeResult, unread: int = 0) -> None:
        """Count the lines the reader got whole: written, less ``unread`` bytes at the end."""
        delivered = self.written_total - unread
        done = [bad for offset, bad in self.line_ends if offset <= delivered]
        result.lines, result.malformed = len(done), sum(done)
