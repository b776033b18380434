"""Guided capture end to end through the tty layer: ``imucal simulate --serve`` performs the
plan's poses, ``imucal capture`` (guided, the default) follows them, and the keyboard is a
scripted pipe."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.formats.session import read_session

from .cli_helpers import spawn
from .served import ThreadServer

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")

CLI = [sys.executable, "-m", "imucal_cli"]
ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}
FACES = sorted(f"face {s}{a} up" for a in "XYZ" for s in "+-")


def serve(*args: str, plan: str | Path = "six") -> tuple[subprocess.Popen, str]:
    """The virtual unit with the defaults (its timer holds each pose 4 s) unless ``args``."""
    proc = spawn(
        [*CLI, "simulate", "--serve", "--plan", str(plan), "--rate", "100", *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/"), proc.stderr.read()
    return proc, path


QUICK = ("--hold", "2", "--move", "0.6")
"""The virtual unit's timer where the defaults are not what a test is about: poses held 2 s
(long enough for a 1 s hold to start once the unit has settled: 0.5 s, and a 0.25 s window of
the stillness detector), turns of 0.6 s."""


def serve_in_thread(*args: str) -> ThreadServer:
    """The same unit as :func:`serve`, served in a thread of this process (tests/served.py):
    for the tests that examine the capture, not the device's process (its output and Enter at
    its terminal are the two tests above that serve with :func:`serve`)."""
    return ThreadServer("--plan", "six", "--rate", "100", *args)


def capture(port: str, out: Path, *args: str, plan: str | Path = "six") -> subprocess.Popen:
    return spawn(
        [*CLI, "capture", "--port", port, "--plan", str(plan), "--output", str(out), *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
    )


def _check_session(out: Path, hold_s: float = 2.0, faces: list[str] = FACES) -> None:
    """Every face held ``hold_s`` with its up, and the turns between them as rotation
    segments that the gyro saw turn."""
    session = read_session(out)
    static = session.static_segments()
    assert sorted(s.label for s in static) == sorted(faces)
    for s in static:
        assert s.n_samples >= 95 * hold_s and s.up is not None
    turns = session.rotation_segments()
    assert len(turns) == len(faces) - 1
    assert all(t.label.startswith("turn to face") for t in turns)
    rest = session.gyro[static[0].start : static[0].stop].mean(axis=0)
    for turn in turns:
        swing = np.abs(session.gyro[turn.start : turn.stop] - rest).max()
        assert swing > 100  # counts: the unit turned (noise is a few counts)


#: The first three poses of plan six, as a plan file: the defaults' test (4 s holds on the
#: device) takes half the time of the six; the six faces guided: the tests below.
THREE = "".join(f'[[step]]\nkind = "static"\nlabel = "face {f} up"\nup = {up}\n'
                for f, up in (("+Z", [0, 0, 1]), ("-Z", [0, 0, -1]), ("+X", [1, 0, 0])))


def test_guided_capture_with_the_defaults_on_both_sides(tmp_path):
    """The device's timer (4 s a pose) and the capture's hold (2 s) at their defaults: a
    plan's poses are each held long enough on the timer to be taken."""
    plan = tmp_path / "three.toml"
    plan.write_text('name = "three"\n' + THREE)
    server, port = serve(plan=plan)
    out = tmp_path / "guided.h5"
    try:
        proc = capture(port, out, plan=plan)
        text, _ = proc.communicate(timeout=120)
    finally:
        server.kill()
        _, served = server.communicate()
    assert proc.returncode == 0, text
    assert "3 of 3" in text and "complete" in text
    assert "plan three: 3 poses; hold each pose still 2 s" in text and "6 s of holding" in text
    # the first prompt once, with how long to hold; a countdown
    assert text.count("Put face +Z up and hold still for 2 s") == 1, text
    assert "1 s left" in text
    assert "3 static and 2 rotation segments" in text
    assert "the plan runs on a timer, each pose held 4 s" in served
    _check_session(out, faces=["face +Z up", "face -Z up", "face +X up"])


