"""Issue 15.2 / 15.4: exports for Kalibr, OpenVINS, Basalt, PX4, ArduPilot, Fusion and
sensor_msgs/Imu covariances.  For each format, a reader written from that format's own
documentation (its equation, nothing of imucal's code) applies the exported numbers to raw
samples and must give imucal's ``apply`` output within float precision (up to the rotation the
format's frame convention imposes, which must be one rotation for both sensors); for the
offset-and-scale targets it must stay within the loss the file states."""

from __future__ import annotations

import json
import math
import re
import shutil

import numpy as np
import pytest
import yaml

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.exporters import ExportOptions, diagonal_fit, lq, published
from imucal_cli.formats.noise import noise_from_dict
from imucal_cli.model.accel import AccelCalibration
from imucal_cli.model.calibration import Calibration
from imucal_cli.model.gyro import GyroCalibration
from imucal_cli.use.export import export
from imucal_cli.use.noise import analyse_noise

from .cli_helpers import assert_one_line_error, run
from .test_noise import still_session

G0 = 9.80665
D2R = math.pi / 180.0
GCC = shutil.which("gcc")


def rotation(axis, angle_deg) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    axis = np.asarray(axis, float)
    return Rotation.from_rotvec(np.radians(angle_deg) * axis / np.linalg.norm(axis)).as_matrix()


def misaligned_sensitivity(gains, angles_deg, turn) -> np.ndarray:
    """Rows = sensitivity axes (raw per SI unit): axis y tilted from x by 90 - a_xy, ...,
    then the whole triad turned by ``turn`` (a rotation matrix)."""
    a_xy, a_xz, a_yz = np.radians(angles_deg)
    x = np.array([1.0, 0, 0])
    y = np.array([math.sin(a_xy), math.cos(a_xy), 0.0])
    z = np.array([math.sin(a_xz), math.sin(a_yz), 0.0])
    z[2] = math.sqrt(1 - z[0] ** 2 - z[1] ** 2)
    return (np.asarray(gains)[:, None] * np.array([x, y, z])) @ turn.T


@pytest.fixture(scope="module")
def cal() -> Calibration:
    """A general calibration: counts accelerometer, deg/s gyroscope with g-sensitivity, full
    matrices in a frame turned from every triangular gauge."""
    S_a = misaligned_sensitivity([1670.0, 1650.0, 1702.0], [0.4, -0.7, 0.3],
                                 rotation([1, 2, 3], 2.0))  # fmt: skip
    S_g = misaligned_sensitivity([57.9, 56.1, 58.8], [-0.5, 0.9, 0.2],
                                 rotation([3, -1, 2], 4.0))  # fmt: skip
    accel = AccelCalibration("gravity", "m/s^2", [35.0, -120.0, 410.0], np.linalg.inv(S_a),
                             0.002, units_in="counts")  # fmt: skip
    gyro = GyroCalibration("gyro-full", "rad/s", [0.9, -1.3, 0.4], np.linalg.inv(S_g) * D2R,
                           0.001, units_in="deg/s",
                           g_sensitivity=[[0.002, -0.001, 0.0004], [0.0015, 0.003, -0.002],
                                          [-0.0007, 0.001, 0.0025]])  # fmt: skip
    return Calibration(accel=accel, gyro=gyro, session="bench.h5",
                       created="2026-01-01T00:00:00Z", sensor="MPU-6050 #3")  # fmt: skip


ACCEL_SCALE = G0 / 16384.0  # the driver's m/s^2 per count


@pytest.fixture(scope="module")
def raw():
    rng = np.random.default_rng(7)
    n = 200
    a = rng.normal(0, 1, (n, 3))
    a = 1.3 * G0 * a / np.linalg.norm(a, axis=1)[:, None] * rng.uniform(0.2, 1, (n, 1))
    w = rng.normal(0, 3.0, (n, 3))  # rad/s
    return a, w


def truth(cal: Calibration, raw_accel, raw_gyro):
    """imucal's apply: accel, then gyro with g-sensitivity subtracted (the spec's order)."""
    a = cal.accel.apply(raw_accel)
    g = np.zeros((3, 3)) if cal.gyro.g_sensitivity is None else cal.gyro.g_sensitivity
    w = (raw_gyro - cal.gyro.bias - a @ g.T) @ cal.gyro.matrix.T
    return a, w


