"""Issue 15.3: calibrations from Kalibr's results YAML and MaD Lab's imucal JSON are read as
imucal calibrations, so ``apply``, ``report``, ``export`` and the history work with them; the
gyro's g-sensitivity is applied (never silently dropped)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.errors import CalibrationFileError, InputError
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.exporters import ExportOptions
from imucal_cli.model.calibration import Calibration
from imucal_cli.model.gyro import GyroCalibration
from imucal_cli.use.apply import apply_calibration
from imucal_cli.use.export import export

from .cli_helpers import assert_one_line_error, run
from .test_export_targets import ACCEL_SCALE, D2R, G0, raw_from_truth, truth
from .test_export_targets import cal as cal  # noqa: F401 - the fixture
from .test_export_targets import raw as raw  # noqa: F401 - the fixture

FERRARIS = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "imucal_ferraris"
needs_ferraris = pytest.mark.skipif(not FERRARIS.is_dir(), reason="shared/data absent")


def test_kalibr_export_reads_back_as_the_same_calibration(cal, raw, tmp_path):  # noqa: F811
    a_true, w_true = raw
    raw_a, raw_w = raw_from_truth(cal, a_true, w_true)
    path = tmp_path / "kalibr.yaml"
    path.write_text(export(cal, "kalibr", options=ExportOptions(scale={"accel": ACCEL_SCALE})))
    back = read_calibration(path)
    assert back.accel.units_in == "m/s^2" and back.gyro.units_in == "rad/s"
    assert back.imported_from.format == "kalibr scale-misalignment"
    a_ref, w_ref = truth(cal, raw_a, raw_w)
    a = back.accel.apply(raw_a * ACCEL_SCALE)
    w = back.gyro.apply(raw_w * D2R, accel=a)
    np.testing.assert_allclose(a, a_ref, atol=1e-9 * G0)
    np.testing.assert_allclose(w, w_ref, atol=1e-9)
    with pytest.raises(CalibrationFileError, match="g_sensitivity"):
        back.gyro.apply(raw_w * D2R)  # the term is never dropped silently


KALIBR_RESULT = """\
imu0:
  T_i_b:
  - [1.0, 0.0, 0.0, 0.0]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  accelerometer_noise_density: 0.0186
  accelerometer_random_walk: 0.000433
  accelerometers:
    M:
    - [1.0021, 0.0, 0.0]
    - [0.0043, 0.9987, 0.0]
    - [-0.0021, 0.0032, 1.0008]
  gyroscope_noise_density: 0.00187
  gyroscope_random_walk: 2.66e-05
  gyroscopes:
    A:
    - [0.0001, 0.0, 0.0]
    - [0.0, -0.0002, 0.0]
    - [0.0, 0.0, 0.0003]
    C_gyro_i:
    - [0.9999, -0.0122, 0.0071]
    - [0.0122, 0.9999, 0.0031]
    - [-0.0071, -0.0032, 0.9999]
    M:
    - [0.9971, 0.0, 0.0]
    - [-0.0019, 1.0032, 0.0]
    - [0.0041, 0.0011, 0.9991]
  model: scale-misalignment
  rostopic: /imu0
  time_offset: 0.0
  update_rate: 200.0
