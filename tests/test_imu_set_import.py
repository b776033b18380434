"""Issue 28.1: ``imucal import`` brings every IMU of a log into one session, each with its own
time stamps: PX4 ULog (every sensor_accel/sensor_gyro instance), ROS (several Imu topics,
rosbags' writer), DataFlash (IMU, IMU.1, IMU.2) and MAVLink telemetry (RAW_IMU, SCALED_IMU2/3)
written by pymavlink, and CSV with several triads per line.  The files hold a simulated set;
one is calibrated after import and gives back the set's time offsets and rotations."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.importers import import_files
from imucal_cli.formats.importers.imu_set import set_streams
from imucal_cli.formats.session import read_session
from imucal_cli.simulate.imu_set import gauge_rotation, simulate_set

from .cli_helpers import run
from .mavlink_fixture import EPOCH_US, DataFlashWriter, TlogWriter, imu_row
from .test_import_formats import ulog_columns
from .ulog_fixture import SENSOR_FIELDS, write_ulog

CREATED = "2026-01-01T00:00:00Z"


@pytest.fixture(scope="module")
def three():
    """A set of 3 IMUs in SI units (no quantisation), 10 poses: each IMU's (time, accel, gyro)."""
    session, truth = simulate_set(3, plan="random:10", seed=5, units="m/s^2", created=CREATED)
    streams = [(session.time, session.accel, session.gyro)]
    streams += [(i.time, i.accel, i.gyro) for i in session.imus.values()]
    return streams, truth


@pytest.fixture(scope="module")
def three_head(three):
    """The set's first :data:`HEAD_S` s (each IMU's own rate and clock offset, the streams
    interleaved as in the whole): for the importers' checks, which compare every sample and
    offset and hold for any length; writing each of the whole set's 17,000 messages through
    a Python log writer took 2-3 s per format. The calibration after import uses the whole."""
    streams, truth = three
    return [(t[t < HEAD_S], a[t < HEAD_S], g[t < HEAD_S]) for t, a, g in streams], truth


HEAD_S = 8.0
"""Seconds of the set (of 34.5) the importers' checks write."""


def _us(t: np.ndarray) -> np.ndarray:
    return np.round(1e6 + t * 1e6).astype(np.uint64)


def _check(session, streams, names, atol_t=1e-6, rtol=1e-6, scale=(1.0, 1.0)):
    assert [session.reference_name, *session.imus] == names
    got = [(session.time, session.accel, session.gyro)]
    got += [(i.time, i.accel, i.gyro) for i in session.imus.values()]
    for (t, a, g), (t2, a2, g2) in zip(streams, got, strict=True):
        assert len(t2) == len(t)  # every sample, none resampled
        np.testing.assert_allclose(t2 - t2[0], t - t[0], atol=atol_t)
        np.testing.assert_allclose(a2 * scale[0], a, rtol=rtol, atol=1e-3 * scale[0])
        np.testing.assert_allclose(g2 * scale[1], g, rtol=rtol, atol=1e-3 * scale[1])
    offsets = [i.time[0] - session.time[0] for i in session.imus.values()]
    want = [s[0][0] - streams[0][0][0] for s in streams[1:]]
    np.testing.assert_allclose(offsets, want, atol=atol_t)  # one clock for every IMU


def _ulog(path, streams):
    topics = []
    for k, (t, a, g) in enumerate(streams):
        t_us = _us(t)
        topics += [("sensor_accel", k, SENSOR_FIELDS, ulog_columns(t_us, a.astype(np.float32),
                                                                   100 + k)),
                   ("sensor_gyro", k, SENSOR_FIELDS, ulog_columns(t_us, g.astype(np.float32),
                                                                  200 + k))]  # fmt: skip
    write_ulog(path, topics)
    return path