def raw_from_truth(cal: Calibration, a, w):
    """Raw samples whose calibrated values are ``a``, ``w``."""
    raw_a = a @ np.linalg.inv(cal.accel.matrix).T + cal.accel.bias
    g = np.zeros((3, 3)) if cal.gyro.g_sensitivity is None else cal.gyro.g_sensitivity
    raw_w = w @ np.linalg.inv(cal.gyro.matrix).T + cal.gyro.bias + a @ g.T
    return raw_a, raw_w


def procrustes(X, Y) -> tuple[np.ndarray, float]:
    """Rotation R minimising |X - Y R^T| and the largest residual."""
    u, _, vt = np.linalg.svd(X.T @ Y)
    d = np.sign(np.linalg.det(u @ vt))
    R = u @ np.diag([1, 1, d]) @ vt
    return R, float(np.abs(X - Y @ R.T).max())


def kalibr_yaml(text: str) -> dict:
    """What Kalibr's config reader (PyYAML) loads; OpenCV's ``%YAML:1.0`` line is not YAML 1.1."""
    return yaml.safe_load(re.sub(r"\A%YAML:1.0[^\n]*\n", "", text))


def noise_doc(seed=0) -> dict:
    session, _, _ = still_session(minutes=5.0, seed=seed)
    return analyse_noise(session).to_dict()


@pytest.fixture(scope="module")
def noise():
    return noise_from_dict(noise_doc(), "noise.json")


# --------------------------------------------------------------------------------------------
# Kalibr
# --------------------------------------------------------------------------------------------


def test_kalibr_reader_reproduces_apply(cal, raw):
    a_true, w_true = raw
    raw_a, raw_w = raw_from_truth(cal, a_true, w_true)
    text = export(cal, "kalibr", options=ExportOptions(scale={"accel": ACCEL_SCALE}))
    imu = kalibr_yaml(text)["imu0"]
    assert imu["model"] == "scale-misalignment"
    M_a = np.array(imu["accelerometers"]["M"])
    M_g = np.array(imu["gyroscopes"]["M"])
    A = np.array(imu["gyroscopes"]["A"])
    C = np.array(imu["gyroscopes"]["C_gyro_i"])
    C_i_b = np.array(imu["T_i_b"])[:3, :3]
    assert np.allclose(M_a, np.tril(M_a), atol=0) and np.allclose(M_g, np.tril(M_g), atol=0)
    assert np.allclose(C @ C.T, np.eye(3), atol=1e-12) and np.linalg.det(C) > 0
    # Kalibr's model: p_a = M_a a_i + b_a; p_w = M_g C w_i + A C a_i + b_w; p what ROS publishes
    p_a, p_w = raw_a * ACCEL_SCALE, raw_w * D2R
    a_i = np.linalg.solve(M_a, (p_a - imu["accelerometer_bias"]).T).T
    w_i = (np.linalg.solve(M_g, (p_w - imu["gyroscope_bias"] - a_i @ (A @ C).T).T).T) @ C
    a_ref, w_ref = truth(cal, raw_a, raw_w)
    np.testing.assert_allclose(a_i @ C_i_b, a_ref, atol=1e-9 * G0)
    np.testing.assert_allclose(w_i @ C_i_b, w_ref, atol=1e-9)
    assert "p_a = M_accel @ a_i + accelerometer_bias" in text
    assert "x 0.000598" in text  # the driver's scale is stated


def test_kalibr_without_gyro_is_identity_and_says_so(cal):
    only = Calibration(accel=cal.accel, created=cal.created)
    imu = kalibr_yaml(export(only, "kalibr", options=ExportOptions(
        scale={"accel": ACCEL_SCALE})))["imu0"]  # fmt: skip
    assert np.array(imu["gyroscopes"]["M"]).tolist() == np.eye(3).tolist()
    assert imu["gyroscope_bias"] == [0.0, 0.0, 0.0]


