"""Running the user's path for ``bench live`` (issue 24.1): processes, not functions.

- :func:`burners`: CPU-burning processes (``python -c "while True: pass"``) beside the run.
- :func:`capture_guided`: ``imucal simulate --serve --step`` and ``imucal capture`` (guided),
  each in its own pseudo-terminal, and a scripted person between them: the person reads the
  capture's screen and, a human reaction time after it says a pose is recorded, presses Enter
  in the device's terminal so that the unit moves to the next pose (as
  ``tests/test_guided_e2e.py::test_serve_stepped_by_enter`` does through pipes).
- :func:`capture_unattended`: ``imucal simulate --serve`` on its timer and ``imucal capture
  --no-prompt``.
- :func:`calibrate`: ``imucal calibrate SESSION`` with no config.

Every process started here is registered and killed by :func:`kill_all` (the bench calls it
when it ends, however it ends); each is killed by its own id, never by name.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

CLI = [sys.executable, "-m", "imucal_cli"]
ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "160"}
#: How long the device may take to start and say its port, s (a Python start-up: seconds on a
#: quiet machine, a minute at load 20 on 2 cores).
START_S = 300.0
#: What a person takes to react to the screen, s (uniform).
REACTION_S = (0.4, 1.2)
#: Control sequences of a terminal (CSI, OSC) and carriage returns, removed before reading.
_ANSI = re.compile(
    rb"\x1b\[[0-9;?]*[ -/]*[@-~]|\x1b\][^\x07\x1b]*(?:\x07|\x1b\\)|\x1b[()][0-9A-Za-z]|\r"
)
#: The guided capture's message for a pose taken: "recorded LABEL [(measured up ...)] (k of n)".
_POSE_TAKEN = re.compile(r"recorded [^\n]*?\((\d+) of (\d+)\)")
#: The guided capture asking for more field directions once every step is done.
_MORE_FIELD = "Keep turning the unit slowly"
#: The capture saying the stream has started (its start-up is over).
_RECEIVING = "receiving data from"
#: The guided capture restarting a hold the unit moved in.
_MOVED = "the unit moved during the hold"

_LOCK = threading.Lock()
_STARTED: list[subprocess.Popen] = []


def _register(proc: subprocess.Popen) -> subprocess.Popen:
    with _LOCK:
        _STARTED.append(proc)
    return proc


def kill_all() -> None:
    """Kill every process this module started that still runs (by id), and reap it."""
    with _LOCK:
        procs = list(_STARTED)
        _STARTED.clear()
    for proc in procs:
        _stop(proc, signal.SIGKILL)


def _stop(proc: subprocess.Popen, sig: int = signal.SIGTERM, wait_s: float = 10.0) -> int | None:
    """Send ``sig`` to a process still running, wait for it; its exit status (None: gone
    before)."""
    try:
        if proc.poll() is None:
            proc.send_signal(sig)
        return proc.wait(timeout=wait_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(timeout=wait_s)
    except OSError:
        return proc.returncode


def burners(n: int) -> list[subprocess.Popen]:
    """``n`` processes that burn a CPU each until killed."""
    return [_register(subprocess.Popen([sys.executable, "-c", "while True: pass"],
                                       stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.DEVNULL))  # fmt: skip
            for _ in range(n)]


def _controlling_tty() -> None:  # pragma: no cover - runs in the child
    """``preexec_fn``: the pseudo-terminal on fd 0 becomes the new session's controlling
    terminal (so that a program asking whether it runs in the foreground is told yes)."""
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


def _pty_spawn(args: list[str], columns: int = 160, rows: int = 48):
    """``args`` in a new pseudo-terminal (stdin, stdout and stderr); the process and the
    master side's descriptor."""
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
    try:
        proc = subprocess.Popen(args, stdin=slave, stdout=slave, stderr=slave, env={
            **ENV, "COLUMNS": str(columns), "LINES": str(rows), "TERM": "xterm-256color"},
            start_new_session=True, preexec_fn=_controlling_tty)  # fmt: skip
    finally:
        os.close(slave)
    return _register(proc), master


def _read(fd: int, timeout: float) -> bytes | None:
    """What the pseudo-terminal has within ``timeout`` s: bytes, b"" (nothing yet) or None
    (closed)."""
    ready, _, _ = select.select([fd], [], [], timeout)
    if not ready:
        return b""
    try:
        data = os.read(fd, 65536)
    except OSError:  # EIO: the other side is closed
        return None
    return data if data else None


