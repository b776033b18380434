"""Issue 15.1: readers of ROS 1/2 bags and MCAP (files written by rosbags), PX4 ULog (written to
the ULog specification and read with pyulog), MotionCal / i2cdevlib lines and WitMotion's binary
frames (MAVLink and DataFlash logs: ``test_import_mavlink.py``; here through ``imucal
import``): the values, times and companions (magnetometer, temperature) come back as written,
the topic is chosen or the choice is asked for, bad frames are counted."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.importers.ros import read_mcap, read_ros
from imucal_cli.formats.importers.serial_lines import detect_line_format, read_serial_lines
from imucal_cli.formats.importers.ulog import read_ulog
from imucal_cli.formats.importers.witmotion import (
    WitMotionDecoder,
    looks_like_witmotion,
    read_witmotion,
)

from .ulog_fixture import SENSOR_FIELDS, write_ulog

RATE = 200.0


def samples(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = 1700000000.0 + np.arange(n) / RATE
    a = rng.normal(0, 3, (n, 3)) + [0, 0, 9.8]
    w = rng.normal(0, 0.5, (n, 3))
    return t, a, w


def write_bag(path: Path, kind: str, topics=("/imu/data",), mag=True, temp=True, stamp=True,
              data=None):  # fmt: skip
    """A bag written with rosbags: ``kind`` ros1, ros2 (sqlite3) or mcap (rosbag2 storage);
    ``data`` (t, a, w) or random samples."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]

    def header(t):
        sec = int(t)
        return Header(Time(sec, int(round((t - sec) * 1e9))) if stamp else Time(0, 0), "imu")

    if kind == "ros1":
        writer, ser = Writer1(path), ts.serialize_ros1
    else:
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer, ser = Writer2(path, version=9, storage_plugin=plugin), ts.serialize_cdr
    t, a, w = samples() if data is None else data
    with writer:
        conns = {name: writer.add_connection(name, "sensor_msgs/msg/Imu", typestore=ts)
                 for name in topics}  # fmt: skip
        mconn = writer.add_connection("/imu/mag", "sensor_msgs/msg/MagneticField",
                                      typestore=ts) if mag else None  # fmt: skip
        tconn = writer.add_connection("/imu/temperature", "sensor_msgs/msg/Temperature",
                                      typestore=ts) if temp else None  # fmt: skip
        for i in range(len(t)):
            log_ns = int(round((t[i] + 0.003) * 1e9))  # received 3 ms after the stamp
            for k, conn in enumerate(conns.values()):
                msg = T["sensor_msgs/msg/Imu"](header(t[i]), Q(0.0, 0.0, 0.0, 1.0), np.zeros(9),
                                               V3(*(w[i] + k)), np.zeros(9), V3(*a[i]),
                                               np.zeros(9))  # fmt: skip
                writer.write(conn, log_ns, ser(msg, "sensor_msgs/msg/Imu"))
            if mconn is not None and i % 4 == 0:
                field = V3(20e-6, -5e-6, 40e-6 + i * 1e-9)
                m = T["sensor_msgs/msg/MagneticField"](header(t[i]), field, np.zeros(9))
                writer.write(mconn, log_ns, ser(m, "sensor_msgs/msg/MagneticField"))
            if tconn is not None and i % 50 == 0:
                tm = T["sensor_msgs/msg/Temperature"](header(t[i]), 25.0 + i / 100, 0.0)
                writer.write(tconn, log_ns, ser(tm, "sensor_msgs/msg/Temperature"))
    return t, a, w


@pytest.mark.parametrize("kind", ["ros1", "ros2", "mcap"])
def test_bags_read_back(tmp_path, kind):
    path = tmp_path / ("rec.bag" if kind == "ros1" else "rec")
    t, a, w = write_bag(path, kind)
    ch = read_ros(path)
    np.testing.assert_allclose(ch.time, t, atol=1e-9 * 2e9 * 1e-9 + 1e-6)
    np.testing.assert_array_equal(ch.accel, a)
    np.testing.assert_array_equal(ch.gyro, w)
    assert ch.accel_units == "m/s^2" and ch.gyro_units == "rad/s"
    # magnetometer every 4th sample, held in between, tesla -> uT
    assert ch.mag_units == "uT"
    np.testing.assert_allclose(ch.mag[5], [20.0, -5.0, 40.0 + 4e-3])
    np.testing.assert_allclose(ch.temperature[[0, 49, 50, 399]], [25.0, 25.0, 25.5, 28.5])
    assert "time from header.stamp" in ch.notes
    if kind == "mcap":  # the MCAP file itself, read with the mcap library
        mcap_file = next(path.glob("*.mcap"))
        ch2 = read_mcap(mcap_file)
        np.testing.assert_array_equal(ch2.gyro, w)