def test_serve_stepped_by_enter(tmp_path):
    """--step: each pose is held until Enter in the server's terminal (here: its stdin). Its
    timer would hold a pose 0.5 s, too short for the capture's 1 s hold: every pose recorded
    shows that the unit stayed put until told, without waiting a fixed time here."""
    server, port = serve("--step", "--hold", "0.5", "--move", "0.6")
    out = tmp_path / "stepped.h5"
    lines: list[str] = []
    try:
        proc = capture(port, out, "--hold", "1")
        deadline = time.monotonic() + 120
        recorded = 0
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("recorded face"):
                recorded += 1
                if recorded == len(FACES):
                    continue  # the plan is over: the capture closes the port and the unit ends
                server.stdin.write("\n")
                server.stdin.flush()
            if time.monotonic() > deadline:
                break
        proc.wait(timeout=30)
    finally:
        server.kill()
        _, served = server.communicate()
    text = "".join(lines)
    assert proc.returncode == 0, text
    assert "6 of 6" in text
    assert "held until Enter here" in served
    _check_session(out, hold_s=1.0)


@pytest.mark.slow
def test_scripted_keys_skip_and_quit(tmp_path):
    """``s`` then ``q`` on the capture's stdin: saved, incomplete (exit 3). In make test-all:
    a key through stdin (``s``) and an incomplete capture saved with exit 3 are
    ``test_interrupted_capture_is_resumed_into_the_same_file``'s first capture, ``q`` the
    guided state's (``test_guided.py``, keys s, r and q)."""
    server = serve_in_thread(*QUICK)
    out = tmp_path / "keys.h5"
    lines: list[str] = []
    try:
        proc = capture(server.path, out, "--hold", "1")
        deadline = time.monotonic() + 60
        sent = []
        for line in proc.stdout:
            lines.append(line)
            if "recorded" in line and not sent:
                proc.stdin.write("s\n")  # skip the step now shown
                proc.stdin.flush()
                sent.append("s")
            elif "recorded" in line and sent == ["s"]:
                proc.stdin.write("q\n")  # and finish after the second pose
                proc.stdin.flush()
                sent.append("q")
            if time.monotonic() > deadline:
                break
        proc.wait(timeout=30)
    finally:
        server.kill()
    text = "".join(lines)
    assert proc.returncode == 3, text  # saved but incomplete
    assert "skip" in text.lower()
    session = read_session(out)
    assert len(session.static_segments()) == 2
    assert "missing" in text


def test_interrupted_capture_is_resumed_into_the_same_file(tmp_path):
    """A key typed on the capture's stdin (``s``: skip the step shown) after the first pose,
    Ctrl-C after the second (exit 3, saved), then `capture --resume` with the unit served
    again from its first pose: the two poses already there are not taken twice, the other
    four are appended, the session ends complete."""
    import signal

    out = tmp_path / "resumed.h5"
    server = serve_in_thread(*QUICK)
    lines: list[str] = []
    try:
        proc = capture(server.path, out, "--hold", "1")
        seen = 0
        for line in proc.stdout:
            lines.append(line)
            seen += line.startswith("recorded face")
            if seen == 1 and line.startswith("recorded face"):
                proc.stdin.write("s\n")  # skip the step now shown
                proc.stdin.flush()
            if seen == 2:
                proc.send_signal(signal.SIGINT)
                break
        rest, _ = proc.communicate(timeout=30)
    finally:
        server.kill()
    text = "".join(lines) + rest
    assert proc.returncode == 3, text  # saved but incomplete
    assert "skipped face -Z up" in text and "missing" in text, text
    assert "stopped by Ctrl-C" in text, text
    first = read_session(out)
    assert len(first.static_segments()) == 2
    server = serve_in_thread(*QUICK)
    try:
        proc = spawn(
            [*CLI, "capture", "--port", server.path, "--plan", "six", "--resume", str(out),
             "--hold", "1"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, env=ENV,
        )  # fmt: skip
        text, _ = proc.communicate(timeout=120)
    finally:
        server.kill()
    assert proc.returncode == 0, text
    assert "resumed: 2 of 6 steps already in the session" in text and "too close" in text
    assert f"continued after the {len(first.time)} samples already there" in text
    session = read_session(out)
    assert sorted(s.label for s in session.static_segments()) == FACES
    np.testing.assert_array_equal(session.accel[: len(first.time)], first.accel)
    assert np.all(np.diff(session.time) > 0)