def clean(data: bytes) -> str:
    """A terminal's output as text: control sequences and carriage returns removed."""
    return _ANSI.sub(b"", data).decode("utf-8", errors="replace")


class _Screen:
    """A terminal's output read as it comes: the poses the capture said it recorded, and the
    last few thousand characters (control sequences removed; a sequence split between two
    reads is kept until it is whole)."""

    KEEP = 4000

    def __init__(self) -> None:
        self.pending = b""
        self.text = ""
        self.tail = ""
        self.poses = 0
        self.moved = 0
        self.receiving = False
        self.more_field = False

    def feed(self, data: bytes) -> None:
        self.pending += data
        cut = self.pending.rfind(b"\x1b")
        whole = cut >= 0 and _ANSI.match(self.pending, cut) is not None
        if cut >= 0 and not whole and len(self.pending) - cut < 64:  # a sequence cut short
            head, self.pending = self.pending[:cut], self.pending[cut:]
        else:
            head, self.pending = self.pending, b""
        self.text += clean(head)
        end = 0
        for m in _POSE_TAKEN.finditer(self.text):
            self.poses += 1
            end = m.end()
        for m in re.finditer(_MOVED, self.text):
            self.moved += 1
            end = max(end, m.end())
        self.more_field = self.more_field or _MORE_FIELD in self.text
        self.receiving = self.receiving or _RECEIVING in self.text
        # what follows the last message may be the start of the next one (at most a line)
        self.text = self.text[max(end, len(self.text) - 400):]
        self.tail = (self.tail + clean(head))[-self.KEEP:]


@dataclass
class CaptureRun:
    """One capture through the virtual port.

    Attributes
    ----------
    mode : str
        ``"guided"`` or ``"unattended"``.
    session : Path
        The session file.
    exit_code : int or None
        ``imucal capture``'s exit status (None: it did not end and was killed).
    wall_s : float
        Wall time of the capture, s.
    served : str
        The device's last words (its ``# sent ...`` line).
    text : str
        The capture's output (cleaned of terminal control; the last 4,000 characters).
    poses_taken : int
        Poses the guided capture said it recorded (unattended: 0).
    error : str
        What went wrong in the harness itself ("" if nothing).
    """

    mode: str
    session: Path
    exit_code: int | None = None
    wall_s: float = 0.0
    served: str = ""
    text: str = ""
    poses_taken: int = 0
    error: str = ""
    events: list[str] = field(default_factory=list)


def _serve_args(plan: str, seed: int, extra: list[str]) -> list[str]:
    return [*CLI, "simulate", "--serve", "--plan", plan, "--seed", str(seed), *extra]


def _device_path(read_more, deadline: float) -> tuple[str, bytes]:
    """Read the device's output until its first line, the device path, is whole."""
    buf = b""
    while time.monotonic() < deadline:
        m = re.search(rb"^(/dev/\S+)\r?\n", buf, re.M)
        if m:
            return m.group(1).decode(), buf
        data = read_more()
        if data is None:
            break
        buf += data
    raise RuntimeError(f"the device announced no path: {clean(buf)[-300:]!r}")