"""


def test_kalibr_result_follows_kalibrs_model(tmp_path):
    path = tmp_path / "imu-imu0.yaml"
    path.write_text(KALIBR_RESULT)
    cal = read_calibration(path)
    M_a = np.array([[1.0021, 0, 0], [0.0043, 0.9987, 0], [-0.0021, 0.0032, 1.0008]])
    M_g = np.array([[0.9971, 0, 0], [-0.0019, 1.0032, 0], [0.0041, 0.0011, 0.9991]])
    C = np.array([[0.9999, -0.0122, 0.0071], [0.0122, 0.9999, 0.0031],
                  [-0.0071, -0.0032, 0.9999]])  # fmt: skip
    A = np.diag([0.0001, -0.0002, 0.0003])
    # Kalibr: p_a = M_a a + b; p_w = M_g C w + A C a + b (biases zero: Kalibr writes none)
    rng = np.random.default_rng(2)
    a, w = rng.normal(0, 5, (50, 3)), rng.normal(0, 2, (50, 3))
    p_a, p_w = a @ M_a.T, (w @ C.T) @ M_g.T + (a @ C.T) @ A.T
    a_out = cal.accel.apply(p_a)
    np.testing.assert_allclose(a_out, a, atol=1e-12)
    np.testing.assert_allclose(cal.gyro.apply(p_w, accel=a_out), w, atol=1e-12)
    assert any("Kalibr writes no fixed bias" in w for w in cal.accel.warnings)
    assert cal.created.endswith("Z") and "modification time" in cal.created_basis


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("imu0:\n  model: calibrated\n  accelerometer_noise_density: 0.01\n", "no intrinsics"),
        ("imu0:\n  model: scale-misalignment\n  accelerometers:\n    M: [[1, 0], [0, 1]]\n"
         "  gyroscopes:\n    M: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n", "accelerometers"),
        ('{"K_a": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "R_a": 3, "b_a": [0, 0, 0]}', "R_a"),
        ('{"K_a": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "R_a": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],'
         ' "b_a": [0, 0, 0], "K_g": [[0, 0, 0], [0, 0, 0], [0, 0, 0]], "R_g": [[1, 0, 0],'
         ' [0, 1, 0], [0, 0, 1]], "b_g": [0, 0, 0]}', "K_g"),
    ],
)  # fmt: skip
def test_foreign_refusals_are_one_line(tmp_path, text, words):
    path = tmp_path / "cal.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=words):
        read_calibration(path)
    assert_one_line_error(run("report", path), words)


def mad_lab_apply(doc: dict, acc_raw, gyr_raw):
    """MaD Lab imucal's documented Ferraris model: acc = R_a^-1 K_a^-1 (raw - b_a);
    gyr = R_g^-1 K_g^-1 (raw - K_ga acc - b_g), in acc_unit and gyr_unit."""
    inv = np.linalg.inv
    K_a, R_a, b_a = (np.array(doc[k]) for k in ("K_a", "R_a", "b_a"))
    K_g, R_g, b_g, K_ga = (np.array(doc[k]) for k in ("K_g", "R_g", "b_g", "K_ga"))
    acc = (acc_raw - b_a) @ (inv(R_a) @ inv(K_a)).T
    gyr = (gyr_raw - acc @ K_ga.T - b_g) @ (inv(R_g) @ inv(K_g)).T
    return acc, gyr


@needs_ferraris
def test_mad_lab_snapshot_applies_as_mad_lab_does(tmp_path):
    src = FERRARIS / "imucal_snapshot_example_cal.json"
    doc = json.loads(src.read_text())
    cal = read_calibration(src)
    assert cal.accel.units_in == "counts" and cal.gyro.units_in == "counts"
    rows = np.genfromtxt(FERRARIS / "annotated_session.csv", delimiter=",", skip_header=1,
                         usecols=range(2, 8))  # fmt: skip
    labels = np.genfromtxt(FERRARIS / "annotated_session.csv", delimiter=",", skip_header=1,
                           usecols=0, dtype=str)  # fmt: skip
    acc_ref, gyr_ref = mad_lab_apply(doc, rows[:, :3], rows[:, 3:])  # m/s^2, deg/s
    a = cal.accel.apply(rows[:, :3])
    w = cal.gyro.apply(rows[:, 3:], accel=a)
    np.testing.assert_allclose(a, acc_ref, atol=1e-9)
    np.testing.assert_allclose(w, np.radians(gyr_ref), atol=1e-12)
    # real data: each +axis-up face reads +g on that axis (MaD Lab used g = 9.81)
    for i, face in enumerate(("x_p", "y_p", "z_p")):
        mean = a[labels == face].mean(axis=0)
        assert mean[i] == pytest.approx(9.81, abs=0.02) and np.linalg.norm(mean) == \
            pytest.approx(9.81, abs=0.02)  # fmt: skip
    # and each 360-degree turn integrates to 360 degrees about its axis (204.8 Hz)
    for i, turn in enumerate(("x_rot", "y_rot", "z_rot")):
        angle = np.degrees(w[labels == turn, i].sum() / 204.8)
        assert abs(angle) == pytest.approx(360.0, abs=3.0), (turn, angle)


@needs_ferraris
def test_mad_lab_snapshot_through_the_cli(tmp_path):
    src = FERRARIS / "imucal_snapshot_example_cal.json"
    out = tmp_path / "si.csv"
    proc = run("apply", src, FERRARIS / "annotated_session.csv", "--columns",
               "_,_,ax,ay,az,gx,gy,gz", "--rate", "204.8", "--output", out)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    data = np.loadtxt(out, delimiter=",", comments="#", skiprows=2)
    doc = json.loads(src.read_text())
    rows = np.genfromtxt(FERRARIS / "annotated_session.csv", delimiter=",", skip_header=1,
                         usecols=range(2, 8))  # fmt: skip
    acc_ref, gyr_ref = mad_lab_apply(doc, rows[:, :3], rows[:, 3:])
    np.testing.assert_allclose(data[:, 1:4], acc_ref, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(data[:, 4:7], np.radians(gyr_ref), rtol=1e-8, atol=1e-10)
    proc = run("report", src)
    assert proc.returncode == 0 and "mad-lab-ferraris" in proc.stdout
    proc = run("report", src, src)  # the history of two calibrations
    assert proc.returncode == 0, proc.stderr
    proc = run("export", src, "--format", "json")
    assert proc.returncode == 0 and json.loads(proc.stdout)["format"] == "imucal-calibration"


def test_mad_lab_units_convert_to_si(tmp_path):
    doc = {
        "acc_unit": "g", "gyr_unit": "rad/s", "from_acc_unit": "a.u.", "from_gyr_unit": "a.u.",
        "K_a": np.diag([2048.0, 2050.0, 2046.0]).tolist(), "R_a": np.eye(3).tolist(),
        "b_a": [1.0, 2.0, 3.0], "K_g": np.diag([939.0, 940.0, 941.0]).tolist(),
        "R_g": np.eye(3).tolist(), "K_ga": (0.5 * np.eye(3)).tolist(), "b_g": [0.0, 0.0, 0.0],
        "cal_type": "Turntable", "_format_version": "2.0",
    }  # fmt: skip
    path = tmp_path / "t.json"
    path.write_text(json.dumps(doc))
    cal = read_calibration(path)
    a = cal.accel.apply(np.array([[2049.0, 2.0, 3.0]]))
    np.testing.assert_allclose(a, [[G0, 0, 0]])  # 1 g in m/s^2
    w = cal.gyro.apply(np.array([[939.0 + 0.5, 0.0, 0.0]]), accel=a)  # K_ga acts per g
    np.testing.assert_allclose(w, [[1.0, 0, 0]])
    assert cal.gyro.solver == "mad-lab-turntable"


def test_apply_refuses_g_sensitivity_without_accel(tmp_path):
    gyro = GyroCalibration("x", "rad/s", [0, 0, 0], np.eye(3), None, g_sensitivity=np.eye(3))
    cal_path = tmp_path / "c.json"
    from imucal_cli.formats.calibration import write_calibration

    write_calibration(cal_path, Calibration(gyro=gyro, created="2026-01-01T00:00:00Z"))
    csv = tmp_path / "in.csv"
    csv.write_text("t,gx,gy,gz\n0,1,2,3\n0.01,1,2,3\n")
    with pytest.raises(InputError, match="g_sensitivity"):
        apply_calibration(read_calibration(cal_path), csv, tmp_path / "o.csv")
