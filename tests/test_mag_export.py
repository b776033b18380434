"""The magnetometer in exports and in apply: Fusion (softIronMatrix, hardIronOffset, compiled
with gcc), PX4 CAL_MAG0_*, ArduPilot COMPASS_*, the C header and JSON, each applied by a reader
written from the target's own equations; imucal apply's /calibrated/mag and mx,my,mz columns."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import (
    LOCAL_FIELD,
    Calibration,
    SensorCalibration,
    calibration_from_json,
    write_calibration,
)
from imucal_cli.formats.exporters import ExportOptions
from imucal_cli.formats.session import write_session
from imucal_cli.simulate.magnetometer import simulate_mag
from imucal_cli.use.apply import apply_calibration
from imucal_cli.use.export import export
from tests.cli_helpers import assert_one_line_error, run
from tests.test_export_targets import parm_params, px4_params

GCC = shutil.which("gcc")


def mag_cal(units_in="gauss", turn_deg=0.0, units="uT") -> Calibration:
    """A magnetometer calibration of known hard and soft iron, rotated by ``turn_deg``."""
    P = np.array([[1.04, 0.02, -0.03], [0.02, 0.97, 0.01], [-0.03, 0.01, 1.01]])
    R = Rotation.from_rotvec(np.radians(turn_deg) * np.array([0.6, -0.8, 0.0])).as_matrix()
    per_raw = {"gauss": 100.0, "uT": 1.0, "nT": 1e-3, "counts": 0.15}[units_in]
    W = R @ P * per_raw * (1.0 if units == "uT" else 1 / 48.0)
    bias = np.array([0.21, -0.35, 0.12]) * 100.0 / per_raw  # about 30 uT of hard iron
    extra = {"units_in": units_in}
    if units == LOCAL_FIELD:
        extra["field_estimate_uT"] = 48.0
    return Calibration(mag=SensorCalibration("magnetometer", units, bias, W, 0.4, extra),
                       created="2026-01-01T00:00:00Z")  # fmt: skip


def raw_readings(cal: Calibration, n=300) -> np.ndarray:
    rng = np.random.default_rng(3)
    h = rng.normal(size=(n, 3))
    h = 48.0 * h / np.linalg.norm(h, axis=1, keepdims=True)
    W = cal.mag.matrix * (48.0 if cal.mag.units == LOCAL_FIELD else 1.0)
    return h @ np.linalg.inv(W).T + cal.mag.bias


def px4_mag(p: dict) -> tuple[np.ndarray, np.ndarray]:
    """PX4's Magnetometer: the symmetric scale from SCALE and ODIAG, and the offset."""
    d = [p[f"CAL_MAG0_{a}SCALE"] for a in "XYZ"]
    o = [p[f"CAL_MAG0_{a}ODIAG"] for a in "XYZ"]  # xy, xz, yz
    S = np.array([[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]])
    return S, np.array([p[f"CAL_MAG0_{a}OFF"] for a in "XYZ"])


@pytest.mark.parametrize("units_in", ["gauss", "uT", "nT"])
def test_px4_and_ardupilot_apply_the_symmetric_part_exactly(units_in):
    cal = mag_cal(units_in)
    raw = raw_readings(cal)
    h_ut = cal.mag.apply(raw)  # uT; no rotation: the symmetric part is all of W
    per_raw = {"gauss": 100.0, "uT": 1.0, "nT": 1e-3}[units_in]
    p4 = px4_params(export(cal, "px4"))
    S, off = px4_mag(p4)
    gauss = raw * per_raw / 100.0  # what PX4's driver publishes
    np.testing.assert_allclose((gauss - off) @ S.T, h_ut / 100.0, atol=1e-12)
    ap = parm_params(export(cal, "ardupilot"))
    D = np.array([[ap["COMPASS_DIA_X"], ap["COMPASS_ODI_X"], ap["COMPASS_ODI_Y"]],
                  [ap["COMPASS_ODI_X"], ap["COMPASS_DIA_Y"], ap["COMPASS_ODI_Z"]],
                  [ap["COMPASS_ODI_Y"], ap["COMPASS_ODI_Z"], ap["COMPASS_DIA_Z"]]])  # fmt: skip
    ofs = np.array([ap[f"COMPASS_OFS_{a}"] for a in "XYZ"])
    mgauss = raw * per_raw * 10.0
    out = ((mgauss + ofs) * ap["COMPASS_SCALE"]) @ D.T  # ArduPilot adds its offsets
    np.testing.assert_allclose(out, h_ut * 10.0, atol=1e-9)