def test_ulog_instances_become_one_session_and_calibrate_as_a_set(three, tmp_path):
    streams, truth = three
    path = _ulog(tmp_path / "px4.ulg", streams)
    session = import_files([path], "ulog")
    _check(session, streams, ["sensor_accel.0", "sensor_accel.1", "sensor_accel.2"])
    assert any("3 IMUs" in n for n in session.import_notes)
    single = import_files([path], "ulog", topic="sensor_accel.1")  # --topic: one IMU, as before
    assert single.imus == {} and len(single.time) == len(streams[1][0])
    # the user's path: import, calibrate; the set's time offsets come back
    out = tmp_path / "px4.h5"
    proc = run("import", path, "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "3 IMUs" in proc.stdout
    proc = run("calibrate", out, "--json", "--no-store")
    assert proc.returncode == 0, proc.stderr
    cal = json.loads(proc.stdout)["calibration"]
    for name, true_name in (("sensor_accel.1", "imu1"), ("sensor_accel.2", "imu2")):
        entry, want = cal["imus"][name], truth.to_dict()["imus"][true_name]
        err = entry["time_offset_s"] - want["time_offset_s"]
        # the float32 values round the signal by ~1e-7 relative: far below the noise
        assert abs(err) <= 4.5 * entry["time_offset_std_s"], (name, err, entry)
        # the rotation between the calibrated frames (the gravity solver's: each IMU's own
        # axes), the truth's mounting seen through each one's gauge
        q0 = gauge_rotation(np.array(truth.accel.matrix))
        qk = gauge_rotation(np.array(want["accel"]["matrix"]))
        true_r = q0.T @ np.array(want["rotation_to_reference"]) @ qk
        err = Rotation.from_matrix(np.array(entry["rotation_to_reference"]) @ true_r.T)
        assert np.all(np.abs(err.as_rotvec()) <= 4.5 * np.radians(entry["rotation_std_deg"]))


def _bag(path, streams, topics):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    rows = []
    for (t, a, g), topic in zip(streams, topics, strict=True):
        rows += [(1.7e9 + t[i], topic, a[i], g[i]) for i in range(len(t))]
    rows.sort(key=lambda r: r[0])
    with Writer(path) as writer:
        conns = {name: writer.add_connection(name, "sensor_msgs/msg/Imu", typestore=ts)
                 for name in topics}  # fmt: skip
        for stamp, topic, a, g in rows:
            sec = int(stamp)
            header = T["std_msgs/msg/Header"](T["builtin_interfaces/msg/Time"](
                sec, int(round((stamp - sec) * 1e9))), "imu")  # fmt: skip
            v3, q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
            msg = T["sensor_msgs/msg/Imu"](header, q(0.0, 0.0, 0.0, 1.0), np.zeros(9), v3(*g),
                                           np.zeros(9), v3(*a), np.zeros(9))  # fmt: skip
            writer.write(conns[topic], int(stamp * 1e9) + 3_000_000,
                         ts.serialize_ros1(msg, "sensor_msgs/msg/Imu"))  # fmt: skip
    return path


def test_ros_imu_topics_become_one_session(three_head, tmp_path):
    streams, _ = three_head
    topics = ["/imu0/data", "/imu1/data", "/imu2/data"]
    path = _bag(tmp_path / "robot.bag", streams, topics)
    session = import_files([path], "ros")
    _check(session, streams, ["imu0_data", "imu1_data", "imu2_data"], atol_t=2e-6)


def test_dataflash_imu_instances_become_one_session(three_head, tmp_path):
    streams, _ = three_head
    writer = DataFlashWriter()
    writer.add("MSG", [0, "ArduCopter V4.5.0"])
    rows = []
    for k, (t, a, g) in enumerate(streams):
        rows += [(int(u), k, a[i], g[i]) for i, u in enumerate(_us(t))]
    for t_us, k, a, g in sorted(rows, key=lambda r: r[0]):
        writer.add("IMU", imu_row(t_us, k, a.astype(np.float32), g.astype(np.float32), 30.0))
    path = writer.write(tmp_path / "00000001.BIN")
    session = import_files([path], "mavlink")
    _check(session, streams, ["IMU.0", "IMU.1", "IMU.2"])
    assert session.imus["IMU.2"].accel_units == "m/s^2"


def test_telemetry_raw_imu_and_scaled_imu2_3_become_one_session(three_head, tmp_path):
    """ArduPilot streams IMU 1 as RAW_IMU and IMUs 2 and 3 as SCALED_IMU2/3 (mG, mrad/s);
    the log also holds HIGHRES_IMU (IMU 1 again), which is not another IMU."""
    streams, _ = three_head
    writer = TlogWriter()
    rows = []
    for k, (t, a, g) in enumerate(streams):
        mg = np.round(a / 9.80665 * 1000).astype(int)
        mrad = np.round(g * 1000).astype(int)
        rows += [(int(u), k, mg[i], mrad[i]) for i, u in enumerate(_us(t))]
    for t_us, k, mg, mrad in sorted(rows, key=lambda r: r[0]):
        recv = EPOCH_US + t_us + 1500
        if k == 0:
            writer.add(recv, "raw_imu", t_us, *mg, *mrad, 0, 0, 0, 0, 2500)
            writer.add(recv + 5, "highres_imu", t_us, *(mg * 9.80665e-3), *(mrad * 1e-3),
                       0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 30.0, 0x1FFF, 0)  # fmt: skip
        else:
            message = "scaled_imu2" if k == 1 else "scaled_imu3"
            writer.add(recv, message, t_us // 1000, *mg, *mrad, 0, 0, 0, 2600)
    path = writer.write(tmp_path / "flight.tlog")
    session = import_files([path], "mavlink")
    assert [session.reference_name, *session.imus] == ["RAW_IMU.0", "SCALED_IMU2", "SCALED_IMU3"]
    assert session.accel_units == "counts" and session.imus["SCALED_IMU2"].accel_units == "g"
    assert len(session.imus["SCALED_IMU3"].time) == len(streams[2][0])
    # SCALED_IMU2/3 stamp in ms: their own time, to the millisecond
    np.testing.assert_allclose(session.imus["SCALED_IMU2"].time - 1.0, streams[1][0], atol=1e-3)
    np.testing.assert_allclose(session.imus["SCALED_IMU2"].gyro,
                               np.round(streams[1][2] * 1000) / 1000, atol=1e-12)


def test_csv_with_several_triads_per_line(tmp_path):
    session, _ = simulate_set(2, plan="random:10", seed=3, units="m/s^2", created=CREATED,
                              synchronous=True)  # fmt: skip
    imu = session.imus["imu1"]
    lines = ["t,ax,ay,az,gx,gy,gz,ax.1,ay.1,az.1,gx.1,gy.1,gz.1"]
    table = np.column_stack([session.time, session.accel, session.gyro, imu.accel, imu.gyro])
    lines += [",".join(f"{v:.9g}" for v in row) for row in table]
    path = tmp_path / "array.csv"
    path.write_text("\n".join(lines) + "\n")
    got = import_files([path], "csv")  # the header names both
    streams = [(session.time, session.accel, session.gyro), (imu.time, imu.accel, imu.gyro)]
    _check(got, streams, ["reference", "imu1"])
    spec = "t,ax,ay,az,gx,gy,gz,ax.1,ay.1,az.1,gx.1,gy.1,gz.1"
    got = import_files([path], "csv", columns=spec, skip_rows=1)
    _check(got, streams, ["reference", "imu1"])
    # its own time column t.1: its own stamps
    own = np.column_stack([table, imu.time + 0.0042])
    path.write_text("\n".join(",".join(f"{v:.9g}" for v in r) for r in own) + "\n")
    got = import_files([path], "csv", columns=spec + ",t.1")
    np.testing.assert_allclose(got.imus["imu1"].time - got.time, 0.0042, atol=1e-9)
    with pytest.raises(InputError, match="IMUs are numbered 1 to"):
        import_files([path], "csv", columns=spec.replace(".1", ".0"))


def test_the_set_is_one_stream_per_imu():
    assert set_streams(["HIGHRES_IMU.0", "RAW_IMU.0", "RAW_IMU.1", "SCALED_IMU2"]) == \
        ["RAW_IMU.0", "RAW_IMU.1"]
    assert set_streams(["SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"]) == \
        ["SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"]
    assert set_streams(["IMU.0", "IMU.1", "ACC.0"]) == ["IMU.0", "IMU.1"]
    assert set_streams(["IMU.0", "ISB.0"]) == []  # one IMU logged two ways
    assert set_streams(["RAW_IMU@1/1", "RAW_IMU@2/1"]) == []  # two vehicles: no set
    assert set_streams(["/a/imu", "/b/imu"]) == ["/a/imu", "/b/imu"]


def test_an_imported_set_is_written_and_read_back(three, tmp_path):
    streams, _ = three
    path = _ulog(tmp_path / "px4.ulg", streams)
    out = tmp_path / "set.h5"
    proc = run("import", path, "-o", out)
    assert proc.returncode == 0, proc.stderr
    back = read_session(out)
    _check(back, streams, ["sensor_accel.0", "sensor_accel.1", "sensor_accel.2"])