def capture_guided(plan: str, seed: int, out: Path, *, n_poses: int, timeout_s: float,
                   serve_extra: list[str] = (), capture_extra: list[str] = (),
                   rng: np.random.Generator | None = None,
                   longest_hold_s: float = 2.0) -> CaptureRun:  # fmt: skip
    """A person at the bench: the device held still in each pose until Enter in its terminal
    (``--step``); the guided capture in another terminal.  After the capture says a pose is
    recorded, the person waits a reaction time and presses Enter at the device (the unit turns
    to the next pose, or through the plan's turn to the still period after it), except after
    the last of the ``n_poses`` holds.  When every step is done and the capture asks for more
    field directions (a magnetometer that has not seen 90 % of them), the device has nothing
    more to show: the person finishes with ``q``.  A capture that takes no pose (counted from
    when it says it receives data: a start-up at load takes a minute) for
    ``timeout_s`` / 4 (or 2.5 times the plan's longest hold, ``longest_hold_s``, and
    30 s) is given up on with Ctrl-C, as a person would; one that does not end in
    ``timeout_s`` is killed."""
    rng = rng or np.random.default_rng(seed)
    run = CaptureRun("guided", out)
    server, sfd = _pty_spawn(_serve_args(plan, seed, ["--step", *serve_extra]))
    cap = None
    cfd = -1
    try:
        path, _ = _device_path(lambda: _read(sfd, 0.5), time.monotonic() + START_S)
        t0 = time.monotonic()
        cap, cfd = _pty_spawn([*CLI, "capture", "--port", path, "--plan", plan, "--output",
                               str(out), *capture_extra])  # fmt: skip
        screen, device = _Screen(), bytearray()
        seen = moved = 0
        receiving = False
        enter_at: float | None = None
        finish_at: float | None = None
        last_progress = t0
        # a person waits for a pose a while, longer when the plan's hold is long (a warm-up)
        stalled = max(timeout_s / 4, 2.5 * longest_hold_s + 30.0)
        interrupted = False
        while True:
            now = time.monotonic()
            data = _read(cfd, 0.05)
            if data:
                screen.feed(data)
            extra = _read(sfd, 0)
            if extra and len(device) < 1_000_000:
                device += extra
            if screen.receiving and not receiving:  # the wait for a pose starts now
                receiving, last_progress = True, now
                run.events.append(f"{now - t0:.1f} s: the capture receives data")
            if screen.moved > moved:
                moved = screen.moved
                run.events.append(f"{now - t0:.1f} s: the capture says the unit moved in a hold")
            if screen.poses > seen:  # a new pose taken
                seen = screen.poses
                last_progress = now
                run.events.append(f"{now - t0:.1f} s: pose {seen} taken")
                if seen < n_poses:
                    enter_at = now + rng.uniform(*REACTION_S)
            if screen.more_field and finish_at is None:
                finish_at = now + rng.uniform(*REACTION_S)
            if finish_at is not None and finish_at > 0 and now >= finish_at:
                os.write(cfd, b"q\n")
                finish_at = -1.0
                run.events.append(f"{now - t0:.1f} s: more field directions asked for: q")
            if enter_at is not None and now >= enter_at:
                os.write(sfd, b"\n")
                enter_at = None
                run.events.append(f"{now - t0:.1f} s: Enter at the device")
            if data is None or cap.poll() is not None:
                break
            if not interrupted and now - last_progress > (stalled if receiving else timeout_s / 2):
                run.events.append(f"{now - t0:.1f} s: no pose for {stalled:.0f} s: Ctrl-C")
                cap.send_signal(signal.SIGINT)
                interrupted = True
                last_progress = now
            if now - t0 > timeout_s:
                run.error = f"no end after {timeout_s:.0f} s: killed"
                break
        run.exit_code = _stop(cap, signal.SIGKILL, 30) if run.error else cap.wait(timeout=60)
        run.wall_s = time.monotonic() - t0
        while rest := _read(cfd, 0.2):
            screen.feed(rest)
        run.text = screen.tail
        run.poses_taken = screen.poses
        _stop(server, signal.SIGTERM, 15)
        while (rest := _read(sfd, 0.2)) and len(device) < 1_000_000:
            device += rest
        run.served = _last_sent(clean(bytes(device)))
    except Exception as exc:  # noqa: BLE001 - the row says what broke
        run.error = run.error or f"{type(exc).__name__}: {exc}"
    finally:
        for proc in (cap, server):
            if proc is not None:
                _stop(proc, signal.SIGKILL, 10)
        for fd in (cfd, sfd):
            if fd >= 0:
                os.close(fd)
    return run


def _last_sent(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if "sent" in ln]
    return lines[-1] if lines else ""


class _TimedLines:
    """The lines a pipe gives, each with the time it came (s since ``t0``), read by a thread
    until the pipe ends."""

    def __init__(self, pipe, name: str, t0: float, lines: list) -> None:
        self.thread = threading.Thread(target=self._read, args=(pipe, name, t0, lines),
                                       daemon=True)  # fmt: skip
        self.thread.start()

    @staticmethod
    def _read(pipe, name: str, t0: float, lines: list) -> None:
        try:
            for raw in iter(pipe.readline, b""):
                line = raw.decode(errors="replace").rstrip("\n")
                with _LOCK:
                    lines.append((time.monotonic() - t0, name, line))
        except (OSError, ValueError):
            pass

    def join(self, timeout: float) -> None:
        self.thread.join(timeout)