def test_kalibr_imu_noise_file(noise):
    text = export(None, "kalibr-imu", options=ExportOptions(noise=noise, topic="/mpu/imu"))
    doc = yaml.safe_load(text)
    assert doc["rostopic"] == "/mpu/imu"
    assert doc["update_rate"] == pytest.approx(100.0)
    assert doc["accelerometer_noise_density"] == pytest.approx(noise.accel.white.max())
    assert doc["gyroscope_noise_density"] == pytest.approx(noise.gyro.white.max())
    assert doc["accelerometer_random_walk"] == pytest.approx(noise.accel.random_walk.max())
    assert doc["gyroscope_random_walk"] == pytest.approx(noise.gyro.random_walk.max())
    # simulated white noise 0.01 m/s^2 and 0.002 rad/s per sample at 100 Hz
    assert doc["accelerometer_noise_density"] == pytest.approx(0.001, rel=0.15)
    assert doc["gyroscope_noise_density"] == pytest.approx(0.0002, rel=0.15)
    assert "per axis: x" in text and "m/s^3/sqrt(Hz)" in text
    # no +1/2 slope in pure white noise: the random walk is the bound the curve allows
    assert all(noise.accel.random_walk_bound) and "upper bound" in text
    assert export(None, "kalibr-imu", options=ExportOptions(noise=noise, rate_hz=200.0)).count(
        "update_rate: 200.0") == 1  # fmt: skip


@pytest.mark.parametrize(
    ("edit", "words"),
    [(lambda d: d.__setitem__("rate_hz", 1e300), "rate_hz must be an IMU's sample rate"),
     (lambda d: [a.__setitem__("vrw_m_s_per_sqrt_s", 1e300)
                 for a in d["sensors"]["accel"]["axes"]], "beyond any sensor"),
     (lambda d: d["sensors"]["accel"].__setitem__("axes", d["sensors"]["accel"]["axes"][:2]),
      "3 or more")],
)  # fmt: skip
def test_noise_figures_no_sensor_has_are_refused(edit, words):
    """Audit: a noise file's rate of 1e300 Hz was written as the filter's rate, a density of
    1e300 as Kalibr's (and ros-imu printed numpy's overflow warnings), two axes exported as
    a whole sensor."""
    doc = noise_doc()
    edit(doc)
    with pytest.raises(InputError, match=words):
        noise_from_dict(doc, "noise.json")


def test_random_walk_bound_is_below_the_curve(noise):
    doc = noise_doc()
    for axis, K in zip(doc["sensors"]["gyro"]["axes"], noise.gyro.random_walk, strict=True):
        tau = np.array(axis["curve"]["tau_s"])
        adev = np.array(axis["curve"]["adev"])
        assert np.all(K * np.sqrt(tau / 3) <= adev * (1 + 1e-12))
        assert np.any(np.isclose(K * np.sqrt(tau / 3), adev))


# --------------------------------------------------------------------------------------------
# OpenVINS
# --------------------------------------------------------------------------------------------


def test_openvins_reader_reproduces_apply(cal, raw, noise):
    a_true, w_true = raw
    raw_a, raw_w = raw_from_truth(cal, a_true, w_true)
    opts = ExportOptions(noise=noise, scale={"accel": ACCEL_SCALE})
    text = export(cal, "openvins", options=opts)
    assert text.startswith("%YAML:1.0\n")
    imu = kalibr_yaml(text)["imu0"]
    for key in ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC", "Tg", "accelerometer_noise_density",
                "gyroscope_random_walk", "update_rate", "rostopic"):  # fmt: skip
        assert key in imu, key
    assert imu["model"] == "kalibr"
    Tw, Ta = np.array(imu["Tw"]), np.array(imu["Ta"])
    R_g, R_a, Tg = np.array(imu["R_IMUtoGYRO"]), np.array(imu["R_IMUtoACC"]), np.array(imu["Tg"])
    assert np.allclose(Ta, np.tril(Ta), atol=0) and np.allclose(Tw, np.tril(Tw), atol=0)
    # OpenVINS (docs, analytical propagation): a_I = R_ACCtoI Da (a_m - b_a);
    # w_I = R_GYROtoI Dw (w_m - Tg a_I - b_g), D = T^-1, R_XtoI = R_ItoX^T
    p_a, p_w = raw_a * ACCEL_SCALE, raw_w * D2R
    a_I = (p_a - imu["accelerometer_bias"]) @ np.linalg.inv(Ta).T @ R_a
    w_I = (p_w - a_I @ Tg.T - imu["gyroscope_bias"]) @ np.linalg.inv(Tw).T @ R_g
    a_ref, w_ref = truth(cal, raw_a, raw_w)
    R, res_a = procrustes(a_I, a_ref)
    assert res_a < 1e-9 * G0
    np.testing.assert_allclose(w_I, w_ref @ R.T, atol=1e-9)  # one frame for both sensors


def test_openvins_needs_noise(cal):
    with pytest.raises(InputError, match="--noise"):
        export(cal, "openvins", options=ExportOptions(scale={"accel": ACCEL_SCALE}))


# --------------------------------------------------------------------------------------------
# Basalt
# --------------------------------------------------------------------------------------------


