"""A virtual serial IMU: ``imucal simulate --serve`` streams a simulated IMU on a pseudo-terminal.

:func:`serve` opens a pseudo-terminal pair, announces the device path of its slave side, waits
for a reader to open it, and writes the text lines of a simulated 6-axis IMU performing a plan
in real time, ``t,ax,ay,az,gx,gy,gz,temp`` (``t`` in seconds, raw counts), so that
``imucal capture --port PATH`` reads it through the real tty layer.

- Plans ``six``, ``qureshi18`` and ``random:N`` play
  :func:`imucal_cli.simulate.triad.simulate_stream`
  (same seed, same samples as ``imucal simulate``).  Any other plan (``gyro-axes``,
  ``hwangbo-iron``, a TOML file) plays :func:`plan_motion`: still, a smooth turn about each
  rotation step's axis, still again, with the simulator's sensor model.
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
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.plans import Plan, load_plan

__all__ = ["SETTLE_S", "ServeResult", "plan_motion", "serve", "stream_arrays"]

SETTLE_S = 0.3
"""Wait after a reader opened the port before the first byte (pyserial flushes its input)."""

DRAIN_S = 0.3
"""Wait after the last byte before closing the pseudo-terminal, so the reader gets it all."""

_SIMULATOR_PLANS = ("six", "qureshi18")


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


def _to_vertical(up: np.ndarray) -> Rotation:
    """A rotation (body -> world) taking body vector ``up`` onto world +Z."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    ez = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, ez)
    s, c = float(np.linalg.norm(axis)), float(up @ ez)
    if s < 1e-12:
        return Rotation.identity() if c > 0 else Rotation.from_rotvec([np.pi, 0.0, 0.0])
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c))