def capture_unattended(plan: str, seed: int, out: Path, *, timeout_s: float,
                       serve_extra: list[str] = (),
                       capture_extra: list[str] = ()) -> CaptureRun:  # fmt: skip
    """The device on its timer (each pose held ``--hold`` s, 4 by default), ``imucal capture
    --no-prompt`` until every step of the plan was seen (or the device ends).  What both say
    is kept with the time it came (``events``: when the device started streaming, when the
    capture saw each step and ended)."""
    run = CaptureRun("unattended", out)
    t_start = time.monotonic()
    server = _register(subprocess.Popen(
        _serve_args(plan, seed, list(serve_extra)), stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV,
    ))  # fmt: skip
    cap = None
    lines: list[tuple[float, str, str]] = []
    readers = [_TimedLines(server.stderr, "device", t_start, lines)]
    try:
        fd = server.stdout.fileno()
        path, _ = _device_path(lambda: _read(fd, 0.5), time.monotonic() + START_S)
        t0 = time.monotonic()
        with _LOCK:
            lines.append((t0 - t_start, "bench", f"device at {path}: capture started"))
        cap = _register(subprocess.Popen(
            [*CLI, "capture", "--port", path, "--plan", plan, "--no-prompt", "--output",
             str(out), *capture_extra],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=ENV,
        ))  # fmt: skip
        readers.append(_TimedLines(cap.stdout, "capture", t_start, lines))
        readers.append(_TimedLines(server.stdout, "device", t_start, lines))
        try:
            cap.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            run.error = f"no end after {timeout_s:.0f} s: killed"
            cap.kill()
            cap.wait(timeout=30)
        run.wall_s = time.monotonic() - t0
        run.exit_code = None if run.error else cap.returncode
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait(timeout=10)
    except Exception as exc:  # noqa: BLE001 - the row says what broke
        run.error = run.error or f"{type(exc).__name__}: {exc}"
    finally:
        for proc in (cap, server):
            if proc is not None:
                _stop(proc, signal.SIGKILL, 10)
        for r in readers:
            r.join(10)
    with _LOCK:
        got = sorted(lines)
    run.text = "\n".join(line for _, who, line in got if who == "capture")[-4000:]
    run.served = _last_sent("\n".join(line for _, who, line in got if who == "device"))
    run.events = [f"{t:.1f} s {who}: {line}" for t, who, line in got]
    return run


@dataclass
class CalibrateRun:
    """``imucal calibrate SESSION`` with no config.

    Attributes
    ----------
    exit_code : int
    output : Path
        The calibration JSON (``SESSION.cal.json``).
    complete : bool or None
        The JSON's ``complete`` (None: no JSON).
    left_out : dict
        The JSON's ``left_out`` (sensor: why).
    sections : list of str
        The sensors in the JSON.
    stderr : str
        What the command printed on stderr (warnings, the error).
    """

    exit_code: int
    output: Path
    complete: bool | None = None
    left_out: dict = field(default_factory=dict)
    sections: list[str] = field(default_factory=list)
    stderr: str = ""


def calibrate(session: Path, timeout_s: float = 600.0, warmup: Path | None = None,
              output: Path | None = None) -> CalibrateRun:  # fmt: skip
    """``imucal calibrate SESSION [--warmup WARMUP]``: the default output beside it, stored in
    the session; with ``output``, that file and nothing stored (``--no-store``)."""
    args = [*CLI, "calibrate", str(session)] + ([] if warmup is None else
                                                ["--warmup", str(warmup)])  # fmt: skip
    if output is not None:
        args += ["--output", str(output), "--no-store"]
    proc = _register(subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                      stdin=subprocess.DEVNULL, env=ENV, text=True))  # fmt: skip
    try:
        _, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate(timeout=30)
        err += f"\n(bench: killed after {timeout_s:.0f} s)"
    out = session.with_suffix(".cal.json") if output is None else output
    run = CalibrateRun(proc.returncode, out, stderr=err)
    if out.exists():
        doc = json.loads(out.read_text())
        run.complete = doc.get("complete")
        run.left_out = doc.get("left_out") or {}
        run.sections = [s for s in ("accel", "gyro", "mag") if doc.get(s)]
    return run