def test_topic_choice_and_receive_time(tmp_path):
    path = tmp_path / "two.bag"
    t, a, w = write_bag(path, "ros1", topics=("/imu0", "/imu1"), mag=False, temp=False,
                        stamp=False)  # fmt: skip
    with pytest.raises(InputError, match=r"several sensor_msgs/Imu topics: /imu0, /imu1; choose"):
        read_ros(path)
    ch = read_ros(path, "/imu1")
    np.testing.assert_array_equal(ch.gyro, w + 1)
    np.testing.assert_allclose(ch.time, t + 0.003, atol=1e-6)  # no stamps: the receive time
    assert any("receive time" in n for n in ch.notes)
    with pytest.raises(InputError, match="--topic /nope is not in the recording"):
        read_ros(path, "/nope")
    assert ch.mag is None and ch.temperature is None


def test_not_a_bag(tmp_path):
    bad = tmp_path / "x.bag"
    bad.write_bytes(b"not a bag at all")
    with pytest.raises(InputError, match="not a readable ROS bag"):
        read_ros(bad)
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n garbage")
    with pytest.raises(InputError, match="not a readable MCAP file"):
        read_ros(bad)


# --------------------------------------------------------------------------------------------
# PX4 ULog
# --------------------------------------------------------------------------------------------


