"""End to end through the tty layer: ``imucal simulate --serve`` -> ``imucal capture``.

Every fault of a capture: Ctrl-C, SIGTERM, the device unplugged (the pseudo-terminal closed), a
stalled stream, ``kill -9`` of the capture, malformed lines, a wrong baud rate (garbage) and a
port that does not exist.  The server reports how many lines it wrote completely, so the
session can be compared with what was sent.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from imucal_cli.formats.session import read_session

from .cli_helpers import LineReader, run, spawn
from .served import ThreadServer

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")

CLI = [sys.executable, "-m", "imucal_cli"]
RATE = 200


class Server:
    """``imucal simulate --serve`` in the background; ``path`` is its device."""

    def __init__(self, *args: str) -> None:
        self.proc = spawn(
            [*CLI, "simulate", "--serve", "--rate", str(RATE), *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.path = self.proc.stdout.readline().strip()
        assert self.path.startswith("/dev/"), self.proc.stderr.read()

    def finish(self, timeout: float = 120.0) -> dict:
        """Wait for the server to end; return its ``sent`` report."""
        try:
            out, err = self.proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, err = self.proc.communicate()
        m = re.search(r"# sent (\d+) lines, (\d+) malformed, (\d+) garbage bytes", out)
        assert m, (out, err)
        return {"lines": int(m[1]), "malformed": int(m[2]), "garbage": int(m[3])}

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


def start_capture(port: str, output: Path, *args: str) -> subprocess.Popen:
    return spawn(
        [*CLI, "capture", "--port", port, "--output", str(output), "--no-prompt", *args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


class Watched:
    """A capture whose stdout and stderr are read as they come (:class:`LineReader`)."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.proc = proc
        self.out, self.err = LineReader(proc.stdout), LineReader(proc.stderr)

    def wait_status(self, words: str) -> None:
        """Until the capture's status line (stderr) says ``words``."""
        self.err.wait_for(lambda line: words in line)

    def finish(self, timeout: float = 120.0) -> tuple[str, str]:
        self.proc.wait(timeout=timeout)
        return self.out.text(), self.err.text()


def wait_for_samples(path: Path, proc: subprocess.Popen, n: int, timeout: float = 120.0) -> None:
    """Until the session being written holds ``n`` samples (it flushes once a second)."""
    import warnings

    end = time.monotonic() + timeout
    while True:
        assert proc.poll() is None, "the capture ended"
        if path.exists():
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    if len(read_session(path).time) >= n:
                        return
            except Exception:  # noqa: BLE001  not yet readable: created, not yet flushed
                pass
        assert time.monotonic() < end, f"the capture did not save {n} samples"
        time.sleep(0.1)  # polling what the process writes, not waiting a fixed time


def saved_samples(stdout: str) -> int:
    m = re.search(r"saved (\d+) samples", stdout)
    assert m, stdout
    return int(m[1])


@pytest.fixture
def server_factory():
    """The device for a test that examines the capture: served in a thread of this process
    (tests/served.py, the same device without an interpreter of its own)."""
    servers = []

    def make(*args: str) -> ThreadServer:
        servers.append(ThreadServer("--rate", str(RATE), *args))
        return servers[-1]

    yield make
    for s in servers:
        s.kill()


@pytest.fixture
def process_factory():
    """The device as ``imucal simulate --serve``, a process: where its own output is examined,
    and the one whole session end to end."""
    servers = []

    def make(*args: str) -> Server:
        servers.append(Server(*args))
        return servers[-1]

    yield make
    for s in servers:
        s.kill()


@pytest.mark.parametrize(("signum", "words"), [(signal.SIGINT, "Ctrl-C"),
                                               (signal.SIGTERM, "SIGTERM")])  # fmt: skip
def test_signal_saves_every_sample_received(tmp_path, server_factory, signum, words):
    server = server_factory("--plan", "six", "--loop")
    out = tmp_path / "sig.h5"
    cap = Watched(start_capture(server.path, out, "--duration", "60"))
    cap.wait_status("receiving data from")
    cap.proc.send_signal(signum)
    stdout, stderr = cap.finish()
    cap = cap.proc
    sent = server.finish()
    assert cap.returncode == 3, (stdout, stderr)
    assert f"stopped by {words}" in stdout and "Traceback" not in stderr
    n = saved_samples(stdout)
    assert len(read_session(out).time) == n
    # every sample line received is saved; the lines still in the port when the capture
    # closed it (any number, on a loaded machine) are the only ones sent and not saved
    m = re.search(r"lines (\d+), comments (\d+), malformed (\d+);", stdout)
    assert m and n == int(m[1]) - int(m[2]) - int(m[3]), stdout
    assert 0 < n <= sent["lines"]


def test_device_vanishes(tmp_path, server_factory):
    # the port closes 6 s after the capture opened it: enough for a first sample under load
    server = server_factory("--plan", "six", "--vanish-after", "6")
    out = tmp_path / "gone.h5"
    cap = start_capture(server.path, out, "--duration", "60")
    stdout, stderr = cap.communicate(timeout=120)
    sent = server.finish()
    assert cap.returncode == 3, (stdout, stderr)
    assert "the device is gone" in stdout
    assert len(read_session(out).time) == saved_samples(stdout) == sent["lines"]


