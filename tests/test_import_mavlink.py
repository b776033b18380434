"""Issue 15: MAVLink telemetry logs and ArduPilot DataFlash logs, written with pymavlink itself
(``tests/mavlink_fixture.py``) and read back: values, units, times, instances and companions
(magnetometer, temperature) as written; the stream is chosen as ``--topic`` chooses a ROS
topic; damaged logs give one line at once."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.importers import detect_format
from imucal_cli.formats.importers.mavlink import (
    looks_like_dataflash,
    looks_like_tlog,
    read_mavlink,
)

from .mavlink_fixture import (
    EPOCH_US,
    DataFlashWriter,
    TlogWriter,
    imu_row,
)

pytest.importorskip("pymavlink")

N = 60


def sensor(seed: int, n: int = N):
    rng = np.random.default_rng(seed)
    return (rng.integers(-16000, 16000, (n, 3)), rng.integers(-3000, 3000, (n, 3)),
            rng.integers(-600, 600, (n, 3)))  # fmt: skip


def telemetry(path, version=2):
    """RAW_IMU of two IMUs (id 0 and 1, 50 Hz), SCALED_IMU2 and HIGHRES_IMU (100 Hz)."""
    writer = TlogWriter(version)
    acc, gyr, mag = sensor(1)
    for k in range(N):
        t_us = 2_000_000 + 20_000 * k
        recv = EPOCH_US + t_us + 1500
        for ident in (0, 1) if version == 2 else (0,):
            fields = (t_us, *acc[k] + ident, *gyr[k], *mag[k])
            writer.add(recv, "raw_imu", *fields, *((ident, 2534 + k) if version == 2 else ()))
        writer.add(recv + 10, "scaled_imu2", t_us // 1000, *acc[k], *gyr[k], *mag[k],
                   *((0 if k < 3 else 2600,) if version == 2 else ()))  # fmt: skip
        for half in (0, 1):
            t_h = t_us + 10_000 * half
            writer.add(recv + 20 + 10_000 * half, "highres_imu", t_h, *(acc[k] / 1000.0),
                       *(gyr[k] / 1000.0), *(mag[k] / 1000.0), 1013.0, 0.0, 0.0, 24.5 + half,
                       0x1FFF, 0)  # fmt: skip
    return writer.write(path), acc, gyr, mag


def test_telemetry_log_streams_units_and_choice(tmp_path):
    path, acc, gyr, mag = telemetry(tmp_path / "flight.tlog")
    assert detect_format([path]) == "mavlink"
    head = path.read_bytes()[:256]
    assert looks_like_tlog(head) and not looks_like_dataflash(head)
    with pytest.raises(InputError, match=r"several IMU streams: HIGHRES_IMU\.0, RAW_IMU\.0, "
                       r"RAW_IMU\.1, SCALED_IMU2; choose one with --topic$"):  # fmt: skip
        read_mavlink(path)
    with pytest.raises(InputError, match=r"--topic RAW_IMU matches several streams"):
        read_mavlink(path, "RAW_IMU")
    raw = read_mavlink(path, "RAW_IMU.1")  # raw counts, device time, cdegC
    np.testing.assert_array_equal(raw.accel, acc + 1)
    np.testing.assert_array_equal(raw.gyro, gyr)
    np.testing.assert_array_equal(raw.mag, mag)
    assert (raw.accel_units, raw.gyro_units, raw.mag_units) == ("counts", "counts", "counts")
    np.testing.assert_allclose(raw.time, 2.0 + 0.02 * np.arange(N))
    np.testing.assert_allclose(raw.temperature, 25.34 + 0.01 * np.arange(N))
    assert "time from time_usec" in raw.notes
    scaled = read_mavlink(path, "SCALED_IMU2")  # mG, mrad/s, mgauss -> g, rad/s, gauss
    np.testing.assert_allclose(scaled.accel, acc / 1000.0, rtol=1e-15)
    np.testing.assert_allclose(scaled.gyro, gyr / 1000.0, rtol=1e-15)
    np.testing.assert_allclose(scaled.mag, mag / 1000.0, rtol=1e-15)
    assert (scaled.accel_units, scaled.gyro_units, scaled.mag_units) == ("g", "rad/s", "gauss")
    assert np.isnan(scaled.temperature[:3]).all() and np.all(scaled.temperature[3:] == 26.0)
    high = read_mavlink(path, "HIGHRES_IMU")  # SI as sent, float32
    assert len(high.time) == 2 * N and (high.accel_units, high.gyro_units) == ("m/s^2", "rad/s")
    np.testing.assert_allclose(high.accel[::2], acc / 1000.0, rtol=1e-6)
    np.testing.assert_allclose(high.time[:3], [2.0, 2.01, 2.02])
    np.testing.assert_array_equal(high.temperature[:2], [24.5, 25.5])
    with pytest.raises(InputError, match=r"--topic SCALED_IMU3 is not in the log; IMU streams"):
        read_mavlink(path, "SCALED_IMU3")


def test_telemetry_log_mavlink1_and_receive_time(tmp_path):
    """MAVLink 1 packets (no id, no temperature), a device clock that stands still: the time
    comes from the log's receive stamps, and the magnetometer that sent zeros is absent."""
    writer = TlogWriter(version=1)
    acc, gyr, _ = sensor(2)
    for k in range(N):
        writer.add(EPOCH_US + 30_000 * k, "scaled_imu", 5000, *acc[k], *gyr[k], 0, 0, 0)
    path = writer.write(tmp_path / "v1.tlog")
    ch = read_mavlink(path)
    np.testing.assert_allclose(ch.time, EPOCH_US * 1e-6 + 0.03 * np.arange(N), rtol=0,
                               atol=2e-6)  # fmt: skip
    assert any("receive stamps" in n for n in ch.notes)
    assert ch.mag is None and ch.temperature is None
    np.testing.assert_allclose(ch.accel, acc / 1000.0, rtol=1e-15)


