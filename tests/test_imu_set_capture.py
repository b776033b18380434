"""Issue 28.1/28.3: capturing several IMUs through the virtual serial port: ``simulate --serve
--imus N`` (every IMU's triads on each line) into ``capture --columns ...,ax.1,...``, and one
port per IMU (``--serve-imu K``) into ``capture --port A --port B``; the sessions calibrate to
the simulated set's rotations (and, on one line, its time offsets)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal_cli.formats.session import read_session
from imucal_cli.simulate.imu_set import gauge_rotation, served_set

from .cli_helpers import run
from .served import ThreadServer
from .test_virtual import CLI, RATE, process_factory, saved_samples, start_capture  # noqa: F401

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")

# 460800 baud carries three IMUs' 96-byte lines at 200 Hz (115200 ran them at 60 % pace)
SET = ("--plan", "random:9", "--seed", "4", "--hold", "1.6", "--move", "0.7",
       "--imu-offset", "8", "--baud", "460800")  # fmt: skip
COLUMNS = ("t,ax,ay,az,gx,gy,gz,temp,ax.1,ay.1,az.1,gx.1,gy.1,gz.1,"
           "ax.2,ay.2,az.2,gx.2,gy.2,gz.2")  # fmt: skip


def _truth(imus: int):
    _, truth = served_set("random:9", imus, seed=4, rate_hz=RATE, hold_s=1.6, move_s=0.7,
                          max_offset_s=0.008)  # fmt: skip
    return truth


def _rotation_error(truth, key, entry) -> np.ndarray:
    q0 = gauge_rotation(np.array(truth.accel.matrix))
    want = truth.to_dict()["imus"][key]
    true_r = q0.T @ np.array(want["rotation_to_reference"]) @ gauge_rotation(
        np.array(want["accel"]["matrix"]))  # fmt: skip
    return Rotation.from_matrix(np.array(entry["rotation_to_reference"]) @ true_r.T).as_rotvec()


# 25 s of CPU and a served plan in make test; its path is the first capture of
# test_imu_set_resume's test_one_line_of_several_imus_is_resumed (the same served set, columns
# and units through one port), which checks the same rotations and time offsets, the units and
# one time stamp per line, after it is resumed to complete: here in make test-all
@pytest.mark.slow
def test_one_port_several_triads_per_line(tmp_path, process_factory):  # noqa: F811
    """Several IMUs' triads on one line, captured uninterrupted: each IMU's rotation and time
    offset calibrated within their bounds. Redundant in ``make test`` with
    ``test_imu_set_resume.py::test_one_line_of_several_imus_is_resumed``."""
    server = process_factory("--imus", "3", *SET)
    out = tmp_path / "array.h5"
    cap = start_capture(server.path, out, "--plan", "random:9", "--columns", COLUMNS,
                        "--accel-units", "counts", "--gyro-units", "counts")  # fmt: skip
    stdout, stderr = cap.communicate(timeout=300)
    sent = server.finish()
    assert cap.returncode == 0, stderr
    session = read_session(out)
    assert list(session.imus) == ["imu1", "imu2"]
    n = saved_samples(stdout)
    assert len(session.time) == n and sent["lines"] >= n
    for imu in session.imus.values():
        np.testing.assert_array_equal(imu.time, session.time)  # one line, one time stamp
        assert imu.accel_units == "counts" or imu.accel_units is None
    proc = run("calibrate", out, "--json", "--no-store")
    assert proc.returncode == 0, proc.stderr
    cal = json.loads(proc.stdout)["calibration"]
    truth = _truth(3)
    for key, entry in cal["imus"].items():
        err = _rotation_error(truth, key, entry)
        assert np.all(np.abs(err) <= 4.5 * np.radians(entry["rotation_std_deg"])), (key, err)
        dt = entry["time_offset_s"] - truth.to_dict()["imus"][key]["time_offset_s"]
        assert abs(dt) <= 4.5 * entry["time_offset_std_s"], (key, dt, entry)


def test_one_port_per_imu(tmp_path):
    """Two devices, one IMU each, served in threads here (tests/served.py: the command's set
    options; ``simulate --serve --imus`` as a process: test_imu_set_resume)."""
    servers = [ThreadServer("--rate", str(RATE), "--imus", "2", "--serve-imu", str(k), *SET)
               for k in (0, 1)]  # fmt: skip
    out = tmp_path / "two.h5"
    cap = subprocess.Popen(
        [*CLI, "capture", "--port", servers[0].path, "--port", servers[1].path, "--output",
         str(out), "--no-prompt", "--plan", "random:9", "--json"],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout, stderr = cap.communicate(timeout=300)
    for s in servers:
        s.finish()
    assert cap.returncode == 0, stderr
    session = read_session(out)
    assert list(session.imus) == ["imu1"]
    assert session.imus["imu1"].sensor == f"serial:{servers[1].path}@115200"
    assert abs(len(session.imus["imu1"].time) - len(session.time)) < 0.05 * len(session.time)
    proc = run("calibrate", out, "--json", "--no-store")
    assert proc.returncode == 0, proc.stderr
    entry = json.loads(proc.stdout)["calibration"]["imus"]["imu1"]
    err = _rotation_error(_truth(2), "imu1", entry)  # the frames do not depend on the clocks
    assert np.all(np.abs(err) <= 4.5 * np.radians(entry["rotation_std_deg"])), err
    # two devices, two clocks: put on one by their first arrival, the rest measured
    assert abs(entry["time_offset_s"]) < 0.2


def test_capture_refuses_what_a_set_does_not_take(tmp_path):
    proc = run("capture", "--port", "/dev/null", "--port", "/dev/null", "--no-prompt",
               "--duration", "1", "-o", tmp_path / "x.h5")  # fmt: skip
    assert proc.returncode == 2 and "same port twice" in proc.stderr
    proc = run("capture", "--port", "/dev/null", "--no-prompt", "--duration", "1", "--columns",
               "t,ax,ay,az,ax.1,ay.1,az.1", "--protocol", "witmotion", "-o", tmp_path / "x.h5")
    assert proc.returncode == 2 and "lines of numbers" in proc.stderr
