"""`imucal noise --imu NAME` (issue 28): a session of several IMUs is measured IMU by IMU, each
from its own samples (``/imus/NAME``, its own rate and noise, read block by block), with the
reference's still segment mapped to its samples by time, and a set's calibration giving that
IMU's own sections; the output names the IMU measured."""

from __future__ import annotations

import json

import numpy as np
import pytest

from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.session import ImuStream, Segment, Session, open_samples, write_session
from imucal_cli.model.calibration import Calibration, ImuEntry, SensorCalibration
from imucal_cli.use.noise import analyse_noise

from .cli_helpers import assert_one_line_error, run

G0 = 9.80665
CREATED = "2026-01-01T00:00:00Z"
MINUTES = 2.0
# Per IMU: rate (Hz), accel and gyro white noise per sample (std, SI), first time (s), counts
# per SI unit of the accelerometer (for the calibrated session).
REF = (100.0, 0.01, 0.002, 0.0, 800.0)
IMU1 = (200.0, 0.04, 0.008, 0.003, 400.0)


def _stream(rng, rate, sigma_a, sigma_g, t0, per_si, counts):
    n = int(MINUTES * 60 * rate)
    time = t0 + np.arange(n) / rate
    accel = np.array([0.0, 0.0, G0]) + sigma_a * rng.standard_normal((n, 3))
    gyro = sigma_g * rng.standard_normal((n, 3))
    if counts:
        accel = np.round(accel * per_si)
    return time, accel, gyro


def _set_session(path, counts=False) -> None:
    """A still set of two IMUs: the reference at 100 Hz, imu1 at 200 Hz with four times its
    noise, a still segment of the reference from 1 s to 110 s."""
    rng = np.random.default_rng(3)
    t0, a0, g0 = _stream(rng, *REF, counts)
    t1, a1, g1 = _stream(rng, *IMU1, counts)
    units = "counts" if counts else "m/s^2"
    other = ImuStream(t1, a1, g1, sensor="second part", accel_units=units, gyro_units="rad/s",
                      sample_rate_hz=IMU1[0])  # fmt: skip
    session = Session(t0, a0, g0, None, [Segment("0000", "static", 100, 11000, label="hold")],
                      CREATED, sensor="first part", accel_units=units, gyro_units="rad/s",
                      imus={"imu1": other})  # fmt: skip
    write_session(path, session)


def _vrw(rate, sigma) -> float:
    return sigma / np.sqrt(rate)