def plan_motion(
    plan: Plan,
    *,
    seed: int = 0,
    rate_hz: float = 100.0,
    hold_s: float = 2.0,
    move_s: float = 1.5,
    lead_s: float = 1.0,
    units: str = "counts",
    gravity: float = 9.80665,
    accel_noise: float = 0.01,
    gyro_noise: float = 0.005,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw samples of a simple motion through any plan: still, smooth turns, still.

    Static steps with ``up`` turn the unit (a smootherstep slerp of ``move_s``) to that
    pose, then hold ``hold_s``; static steps without ``up`` hold where the unit is.  Rotation
    steps turn about the body ``axis`` by ``angle_deg`` (90 degrees when the plan leaves it
    free), then hold ``hold_s`` when the next step is not a static one.  The sensor is
    :func:`imucal_cli.simulate.triad.random_imu` drawn from ``seed``.

    Returns
    -------
    time, accel, gyro : ndarray
        ``(N,)`` seconds, ``(N, 3)`` raw accelerometer and gyroscope samples.
    """
    from imucal_cli.simulate.triad import random_imu

    truth_ss, noise_ss = np.random.SeedSequence(int(seed)).spawn(2)
    truth = random_imu(np.random.default_rng(truth_ss), units, accel_noise, gyro_noise)
    n_hold = max(2, int(round(hold_s * rate_hz)))
    n_move = max(2, int(round(move_s * rate_hz)))
    world_g = np.array([0.0, 0.0, gravity])
    forces: list[np.ndarray] = []
    rates: list[np.ndarray] = []
    first_up = next((s.up for s in plan.steps if s.kind == "static" and s.up is not None), None)
    attitude = Rotation.identity() if first_up is None else _to_vertical(first_up)

    def hold(n: int) -> None:
        forces.append(np.tile(attitude.inv().apply(world_g), (n, 1)))
        rates.append(np.zeros((n, 3)))

    def turn(rotvec: np.ndarray) -> None:
        nonlocal attitude
        dur = (n_move + 1) / rate_hz
        tau = np.arange(1, n_move + 1) / (n_move + 1)
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        ds = 30.0 * tau**2 * (1.0 - tau) ** 2 / dur
        att = attitude * Rotation.from_rotvec(s[:, None] * rotvec)
        forces.append(att.inv().apply(world_g))
        rates.append(ds[:, None] * rotvec)
        attitude = attitude * Rotation.from_rotvec(rotvec)

    hold(max(1, int(round(lead_s * rate_hz))))
    steps = plan.steps
    for i, step in enumerate(steps):
        if step.kind == "static":
            if step.up is not None:
                target = _to_vertical(step.up)
                rv = (attitude.inv() * target).as_rotvec()
                if np.linalg.norm(rv) > np.radians(1.0):
                    turn(rv)
            hold(n_hold)
        else:
            axis = np.array([0.0, 0.0, 1.0]) if step.axis is None else np.asarray(step.axis)
            angle = 90.0 if step.angle_deg is None else step.angle_deg
            turn(axis / np.linalg.norm(axis) * np.radians(angle))
            if i + 1 == len(steps) or steps[i + 1].kind != "static":
                hold(n_hold)
    force, rate = np.vstack(forces), np.vstack(rates)
    rng = np.random.default_rng(noise_ss)
    accel = truth.accel_raw(force, rng.standard_normal(force.shape) * truth.accel_noise)
    gyro = truth.gyro_raw(rate, rng.standard_normal(rate.shape) * truth.gyro_noise)
    return np.arange(len(force)) / rate_hz, accel, gyro


def stream_arrays(
    plan: str, *, seed: int = 0, rate_hz: float = 100.0, hold_s: float = 2.0,
    units: str = "counts", move_s: float = 1.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Time (N,), raw accel (N, 3) and raw gyro (N, 3) of one pass through ``plan``.

    Raises
    ------
    InputError
        Unknown plan or bad options.
    """
    key = plan.strip().lower()
    if key in _SIMULATOR_PLANS or key.startswith("random:"):
        from imucal_cli.simulate.triad import simulate_stream

        s = simulate_stream(
            plan=key, seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s
        )
        return s.time, s.accel, s.gyro
    if not rate_hz > 0 or not hold_s > 0 or not move_s > 0:
        raise InputError("rate, hold and move time must be positive")
    return plan_motion(
        load_plan(plan), seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s
    )


def _format(
    time: np.ndarray, accel: np.ndarray, gyro: np.ndarray, temperature: bool, counts: bool
) -> list[bytes]:
    value = "%.0f" if counts else "%.6f"
    fmt = ",".join(["%.4f"] + [value] * 6 + (["%.2f"] if temperature else []))
    columns = [time, accel, gyro]
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
    hold_s: float = 2.0,
    move_s: float = 1.5,
    units: str = "counts",
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
    temperature : bool
        Print the temperature field (8 fields per line, else 7).
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
        plan, seed=seed, rate_hz=rate_hz, hold_s=hold_s, units=units, move_s=move_s
    )
    counts = units == "counts"
    lines = _format(time, accel, gyro, temperature, counts)
    pass_s = len(time) / rate_hz
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
        fields = "t,ax,ay,az,gx,gy,gz" + (",temp" if temperature else "")
        say(f"serving plan {plan} at {rate_hz:g} Hz, {baud} baud on {path}; waiting for a reader")
        waited = _time.monotonic()
        while any(ev & select.POLLHUP for _, ev in poller.poll(50)):
            if stop["kind"] is not None:
                result.end = "signal"
                return result
            if wait_reader_s is not None and _time.monotonic() - waited > wait_reader_s:
                result.end = "no-reader"
                return result
        _time.sleep(SETTLE_S)
        os.set_blocking(master, False)
        header = (
            f"# imucal virtual IMU: plan {plan}, {rate_hz:g} Hz, {units}, "
            f"columns {fields}, seed {seed}\n"
        ).encode()
        out = bytearray(header)
        rng = np.random.default_rng(seed + 1)
        t0 = _time.monotonic()
        queued_bytes = len(header)  # bytes put into `out` (paced by the baud rate)
        written_total = 0
        line_ends: list[tuple[int, bool]] = []  # (byte offset after the line, malformed)
        index = 0  # next line to queue, counting passes
        n = len(lines)
        end = ""
        while True:
            now = _time.monotonic() - t0
            if stop["kind"] is not None:
                end = "signal"
            elif any(ev & select.POLLHUP for _, ev in poller.poll(0)):
                end = "reader-closed"
            elif vanish_after_s is not None and now >= vanish_after_s:
                end = "vanished"
            elif duration_s is not None and now >= duration_s:
                end = "duration"
            elif not loop and index >= n and not out:
                end = "plan"
            if end:
                break
            stalled = stall_after_s is not None and now >= stall_after_s
            budget = now * baud / 10.0 - queued_bytes
            if not stalled and budget > 0:
                if garbage:
                    k = int(budget)
                    junk = rng.integers(128, 256, k, dtype=np.uint8)
                    junk[rng.random(k) < 1 / 64] = ord("\n")
                    out += junk.tobytes()
                    queued_bytes += k
                    result.garbage_bytes += k
                else:
                    due = int(now * rate_hz) + 1 if loop else min(n, int(now * rate_hz) + 1)
                    while index < due and budget > 0:
                        p, i = divmod(index, n)
                        line = lines[i]
                        if p:
                            t_text, rest = line.split(b",", 1)
                            line = b"%.4f," % (float(t_text) + p * pass_s) + rest
                        bad = malformed_every is not None and (index + 1) % malformed_every == 0
                        if bad:
                            line = _damage(line)
                        out += line
                        queued_bytes += len(line)
                        budget -= len(line)
                        line_ends.append((queued_bytes, bad))
                        index += 1
            if out:
                try:
                    written = os.write(master, out)
                except BlockingIOError:
                    written = 0
                except OSError:  # the reader's side is gone
                    end = "reader-closed"
                    break
                del out[:written]
                written_total += written
            _time.sleep(0.004)
        # Count what was written completely.
        done = [bad for offset, bad in line_ends if offset <= written_total]
        result.lines, result.malformed = len(done), sum(done)
        result.seconds = _time.monotonic() - t0
        result.end = end
        if end in ("plan", "duration", "signal", "vanished"):
            _time.sleep(DRAIN_S)
        say(
            f"sent {result.lines} lines ({result.malformed} malformed) in "
            f"{result.seconds:.1f} s; end: {end}"
        )
        return result
    finally:
        os.close(master)
        for signum, old in old_handlers.items():
            signal.signal(signum, old)