def test_telemetry_log_receive_stamps_are_the_host_time(tmp_path):
    """A telemetry log's receive stamps are when the ground station (the host) received each
    packet: beside the device's own time they are the session's /raw/host_time (the sample
    clock's reference, issue 17.2); when they are the time itself, there is no host_time."""
    from imucal_cli.formats.importers import import_files
    from imucal_cli.formats.session import read_session, write_session
    from imucal_cli.simulate.device import stream_arrays

    from .mavlink_fixture import write_tlog_six

    t, a, g = stream_arrays("six", rate_hz=100.0, hold_s=1.5, move_s=1.0)
    path = write_tlog_six(tmp_path / "six.tlog", (t, a, g))
    t_us = np.round((t - t[0]) * 1e6 + 1e6)
    received = (EPOCH_US + t_us + 2000) * 1e-6
    ch = read_mavlink(path)
    np.testing.assert_allclose(ch.time, t_us * 1e-6, rtol=0, atol=1e-9)  # the device's time
    np.testing.assert_allclose(ch.host_time, received, rtol=0, atol=2e-6)
    session = import_files([path], None)
    np.testing.assert_array_equal(session.host_time, ch.host_time)
    write_session(tmp_path / "six.h5", session)
    np.testing.assert_array_equal(read_session(tmp_path / "six.h5").host_time, ch.host_time)
    writer = TlogWriter(version=1)  # a device clock that stands still: receive stamps as time
    acc, gyr, _ = sensor(2)
    for k in range(N):
        writer.add(EPOCH_US + 30_000 * k, "scaled_imu", 5000, *acc[k], *gyr[k], 0, 0, 0)
    assert read_mavlink(writer.write(tmp_path / "v1.tlog")).host_time is None