def test_autopilots_say_what_rotation_they_cannot_hold():
    cal = mag_cal("gauss", turn_deg=3.0)
    text = export(cal, "px4")
    assert "the rotation R (3.00 deg" in text and "WARNING" not in text
    raw = raw_readings(cal)
    p4 = px4_params(text)
    S, off = px4_mag(p4)
    out = (raw - off) @ S.T * 100.0  # uT, without the rotation
    h = cal.mag.apply(raw)
    ang = np.degrees(np.arccos(np.sum(out * h, 1) / np.linalg.norm(out, axis=1)
                               / np.linalg.norm(h, axis=1)))  # fmt: skip
    assert 2.9 < ang.max() <= 3.0 + 1e-6  # the rotation left out, as stated
    assert np.allclose(np.linalg.norm(out, axis=1), np.linalg.norm(h, axis=1))
    big = export(mag_cal("gauss", turn_deg=90.0), "ardupilot")
    assert "WARNING: the magnetometer's axes are 90 deg from the accelerometer's" in big


def test_autopilot_units_refusals_and_the_local_field():
    with pytest.raises(InputError, match="--mag-scale"):
        export(mag_cal("counts"), "px4")
    counts = export(mag_cal("counts"), "px4", options=ExportOptions(scale={"mag": 0.15}))
    assert "x 0.15 uT per raw unit (--mag-scale)" in counts
    local = mag_cal("gauss", units=LOCAL_FIELD)
    p4 = px4_params(export(local, "px4"))
    assert p4["CAL_MAG0_XSCALE"] == pytest.approx(1.04)  # scaled back by the field estimate
    del local.mag.extra["field_estimate_uT"]
    with pytest.raises(InputError, match="set \\[mag\\] field_uT"):
        export(local, "ardupilot")
    assert "COMPASS_OFFS_MAX" in export(_far_offset(), "ardupilot")


def _far_offset() -> Calibration:
    cal = mag_cal("gauss")
    cal.mag.bias = cal.mag.bias * 10.0  # 3 gauss of hard iron
    return cal


def test_fusion_prefixed_magnetic_constants():  # compiled and applied: test_fusion_export.py
    cal = mag_cal("uT", turn_deg=20.0)
    prefixed = export(cal, "fusion", options=ExportOptions(prefix="imu0"))
    assert "imu0SoftIronMatrix" in prefixed and "imu0HardIronOffset" in prefixed


def test_c_header_and_json_carry_the_magnetometer():
    cal = mag_cal("counts")
    header = export(cal, "c-header")
    assert "IMUCAL_MAG_MATRIX" in header and "imucal_mag_apply" in header and "-> uT" in header
    back = calibration_from_json(export(cal, "json"))
    np.testing.assert_array_equal(back.mag.matrix, cal.mag.matrix)


# ---------------------------------------------------------------------------- apply


def test_apply_writes_calibrated_mag_to_h5_and_csv(tmp_path):
    session, _ = simulate_mag("random:10", 1, hold_s=1.0, tumble_s=2.0)
    write_session(tmp_path / "s.h5", session)
    from imucal_cli.formats.config import Config
    from imucal_cli.pipeline.calibrate import calibrate_session

    cal = calibrate_session(session, Config())
    write_calibration(tmp_path / "c.json", cal)
    summary = apply_calibration(cal, tmp_path / "s.h5", tmp_path / "o.h5")
    assert summary.sensors == ("accel", "gyro", "mag")
    with h5py.File(tmp_path / "o.h5") as f:
        ds = f["calibrated/mag"]
        assert ds.attrs["units"] == "uT" and ds.attrs["units_in"] == "counts"
        np.testing.assert_array_equal(ds[:], cal.mag.apply(session.mag))
    rows = np.column_stack([session.time, session.accel, session.gyro, session.mag])
    np.savetxt(tmp_path / "in.csv", rows, delimiter=",", header="t,ax,ay,az,gx,gy,gz,mx,my,mz",
               comments="")  # fmt: skip
    apply_calibration(cal, tmp_path / "in.csv", tmp_path / "o.csv")
    lines = (tmp_path / "o.csv").read_text().splitlines()
    assert lines[0] == "t,ax,ay,az,gx,gy,gz,mx,my,mz" and "mx my mz uT" in lines[1]
    out = np.loadtxt(lines[2:], delimiter=",")
    np.testing.assert_allclose(out[:, 7:], cal.mag.apply(session.mag), rtol=1e-9)
    no_mag = tmp_path / "nomag.csv"
    np.savetxt(no_mag, rows[:, :7], delimiter=",", header="t,ax,ay,az,gx,gy,gz", comments="")
    assert_one_line_error(run("apply", tmp_path / "c.json", no_mag, "-o", tmp_path / "x.csv"),
                          "no mag columns (mx,my,mz")  # fmt: skip
