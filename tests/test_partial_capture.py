"""Issue 24.2 and 24.7 on the user's path: ``imucal simulate --serve`` is the device,
``imucal capture`` (guided, the keyboard a pipe; or unattended) records it, ``imucal
calibrate`` with no config calibrates what the capture determines.

* six faces, guided, from a device with a magnetometer (MotionCal lines): the person holds each
  pose 4 s (the capture takes 2), so every turn starts 2-3 s after its pose's segment (one
  turn was lost before, and the accelerometer with it); the magnetometer sees about half of
  the sphere: it is left out and the rest saved, ``complete`` false;
* ``random:9``, the README's minimum, and ``ferraris`` captured guided calibrate (exit 0);
* options for a sensor the device does not send are warned about.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from imucal_cli.formats.session import read_session

from .cli_helpers import run, spawn
from .served import ThreadServer

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")

CLI = [sys.executable, "-m", "imucal_cli"]
ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}


def serve(*args: str) -> tuple[subprocess.Popen, str]:
    """The virtual unit; its device path is the first line it prints."""
    proc = spawn([*CLI, "simulate", "--serve", "--rate", "100", *args], stdin=subprocess.PIPE,
                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)  # fmt: skip
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/"), proc.stderr.read()
    return proc, path


def capture_guided(port: str, out: Path, plan: str, *args: str) -> tuple[int, str]:
    """A guided capture to its end (the plan done, or the device gone); exit status, text."""
    proc = spawn([*CLI, "capture", "--port", port, "--plan", plan, "--output", str(out), *args],
                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                 text=True, env=ENV)  # fmt: skip
    text, _ = proc.communicate(timeout=240)
    return proc.returncode, text


def served_and_captured(tmp_path: Path, name: str, plan: str, serve_args=(), capture_args=()):
    server, port = serve("--plan", plan, *serve_args)
    out = tmp_path / f"{name}.h5"
    try:
        code, text = capture_guided(port, out, plan, *capture_args)
    finally:
        server.kill()
        server.communicate()
    return out, code, text


def calibrate_json(session: Path, *args) -> tuple[int, dict, str]:
    proc = run("calibrate", session, "--json", "--no-store", "-o",
               session.with_suffix(".cal.json"), *args)  # fmt: skip
    return proc.returncode, (json.loads(proc.stdout) if proc.stdout else {}), proc.stderr


@pytest.mark.slow
def test_guided_six_faces_with_a_magnetometer_saves_what_it_determines(tmp_path):
    out, code, text = served_and_captured(tmp_path, "six-mag", "six",
                                          ("--protocol", "motioncal", "--seed", "2",
                                           "--hold", "5"))  # fmt: skip
    assert code == 0 and "6 of 6" in text, text
    session = read_session(out)
    statics, turns = session.static_segments(), session.rotation_segments()
    assert session.mag is not None and len(statics) == 6 and len(turns) == 5
    # each turn starts about 3 s after its pose's 2 s segment: past max_gap_s (2 s)
    gaps = [session.time[t.start] - session.time[s.stop - 1]
            for s, t in zip(statics[:-1], turns, strict=True)]  # fmt: skip
    assert min(gaps) > 2.0, gaps
    code, doc, err = calibrate_json(out)
    assert code == 0, err  # saved, whatever could not be calibrated
    cal = doc["calibration"]
    assert cal["accel"]["solver"] == "labelled"
    # every turn reaches its still periods through the samples between (none before)
    from imucal_cli.calibrate.gyro.rotations import gyro_data
    from imucal_cli.formats.calibration import read_calibration
    from imucal_cli.formats.config import Config

    accel = read_calibration(out.with_suffix(".cal.json")).accel
    assert len(gyro_data(session, Config(), accel).turns) == 5
    assert (cal.get("gyro") is None) == ("gyro" in doc["left_out"])
    if cal.get("mag") is None:  # about half of the sphere seen: left out, saying why
        assert "of the directions around it" in doc["left_out"]["mag"]
    assert doc["complete"] is False and cal["complete"] is False
    # the same with a magnetometer that must see 90 %: certainly left out, the rest saved
    cfg = tmp_path / "c.toml"
    cfg.write_text("[mag]\nmin_coverage = 0.9\n")
    code, doc, err = calibrate_json(out, "-c", cfg, "--force")
    assert code == 0, err
    assert doc["calibration"].get("mag") is None and doc["calibration"]["accel"] is not None
    assert "(at least 90 % needed" in doc["left_out"]["mag"]
    assert doc["left_out"]["mag"] in doc["warnings"]


@pytest.mark.slow
def test_guided_random_9_calibrates(tmp_path):
    """The minimum of random:N through the user's path: 9 poses, none refused as too close
    to another (the virtual unit spreads them as a person asked for new directions does)."""
    out, code, text = served_and_captured(tmp_path, "r9", "random:9",
                                          ("--seed", "1", "--hold", "3", "--move", "1"))
    assert code == 0 and "9 of 9" in text and "too close" not in text, text
    code, doc, err = calibrate_json(out)
    assert code == 0, err
    accel = doc["calibration"]["accel"]
    assert accel["solver"] == "gravity" and accel["coverage"]["n_distinct"] == 9


@pytest.mark.slow
def test_guided_ferraris_capture_calibrates(tmp_path):
    out, code, text = served_and_captured(tmp_path, "ferraris", "ferraris",
                                          ("--seed", "1", "--hold", "3", "--move", "1"))
    assert code == 0 and "12 of 12" in text, text
    session = read_session(out)
    known = [s for s in session.rotation_segments() if s.angle_deg is not None]
    assert [s.angle_deg for s in known] == [-360.0] * 3
    assert [s.label[-6:] for s in known] == ["x_rot)", "y_rot)", "z_rot)"]
    code, doc, err = calibrate_json(out)
    assert code == 0, err
    assert doc["calibration"]["accel"]["solver"] == "labelled"
    assert doc["complete"] == (not doc["left_out"])


def test_capture_warns_about_options_for_a_sensor_the_device_does_not_send(tmp_path):
    """The device in a thread and the capture in this process (what is examined is the
    capture's exit status and stderr, the same in a process)."""
    server = ThreadServer("--rate", "100", "--plan", "six", "--loop")  # until stopped below
    out = tmp_path / "w.h5"
    try:
        proc = run("capture", "--port", server.path, "--no-prompt", "--duration", "1",
                   "--mag-units", "uT", "--field-uT", "48", "--output", out)  # fmt: skip
    finally:
        server.stop()
    stdout, stderr = proc.stdout, proc.stderr
    assert proc.returncode == 0, (stdout, stderr)
    assert ("imucal: warning: --mag-units, --field-uT: the device sent no magnetometer data "
            "(the session has no /raw/mag): ignored") in stderr  # fmt: skip
    assert read_session(out).mag is None