def test_telemetry_logs_of_two_senders_are_not_mixed(tmp_path):
    writer_a, writer_b = TlogWriter(system=1), TlogWriter(system=2)
    acc, gyr, mag = sensor(3)
    for k in range(N):
        writer_a.add(EPOCH_US + 10_000 * k, "raw_imu", 1000 * k + 1, *acc[k], *gyr[k], *mag[k])
        writer_b.add(EPOCH_US + 10_000 * k + 5, "raw_imu", 1000 * k + 1, *(-acc[k]), *gyr[k],
                     *mag[k])  # fmt: skip
    path = tmp_path / "two.tlog"
    path.write_bytes(bytes(writer_a.data + writer_b.data))
    with pytest.raises(InputError, match=r"RAW_IMU\.0@1/1, RAW_IMU\.0@2/1; choose"):
        read_mavlink(path)
    np.testing.assert_array_equal(read_mavlink(path, "RAW_IMU.0@2/1").accel, -acc)


# --------------------------------------------------------------------------------------------
# DataFlash
# --------------------------------------------------------------------------------------------


def dataflash(path):
    """IMU instances 0 and 1 at 400 Hz, ACC/GYR instance 0 at 1 kHz (ACC and GYR samples 100 us
    apart), MAG instance 0 at 40 Hz (mGauss), in ArduPilot's message formats."""
    writer = DataFlashWriter()
    acc, gyr, mag = sensor(4, 4 * N)
    si_acc, si_gyr = (acc / 1000.0).astype(np.float32), (gyr / 1000.0).astype(np.float32)
    writer.add("MSG", [0, "ArduCopter V4.5.0"])
    for k in range(4 * N):
        t_us = 1_000_000 + 2500 * k
        for instance in (0, 1):
            writer.add("IMU", imu_row(t_us, instance, si_acc[k] * (1 + instance), si_gyr[k],
                                      40.0 + 0.25 * k))  # fmt: skip
        if k % 10 == 0:
            writer.add("MAG", [t_us, 0, *mag[k], 10, 20, 30, 0, 0, 0, 1, t_us])
    for k in range(3 * N):
        sample = 1_000_000 + 1000 * k
        writer.add("ACC", [sample + 400, 0, sample, *map(float, si_acc[k])])
        writer.add("GYR", [sample + 400, 0, sample + 100, *map(float, si_gyr[k])])
    return writer.write(path), si_acc, si_gyr, mag


def test_dataflash_imu_instances_mag_and_temperature(tmp_path):
    path, acc, gyr, mag = dataflash(tmp_path / "00000042.BIN")
    assert looks_like_dataflash(path.read_bytes()[:16])
    assert detect_format([path]) == "mavlink"
    with pytest.raises(InputError, match=r"several IMU streams: IMU\.0, IMU\.1, ACC\.0; choose"):
        read_mavlink(path)
    ch = read_mavlink(path, "IMU.1")
    np.testing.assert_array_equal(ch.accel, (acc * 2).astype(np.float64))
    np.testing.assert_array_equal(ch.gyro, gyr.astype(np.float64))
    assert (ch.accel_units, ch.gyro_units) == ("m/s^2", "rad/s")
    np.testing.assert_allclose(ch.time, 1.0 + 0.0025 * np.arange(4 * N))
    np.testing.assert_allclose(ch.temperature, 40.0 + 0.25 * np.arange(4 * N))
    # MAG instance 0 (there is no instance 1), every 10th sample, held; mGauss -> gauss
    assert ch.mag_units == "gauss"
    np.testing.assert_allclose(ch.mag[:25], np.repeat(mag[[0, 10, 20]], 10, axis=0)[:25] / 1e3)
    assert any("MAG instance 0" in n for n in ch.notes)
    assert any("INS_ACCOFFS" in n for n in ch.notes)


