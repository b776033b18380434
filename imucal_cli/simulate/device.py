"""A virtual serial IMU: ``imucal simulate --serve`` streams a simulated IMU on a pseudo-terminal.

:func:`serve` opens a pseudo-terminal pair, announces the device path of its slave side, waits
for a reader to open it, and writes the text lines of a simulated IMU performing a plan in real
time, ``t,ax,ay,az,gx,gy,gz,temp`` (``t`` in seconds, raw counts; the redundant unit of
``hk-redundant``: ``t,ax,ay,az,a4,temp``), so that ``imucal capture --port PATH`` reads it
through the real tty layer.

- Every plan of the registry and every plan file plays
  :func:`imucal_cli.simulate.play.simulate_plan`: the same seed and options give the same
  samples as ``imucal simulate`` writes to a file; lines are sent when their time comes.
- A pseudo-terminal has no baud rate: the bytes are paced to ``baud / 10`` bytes per second
  (8N1), so a stream too fast for the baud rate falls behind as it would on a real line.
- The first line is a comment ``# imucal virtual IMU ...``; then data lines.
- Faults for tests: ``garbage`` (random bytes at the same byte rate, as a wrong baud rate
  shows), ``stall_after_s`` (stop sending, keep the port open), ``vanish_after_s`` (close the
  pseudo-terminal: the device is unplugged), ``malformed_every`` (every N-th line loses fields).

The stream starts when a reader opens the port (plus :data:`SETTLE_S`, since pyserial flushes
the input when it configures the port) and ends after the plan (or after ``duration_s``, with
``loop`` repeating the plan), when the reader closes the port, or on SIGINT/SIGTERM.
"""

from __future__ import annotations

import os
import select
import signal
import threading
import time as _time
import tty
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.plans import Plan

__all__ = ["SETTLE_S", "ServeResult", "plan_motion", "serve", "stream_arrays"]

SETTLE_S = 0.3
"""Wait after a reader opened the port before the first byte (pyserial flushes its input)."""

DRAIN_S = 0.3
"""Wait after the last byte before closing the pseudo-terminal, so the reader gets it all."""


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
        ``"plan"``, ``"duration"``, ``"signal"``, ``"reader-closed"``, ``"vanished"``,
        ``"no-reader"``.
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
    from imucal_cli.plans import find_plan, load_plan
    from imucal_cli.simulate.steps import simulate_steps

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
    plan: str, *, seed: int = 0, rate_hz: float = 100.0, hold_s: float | None = 2.0,
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
    from imucal_cli.simulate.play import simulate_plan

    session, _ = simulate_plan(
        plan, seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s, **options
    )
    return session.time, session.accel, session.gyro


def _columns(accel: np.ndarray, gyro: np.ndarray | None, temperature: bool) -> str:
    """The field names of a line: ``t,ax,ay,az[,a4..],gx,gy,gz[,temp]``."""
    names = ["t", "ax", "ay", "az"] + [f"a{k}" for k in range(4, accel.shape[1] + 1)]
    if gyro is not None:
        names += ["gx", "gy", "gz"] + [f"g{k}" for k in range(4, gyro.shape[1] + 1)]
    return ",".join(names + (["temp"] if temperature else []))


def _format(
    time: np.ndarray, accel: np.ndarray, gyro: np.ndarray | None, temperature: bool,
    counts: bool,
) -> list[bytes]:  # fmt: skip
    columns = [time, accel] + ([] if gyro is None else [gyro])
    n_values = sum(c.shape[1] for c in columns[1:])
    value = "%.0f" if counts else "%.6f"
    fmt = ",".join(["%.4f"] + [value] * n_values + (["%.2f"] if temperature else []))
    if temperature:
        columns.append((25.0 + 0.01 * time)[:, None])
    rows = np.column_stack(columns).tolist()
    return [(fmt % tuple(r) + "\n").encode() for r in rows]


def _damage(line: bytes) -> bytes:
    """A malformed version of a data line: its last two fields are lost."""
    return b",".join(line.rstrip(b"\n").split(b",")[:-2]) + b"\n"


# --------------------------------------------------------------------------------------------
# Serving
# --------------------------------------------------------------------------------------------