def _noise_json(*args) -> dict:
    proc = run("noise", *args, "--json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_each_imu_of_a_set_from_its_own_samples(tmp_path):
    path = tmp_path / "set.h5"
    _set_session(path)
    for args, name, (rate, sigma_a, sigma_g, t0, _) in (
        ((), "reference", REF), (("--imu", "reference"), "reference", REF),
        (("--imu", "imu1"), "imu1", IMU1),
    ):  # fmt: skip
        d = _noise_json(path, *args)
        assert d["imu"] == name
        assert d["rate_hz"] == pytest.approx(rate, rel=1e-6)
        # The reference's segment [1 s, 109.99 s] in this IMU's samples (within a sample).
        assert d["start"] == int(np.ceil((1.0 - t0) * rate - 1e-9))
        assert d["duration_s"] == pytest.approx(108.99, abs=1.5 / rate)
        for row in d["sensors"]["accel"]["axes"]:
            assert row["vrw_m_s_per_sqrt_s"] == pytest.approx(_vrw(rate, sigma_a), rel=0.1)
        for row in d["sensors"]["gyro"]["axes"]:
            assert row["arw_rad_per_sqrt_s"] == pytest.approx(_vrw(rate, sigma_g), rel=0.1)
    text = run("noise", path, "--imu", "imu1").stdout
    assert "set.h5 IMU imu1 (second part), of 2 (reference, imu1;" in text
    assert "IMU reference (first part)" in run("noise", path).stdout


def test_the_stream_of_another_imu_is_that_imu_as_a_session(tmp_path, monkeypatch):
    """Block by block from /imus/imu1 (blocks smaller than the span) gives what the same
    analysis gives on imu1 read whole as a session of its own (read_session, imu_session)."""
    from imucal_cli.formats.session import imu_session, read_session, samples_of

    path = tmp_path / "set.h5"
    _set_session(path)
    whole = analyse_noise(samples_of(imu_session(read_session(path), "imu1"))).to_dict()
    with open_samples(path, "imu1") as samples:
        assert samples.n == len(read_session(path).imus["imu1"].time)
        blocks = samples.blocks
        monkeypatch.setattr(samples, "blocks", lambda *a, **k: blocks(*a, rows=5000))
        streamed = analyse_noise(samples).to_dict()
    for key in ("start", "stop", "sensor", "rate_hz", "still_fraction"):
        assert streamed[key] == whole[key], key
    assert streamed["sensor"] == "second part" and streamed["imu"] == "imu1"
    for kind in ("accel", "gyro"):
        for a, b in zip(whole["sensors"][kind]["axes"], streamed["sensors"][kind]["axes"],
                        strict=True):  # fmt: skip
            np.testing.assert_allclose(b["curve"]["adev"], a["curve"]["adev"], rtol=1e-9)


def test_a_set_calibration_gives_the_imu_measured_its_own_sections(tmp_path):
    """Counts: the reference at 800, imu1 at 400 counts per m/s^2. The set's calibration holds
    each one's scale: imu1's noise in m/s^2 comes out right only with imu1's own section."""
    path = tmp_path / "set.h5"
    _set_session(path, counts=True)
    sections = {name: SensorCalibration("gravity", "m/s^2", np.zeros(3), np.eye(3) / per_si)
                for name, per_si in (("reference", REF[4]), ("imu1", IMU1[4]))}  # fmt: skip
    cal = Calibration(accel=sections["reference"], created=CREATED,
                      imus={"imu1": ImuEntry(accel=sections["imu1"])})  # fmt: skip
    write_calibration(tmp_path / "set.cal.json", cal)
    for name, (rate, sigma_a, *_) in (("reference", REF), ("imu1", IMU1)):
        d = _noise_json(path, "--imu", name, "-c", tmp_path / "set.cal.json")
        assert d["imu"] == name and list(d["sensors"]) == ["accel", "gyro"]
        for row in d["sensors"]["accel"]["axes"]:  # + quantisation
            assert row["vrw_m_s_per_sqrt_s"] == pytest.approx(_vrw(rate, sigma_a), rel=0.12)
    # A calibration of one IMU is taken as given for the IMU measured.
    one = Calibration(accel=sections["imu1"], created=CREATED)
    write_calibration(tmp_path / "imu1.cal.json", one)
    d = _noise_json(path, "--imu", "imu1", "-c", tmp_path / "imu1.cal.json")
    assert d["sensors"]["accel"]["axes"][0]["vrw_m_s_per_sqrt_s"] == pytest.approx(
        _vrw(IMU1[0], IMU1[1]), rel=0.12)  # fmt: skip


def test_an_imu_not_in_the_session_or_the_calibration_is_one_line(tmp_path):
    path = tmp_path / "set.h5"
    _set_session(path)
    assert_one_line_error(run("noise", path, "--imu", "imu7"),
                          "set.h5: no IMU 'imu7' (IMUs: reference, imu1)")  # fmt: skip
    cal = Calibration(accel=SensorCalibration("gravity", "m/s^2", np.zeros(3), np.eye(3)),
                      created=CREATED,
                      imus={"imu2": ImuEntry(accel=SensorCalibration(
                          "gravity", "m/s^2", np.zeros(3), np.eye(3)))})  # fmt: skip
    write_calibration(tmp_path / "other.cal.json", cal)
    assert_one_line_error(run("noise", path, "--imu", "imu1", "-c", tmp_path / "other.cal.json"),
                          "the calibration has no IMU 'imu1' (it has reference, imu2)")
    # A session of one IMU: its IMU is 'reference'; no other.
    single = tmp_path / "one.h5"
    rng = np.random.default_rng(0)
    t, a, g = _stream(rng, *REF, False)
    write_session(single, Session(t, a, g, None, [], CREATED, accel_units="m/s^2",
                                  gyro_units="rad/s"))  # fmt: skip
    assert _noise_json(single, "--imu", "reference")["imu"] is None
    assert_one_line_error(run("noise", single, "--imu", "imu1"), "no IMU 'imu1' (IMUs: reference)")
