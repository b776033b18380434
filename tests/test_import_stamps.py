"""Issue 26: time stamps and lost samples as the writers leave them.

- One repeated ``header.stamp`` (ROS, written by rosbags) or ``time_usec`` (MAVLink, written by
  pymavlink) no longer switches the whole recording to receive time: the sample is left out
  (counted), the device's time kept, and a telemetry log keeps its ``/raw/host_time``.
- WitMotion: a sample whose angular-velocity frame is missing is left out with a warning
  instead of the whole gyro.
- A 2 s gap inside a turn is reported at import, and calibrate leaves that turn out saying why.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.formats.importers import import_files
from imucal_cli.formats.importers.mavlink import read_mavlink
from imucal_cli.formats.importers.ros import read_ros
from imucal_cli.formats.importers.witmotion import read_witmotion
from imucal_cli.formats.session import read_session

from .cli_helpers import run
from .test_import_formats import samples, wit_frame, write_bag


@pytest.mark.parametrize("kind", ["ros1", "ros2"])
def test_one_repeated_header_stamp_keeps_the_device_time(tmp_path, kind):
    t, a, w = samples()
    t = t.copy()
    t[100] = t[99]  # the driver stamped two messages alike
    path = tmp_path / ("rec.bag" if kind == "ros1" else "rec")
    write_bag(path, kind, mag=False, temp=False, data=(t, a, w))
    ch = read_ros(path)
    assert ch.notes[-1].startswith("time from header.stamp (1 messages")
    keep = np.delete(np.arange(len(t)), 100)
    np.testing.assert_allclose(ch.time, t[keep], rtol=0, atol=1e-6)  # not the receive time
    np.testing.assert_array_equal(ch.accel, a[keep])
    assert ch.dropped == 1


def test_the_rule_between_device_and_receive_time():
    from imucal_cli.formats.importers.recording import choose_time, increasing

    device = 10.0 + np.arange(1000) * 0.005
    received = device + 0.003
    finite = np.ones(1000, bool)
    repeated = device.copy()
    repeated[[100, 500]] = repeated[[99, 499]]
    assert choose_time(repeated, received, finite)[1:] == (True, 2)
    coarse = np.floor(device * 20) / 20  # a 20 Hz stamp clock for 200 Hz samples
    time, use, _ = choose_time(coarse, received, finite)
    assert not use and time is received
    restart = np.r_[device[:500], device[:500]]  # the device rebooted half way
    assert not choose_time(restart, received, finite)[1]
    unset = device.copy()
    unset[0] = 0.0  # one unset stamp is left out like a repeated one
    assert choose_time(unset, received, finite)[1:] == (True, 1)
    assert not choose_time(np.zeros(1000), received, finite)[1]  # no stamps: receive time
    spike = device.copy()
    spike[3] = 1e9  # a damaged stamp far ahead: the one sample, not all after it
    time, use, left_out = choose_time(spike, received, finite)
    assert use and left_out == 1
    assert np.count_nonzero(increasing(time, finite)) == 999  # what the readers keep
    gap = np.r_[device[:500], device[500:] + 60.0]  # a minute's pause is no spike: all kept
    time, use, left_out = choose_time(gap, gap + 0.003, finite)
    assert use and left_out == 0 and np.count_nonzero(increasing(time, finite)) == 1000


def test_one_repeated_time_usec_keeps_the_device_time_and_host_time(tmp_path):
    from .mavlink_fixture import EPOCH_US, TlogWriter

    rng = np.random.default_rng(1)
    acc, gyr = rng.integers(-16000, 16000, (80, 3)), rng.integers(-3000, 3000, (80, 3))
    writer = TlogWriter()
    t_us = 2_000_000 + 20_000 * np.arange(80)
    t_us[40] = t_us[39]  # the autopilot sent one time_usec twice
    received = EPOCH_US + 2_000_000 + 20_000 * np.arange(80) + 1500
    for k in range(80):
        writer.add(int(received[k]), "raw_imu", int(t_us[k]), *acc[k], *gyr[k], 0, 0, 0, 0,
                   2534)  # fmt: skip
    path = writer.write(tmp_path / "r.tlog")
    ch = read_mavlink(path)
    keep = np.delete(np.arange(80), 40)
    np.testing.assert_allclose(ch.time, t_us[keep] * 1e-6, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ch.host_time, received[keep] * 1e-6, rtol=0, atol=2e-6)
    np.testing.assert_array_equal(ch.accel, acc[keep])
    assert ch.dropped == 1 and "1 messages whose time_usec did not follow" in ch.notes[1]


def test_witmotion_keeps_the_gyro_when_one_frame_is_missing(tmp_path):
    rng = np.random.default_rng(5)
    n = 1500
    acc, gyr = rng.integers(-30000, 30000, (n, 3)), rng.integers(-30000, 30000, (n, 3))
    frames = []
    for i in range(n):
        frames.append(wit_frame(0x51, [*acc[i], 2500]))
        if i != 700:  # one angular-velocity frame lost
            frames.append(wit_frame(0x52, [*gyr[i], 0]))
    data = b"".join(frames)
    path = tmp_path / "wit.bin"
    path.write_bytes(data[:-5])  # and the log cut inside the last sample's gyro frame
    rec = read_witmotion(path, rate_hz=100.0)
    keep = np.delete(np.arange(n), [700, n - 1])
    np.testing.assert_array_equal(rec.gyro, gyr[keep])
    np.testing.assert_array_equal(rec.accel, acc[keep])
    np.testing.assert_allclose(rec.time, keep / 100.0)  # the gap stays where it was
    assert rec.warnings == [f"2 of {n} samples had no angular-velocity frame (0x52; a frame lost "
                            "or the log cut): left out, accelerometer too"]  # fmt: skip
    out = tmp_path / "wit.h5"
    proc = run("import", path, "-o", out, "--rate", "100", "--json", "--format", "witmotion",
               "--sections", _one_section(tmp_path, n - 2))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert rec.warnings[0] in json.loads(proc.stdout)["warnings"]


def _one_section(tmp_path: Path, n: int) -> Path:
    path = tmp_path / "sections.json"
    path.write_text(json.dumps({"z_p": {"start": 0, "end": n}}))
    return path


@pytest.fixture(scope="module")
def gap_recording(tmp_path_factory):
    """Nine slow hand turns (three per axis, 6 to 14 s each) recorded at 100 Hz, written as CSV
    with 2 s of samples missing in the middle of the third turn; the truth calibration."""
    folder = tmp_path_factory.mktemp("gap")
    session = folder / "qa.h5"
    proc = run("simulate", "--plan", "qureshi-axes:3", "--peak-rate", "30", "--seed", "4",
               "-o", session)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    s = read_session(session)
    turn = s.rotation_segments()[2]
    mid = (turn.start + turn.stop) // 2
    keep = np.r_[0 : mid - 100, mid + 100 : len(s.time)]
    path = folder / "gap.csv"
    np.savetxt(path, np.column_stack([s.time, s.accel, s.gyro])[keep], delimiter=",",
               header="t,ax,ay,az,gx,gy,gz", comments="", fmt="%.6f")  # fmt: skip
    return path, session.with_name("qa.truth.json"), float(s.time[mid - 101])


def test_a_gap_inside_a_turn_is_reported_at_import_and_left_out_by_calibrate(gap_recording,
                                                                            tmp_path):  # fmt: skip
    path, truth, at = gap_recording
    session = import_files([path], "csv", accel_units="counts", gyro_units="counts")
    found = [w for w in session.import_warnings if w.startswith("rotation segment")]
    assert len(found) == 1 and f"a gap of 2.01 s after {at:.6g} s" in found[0]
    out = tmp_path / "gap.h5"
    proc = run("import", path, "-o", out, "--accel-units", "counts", "--gyro-units", "counts")
    assert proc.returncode == 0 and found[0] in proc.stdout
    proc = run("calibrate", out, "--accel", truth, "-o", tmp_path / "c.json", "--no-store")
    assert proc.returncode == 0, proc.stderr
    assert "1 rotation(s) have a gap in their samples" in proc.stdout
    assert f"(2.01 s at {at:.6g} s)" in proc.stdout


def test_no_gap_no_warning(tmp_path):
    src = Path(__file__).resolve().parents[1] / "sessions" / "six-seed3.h5"
    shutil.copy(src, tmp_path / "s.h5")
    s = read_session(tmp_path / "s.h5")
    path = tmp_path / "s.csv"
    np.savetxt(path, np.column_stack([s.time, s.accel, s.gyro]), delimiter=",",
               header="t,ax,ay,az,gx,gy,gz", comments="", fmt="%.6f")  # fmt: skip
    assert import_files([path], "csv").import_warnings == []
