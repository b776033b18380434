"""Issue 27.3, the gyroscope: a log whose turns cannot determine the gyro's model (a vehicle's
log: a few still periods and free turns, no labels, the accelerometer determined only in
part; poses on one face and no turns) saves the gyro with its bias measured by the still
periods (with std) and its matrix assumed: held at the nominal prior (``[gyro]
nominal_sensitivity`` or the units' 1 rad/s per rad/s; gains 3 %, axes 2 deg) or at an earlier
calibration's gyro (``--prior CAL.json``), marked as the accelerometer's partial fit marks it
(``status``, ``prior_std``, the section's ``partial``), saying what would measure the rest.

Against the truth: the bias within its std (95 % intervals: 5 seeds here, 50 in the slow
test, 93-97 %; the figure in docs/accuracy.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.calibrate.gyro.partial import ANGLE_STD_DEG, GAIN_STD, NAMES
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.formats.session import write_session
from imucal_cli.simulate.play import simulate_plan

from .cli_helpers import run
from .test_partial_design import CREATED, ONE_FACE, VEHICLE, _simulate

#: The simulated part's datasheet gain: 16.4 LSB per deg/s, in counts per rad/s.
NOMINAL = 16.4 * 180 / np.pi
CFG = {"gyro": {"nominal_sensitivity": NOMINAL}}


def _nominal_matrix_and_std() -> tuple[np.ndarray, np.ndarray]:
    std = np.full((3, 3), np.radians(ANGLE_STD_DEG) / NOMINAL)
    np.fill_diagonal(std, GAIN_STD / NOMINAL)
    return np.eye(3) / NOMINAL, std


def _bias_z(sec, truth) -> np.ndarray:
    rows = {p.name: p for p in sec.parameters}
    b = np.array([rows[f"b_{a}"].value for a in "xyz"])
    sd = np.array([rows[f"b_{a}"].std for a in "xyz"])
    return (b - truth.gyro.bias) / sd


def _check_partial(sec, matrix: np.ndarray, std: np.ndarray) -> None:
    """What every partial gyro section holds: the bias measured, the matrix the prior's."""
    assert sec.solver == "gyro-partial" and sec.choice.solver == "partial"
    assert [p.name for p in sec.parameters] == list(NAMES)
    part = sec.partial
    assert part.measured == ["b_x", "b_y", "b_z"]
    assert part.assumed == list(NAMES[3:])
    rows = {p.name: p for p in sec.parameters}
    for k, name in enumerate(NAMES[3:]):
        r, c = divmod(k, 3)
        row = rows[name]
        assert row.status == "assumed"
        # held exactly at the prior: the still periods say nothing of the matrix
        assert row.value == pytest.approx(matrix[r, c], rel=1e-12, abs=1e-15)
        assert row.std == pytest.approx(std[r, c], rel=1e-12)
        assert row.prior_std == pytest.approx(std[r, c], rel=1e-12)
    assert np.allclose(np.asarray(sec.matrix), matrix, rtol=1e-12, atol=1e-15)
    for name in ("b_x", "b_y", "b_z"):
        assert rows[name].status == "measured"
        assert rows[name].std < 0.5 * rows[name].prior_std
    assert "turns about each axis" in part.capture
    assert sec.notes[0].startswith("these still periods determine only part of the model: "
                                   "measured b_x, b_y, b_z; assumed (held at the prior, with "
                                   "its std) m_xx")  # fmt: skip


def test_a_vehicle_log_measures_the_gyro_bias_and_assumes_the_matrix(tmp_path):
    matrix, std = _nominal_matrix_and_std()
    z = []
    for seed in range(5):
        session, truth = _simulate(tmp_path, VEHICLE, seed)
        cal = calibrate_session(session, config_from_dict(CFG))
        assert "gyro" not in (cal.left_out or {}) and cal.complete is False
        assert cal.accel.partial is not None
        _check_partial(cal.gyro, matrix, std)
        assert "prior: nominal" in cal.gyro.notes[0]
        z.extend(_bias_z(cal.gyro, truth))
    z = np.abs(np.array(z))
    # 15 intervals: every error within 3.5 std, most within 1.96 (95 %; 50 seeds when slow)
    assert z.max() < 3.5, z
    assert np.mean(z < 1.96) >= 0.8, z


def test_still_periods_alone_measure_the_bias(tmp_path):
    session, truth = _simulate(tmp_path, ONE_FACE, seed=2, labels=True)
    assert not session.rotation_segments()
    cal = calibrate_session(session, config_from_dict(CFG))
    _check_partial(cal.gyro, *_nominal_matrix_and_std())
    assert np.all(np.abs(_bias_z(cal.gyro, truth)) < 4)