def test_dataflash_acc_and_gyr_paired_by_sample_time(tmp_path):
    path, acc, gyr, _ = dataflash(tmp_path / "log.bin")
    ch = read_mavlink(path, "ACC")
    assert len(ch.time) == 3 * N
    np.testing.assert_array_equal(ch.accel, acc[: 3 * N].astype(np.float64))
    np.testing.assert_array_equal(ch.gyro, gyr[: 3 * N].astype(np.float64))
    np.testing.assert_allclose(ch.time, 1.0 + 0.001 * np.arange(3 * N))
    # the IMU's temperature (400 Hz), latest at each 1 kHz sample
    np.testing.assert_allclose(ch.temperature[:4], [40.0, 40.0, 40.0, 40.25])


def test_dataflash_old_layout_without_instance_field(tmp_path):
    """Older firmware: IMU2 (the second IMU) with Temp and no I field."""
    writer = DataFlashWriter()
    acc, gyr, _ = sensor(5)
    for k in range(N):
        writer.add("IMU2", imu_row(10_000 * k + 5, None, acc[k] / 1e3, gyr[k] / 1e3, 22.0))
    ch = read_mavlink(writer.write(tmp_path / "old.bin"))
    np.testing.assert_allclose(ch.accel, (acc / 1e3).astype(np.float32), rtol=0)
    assert "DataFlash IMU instance 1" in ch.notes[0] and np.all(ch.temperature == 22.0)


# --------------------------------------------------------------------------------------------
# Damaged and hostile logs: one line, at once
# --------------------------------------------------------------------------------------------


def bad_format_log(path):
    """A DataFlash log declaring a message format of length 0 without fields, then using it."""
    writer = DataFlashWriter()
    writer.add("IMU", imu_row(1000, 0, [0, 0, 9.8], [0, 0, 0], 20.0))
    writer.declare("BAD", "", "", length=0)
    writer.data += b"\xa3\x95" + bytes([0x80 + len(writer.types)]) + bytes(40)
    return writer.write(path)


def test_a_format_of_length_zero_does_not_hang(tmp_path, capfd):
    """pymavlink's reader reads such a message for ever (in this process, and so in `imucal
    import` with a time limit: the test fails, not hangs, if the guard goes)."""
    import subprocess

    from .cli_helpers import IMUCAL, assert_one_line_error

    path = bad_format_log(tmp_path / "bad.bin")
    try:
        proc = subprocess.run([IMUCAL, "import", str(path), "-o", str(tmp_path / "x.h5")],
                              capture_output=True, text=True, timeout=60)  # fmt: skip
    except subprocess.TimeoutExpired:
        pytest.fail("imucal import of a DataFlash log with a format of length 0 hung")
    assert_one_line_error(proc, "bad.bin: not a readable DataFlash log (a message format of "
                          "length 0")  # fmt: skip
    with pytest.raises(InputError, match="format of length 0"):
        read_mavlink(path)
    out, err = capfd.readouterr()
    assert out == err == ""  # pymavlink's own messages (also its compiled indexer's) kept quiet


@pytest.mark.parametrize(
    ("content", "words"),
    [(b"", "empty file"),
     (b"\xa3\x95\x80" + bytes(30), "no IMU, ACC/GYR or ISBH/ISBD messages"),
     (np.random.default_rng(7).integers(0, 0xFD, 5000, dtype=np.uint8).tobytes(),
      "no RAW_IMU, SCALED_IMU or HIGHRES_IMU messages")],
)  # fmt: skip
def test_damaged_logs_give_one_line(tmp_path, content, words):
    path = tmp_path / "x.tlog"
    path.write_bytes(content)
    with pytest.raises(InputError, match=words) as info:
        read_mavlink(path)
    assert "\n" not in str(info.value)


def test_a_fifo_is_refused_not_read(tmp_path):
    fifo = tmp_path / "log.tlog"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        read_mavlink(fifo)


def test_missing_pymavlink_names_the_extra(monkeypatch, tmp_path):
    path, *_ = telemetry(tmp_path / "t.tlog")
    monkeypatch.setitem(sys.modules, "pymavlink", None)  # as if not installed
    with pytest.raises(InputError, match=r"needs pymavlink: pip install 'imucal-cli\[mavlink\]'"):
        read_mavlink(path)
