"""Issue 26: PX4 logs as PX4 writes them (ULog files written to the ULog specification with the
uORB message layouts of PX4-Autopilot's msg/*.msg, read with pyulog): the full-rate FIFO topics
with their scale, vehicle_imu and sensor_combined, the rawest usable one by default; a 1 Hz log
read with a warning; unpaired samples called unpaired; the magnetometer picked with
--mag-topic (ULog, ROS)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.importers.ros import read_ros
from imucal_cli.formats.importers.ulog import read_ulog

from .cli_helpers import run
from .test_import_formats import samples, ulog_columns
from .ulog_fixture import (
    FIFO_FIELDS,
    MAG_FIELDS,
    SENSOR_COMBINED_FIELDS,
    SENSOR_FIELDS,
    VEHICLE_IMU_FIELDS,
    write_ulog,
)

pytest.importorskip("pyulog")

T0 = 5_000_000  # us since boot


def fifo_topic(rng, n_msgs: int, dt_us: float, scale: float, offset_us: int = 0):
    """Messages of 4 to 8 FIFO samples each, ``dt_us`` apart; the samples' times (s) and SI
    values."""
    counts = rng.integers(4, 9, n_msgs)
    ends = T0 + offset_us + np.cumsum(counts) * dt_us
    raw = rng.integers(-20000, 20000, (n_msgs, 32, 3)).astype(np.int16)
    cols = {"timestamp": (ends + 300).astype(np.uint64),
            "timestamp_sample": ends.astype(np.uint64), "device_id": [1310988] * n_msgs,
            "dt": [dt_us] * n_msgs, "scale": [scale] * n_msgs, "samples": counts,
            "x": raw[:, :, 0], "y": raw[:, :, 1], "z": raw[:, :, 2]}  # fmt: skip
    times, values = [], []
    for m in range(n_msgs):
        for k in range(counts[m]):
            times.append((ends[m] - (counts[m] - 1 - k) * dt_us) * 1e-6)
            values.append(raw[m, k].astype(float) * np.float32(scale))
    return cols, np.array(times), np.array(values)


def slow_topic(t_us, rng):
    xyz = rng.normal(0, 1, (len(t_us), 3)).astype(np.float32)
    return ulog_columns(t_us.astype(np.uint64), xyz, 1310988)


def test_fifo_topics_read_at_full_rate_with_their_scale(tmp_path):
    rng = np.random.default_rng(3)
    acc_cols, t_a, acc = fifo_topic(rng, 150, 1000.0, 9.80665 / 2048)  # 1 kHz
    gyr_cols, t_g, gyr = fifo_topic(np.random.default_rng(3), 150, 1000.0, 0.0010652644)
    t_slow = T0 + np.arange(1, 3) * 1_000_000.0  # sensor_accel at 1 Hz as well
    path = tmp_path / "fifo.ulg"
    write_ulog(path, [("sensor_accel_fifo", 0, FIFO_FIELDS, acc_cols),
                      ("sensor_gyro_fifo", 0, FIFO_FIELDS, gyr_cols),
                      ("sensor_accel", 0, SENSOR_FIELDS, slow_topic(t_slow, rng)),
                      ("sensor_gyro", 0, SENSOR_FIELDS, slow_topic(t_slow, rng))])  # fmt: skip
    ch = read_ulog(path)
    assert ch.notes[0].startswith("sensor_accel_fifo/sensor_gyro_fifo instance 0 (FIFO")
    np.testing.assert_allclose(ch.time, t_a, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ch.accel, acc, rtol=1e-7)  # int16 times the float32 scale
    np.testing.assert_allclose(ch.gyro, gyr, rtol=1e-7)
    assert ch.warnings == [] and ch.unpaired == 0
    assert 990 < 1 / np.median(np.diff(ch.time)) < 1010
    slow = read_ulog(path, "sensor_accel")  # chosen: 1 Hz, with the warning
    assert len(slow.time) == 2 and "logged at 1 Hz: too slow" in slow.warnings[0]


def test_vehicle_imu_and_sensor_combined_are_read_and_said_calibrated(tmp_path):
    rng = np.random.default_rng(4)
    n = 400
    t = T0 + np.arange(n) * 5000.0  # 200 Hz
    da = rng.normal(0, 0.01, (n, 3)).astype(np.float32)
    dv = rng.normal(0, 0.05, (n, 3)).astype(np.float32)
    imu = {"timestamp": (t + 100).astype(np.uint64), "timestamp_sample": t.astype(np.uint64),
           "accel_device_id": [7] * n, "gyro_device_id": [8] * n, "delta_angle": da,
           "delta_velocity": dv, "delta_angle_dt": [5000] * n, "delta_velocity_dt": [5000] * n,
           "delta_angle_clipping": [0] * n, "delta_velocity_clipping": [0] * n,
           "accel_calibration_count": [1] * n, "gyro_calibration_count": [1] * n}  # fmt: skip
    comb = {"timestamp": t.astype(np.uint64), "gyro_rad": da * 100, "gyro_integral_dt": [5000] * n,
            "accelerometer_timestamp_relative": [0] * n, "accelerometer_m_s2": dv * 50,
            "accelerometer_integral_dt": [5000] * n, "accelerometer_clipping": [0] * n,
            "gyro_clipping": [0] * n, "accel_calibration_count": [1] * n,
            "gyro_calibration_count": [1] * n}  # fmt: skip
    t_slow = T0 + np.arange(1, 3) * 1_000_000.0
    path = tmp_path / "default.ulg"  # what PX4's default profile leaves: raw topics at 1 Hz
    write_ulog(path, [("sensor_accel", 0, SENSOR_FIELDS, slow_topic(t_slow, rng)),
                      ("sensor_gyro", 0, SENSOR_FIELDS, slow_topic(t_slow, rng)),
                      ("vehicle_imu", 0, VEHICLE_IMU_FIELDS, imu),
                      ("sensor_combined", 0, SENSOR_COMBINED_FIELDS, comb)])  # fmt: skip
    ch = read_ulog(path)  # the rawest at a usable rate: vehicle_imu
    assert ch.notes[0].startswith("vehicle_imu/vehicle_imu instance 0")
    assert any("PX4's calibrated values" in n for n in ch.notes)
    np.testing.assert_allclose(ch.accel, dv.astype(float) / 0.005, rtol=1e-12)
    np.testing.assert_allclose(ch.gyro, da.astype(float) / 0.005, rtol=1e-12)
    np.testing.assert_allclose(ch.time, t * 1e-6, rtol=0, atol=1e-9)
    combined = read_ulog(path, "sensor_combined")
    np.testing.assert_array_equal(combined.accel, (dv * 50).astype(float))
    np.testing.assert_array_equal(combined.gyro, (da * 100).astype(float))


def test_a_1_hz_log_is_imported_with_a_warning_and_unpaired_samples_said(tmp_path):
    rng = np.random.default_rng(5)
    t_a = T0 + np.arange(60) * 1_000_000.0  # 1 Hz, as PX4's default profile
    path = tmp_path / "slow.ulg"
    t_g = t_a.copy()
    t_g[::5] += 600_000  # a fifth of the gyro samples have no accelerometer sample near them
    write_ulog(path, [("sensor_accel", 0, SENSOR_FIELDS, slow_topic(t_a, rng)),
                      ("sensor_gyro", 0, SENSOR_FIELDS, slow_topic(t_g, rng))])  # fmt: skip
    ch = read_ulog(path)
    assert len(ch.time) == 48 and ch.unpaired == 24 and "too slow" in ch.warnings[0]
    sections = tmp_path / "s.json"
    sections.write_text('{"z_p": {"start": 0, "end": 48}}')
    proc = run("import", path, "-o", tmp_path / "s.h5", "--rate", "1", "--sections", sections)
    assert proc.returncode == 0, proc.stderr
    assert "24 unpaired (an accelerometer or gyroscope sample" in proc.stdout
    assert "malformed" not in proc.stdout and "first at None" not in proc.stdout
    proc = run("import", path, "-o", tmp_path / "s.h5", "--rate", "1", "--sections", sections,
               "--json", "--force")  # fmt: skip
    doc = json.loads(proc.stdout)
    assert doc["skipped_lines"]["unpaired"] == 24 and "too slow" in doc["warnings"][0]


def test_mag_topic_picks_the_ulog_magnetometer(tmp_path):
    rng = np.random.default_rng(6)
    t = T0 + np.arange(200) * 5000.0
    mags = [("sensor_mag", k, MAG_FIELDS, ulog_columns(t[::10].astype(np.uint64),
                                                       np.full((20, 3), k + 0.25, np.float32),
                                                       100 + k)) for k in (2, 3)]  # fmt: skip
    path = tmp_path / "mag.ulg"
    write_ulog(path, [("sensor_accel", 0, SENSOR_FIELDS, slow_topic(t, rng)),
                      ("sensor_gyro", 0, SENSOR_FIELDS, slow_topic(t, rng)), *mags])  # fmt: skip
    assert read_ulog(path).mag[-1, 0] == 2.25  # the first, without a choice
    assert read_ulog(path, mag_topic="sensor_mag.3").mag[-1, 0] == 3.25
    with pytest.raises(InputError, match=r"--mag-topic 5: sensor_mag instances in the log: \[2, 3"):
        read_ulog(path, mag_topic="5")
    from imucal_cli.formats.importers import read_recording

    csv = tmp_path / "r.csv"
    csv.write_text("t,ax,ay,az\n0,0,0,9\n0.01,0,0,9\n")
    with pytest.raises(InputError, match="--mag-topic applies to ros, ulog and mavlink"):
        read_recording([csv], None, mag_topic="x")


def test_mag_topic_picks_a_ros_magnetometer_outside_the_imu_namespace(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    t, a, w = samples(100)
    path = tmp_path / "two.bag"
    with Writer(path) as writer:
        imu = writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=ts)
        mags = {name: writer.add_connection(name, "sensor_msgs/msg/MagneticField", typestore=ts)
                for name in ("/compass/a", "/compass/b")}  # fmt: skip
        for i in range(len(t)):
            sec = int(t[i])
            head = T["std_msgs/msg/Header"](T["builtin_interfaces/msg/Time"](
                sec, int(round((t[i] - sec) * 1e9))), "imu")  # fmt: skip
            V3 = T["geometry_msgs/msg/Vector3"]
            msg = T["sensor_msgs/msg/Imu"](head, T["geometry_msgs/msg/Quaternion"](0., 0., 0., 1.),
                                           np.zeros(9), V3(*w[i]), np.zeros(9), V3(*a[i]),
                                           np.zeros(9))  # fmt: skip
            ns = int(round(t[i] * 1e9))
            writer.write(imu, ns, ts.serialize_ros1(msg, "sensor_msgs/msg/Imu"))
            for k, conn in enumerate(mags.values()):
                m = T["sensor_msgs/msg/MagneticField"](head, V3(1e-6 * (k + 1), 0.0, 0.0),
                                                       np.zeros(9))  # fmt: skip
                writer.write(conn, ns, ts.serialize_ros1(m, "sensor_msgs/msg/MagneticField"))
    ch = read_ros(path)
    assert ch.mag is None and any("choose one with --mag-topic" in n for n in ch.notes)
    np.testing.assert_allclose(read_ros(path, mag_topic="/compass/b").mag[:, 0], 2.0)
    with pytest.raises(InputError, match="--mag-topic /nope is not a MagneticField topic"):
        read_ros(path, mag_topic="/nope")


def test_one_unset_timestamp_sample_and_a_damaged_field_name(tmp_path):
    """Found by the format fuzzer: one zeroed timestamp_sample moved every sample to its
    publication time; a flipped bit in a field's name raised a KeyError."""
    rng = np.random.default_rng(7)
    t = T0 + np.arange(200) * 5000.0
    acc, gyr = slow_topic(t, rng), slow_topic(t, rng)
    acc["timestamp_sample"] = acc["timestamp_sample"].copy()
    acc["timestamp_sample"][50] = 0
    path = tmp_path / "zero.ulg"
    write_ulog(path, [("sensor_accel", 0, SENSOR_FIELDS, acc),
                      ("sensor_gyro", 0, SENSOR_FIELDS, gyr)])  # fmt: skip
    ch = read_ulog(path)
    np.testing.assert_allclose(ch.time, np.delete(t, 50) * 1e-6, rtol=0, atol=1e-9)
    assert ch.dropped == 1
    acc_cols, _, _ = fifo_topic(rng, 40, 1000.0, 0.01)
    gyr_cols, _, _ = fifo_topic(rng, 40, 1000.0, 0.001)
    fifo = tmp_path / "fifo.ulg"
    write_ulog(fifo, [("sensor_accel_fifo", 0, FIFO_FIELDS, acc_cols),
                      ("sensor_gyro_fifo", 0, FIFO_FIELDS, gyr_cols)])  # fmt: skip
    assert len(read_ulog(fifo).time) > 100  # as written: read
    fifo.write_bytes(fifo.read_bytes().replace(b"uint8_t samples;", b"uint8_t sampmes;"))
    with pytest.raises(InputError, match="damaged ULog"):
        read_ulog(fifo)