def test_raw_rad_per_s_needs_no_nominal_from_the_config(tmp_path):
    plan = tmp_path / "vehicle.toml"
    plan.write_text(VEHICLE)
    session, truth = simulate_plan(str(plan), seed=3, created=CREATED, units="m/s^2")
    cal = calibrate_session(session, Config())
    std = np.full((3, 3), np.radians(ANGLE_STD_DEG))
    np.fill_diagonal(std, GAIN_STD)
    _check_partial(cal.gyro, np.eye(3), std)
    assert np.all(np.abs(_bias_z(cal.gyro, truth)) < 4)


def test_counts_without_a_nominal_gain_leave_the_gyro_out_with_its_bias(tmp_path):
    """The range of raw counts cannot be read from still data: no value to hold the matrix
    at, so no section; the note gives the bias and what would save it."""
    session, truth = _simulate(tmp_path, VEHICLE, seed=1)
    cal = calibrate_session(session, Config())
    assert cal.gyro is None
    note = cal.left_out["gyro"]
    assert "its still periods measure the bias (" in note
    assert "[gyro] nominal_sensitivity" in note and "--prior CAL.json" in note
    said = note.split("measure the bias (")[1].split(" +- ")[0]
    assert np.allclose([float(x) for x in said.split(", ")], truth.gyro.bias, atol=1.0)


