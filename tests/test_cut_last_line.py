"""A text recording whose writer stopped mid-line (killed, power lost, the disk full) ends with
a line without its line break, and the number it stops in still reads as a number (``-9.8`` of
``-9.81234``).  Every text reader drops that last line with a one-line warning naming it
(:func:`imucal_cli.formats.importers.text_scan.cut_line_start`): ``import`` of a CSV, an imu_tk
pair, MotionCal lines and a DataFlash text log, and ``apply`` of a CSV; a capture never makes
a sample of the part of a line the port gave before it closed."""

from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest

from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.session import read_session
from imucal_cli.simulate.triad import simulate

from .cli_helpers import LineReader, run, spawn


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A simulated session (counts, 6250 samples) and its truth calibration file."""
    session, truth = simulate(seed=7, created="2026-01-01T00:00:00Z")
    folder = tmp_path_factory.mktemp("cut")
    write_calibration(folder / "truth.json", truth)
    return session, folder / "truth.json"


def csv_lines(session) -> list[str]:
    """The session as CSV rows (every float as repr: read back exactly)."""
    data = np.column_stack([session.time, session.accel, session.gyro])
    return [",".join(repr(float(v)) for v in row) for row in data]


def cut_in_last_number(text: str, keep: int = 1) -> str:
    """``text`` without its final line break, cut ``keep`` characters into the last line's
    last number (as a writer killed mid-number leaves it)."""
    body = text.rstrip("\n")
    start = body.rfind(",") + 1
    assert len(body) - start > keep + 1  # the cut number is a shorter, different number
    return body[: start + keep]


def import_json(*args) -> dict:
    proc = run("import", *args, "--json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def cut_warnings(result: dict) -> list[str]:
    return [w for w in result["warnings"] if "no line break" in w]


def test_csv_cut_inside_its_last_number_drops_that_line(sim, tmp_path):
    session, _ = sim
    rows = csv_lines(session)
    whole = "t,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n"
    path = tmp_path / "cut.csv"
    path.write_text(cut_in_last_number(whole))
    got = import_json(path, "-o", tmp_path / "cut.h5")
    n = len(rows)
    assert got["samples"] == n - 1
    assert got["skipped_lines"]["malformed"] == 0  # dropped as cut, not counted malformed
    (warning,) = cut_warnings(got)
    assert warning.startswith(f"{path}:{n + 1}:") and "\n" not in warning  # header is line 1
    back = read_session(tmp_path / "cut.h5")
    np.testing.assert_array_equal(back.gyro[-1], session.gyro[-2])  # the last whole line
    np.testing.assert_array_equal(back.time, session.time[:-1])
    proc = run("import", path, "-o", tmp_path / "said.h5", "--force")  # people see it too
    assert f"warning: {path}:{n + 1}: the last line has no line break" in proc.stdout


@pytest.mark.parametrize(("ending", "kept"), [("\n", True), ("\r\n", True), ("\r", True),
                                              ("", False)])  # fmt: skip
def test_a_last_line_is_whole_when_its_line_break_is(sim, tmp_path, ending, kept):
    """With its break (LF, CR LF, or the CR of a CR LF cut before the LF) the last line is
    kept; without one it is dropped, even though nothing in it looks cut."""
    session, _ = sim
    rows = csv_lines(session)
    path = tmp_path / "in.csv"
    sep = "\r\n" if ending.startswith("\r") else "\n"
    path.write_text("t,ax,ay,az,gx,gy,gz" + sep + sep.join(rows) + ending, newline="")
    got = import_json(path, "-o", tmp_path / "in.h5")
    assert got["samples"] == len(rows) - (0 if kept else 1)
    assert len(cut_warnings(got)) == (0 if kept else 1)


def test_imu_tk_pair_with_its_gyro_file_cut(sim, tmp_path):
    session, _ = sim
    acc, gyr = tmp_path / "acc.txt", tmp_path / "gyr.txt"
    t = [repr(float(v)) for v in session.time]
    acc.write_text("".join(f"{t[k]} " + " ".join(repr(float(v)) for v in session.accel[k])
                           + "\n" for k in range(len(t))))  # fmt: skip
    gyr_text = "".join(f"{t[k]}\t" + "\t".join(repr(float(v)) for v in session.gyro[k]) + "\n"
                       for k in range(len(t)))  # fmt: skip
    gyr.write_text(gyr_text.rstrip("\n")[:-4])
    got = import_json("--format", "imu_tk", acc, gyr, "-o", tmp_path / "tk.h5")
    assert got["samples"] == len(t) - 1 and got["skipped_lines"]["unmatched"] == 1
    (warning,) = cut_warnings(got)
    assert warning.startswith(f"{gyr}:{len(t)}:")


def test_motioncal_lines_cut_in_the_last_count(sim, tmp_path):
    session, _ = sim
    accel, gyro = session.accel.astype(int), session.gyro.astype(int)  # counts
    lines = ["MotionCal sketch ready"] + [
        "Raw:" + ",".join(map(str, (*accel[k], *gyro[k], 100, -200, 30000)))
        for k in range(len(accel))]  # fmt: skip
    path = tmp_path / "mc.txt"
    path.write_text("\n".join(lines)[:-3])  # "30000" cut to "30": still nine numbers
    got = import_json(path, "--rate", "100", "-o", tmp_path / "mc.h5")
    assert got["samples"] == len(accel) - 1
    (warning,) = cut_warnings(got)
    assert warning.startswith(f"{path}:{len(lines)}:")
    back = read_session(tmp_path / "mc.h5")
    np.testing.assert_array_equal(back.mag[-1], [100, -200, 30000])


def test_dataflash_text_log_cut_in_the_last_gyro_value(tmp_path):
    from imucal_cli.simulate.device import stream_arrays
    from tests.mavlink_fixture import DataFlashWriter

    t, a, g = stream_arrays("six", rate_hz=100.0, hold_s=1.5, move_s=1.0)
    writer = DataFlashWriter()
    writer.add("MSG", [0, "ArduCopter V4.5.0"])
    t_us = np.round((t - t[0]) * 1e6 + 1e6).astype(np.int64)
    acc, gyr = (a / 835.0).astype(np.float32), (g / 939.7).astype(np.float32)
    gyr[-1, 2] = 0.0312345  # the last GYR line ends in a number long enough to cut
    for k in range(len(t)):
        writer.add("ACC", [int(t_us[k]) + 300, 0, int(t_us[k]), *map(float, acc[k])])
        writer.add("GYR", [int(t_us[k]) + 300, 0, int(t_us[k]), *map(float, gyr[k])])
    path = tmp_path / "acc_gyr.log"
    path.write_text(writer.text()[:-6])  # "...0.0312345\n" cut to "...0.031"
    got = import_json(path, "-o", tmp_path / "df.h5")
    assert got["samples"] == len(t) - 1
    (warning,) = cut_warnings(got)
    assert warning.startswith(f"{path}:{len(writer.lines)}:")
    back = read_session(tmp_path / "df.h5")
    np.testing.assert_allclose(back.gyro[-1], gyr[-2], rtol=1e-6)


def test_apply_drops_the_cut_last_line_of_a_csv(sim, tmp_path):
    session, cal = sim
    rows = csv_lines(session)
    path = tmp_path / "in.csv"
    path.write_text(cut_in_last_number("t,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n"))
    proc = run("apply", cal, path, "-o", tmp_path / "o.h5", "--json")
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    assert got["samples"] == len(rows) - 1 and got["malformed"] == 0
    (warning,) = cut_warnings(got)
    assert warning.startswith(f"in.csv:{len(rows) + 1}: the last line has no line break")
    proc = run("apply", cal, path, "-o", tmp_path / "o.csv")
    assert proc.returncode == 0, proc.stderr
    assert f"warning: in.csv:{len(rows) + 1}: the last line has no line break" in proc.stdout
    data = np.loadtxt(tmp_path / "o.csv", delimiter=",", skiprows=2)
    np.testing.assert_array_equal(data[:, 0], session.time[:-1])


@pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")
def test_capture_makes_no_sample_of_a_line_cut_when_the_port_closes(tmp_path):
    """The device writes whole lines, then half of one, and is gone: the session holds the
    whole lines' samples, the last of them as sent."""
    import fcntl
    import pty
    import struct
    import subprocess
    import termios
    import time

    master, slave = pty.openpty()
    port = os.ttyname(slave)
    out = tmp_path / "cap.h5"
    cap = spawn([sys.executable, "-m", "imucal_cli", "capture", "--port", port, "--output",
                 str(out), "--no-prompt", "--duration", "60", "--columns", "t,ax,ay,az,gx,gy,gz",
                 "--json"], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        LineReader(cap.stderr).wait_for(lambda line: "waiting for data on" in line)
        rows = [f"{k / 100:.2f},0.01,-0.02,9.81,0.001,0.002,-0.003\n" for k in range(300)]
        os.write(master, "".join(rows).encode() + b"3.00,0.01,-0.02,9.8")  # cut: az 9.81
        waiting = True
        deadline = time.monotonic() + 60
        while waiting and time.monotonic() < deadline:  # until the capture has read it all
            waiting = struct.unpack("i", fcntl.ioctl(slave, termios.FIONREAD, b"\0" * 4))[0]
            time.sleep(0.02)  # polling the port's queue, not waiting a fixed time
        assert not waiting, "the capture did not read the port"
    finally:
        os.close(slave)
        os.close(master)  # the device is gone
    stdout, stderr = cap.communicate(timeout=120)
    got = json.loads(stdout)
    assert got["end"] == "device-gone", (got, stderr)
    back = read_session(out)
    assert len(back.time) == got["samples"] == 300
    np.testing.assert_allclose(back.time[-1], 2.99)
    np.testing.assert_allclose(back.accel[:, 2], 9.81)