def test_basalt_reader_reproduces_apply(cal, raw, noise):
    no_gs = Calibration(accel=cal.accel, gyro=GyroCalibration(
        cal.gyro.solver, "rad/s", cal.gyro.bias, cal.gyro.matrix, None,
        units_in="deg/s"), created=cal.created)  # fmt: skip
    a_true, w_true = raw
    raw_a, raw_w = raw_from_truth(no_gs, a_true, w_true)
    doc = json.loads(export(no_gs, "basalt", options=ExportOptions(scale={"accel": ACCEL_SCALE},
                                                                noise=noise)))  # fmt: skip
    ab, gb = np.array(doc["value0"]["calib_accel_bias"]), np.array(doc["value0"]["calib_gyro_bias"])
    assert ab.shape == (9,) and gb.shape == (12,)
    # Basalt (calib_bias.hpp): a = (I + S_a) p - b, S_a lower [s1 0 0; s2 s4 0; s3 s5 s6];
    # w = (I + S_w) p - b, S_w column-major
    s = ab[3:]
    S_a = np.array([[s[0], 0, 0], [s[1], s[3], 0], [s[2], s[4], s[5]]])
    S_w = gb[3:].reshape(3, 3).T
    a = (raw_a * ACCEL_SCALE) @ (np.eye(3) + S_a).T - ab[:3]
    w = (raw_w * D2R) @ (np.eye(3) + S_w).T - gb[:3]
    a_ref, w_ref = truth(no_gs, raw_a, raw_w)
    R, res = procrustes(a, a_ref)
    assert res < 1e-9 * G0
    np.testing.assert_allclose(w, w_ref @ R.T, atol=1e-9)
    assert not any("g-sensitivity dropped" in n for n in doc["value0"]["imucal_notes"])


def test_basalt_refuses_or_states_the_dropped_g_sensitivity(cal, noise):
    with pytest.raises(InputError, match="g_sensitivity .* --format basalt cannot hold"):
        export(cal, "basalt", options=ExportOptions(scale={"accel": ACCEL_SCALE}, noise=noise))
    doc = json.loads(export(cal, "basalt", options=ExportOptions(
        scale={"accel": ACCEL_SCALE}, drop=frozenset({"g-sensitivity"}), noise=noise)))  # fmt: skip
    note = [n for n in doc["value0"]["imucal_notes"] if "g-sensitivity dropped" in n]
    G = np.asarray(cal.gyro.g_sensitivity) * D2R
    assert note and f"{np.linalg.norm(G, 2) * G0:.4g} rad/s" in note[0]


# --------------------------------------------------------------------------------------------
# PX4 and ArduPilot: offset and diagonal scale
# --------------------------------------------------------------------------------------------


def px4_params(text: str) -> dict[str, float]:
    """QGroundControl's .params: tab-separated vehicle, component, name, value, type."""
    out = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            _, _, name, value, ptype = line.split("\t")
            out[name] = int(value) if ptype == "6" else float(value)
    return out


def parm_params(text: str) -> dict[str, float]:
    """ArduPilot .parm: NAME,VALUE lines, # comments."""
    return {n: float(v) for n, v in (ln.split(",") for ln in text.splitlines()
                                     if ln and not ln.startswith("#"))}  # fmt: skip


def si_cal(angles_deg, turn_deg=0.0) -> Calibration:
    """An m/s^2 / rad/s calibration with known misalignment angles."""
    S_a = misaligned_sensitivity([1.02, 0.97, 1.01], angles_deg, rotation([0, 0, 1], turn_deg))
    S_g = misaligned_sensitivity([1.05, 0.96, 1.0], angles_deg, np.eye(3))
    return Calibration(
        accel=AccelCalibration("gravity", "m/s^2", [0.12, -0.3, 0.25], np.linalg.inv(S_a),
                               None, units_in="m/s^2"),
        gyro=GyroCalibration("gyro-full", "rad/s", [0.01, -0.02, 0.004], np.linalg.inv(S_g),
                             None, units_in="rad/s"),
        created="2026-01-01T00:00:00Z",
    )  # fmt: skip