def test_device_vanishes_json_on_both_sides(tmp_path, process_factory):
    """--json (README schemas): the server's device path first, then one JSON line; the
    capture's stdout one JSON document."""
    import json

    server = process_factory("--plan", "six", "--vanish-after", "2.5", "--json")
    out = tmp_path / "gone.h5"
    cap = start_capture(server.path, out, "--duration", "60", "--json")
    stdout, stderr = cap.communicate(timeout=120)
    served, _ = server.proc.communicate(timeout=120)
    assert cap.returncode == 3, (stdout, stderr)
    sent, got = json.loads(served), json.loads(stdout)
    assert sent["format"] == "imucal-serve" and sent["end"] == "vanished"
    assert got["format"] == "imucal-capture" and got["end"] == "device-gone"
    assert got["complete"] is False and got["output"] == str(out)
    assert got["samples"] == sent["lines"] == len(read_session(out).time) > 0


def test_stalled_stream_times_out(tmp_path, server_factory):
    server = server_factory("--plan", "six", "--stall-after", "2")
    out = tmp_path / "stall.h5"
    cap = start_capture(server.path, out, "--duration", "60", "--read-timeout", "1")
    stdout, stderr = cap.communicate(timeout=120)
    sent = server.finish()  # the server ends when the capture closes the port
    assert cap.returncode == 3, (stdout, stderr)
    assert "for 1 s after" in stdout and "the device stopped sending" in stdout
    assert len(read_session(out).time) == saved_samples(stdout) == sent["lines"]


def test_kill_9_loses_at_most_the_last_second(tmp_path, server_factory):
    server = server_factory("--plan", "six", "--loop")
    out = tmp_path / "killed.h5"
    cap = start_capture(server.path, out, "--duration", "60")
    wait_for_samples(out, cap, int(1.6 * RATE))
    cap.kill()
    cap.communicate()
    sent = server.finish()
    session = read_session(out)
    missing = sent["lines"] - len(session.time)
    # the last second (one flush a second), and the lines in flight: a pseudo-terminal's
    # buffer (4 KiB, lines of 40 bytes and more)
    assert 0 <= missing <= 1.0 * RATE + 4096 // 40
    assert len(session.time) >= 1.6 * RATE


def test_wrong_baud_rate_garbage(tmp_path, server_factory):
    server = server_factory("--garbage")
    out = tmp_path / "garbage.h5"
    cap = start_capture(server.path, out, "--duration", "10", "--wait-timeout", "2")
    stdout, stderr = cap.communicate(timeout=120)
    assert cap.returncode == 2, (stdout, stderr)
    last = stderr.splitlines()[-1]  # after the "waiting for data" status
    assert last.startswith("imucal: error: received ") and "wrong baud rate?" in last
    assert not out.exists()


def test_garbage_then_unplugged_says_what_came(tmp_path, server_factory):
    """Only garbage, then the device is gone before the wait ends: no file, exit 2 (the
    README's "nothing was written"; 3 is "saved but incomplete"), and the one line says what
    arrived (not only that the device went)."""
    server = server_factory("--garbage", "--vanish-after", "2")
    out = tmp_path / "garbage.h5"
    cap = start_capture(server.path, out, "--duration", "30", "--wait-timeout", "20")
    stdout, stderr = cap.communicate(timeout=120)
    sent = server.finish()
    assert cap.returncode == 2, (stdout, stderr)
    assert sent["lines"] == 0 and sent["garbage"] > 0 and not out.exists()
    last = stderr.splitlines()[-1]
    assert last.startswith("imucal: error: ") and "the device is gone" in last, last
    assert "before any data; received " in last and "wrong baud rate?" in last, last
    assert last.endswith(": no file written") and "Traceback" not in stderr


@pytest.mark.parametrize(("signum", "code", "words"), [
    (signal.SIGINT, 130, "imucal: stopped by Ctrl-C before any data"),
    (signal.SIGTERM, 2, "imucal: error: stopped by SIGTERM before any data"),
])  # fmt: skip
def test_signal_before_any_data_saves_nothing(tmp_path, server_factory, signum, code, words):
    """Stopped before a sample came: no file, and the README's status for nothing saved (130
    after Ctrl-C, else 2), never 3 ("saved but incomplete")."""
    server = server_factory("--plan", "six", "--stall-after", "0")
    out = tmp_path / "none.h5"
    cap = Watched(start_capture(server.path, out, "--duration", "30", "--wait-timeout", "20"))
    cap.wait_status("waiting for data on")  # its signal handlers are in place
    cap.proc.send_signal(signum)
    stdout, stderr = cap.finish()
    assert cap.proc.returncode == code, (stdout, stderr)
    last = stderr.splitlines()[-1]
    assert last.startswith(words) and last.endswith(": no file written"), last
    assert not out.exists() and "Traceback" not in stderr