def ulog_columns(t_us, xyz, device_id, temp=35.0):
    n = len(t_us)
    return {"timestamp": t_us + 50, "timestamp_sample": t_us, "device_id": [device_id] * n,
            "x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "temperature": [temp] * n}  # fmt: skip


def test_ulog_pairs_accel_and_gyro(tmp_path):
    rng = np.random.default_rng(1)
    t_acc = (1_000_000 + np.arange(300) * 2500).astype(np.uint64)  # 400 Hz
    t_gyr = (1_000_000 + 40 + np.arange(600) * 1250).astype(np.uint64)  # 800 Hz, offset 40 us
    acc = rng.normal(0, 1, (300, 3)).astype(np.float32)
    gyr = rng.normal(0, 1, (600, 3)).astype(np.float32)
    path = tmp_path / "log.ulg"
    write_ulog(path, [
        ("sensor_accel", 0, SENSOR_FIELDS, ulog_columns(t_acc, acc, 1310988)),
        ("sensor_gyro", 0, SENSOR_FIELDS, ulog_columns(t_gyr, gyr, 2359306)),
    ])  # fmt: skip
    ch = read_ulog(path)
    assert len(ch.time) == 300
    np.testing.assert_array_equal(ch.accel, acc.astype(float))
    np.testing.assert_array_equal(ch.gyro, gyr[::2].astype(float))  # the nearest gyro sample
    np.testing.assert_allclose(ch.time, t_acc * 1e-6)
    np.testing.assert_allclose(ch.temperature, 35.0)
    assert any("device_id 1310988" in n for n in ch.notes)


def test_ulog_instances(tmp_path):
    t = (1_000_000 + np.arange(50) * 1000).astype(np.uint64)
    xyz = np.ones((50, 3), np.float32)
    path = tmp_path / "multi.ulg"
    write_ulog(path, [
        ("sensor_accel", 0, SENSOR_FIELDS, ulog_columns(t, xyz, 11)),
        ("sensor_gyro", 0, SENSOR_FIELDS, ulog_columns(t, xyz, 12)),
        ("sensor_accel", 1, SENSOR_FIELDS, ulog_columns(t, 2 * xyz, 21)),
        ("sensor_gyro", 1, SENSOR_FIELDS, ulog_columns(t, 3 * xyz, 22)),
    ])  # fmt: skip
    with pytest.raises(InputError, match=r"several IMU instances: sensor_accel.0 \(device_id "
                                         r"11\), sensor_accel.1 "):  # fmt: skip
        read_ulog(path)
    ch = read_ulog(path, "sensor_accel.1")
    assert ch.accel[0, 0] == 2.0 and ch.gyro[0, 0] == 3.0 and len(ch.time) == 50
    with pytest.raises(InputError, match="no sensor_accel and sensor_gyro instance 4"):
        read_ulog(path, "4")


def test_ulog_refusals(tmp_path):
    path = tmp_path / "acc.ulg"
    t = (1_000_000 + np.arange(10) * 1000).astype(np.uint64)
    write_ulog(path, [("sensor_accel", 0, SENSOR_FIELDS, ulog_columns(t, np.ones((10, 3)), 1))])
    with pytest.raises(InputError, match="sensor_gyro missing"):
        read_ulog(path)
    bad = tmp_path / "bad.ulg"
    bad.write_bytes(b"nope")
    with pytest.raises(InputError, match="not a readable ULog"):
        read_ulog(bad)


# --------------------------------------------------------------------------------------------
# MotionCal and i2cdevlib lines
# --------------------------------------------------------------------------------------------


def test_motioncal_and_i2cdevlib_lines(tmp_path):
    rng = np.random.default_rng(2)
    data = rng.integers(-20000, 20000, (30, 9))
    mc = tmp_path / "motioncal.txt"
    lines = ["MotionCal sketch ready", "Uni:0.01,0.02,9.8,0,0,0,20,5,40"]
    lines += ["Raw:" + ",".join(map(str, row)) for row in data]
    lines.insert(10, "Raw:1,2,3")  # a partial line
    mc.write_text("\n".join(lines) + "\n")
    assert detect_line_format(mc.read_text()) == "motioncal"
    rec = read_serial_lines(mc, 100.0)
    np.testing.assert_array_equal(rec.accel, data[:, :3])
    np.testing.assert_array_equal(rec.gyro, data[:, 3:6])
    np.testing.assert_array_equal(rec.mag, data[:, 6:])
    assert (rec.skipped, rec.malformed) == (2, 1) and rec.first_malformed.endswith(":11")
    np.testing.assert_allclose(rec.time[:3], [0, 0.01, 0.02])

    ig = tmp_path / "i2cdev.txt"
    ig.write_text("Initializing I2C devices...\n" + "".join(
        "a/g:\t" + "\t".join(map(str, row[:6])) + "\n" for row in data))  # fmt: skip
    assert detect_line_format(ig.read_text()) == "i2cdevlib"
    rec = read_serial_lines(ig, 50.0)
    np.testing.assert_array_equal(rec.gyro, data[:, 3:6])
    assert rec.mag is None
    agm = tmp_path / "agm.txt"
    agm.write_text("".join("a/g/m:\t" + "\t".join(map(str, row)) + "\n" for row in data))
    assert detect_line_format(agm.read_text()) == "i2cdevlib-mag"
    assert read_serial_lines(agm, 50.0).mag.shape == (30, 3)
    with pytest.raises(InputError, match="--rate"):
        read_serial_lines(ig, None)
    plain = tmp_path / "plain.csv"
    plain.write_text("1,2,3\n")
    assert detect_line_format(plain.read_text()) is None


# --------------------------------------------------------------------------------------------
# WitMotion binary frames
# --------------------------------------------------------------------------------------------


def wit_frame(kind: int, values) -> bytes:
    """A WitMotion frame as its manual gives it: 0x55, type, 4 int16 LE, checksum."""
    body = bytes([0x55, kind]) + struct.pack("<4h", *values)
    return body + bytes([sum(body) & 0xFF])


def wit_stream(n=50, seed=3, time=True, garbage=True):
    rng = np.random.default_rng(seed)
    acc = rng.integers(-32768, 32767, (n, 3))
    gyr = rng.integers(-32768, 32767, (n, 3))
    mag = rng.integers(-3000, 3000, (n, 3))
    out = bytearray(b"\x00\x13junk" if garbage else b"")
    for i in range(n):
        if time:
            ms = (i * 10) % 1000
            s = (i * 10) // 1000
            out += bytes([0x55, 0x50, 26, 11, 23, 12, 0, s]) + struct.pack("<H", ms)
            out += bytes([sum(out[-10:]) & 0xFF])
        out += wit_frame(0x51, [*acc[i], 2534])
        out += wit_frame(0x52, [*gyr[i], 0])
        out += wit_frame(0x53, [1, 2, 3, 4])  # angles: skipped
        out += wit_frame(0x54, [*mag[i], 0])
    return bytes(out), acc, gyr, mag


def test_witmotion_frames_decode_in_any_pieces():
    data, acc, gyr, mag = wit_stream()
    bad = bytearray(data)
    bad[200] ^= 0xFF  # one corrupted byte
    dec = WitMotionDecoder()
    got = []
    for i in range(0, len(bad), 7):  # fed in 7-byte pieces
        got += dec.feed(bytes(bad[i : i + 7]))
    got += dec.flush()
    assert dec.stats["malformed"] >= 2  # the junk and the corrupted frame
    good = [s for s in got if s.gyro is not None]
    assert len(got) >= 49 and len(good) >= 48
    rows = {tuple(s.accel) for s in got}
    assert sum(tuple(r) in rows for r in acc) >= 49
    first = got[0]
    assert first.temperature == pytest.approx(25.34) and first.device_time == pytest.approx(
        12 * 3600)  # fmt: skip


def test_witmotion_file(tmp_path):
    data, acc, gyr, mag = wit_stream(garbage=False)
    path = tmp_path / "wit.bin"
    path.write_bytes(data)
    assert looks_like_witmotion(data[:512]) and not looks_like_witmotion(b"1,2,3\n" * 50)
    rec = read_witmotion(path)
    np.testing.assert_array_equal(rec.accel, acc)
    np.testing.assert_array_equal(rec.gyro, gyr)
    np.testing.assert_array_equal(rec.mag, mag)
    np.testing.assert_allclose(rec.time[:3], [0, 0.01, 0.02])
    assert any("0x50" in n for n in rec.notes)
    path.write_bytes(wit_stream(time=False, garbage=False)[0])
    with pytest.raises(InputError, match="--rate"):
        read_witmotion(path)
    assert len(read_witmotion(path, rate_hz=100).time) == 50


def test_witmotion_capture_protocol_records_a_session(tmp_path):
    from imucal_cli.capture.recorder import Recorder
    from imucal_cli.capture.stream import WitMotionProtocol
    from imucal_cli.formats.session import read_session

    from .test_capture import ScriptedSource

    data, acc, gyr, _ = wit_stream(n=120, time=False)
    chunks = [data[i : i + 64] for i in range(0, len(data), 64)]
    protocol = WitMotionProtocol()
    rec = Recorder(tmp_path / "wit.h5", ScriptedSource(chunks), protocol, accel_units="counts",
                   gyro_units="counts")  # fmt: skip
    got = sum(len(b) for b in rec.blocks())
    rec.close()
    s = read_session(tmp_path / "wit.h5")
    assert got == len(s.time) == 119  # the last sample waits for the next 0x51 frame
    np.testing.assert_array_equal(s.accel, acc[:119])
    np.testing.assert_array_equal(s.gyro, gyr[:119])
    np.testing.assert_allclose(s.temperature, 25.34)
    assert np.all(np.diff(s.time) > 0) and s.accel_units == "counts"
    assert protocol.stats["malformed"] >= 1 and protocol.stats["comments"] == 120  # 0x53 angles


def test_capture_refuses_an_unknown_protocol(tmp_path):
    from .cli_helpers import assert_one_line_error, run

    assert_one_line_error(run("capture", "--port", "/dev/null", "--protocol", "nope",
                              "--no-prompt", "--duration", "1", "-o", tmp_path / "x.h5"),
                          "--protocol")  # fmt: skip


# --------------------------------------------------------------------------------------------
# imucal import: every format detected by itself and segmented into a session
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def six():
    """The six faces of a simulated unit at 100 Hz: time, accel and gyro counts."""
    from imucal_cli.simulate.device import stream_arrays

    t, a, g = stream_arrays("six", rate_hz=100.0, hold_s=1.5, move_s=1.0)
    return t + 1700000000.0, np.round(a), np.round(g)


def write_format(kind: str, tmp_path: Path, six) -> Path:
    t, a, g = six
    if kind in ("ros1", "mcap"):
        path = tmp_path / ("six.bag" if kind == "ros1" else "six")
        write_bag(path, kind, mag=False, temp=False, data=(t, a / 835.0, g / 939.7))
        return next(path.glob("*.mcap")) if kind == "mcap" else path
    if kind == "ulog":
        path = tmp_path / "six.ulg"
        t_us = np.round((t - t[0]) * 1e6 + 1e6).astype(np.uint64)
        acc, gyr = (a / 835.0).astype(np.float32), (g / 939.7).astype(np.float32)
        write_ulog(path, [("sensor_accel", 0, SENSOR_FIELDS, ulog_columns(t_us, acc, 7)),
                          ("sensor_gyro", 0, SENSOR_FIELDS, ulog_columns(t_us, gyr, 8))])
        return path
    if kind == "tlog":
        from .mavlink_fixture import write_tlog_six

        return write_tlog_six(tmp_path / "six.tlog", six)
    if kind in ("dataflash", "dataflash-acc"):
        from .mavlink_fixture import write_dataflash_six

        return write_dataflash_six(tmp_path / "six.bin", six, acc_gyr=kind == "dataflash-acc")
    if kind == "motioncal":
        path = tmp_path / "six.txt"
        path.write_text("".join("Raw:" + ",".join(f"{v:.0f}" for v in (*ra, *rg, 10, 20, 30))
                                + "\n" for ra, rg in zip(a, g, strict=True)))  # fmt: skip
        return path
    if kind == "i2cdevlib":
        path = tmp_path / "six.txt"
        path.write_text("".join("a/g:\t" + "\t".join(f"{v:.0f}" for v in (*ra, *rg)) + "\n"
                                for ra, rg in zip(a, g, strict=True)))  # fmt: skip
        return path
    path = tmp_path / "six.bin"
    path.write_bytes(b"".join(wit_frame(0x51, [*ra.astype(int), 2500])
                              + wit_frame(0x52, [*rg.astype(int), 0])
                              for ra, rg in zip(a, g, strict=True)))  # fmt: skip
    return path


@pytest.mark.parametrize(
    ("kind", "units", "extra"),
    [("ros1", "m/s^2", []), ("mcap", "m/s^2", []), ("ulog", "m/s^2", []),
     ("tlog", "m/s^2", []), ("dataflash", "m/s^2", []), ("dataflash-acc", "m/s^2", []),
     ("motioncal", "counts", ["--rate", "100"]), ("i2cdevlib", "counts", ["--rate", "100"]),
     ("witmotion", "counts", ["--rate", "100"])],
)  # fmt: skip
def test_import_detects_the_format_and_segments(kind, units, extra, tmp_path, six):
    from imucal_cli.formats.session import read_session

    from .cli_helpers import run

    path = write_format(kind, tmp_path, six)
    out = tmp_path / "s.h5"
    proc = run("import", path, "-o", out, *extra)
    assert proc.returncode == 0, proc.stderr
    s = read_session(out)
    assert len(s.static_segments()) == 6, proc.stdout
    assert s.accel_units == units and len(s.time) >= len(six[0]) - 1
    if kind == "motioncal":  # the magnetometer is stored with its units
        assert s.mag_units == "counts" and np.all(s.mag[:, 0] == 10.0)
    if kind == "tlog":  # HIGHRES_IMU's magnetometer (gauss) and temperature
        assert s.mag_units == "gauss" and np.allclose(s.mag[:, 2], 0.4)
        assert np.all(s.temperature == 30.0)


def test_import_topic_option_and_refusals(tmp_path, six):
    from imucal_cli.formats.session import read_session

    from .cli_helpers import assert_one_line_error, run

    t, a, g = six
    path = tmp_path / "two.bag"
    write_bag(path, "ros1", topics=("/a/imu", "/b/imu"), mag=False, temp=False,
              data=(t, a / 835.0, g / 939.7))  # fmt: skip
    proc = run("import", path, "-o", tmp_path / "x.h5")  # issue 28: both IMUs, one session
    assert proc.returncode == 0, proc.stderr
    assert list(read_session(tmp_path / "x.h5").imus) == ["b_imu"]
    proc = run("import", path, "--topic", "/b/imu", "-o", tmp_path / "b.h5")
    assert proc.returncode == 0, proc.stderr
    assert read_session(tmp_path / "b.h5").imus == {}
    assert_one_line_error(run("import", path, "--columns", "t,ax,ay,az", "-o",
                              tmp_path / "y.h5"), "--columns does not apply")  # fmt: skip
    motion = write_format("motioncal", tmp_path, six)
    assert_one_line_error(run("import", motion, "-o", tmp_path / "z.h5"), "--rate")


@pytest.mark.parametrize(
    ("module", "reader", "name", "extra"),
    [("rosbags.highlevel", read_ros, "x.bag", "[ros]"),
     ("mcap.reader", read_ros, "x.mcap", "[mcap]"),
     ("pyulog", read_ulog, "x.ulg", "[px4]")],
)  # fmt: skip
def test_missing_library_names_the_extra(monkeypatch, tmp_path, module, reader, name, extra):
    path = tmp_path / name
    path.write_bytes(b"data")
    monkeypatch.setitem(__import__("sys").modules, module, None)  # as if not installed
    with pytest.raises(InputError, match=rf"pip install 'imucal-cli\{extra}'"):
        reader(path)