@pytest.mark.parametrize("fmt", ["px4", "ardupilot"])
def test_offset_scale_targets_exact_without_misalignment(fmt, raw):
    cal = si_cal([0.0, 0.0, 0.0])
    cal.gyro = None
    text = export(cal, fmt)
    p = px4_params(text) if fmt == "px4" else parm_params(text)
    off = "CAL_ACC0_{}OFF" if fmt == "px4" else "INS_ACCOFFS_{}"
    scl = "CAL_ACC0_{}SCALE" if fmt == "px4" else "INS_ACCSCAL_{}"
    raw_a = raw[0]
    # PX4 Accelerometer::Correct / ArduPilot _rotate_and_correct_accel: (p - off) * scale
    out = np.column_stack([(raw_a[:, i] - p[off.format(a)]) * p[scl.format(a)]
                           for i, a in enumerate("XYZ")])  # fmt: skip
    np.testing.assert_allclose(out, cal.accel.apply(raw_a), atol=1e-12 * G0)
    assert "worst error over all directions: 0.000 deg" in text


@pytest.mark.parametrize("fmt", ["px4", "ardupilot"])
def test_offset_scale_targets_state_the_loss(fmt, raw):
    angles = [0.8, -1.1, 0.5]
    cal = si_cal(angles, turn_deg=0.0)
    text = export(cal, fmt)
    p = px4_params(text) if fmt == "px4" else parm_params(text)
    names = ("CAL_ACC0_{}OFF", "CAL_ACC0_{}SCALE", "CAL_GYRO0_{}OFF") if fmt == "px4" else \
        ("INS_ACCOFFS_{}", "INS_ACCSCAL_{}", "INS_GYROFFS_{}")  # fmt: skip
    a_true = G0 * np.array([v / np.linalg.norm(v) for v in
                            np.random.default_rng(1).normal(size=(500, 3))])  # fmt: skip
    raw_a = a_true @ np.linalg.inv(cal.accel.matrix).T + cal.accel.bias
    out = np.column_stack([(raw_a[:, i] - p[names[0].format(a)]) * p[names[1].format(a)]
                           for i, a in enumerate("XYZ")])  # fmt: skip
    err = np.linalg.norm(out - a_true, axis=1).max()
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", out, a_true)
                                         / np.linalg.norm(out, axis=1) / G0, -1, 1))).max()
    m = re.search(r"accel: .*?worst error over all directions: ([\d.]+) deg, ([\d.e-]+) m/s\^2",
                  text, re.S)  # fmt: skip
    assert m, text
    assert angle <= float(m.group(1)) + 1e-3 and err <= float(m.group(2)) * 1.001
    assert float(m.group(1)) > 0.5  # a degree of misalignment is not hidden
    # the angles between the sensitivity axes are the ones the calibration was built with
    no = re.search(r"angles between sensitivity axes minus 90 deg: xy ([-+\d.]+), xz ([-+\d.]+), "
                   r"yz ([-+\d.]+)", text)  # fmt: skip
    rows = np.linalg.inv(cal.accel.matrix)
    rows = rows / np.linalg.norm(rows, axis=1)[:, None]
    expected = [np.degrees(np.arccos(rows[i] @ rows[j])) - 90 for i, j in ((0, 1), (0, 2), (1, 2))]
    np.testing.assert_allclose([float(x) for x in no.groups()], expected, atol=1e-3)
    np.testing.assert_allclose(expected[:2], [-angles[0], -angles[1]], atol=1e-9)
    assert "holds an offset only" in text  # the gyro: no scale in PX4 or ArduPilot
    for a in "XYZ":
        assert names[2].format(a) in p


def test_px4_device_id_and_units_refusal(cal):
    text = export(si_cal([0, 0, 0]), "px4", options=ExportOptions(device_id=1310988))
    p = px4_params(text)
    assert p["CAL_ACC0_ID"] == 1310988 and p["CAL_GYRO0_ID"] == 1310988
    with pytest.raises(InputError, match="--accel-scale"):  # counts without the driver's scale
        export(cal, "px4", options=ExportOptions(drop=frozenset({"g-sensitivity"})))
    with pytest.raises(InputError, match="--drop g-sensitivity"):  # PX4 has no g-sensitivity
        export(cal, "px4", options=ExportOptions(scale={"accel": ACCEL_SCALE}))


def test_diagonal_fit_scale_is_the_inverse_axis_gain():
    cal = si_cal([0.3, 0.2, -0.4])
    fit = diagonal_fit(published(cal, "accel", "t"), with_scale=True)
    np.testing.assert_allclose(fit.scale, 1 / np.array([1.02, 0.97, 1.01]), rtol=1e-12)
    np.testing.assert_allclose(fit.offset, cal.accel.bias, rtol=0)


