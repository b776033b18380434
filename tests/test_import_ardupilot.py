"""Issue 26.2: ArduPilot's batch sampler (DataFlash ISBH/ISBD, ``LogStructure.h``: ISBH
``QHBBHHQf TimeUS,N,type,instance,mul,smp_cnt,SampleUS,smp_rate``, ISBD ``QHHaaa
TimeUS,N,seqno,x,y,z``) and its text logs (``.log``), written with pymavlink's own DataFlash
message packer (``tests/mavlink_fixture.py``) and read back: values are int16 / mul, sample
``32 seqno + k`` at ``SampleUS + (32 seqno + k) / smp_rate``; accelerometer and gyroscope
batches paired where they overlap, else the accelerometer alone; the text form of a log gives
the same samples as the binary one."""

from __future__ import annotations

import array

import numpy as np
import pytest

from imucal_cli.formats.importers import detect_format
from imucal_cli.formats.importers.mavlink import read_mavlink

from .cli_helpers import run
from .mavlink_fixture import DataFlashWriter, imu_row

pytest.importorskip("pymavlink")

MUL_ACCEL, MUL_GYRO = 208, 938  # INT16_MAX / (16 g), INT16_MAX / radians(2000)


def write_batches(writer, number, sensor, count, start_us, rate, raw, sample_us=None):
    logged = int(start_us + count / rate * 1e6 + 500)  # ArduPilot logs the header once complete
    writer.add("ISBH", [logged, number, sensor, 0, MUL_ACCEL if sensor == 0 else MUL_GYRO,
                        count, start_us if sample_us is None else sample_us, rate])  # fmt: skip
    for seqno in range((count + 31) // 32):
        part = raw[32 * seqno : 32 * seqno + 32]
        part = np.vstack([part, np.zeros((32 - len(part), 3), int)])
        writer.add("ISBD", [start_us + 1000 * seqno, number, seqno,
                            *(array.array("h", map(int, part[:, j])) for j in range(3))])


def test_batch_samples_paired_where_they_overlap(tmp_path):
    rng = np.random.default_rng(1)
    count = 1000  # not a multiple of 32: the last message's tail is no sample
    acc, gyr = rng.integers(-3000, 3000, (count, 3)), rng.integers(-3000, 3000, (count, 3))
    writer = DataFlashWriter()
    write_batches(writer, 0, 0, count, 2_000_000, 1000.0, acc)
    write_batches(writer, 1, 1, count, 2_000_000, 1000.0, gyr)
    path = writer.write(tmp_path / "isb.bin")
    ch = read_mavlink(path)
    np.testing.assert_allclose(ch.accel, acc / MUL_ACCEL, rtol=1e-15)
    np.testing.assert_allclose(ch.gyro, gyr / MUL_GYRO, rtol=1e-15)
    np.testing.assert_allclose(ch.time, 2.0 + np.arange(count) / 1000.0, rtol=0, atol=1e-12)
    assert "ISBH/ISBD batch samples of IMU 0" in ch.notes[0]


def test_batches_that_do_not_overlap_give_the_accelerometer_alone(tmp_path):
    rng = np.random.default_rng(2)
    writer = DataFlashWriter()
    writer.add("IMU", imu_row(1_000_000, 0, [0, 0, 9.8], [0, 0, 0], 30.0))
    a1, g1, a2 = (rng.integers(-3000, 3000, (512, 3)) for _ in range(3))
    write_batches(writer, 0, 0, 512, 2_000_000, 1000.0, a1)
    write_batches(writer, 1, 1, 512, 3_000_000, 1000.0, g1)  # the sampler's next sensor
    write_batches(writer, 2, 0, 512, 4_000_000, 1000.0, a2)
    path = writer.write(tmp_path / "isb.bin")
    ch = read_mavlink(path, "ISB.0")
    assert ch.gyro is None and "accelerometer alone" in ch.notes[1]
    np.testing.assert_allclose(ch.accel, np.vstack([a1, a2]) / MUL_ACCEL, rtol=1e-15)
    np.testing.assert_allclose(ch.time[512:], 4.0 + np.arange(512) / 1000.0, rtol=0, atol=1e-12)
    with pytest.raises(Exception, match="several IMU streams: IMU.0, ISB.0"):
        read_mavlink(path)


def test_a_damaged_batch_header_leaves_its_batch_out(tmp_path):
    rng = np.random.default_rng(3)
    acc, acc2 = rng.integers(-3000, 3000, (256, 3)), rng.integers(-3000, 3000, (256, 3))
    writer = DataFlashWriter()
    write_batches(writer, 0, 0, 256, 2_000_000, 1000.0, acc)
    write_batches(writer, 1, 0, 256, 3_000_000, 1000.0, acc2,
                  sample_us=9_000_000_000_000)  # damaged: sampled long after it was logged
    ch = read_mavlink(writer.write(tmp_path / "isb.bin"))
    np.testing.assert_allclose(ch.accel, acc / MUL_ACCEL, rtol=1e-15)


def test_a_text_log_reads_as_its_binary_log(tmp_path):
    from imucal_cli.simulate.device import stream_arrays

    t, a, g = stream_arrays("six", rate_hz=100.0, hold_s=1.5, move_s=1.0)
    writer = DataFlashWriter()
    writer.add("MSG", [0, "ArduCopter V4.5.0"])
    t_us = np.round((t - t[0]) * 1e6 + 1e6).astype(np.int64)
    acc, gyr = (a / 835.0).astype(np.float32), (g / 939.7).astype(np.float32)
    for k in range(len(t)):
        writer.add("IMU", imu_row(int(t_us[k]), 0, acc[k], gyr[k], 31.5))
        if k % 10 == 0:
            writer.add("MAG", [int(t_us[k]), 0, 100, -200, 300, 0, 0, 0, 0, 0, 0, 1, 0])
    binary = read_mavlink(writer.write(tmp_path / "six.bin"))
    text_path = tmp_path / "six.log"
    text_path.write_text(writer.text())
    assert detect_format([text_path]) == "mavlink"
    text = read_mavlink(text_path)
    np.testing.assert_array_equal(text.time, binary.time)
    np.testing.assert_allclose(text.accel, binary.accel, rtol=1e-6)  # float32 printed by repr
    np.testing.assert_allclose(text.gyro, binary.gyro, rtol=1e-6)
    np.testing.assert_allclose(text.mag, binary.mag, rtol=1e-12)
    proc = run("import", text_path, "-o", tmp_path / "s.h5")
    assert proc.returncode == 0, proc.stderr
    assert "6 static segments" in proc.stdout