def test_no_such_port(tmp_path):
    r = subprocess.run(
        [*CLI, "capture", "--port", "/dev/ttyIMUCAL_NOPE", "--no-prompt", "--duration", "1",
         "--output", str(tmp_path / "x.h5")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.startswith(
        "imucal: error: /dev/ttyIMUCAL_NOPE: no such serial port (available:"
    )
    assert r.stderr.count("\n") == 1


def test_no_prompt_needs_a_duration_or_a_plan(tmp_path):
    # in this process: the capture's own exit path with a one-line error is test_no_such_port
    r = run("capture", "--port", "/dev/null", "--no-prompt")
    assert r.returncode == 2 and "--no-prompt needs --duration" in r.stderr


@pytest.mark.parametrize(("protocol", "capture_args"), [
    ("motioncal", []),
    # the same path with the other sketch's lines (parsed alike: tests/test_capture_lines.py)
    pytest.param("i2cdevlib", ["--protocol", "i2cdevlib"], marks=pytest.mark.slow),
])  # fmt: skip
def test_sketch_lines_captured_end_to_end(tmp_path, process_factory, protocol, capture_args):
    """The whole unattended session end to end, the device a process: the virtual IMU prints
    MotionCal's Raw: lines (recognised by themselves) or i2cdevlib's a/g: lines (asked for):
    every line sent arrives with its counts, malformed lines counted and left out, the six
    faces found in the plan's order with the turns between them, and the session calibrates.
    (The plain t,ax,... lines of a plan, unattended through the device's process:
    ``test_imu_set_capture``, ``test_capture_until``, ``test_bench_live``.)"""
    import numpy as np

    from imucal_cli.simulate.device import HARD_IRON_COUNTS, stream_arrays

    # 2 s holds: the host clock stamps these lines, in bursts as they arrive, which leaves a
    # 1.5 s hold's still period at the edge of --min-still 1 s
    server = process_factory("--plan", "six", "--hold", "2", "--move", "0.8", "--baud",
                             "460800", "--protocol", protocol, "--malformed-every", "97")
    out = tmp_path / f"{protocol}.h5"
    cap = start_capture(server.path, out, "--plan", "six", *capture_args)
    stdout, stderr = cap.communicate(timeout=120)
    sent = server.finish()
    assert cap.returncode == 0, (stdout, stderr)
    session = read_session(out)
    n = len(session.time)
    assert n == saved_samples(stdout) == sent["lines"] - sent["malformed"] > 0
    assert f"malformed {sent['malformed']};" in stdout and sent["malformed"] > 0
    _, accel, gyro = stream_arrays("six", rate_hz=RATE, hold_s=2.0, move_s=0.8)
    kept = np.flatnonzero(np.arange(len(accel)) % 97 != 96)[:n]  # the lines sent whole
    np.testing.assert_array_equal(session.accel, np.round(accel[kept]))
    np.testing.assert_array_equal(session.gyro, np.round(gyro[kept]))
    assert session.accel_units == session.gyro_units == "counts"
    assert "complete (6 steps seen)" in stdout
    static = session.static_segments()
    assert [s.label for s in static] == ["face +Z up", "face -Z up", "face +X up", "face -X up",
                                         "face +Y up", "face -Y up"]  # fmt: skip
    assert all(s.up is not None for s in static) and len(session.rotation_segments()) == 5
    assert session.source == f"serial:{server.path}@115200"  # the capture's own --baud
    # The session is one the calibrator reads (in this process: its own process is
    # test_calibrate's test_bad_inputs_are_exit_2 and test_cli_conformance's)
    cal = run("calibrate", out)
    # six labelled faces calibrate by default with the labelled-pose solver (issue 9.1)
    assert cal.returncode == 0, cal.stderr
    assert "labelled" in cal.stdout
    # the host's stamps, once the capture ended: each run between pauses on the device's
    # steady clock, without the read jitter (which the gyro's turns integrate over)
    from imucal_cli.capture.host_clock import MIN_STEADY, PAUSE_S, STEADY_MISS

    straight = 0
    for stamps in np.split(session.time, np.flatnonzero(np.diff(session.time) > PAUSE_S) + 1):
        i = np.arange(len(stamps))
        miss = np.abs(stamps - np.polyval(np.polyfit(i, stamps, 1), i)).max()
        if miss < 1e-6:
            straight += len(stamps)
        else:  # kept live: only a run too short to fit, or one the line missed by steps of
            # several intervals (a host far busier than two burners: load 9 on 2 cores)
            assert len(stamps) < MIN_STEADY or miss > STEADY_MISS / 2 / RATE, miss
    assert straight >= 0.5 * n, (straight, n)
    if protocol == "motioncal":
        assert "recognised MotionCal Raw:" in stderr and session.mag_units == "counts"
        field_uT = np.linalg.norm(session.mag - HARD_IRON_COUNTS, axis=1) / 10.0
        np.testing.assert_allclose(field_uT, 48.0, atol=0.1)  # the earth's field, any pose
    else:
        assert session.mag is None