# --------------------------------------------------------------------------------------------
# Fusion: compiled with gcc against Fusion's own sources in tests/test_fusion_export.py
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# sensor_msgs/Imu covariances
# --------------------------------------------------------------------------------------------


def test_ros_imu_covariance_is_the_per_sample_variance(noise):
    doc = yaml.safe_load(export(None, "ros-imu", options=ExportOptions(noise=noise)))
    assert doc["orientation_covariance"][0] == -1.0
    acc = np.array(doc["linear_acceleration_covariance"]).reshape(3, 3)
    gyr = np.array(doc["angular_velocity_covariance"]).reshape(3, 3)
    assert np.count_nonzero(acc - np.diag(np.diag(acc))) == 0
    # still_session: white noise 0.01 m/s^2 and 0.002 rad/s per sample; the Allan estimate of
    # a 5-minute recording carries a few percent: 4 sigma of (1 / sqrt(2 (300 - 1))) doubled
    tol = 4 * 2 / math.sqrt(2 * 299)
    np.testing.assert_allclose(np.diag(acc), 0.01**2, rtol=tol)
    np.testing.assert_allclose(np.diag(gyr), 0.002**2, rtol=tol)
    half = yaml.safe_load(export(None, "ros-imu", options=ExportOptions(noise=noise, rate_hz=50)))
    np.testing.assert_allclose(np.array(half["angular_velocity_covariance"]), gyr.ravel() / 2)


# --------------------------------------------------------------------------------------------
# The decomposition and the CLI
# --------------------------------------------------------------------------------------------


def test_lq_gives_lower_triangular_and_a_rotation():
    rng = np.random.default_rng(3)
    for _ in range(20):
        S = rng.normal(size=(3, 3))
        L, Q = lq(S)
        np.testing.assert_allclose(L @ Q, S, atol=1e-12)
        assert np.allclose(L, np.tril(L)) and np.linalg.det(Q) == pytest.approx(1.0)


def test_cli_export_targets(cal, tmp_path, noise):
    path = tmp_path / "cal.json"
    write_calibration(path, cal)
    noise_path = tmp_path / "noise.json"
    noise_path.write_text(json.dumps(noise_doc()))
    out = tmp_path / "imu.yaml"
    proc = run("export", path, "--format", "kalibr", "--noise", noise_path, "--accel-scale",
               "9.80665/16384", "-o", out)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "wrote" in proc.stderr and kalibr_yaml(out.read_text())["imu0"]["update_rate"] == 100.0
    proc = run("export", noise_path, "--format", "kalibr-imu")
    assert proc.returncode == 0 and "gyroscope_random_walk" in proc.stdout
    # --rate 1e300 was written as update_rate: 1.0e+300 (audit)
    assert_one_line_error(run("export", noise_path, "--format", "kalibr-imu", "--rate", "1e300"),
                          "--rate", "implausible")  # fmt: skip
    proc = run("export", path, "-o", tmp_path / "x.params", "--accel-scale", "0.000598",
               "--drop", "g-sensitivity")  # fmt: skip
    assert proc.returncode == 0 and "CAL_ACC0_XSCALE" in (tmp_path / "x.params").read_text()
    assert_one_line_error(run("export", path, "--format", "px4", "--drop", "g-sensitivity"),
                          "--accel-scale")  # fmt: skip
    assert_one_line_error(run("export", path, "--format", "px4", "--accel-scale", "0.0006"),
                          "--drop g-sensitivity")  # fmt: skip
    assert_one_line_error(run("export", path, "--format", "kalibr-imu"), "--noise")
    assert_one_line_error(run("export", noise_path, "--format", "px4"), "needs a calibration")
    assert_one_line_error(run("export", path, "--format", "px4", "--accel-scale", "x/2"),
                          "--accel-scale")  # fmt: skip
    assert_one_line_error(run("export", path, "--format", "nope"), "kalibr-imu")


def test_cli_export_output_is_safe(cal, tmp_path):
    path = tmp_path / "cal.json"
    write_calibration(path, cal)
    out = tmp_path / "cal.h"
    assert run("export", path, "-o", out).returncode == 0
    assert_one_line_error(run("export", path, "-o", out), "--force")
    proc = run("export", path, "-o", out, "--force", "--format", "fusion", "--drop",
               "g-sensitivity")  # fmt: skip
    assert proc.returncode == 0 and "FusionModelInertial" in out.read_text()
    assert_one_line_error(run("export", path, "-o", path, "--force", "--format", "json"), "input")