def serve(
    plan: str = "six",
    rate_hz: float = 100.0,
    baud: int = 115200,
    *,
    seed: int = 0,
    hold_s: float | None = 2.0,
    move_s: float = 1.5,
    units: str = "counts",
    plan_options: dict | None = None,
    temperature: bool = True,
    loop: bool = False,
    duration_s: float | None = None,
    wait_reader_s: float | None = None,
    garbage: bool = False,
    stall_after_s: float | None = None,
    vanish_after_s: float | None = None,
    malformed_every: int | None = None,
    announce: Callable[[str], None] = print,
    status: Callable[[str], None] | None = None,
) -> ServeResult:
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
        ``rotations_per_axis``, ``mountings``, ...).
    temperature : bool
        Print the temperature field (the last field of a line).
    loop : bool
        Repeat the plan (time keeps increasing) until ``duration_s`` or a signal.
    duration_s : float, optional
        Stop streaming after this long, s.
    wait_reader_s : float, optional
        Give up when no reader opened the port within this long (default: wait forever).
    garbage : bool
        Send random bytes instead of lines (a wrong baud rate).
    stall_after_s : float, optional
        Stop sending after this long but keep the port open (until a signal or the reader
        closes it).
    vanish_after_s : float, optional
        Close the pseudo-terminal after this long (the device is unplugged).
    malformed_every : int, optional
        Every N-th data line is sent with two fields missing.
    announce : callable
        Called once with the slave device path, before anything else.
    status : callable, optional
        Called with progress messages.

    Returns
    -------
    ServeResult
    """
    if not rate_hz > 0:
        raise InputError(f"rate must be > 0 Hz, got {rate_hz:g}")
    if not isinstance(baud, int) or baud <= 0:
        raise InputError(f"baud rate must be a positive integer, got {baud!r}")
    if malformed_every is not None and malformed_every < 1:
        raise InputError(f"--malformed-every must be >= 1, got {malformed_every}")
    time, accel, gyro = stream_arrays(
        plan, seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s,
        **(plan_options or {}),
    )  # fmt: skip
    lines = _format(time, accel, gyro, temperature, units == "counts")
    say = status or (lambda message: None)
    stop = {"kind": None}
    old_handlers = {}
    if threading.current_thread() is threading.main_thread():

        def handler(signum, frame):  # noqa: ARG001
            stop["kind"] = "signal"

        for signum in (signal.SIGINT, signal.SIGTERM):
            old_handlers[signum] = signal.signal(signum, handler)

    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    os.close(slave)  # the reader's open is seen as the end of the master's POLLHUP
    result = ServeResult(path=path)
    poller = select.poll()
    poller.register(master, select.POLLHUP)
    try:
        announce(path)
        fields = _columns(accel, gyro, temperature)
        say(f"serving plan {plan} at {rate_hz:g} Hz, {baud} baud on {path}; waiting for a reader")
        result.end = _wait_for_reader(poller, stop, wait_reader_s)
        if result.end:
            return result
        header = (
            f"# imucal virtual IMU: plan {plan}, {rate_hz:g} Hz, {units}, "
            f"columns {fields}, seed {seed}\n"
        ).encode()
        line = _Line(
            master, poller, stop, lines, time, rate_hz, baud, loop=loop, duration_s=duration_s,
            garbage=garbage, stall_after_s=stall_after_s, vanish_after_s=vanish_after_s,
            malformed_every=malformed_every, rng=np.random.default_rng(seed + 1),
        )  # fmt: skip
        line.run(header, result)
        if result.end in ("plan", "duration", "signal", "vanished"):
            _time.sleep(DRAIN_S)
        say(
            f"sent {result.lines} lines ({result.malformed} malformed) in "
            f"{result.seconds:.1f} s; end: {result.end}"
        )
        return result
    finally:
        os.close(master)
        for signum, old in old_handlers.items():
            signal.signal(signum, old)


def _wait_for_reader(poller, stop: dict, wait_reader_s: float | None) -> str:
    """Wait until a reader opened the port (then :data:`SETTLE_S`); "" or why it gave up."""
    waited = _time.monotonic()
    while any(ev & select.POLLHUP for _, ev in poller.poll(50)):
        if stop["kind"] is not None:
            return "signal"
        if wait_reader_s is not None and _time.monotonic() - waited > wait_reader_s:
            return "no-reader"
    _time.sleep(SETTLE_S)
    return ""


class _Line:
    """The serial line: queues lines (or garbage) as their time comes, paced to the baud
    rate, writes them to the master side, and counts what was written completely."""

    def __init__(
        self, master: int, poller, stop: dict, lines: list[bytes], time: np.ndarray,
        rate_hz: float, baud: int, *, loop: bool, duration_s, garbage: bool, stall_after_s,
        vanish_after_s, malformed_every, rng: np.random.Generator,
    ) -> None:  # fmt: skip
        self.master, self.poller, self.stop, self.lines = master, poller, stop, lines
        self.baud, self.loop, self.garbage = baud, loop, garbage
        self.duration_s, self.stall_after_s = duration_s, stall_after_s
        self.vanish_after_s, self.malformed_every, self.rng = vanish_after_s, malformed_every, rng
        self.when = np.asarray(time, float) - float(time[0])  # when each line is due, s
        self.pass_s = float(self.when[-1]) + 1.0 / rate_hz
        self.out = bytearray()
        self.queued_bytes = 0  # bytes put into `out` (paced by the baud rate)
        self.line_ends: list[tuple[int, bool]] = []  # (byte offset after the line, malformed)
        self.index = 0  # next line to queue, counting passes
        self.garbage_bytes = 0

    def why_end(self, now: float) -> str:
        """Why streaming ends now, or ""."""
        if self.stop["kind"] is not None:
            return "signal"
        if any(ev & select.POLLHUP for _, ev in self.poller.poll(0)):
            return "reader-closed"
        if self.vanish_after_s is not None and now >= self.vanish_after_s:
            return "vanished"
        if self.duration_s is not None and now >= self.duration_s:
            return "duration"
        if not self.loop and self.index >= len(self.lines) and not self.out:
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
        n = len(self.lines)
        passes = int(now // self.pass_s)
        due = passes * n + int(np.searchsorted(self.when, now - passes * self.pass_s, "right"))
        due = due if self.loop else min(n, due)
        while self.index < due and budget > 0:
            p, i = divmod(self.index, n)
            line = self.lines[i]
            if p:
                t_text, rest = line.split(b",", 1)
                line = b"%.4f," % (float(t_text) + p * self.pass_s) + rest
            every = self.malformed_every
            bad = every is not None and (self.index + 1) % every == 0
            if bad:
                line = _damage(line)
            self.out += line
            self.queued_bytes += len(line)
            budget -= len(line)
            self.line_ends.append((self.queued_bytes, bad))
            self.index += 1

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
        done = [bad for offset, bad in self.line_ends if offset <= written_total]
        result.lines, result.malformed = len(done), sum(done)
        result.garbage_bytes = self.garbage_bytes
        result.seconds = _time.monotonic() - t0
        result.end = end
