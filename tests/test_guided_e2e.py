"""Guided capture end to end through the tty layer: ``imucal simulate --serve`` performs the
plan's poses, ``imucal capture`` (guided, the default) follows them, and the keyboard is a
scripted pipe."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from imucal_cli.formats.session import read_session

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")

CLI = [sys.executable, "-m", "imucal_cli"]
ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}


def serve(*args: str) -> tuple[subprocess.Popen, str]:
    # The virtual unit holds each pose 3.5 s: long enough for the guided hold (2 s) once the
    # stillness detector has seen the unit settle, as a person would hold it.
    proc = subprocess.Popen(
        [*CLI, "simulate", "--serve", "--plan", "six", "--rate", "100", "--hold", "3.5", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/"), proc.stderr.read()
    return proc, path


def capture(port: str, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [*CLI, "capture", "--port", port, "--plan", "six", "--output", str(out)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=ENV,
    )


def test_guided_capture_completes_every_pose_through_the_virtual_port(tmp_path):
    server, port = serve()
    out = tmp_path / "guided.h5"
    try:
        proc = capture(port, out)
        text, _ = proc.communicate(timeout=90)
    finally:
        server.kill()
        server.communicate()
    assert proc.returncode == 0, text
    assert "Put face +Z up and hold still" in text
    assert "6 of 6" in text and "complete" in text
    session = read_session(out)
    static = session.static_segments()
    assert sorted(s.label for s in static) == sorted(f"face {s}{a} up" for a in "XYZ" for s in "+-")
    for s in static:  # each hold is 2 s of still data, labelled with its up vector
        assert s.n_samples >= 190 and s.up is not None


def test_scripted_keys_skip_and_quit(tmp_path):
    server, port = serve()
    out = tmp_path / "keys.h5"
    lines: list[str] = []
    try:
        proc = capture(port, out)
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
        server.communicate()
    text = "".join(lines)
    assert proc.returncode == 3, text  # saved but incomplete
    assert "skip" in text.lower()
    session = read_session(out)
    assert len(session.static_segments()) == 2
    assert "missing" in text