def test_cli_and_report_say_which_are_measured_and_which_assumed(tmp_path):
    plan = tmp_path / "vehicle.toml"
    plan.write_text(VEHICLE)
    path = tmp_path / "log.h5"
    assert run("simulate", "--plan", plan, "--seed", 1, "-o", path).returncode == 0
    config = tmp_path / "gyro.toml"
    config.write_text(f"[gyro]\nnominal_sensitivity = {NOMINAL!r}\n")
    out = tmp_path / "log.cal.json"
    proc = run("calibrate", path, "--no-store", "--config", config, "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "gyro: gyro-partial" in proc.stdout
    assert "measured by this session: b_x " in proc.stdout
    assert "assumed (not measured: the prior's value and std): m_xx " in proc.stdout
    assert "to measure the rest: turns about each axis" in proc.stdout
    gyro = json.loads(out.read_text())["gyro"]
    assert gyro["partial"]["measured"] == ["b_x", "b_y", "b_z"]
    assert {p["name"]: p["status"] for p in gyro["parameters"]} == {
        n: "measured" if n.startswith("b_") else "assumed" for n in NAMES}
    assert all(p["prior_std"] > 0 for p in gyro["parameters"])
    report = run("report", out)
    assert report.returncode == 0, report.stderr
    assert "m_xx (assumed)" in report.stdout and "b_x (assumed)" not in report.stdout
    rep = json.loads(run("report", out, "--json").stdout)
    tables = [t for t in rep["sensors"]["gyro"]["tables"] if t["title"] == "measured and assumed"]
    assert len(tables) == 1 and len(tables[0]["rows"]) == 12
    # an export holds the whole model: it says which gyro terms are assumed
    exp = run("export", out, "--format", "c-header", "-o", tmp_path / "cal.h")
    assert exp.returncode == 0, exp.stderr
    assert "warning: the gyro calibration is partial: m_xx, m_xy" in exp.stderr


def test_an_earlier_calibration_is_the_gyro_prior(tmp_path):
    """``--prior CAL.json`` with a gyro: the matrix held at its values and std (the same
    part: the seed draws it), the bias still measured by this log's still periods."""
    full, _ = simulate_plan("qureshi18", seed=7, created=CREATED)
    earlier = tmp_path / "q18.h5"
    write_session(earlier, full)
    cal_path = tmp_path / "q18.cal.json"
    assert run("calibrate", earlier, "--no-store", "-o", cal_path).returncode == 0
    before = json.loads(cal_path.read_text())["gyro"]
    assert before["solver"] == "gyro-full"
    std_of = {p["name"]: p["std"] for p in before["parameters"]}
    matrix = np.array(before["matrix"])
    std = np.array([std_of[n] for n in NAMES[3:]]).reshape(3, 3)
    session, truth = _simulate(tmp_path, VEHICLE, seed=7)
    log = tmp_path / "log.h5"
    write_session(log, session)
    out = tmp_path / "log.cal.json"
    proc = run("calibrate", log, "--no-store", "--prior", cal_path, "-o", out)  # no config
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(out.read_text())
    gyro = doc["gyro"]
    assert gyro["solver"] == "gyro-partial" and str(cal_path) in gyro["partial"]["prior"]
    assert gyro["frame"] == before["frame"]
    rows = {p["name"]: p for p in gyro["parameters"]}
    for k, name in enumerate(NAMES[3:]):
        r, c = divmod(k, 3)
        assert rows[name]["status"] == "assumed"
        assert rows[name]["value"] == pytest.approx(matrix[r, c], rel=1e-12)
        assert rows[name]["std"] == pytest.approx(std[r, c], rel=1e-12)
        # (its frame is the earlier accelerometer calibration's, not the truth's: said)
    for k, a in enumerate("xyz"):
        row = rows[f"b_{a}"]
        assert row["status"] == "measured"
        assert abs(row["value"] - truth.gyro.bias[k]) < 4 * row["std"]


def test_a_full_gyro_design_is_not_partial():
    session, _ = simulate_plan("qureshi18", seed=2, created=CREATED)
    gyro = calibrate_session(session, config_from_dict(CFG)).gyro
    assert gyro.solver == "gyro-full" and gyro.partial is None
    assert all(p.status is None and p.prior_std is None for p in gyro.parameters)


def test_a_drifting_bias_scales_its_std(tmp_path):
    """Still periods whose means scatter beyond their noise (a bias that drifted between
    them): said, and the std scaled by the scatter, so that it still covers."""
    session, _ = _simulate(tmp_path, VEHICLE, seed=4)
    gyro = session.gyro.astype(float).copy()
    for k, seg in enumerate(session.static_segments()):
        gyro[seg.start:seg.stop] += 3.0 * k  # 3 counts (0.18 deg/s) more each period
    from dataclasses import replace

    drifted = calibrate_session(replace(session, gyro=gyro), config_from_dict(CFG)).gyro
    still = calibrate_session(session, config_from_dict(CFG)).gyro
    assert any("scatter" in w and "drifted" in w for w in drifted.warnings)
    assert drifted.parameters[0].std > 3 * still.parameters[0].std
    assert not any("scatter" in w for w in still.warnings or [])


@pytest.mark.slow
def test_the_bias_covers_the_truth_over_50_seeds(tmp_path):
    z = []
    for seed in range(100, 150):
        session, truth = _simulate(tmp_path, VEHICLE, seed)
        z.extend(_bias_z(calibrate_session(session, config_from_dict(CFG)).gyro, truth))
    inside = float(np.mean(np.abs(np.array(z)) < 1.959964))
    assert 0.93 <= inside <= 0.97, (inside, len(z))


def test_still_poses_beside_a_determined_accelerometer(tmp_path):
    """Poses that determine the accelerometer and a gyro that never turned (rad/s: nominal 1):
    the gyro's bias measured, its matrix assumed; a capture's refit counts it as not yet
    determined (its targets are not the prior's)."""
    from dataclasses import replace

    from imucal_cli.calibrate.refit import refit

    session, truth = simulate_plan("qureshi18", seed=3, created=CREATED, units="m/s^2")
    rng = np.random.default_rng(5)
    still = replace(session, gyro=truth.gyro.bias + rng.normal(0.0, 0.005, session.gyro.shape),
                    segments=[s for s in session.segments if s.kind == "static"])  # fmt: skip
    cal = calibrate_session(still, Config())
    assert cal.accel.partial is None and cal.accel.solver == "gravity"
    std = np.full((3, 3), np.radians(ANGLE_STD_DEG))
    np.fill_diagonal(std, GAIN_STD)
    _check_partial(cal.gyro, np.eye(3), std)
    assert "no usable rotations" in cal.gyro.choice.reason
    assert np.all(np.abs(_bias_z(cal.gyro, truth)) < 4)
    so_far, notes = refit(still, Config())
    assert so_far.gyro is None and "determined only in part" in notes["gyro"]
    assert so_far.accel is not None


DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.mark.skipif(not DATA.is_dir(), reason="shared/data recordings not present")
def test_a_real_still_recording_measures_the_bias_and_says_it_drifted(tmp_path):
    """tomisuarez2's MPU-6050 still recording (100 s, +-250 deg/s: 131 LSB per deg/s): the
    gyro saved in part, and its z bias, which drifts by about 1 count between the halves (4
    times the white noise's std of a half's mean), found drifting: its std scaled."""
    out = tmp_path / "still.h5"
    proc = run("import", DATA / "tomisuarez2_mpu6050/imu_static_test.csv", "--rate", 100,
               "--accel-units", "counts", "--gyro-units", "counts", "-o", out)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    config = tmp_path / "gyro.toml"
    config.write_text(f"[gyro]\nnominal_sensitivity = {131 * 180 / np.pi!r}\n")
    cal_path = tmp_path / "still.cal.json"
    proc = run("calibrate", out, "--no-store", "--config", config, "-o", cal_path)
    assert proc.returncode == 0, proc.stderr
    gyro = json.loads(cal_path.read_text())["gyro"]
    assert gyro["solver"] == "gyro-partial"
    rows = {p["name"]: p for p in gyro["parameters"]}
    raw = np.loadtxt(DATA / "tomisuarez2_mpu6050/imu_static_test.csv", delimiter=",",
                     skiprows=5)[:, 3:6]  # fmt: skip
    white = raw.std(axis=0) / np.sqrt(len(raw))
    for k, a in enumerate("xyz"):  # the mean rate of the still data (the MAP prior: nil)
        assert abs(rows[f"b_{a}"]["value"] - raw[:, k].mean()) < 0.5 * white[k]
    (warning,) = [w for w in gyro["warnings"] if "drifted" in w]
    assert rows["b_z"]["std"] > 1.5 * white[2]  # scaled by the scatter
    assert rows["b_x"]["std"] == pytest.approx(white[0], rel=0.05)  # x: white
