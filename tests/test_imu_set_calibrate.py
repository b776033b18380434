"""Issue 28.2: a set of IMUs calibrated: each IMU's own calibration, each one's rotation to the
reference and time offset with their std, ``imus`` in the calibration JSON as the spec shows;
a session of one IMU gives exactly today's result.  The Monte-Carlo coverage of the 95 %
intervals and the ratio to the Cramér-Rao bounds are the slow test (``bench --only multi``
prints the same figures)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bench.multi import one_seed, summary
from imucal_cli.calibrate.imu_set import calibrate_set
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.formats.calibration import calibration_to_json, read_calibration
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.formats.session import imu_session, write_session
from imucal_cli.simulate.imu_set import gauge_rotation, simulate_set

from .cli_helpers import run

CREATED = "2026-01-01T00:00:00Z"


def _same(a, b):
    """Two calibrations' JSON, apart from when they were made."""
    da, db = json.loads(calibration_to_json(a)), json.loads(calibration_to_json(b))
    da.pop("created"), db.pop("created")
    return da == db


def test_a_one_imu_session_gives_exactly_todays_result():
    session, _ = simulate_set(1, seed=3, created=CREATED)
    assert _same(calibrate_set(session, Config(), name="s.h5"),
                 calibrate_session(session, Config(), name="s.h5"))  # fmt: skip


def test_the_cli_calibrates_a_one_imu_session_as_before(tmp_path):
    session, _ = simulate_set(1, seed=3, created=CREATED)
    path = tmp_path / "one.h5"
    write_session(path, session)
    proc = run("calibrate", path, "--no-store")
    assert proc.returncode == 0, proc.stderr
    assert "set:" not in proc.stdout
    got = read_calibration(tmp_path / "one.cal.json")
    assert got.imus is None and "imus" not in got.to_dict()
    assert _same(got, calibrate_session(session, Config(), name="one.h5"))


@pytest.fixture(scope="module")
def calibrated():
    session, truth = simulate_set(3, seed=11, created=CREATED)
    return session, truth, calibrate_set(session, Config(), name="set.h5")


def _true_rotation(truth, key):
    q0 = gauge_rotation(np.array(truth.accel.matrix))
    entry = truth.to_dict()["imus"][key]
    return q0.T @ np.array(entry["rotation_to_reference"]) @ gauge_rotation(
        np.array(entry["accel"]["matrix"]))  # fmt: skip


def test_imus_in_the_json_as_the_spec_shows(calibrated, tmp_path):
    session, _, cal = calibrated
    doc = json.loads(calibration_to_json(cal))
    assert list(doc["imus"]) == ["imu1", "imu2"]
    for entry in doc["imus"].values():
        for sensor in ("accel", "gyro"):
            assert {"solver", "units", "bias", "matrix", "residual_rms"} <= set(entry[sensor])
        R = np.array(entry["rotation_to_reference"])
        assert R.shape == (3, 3) and np.allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        assert len(entry["rotation_std_deg"]) == 3 and all(s > 0 for s in entry["rotation_std_deg"])
        assert isinstance(entry["time_offset_s"], float) and entry["time_offset_std_s"] > 0
    path = tmp_path / "set.cal.json"
    path.write_text(calibration_to_json(cal))
    assert json.loads(calibration_to_json(read_calibration(path)))["imus"] == doc["imus"]


def test_rotations_and_offsets_against_the_truth(calibrated):
    """Each within 4.5 std of the truth (a false alarm once in ~10^4 tests per value)."""
    session, truth, cal = calibrated
    for key, entry in cal.to_dict()["imus"].items():
        err = Rotation.from_matrix(np.array(entry["rotation_to_reference"])
                                   @ _true_rotation(truth, key).T).as_rotvec()  # fmt: skip
        assert np.all(np.abs(err) <= 4.5 * np.radians(entry["rotation_std_deg"])), (key, err)
        dt = entry["time_offset_s"] - truth.to_dict()["imus"][key]["time_offset_s"]
        assert abs(dt) <= 4.5 * entry["time_offset_std_s"], (key, dt)
        assert entry["time_offset_std_s"] < 1e-3  # turns of 1.5 s: tens of microseconds
        assert entry["warnings"] == []


def test_each_imu_is_calibrated_like_a_single_imu(calibrated):
    """Each IMU's own calibration in its own frame: its matrix applied to its raw still
    readings gives gravity's magnitude; the joint fit is said and is at least as precise as
    the IMU alone."""
    session, _, cal = calibrated
    for key in session.imus:
        entry = cal.to_dict()["imus"][key]
        sec = entry["accel"]
        assert sec["set_fit"]["method"].startswith("joint maximum likelihood")
        sub = imu_session(session, key, entry["set"]["coarse_offset_s"])
        M, b = np.array(sec["matrix"]), np.array(sec["bias"])
        for seg in sub.static_segments():
            a = (sub.accel[seg.start:seg.stop].mean(axis=0) - b) @ M.T
            assert abs(np.linalg.norm(a) - session.gravity) < 0.01
        alone = calibrate_session(sub, Config())
        std_joint = np.array([p["std"] for p in sec["parameters"]])
        std_alone = np.array([p["std"] for p in alone.accel.to_dict()["parameters"]])
        assert np.all(std_joint <= std_alone * 1.001)
        assert entry["gyro"]["solver"] == alone.gyro.solver


def test_the_cli_prints_the_set(tmp_path):
    proc = run("simulate", "--imus", "2", "--plan", "random:12", "--seed", "2", "-o",
               tmp_path / "s.h5")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "2 IMUs (reference in /raw, imu1 in /imus)" in proc.stdout
    proc = run("calibrate", tmp_path / "s.h5", "--no-store")
    assert proc.returncode == 0, proc.stderr
    assert "imu1: rotated" in proc.stdout and "ms; calibrated: accel, gyro" in proc.stdout
    assert "frame of the labels" not in proc.stdout  # gravity solver: each IMU's own axes
    proc = run("calibrate", tmp_path / "s.h5", "--accel", tmp_path / "s.cal.json", "-o",
               tmp_path / "x.json")  # fmt: skip
    assert proc.returncode == 2 and "several IMUs takes no --accel" in proc.stderr


def test_the_cli_says_a_time_offset_came_from_the_raw_rates(tmp_path):
    """Six faces, 2 IMUs in counts: neither gyro is calibrated (five turns), and the summary
    gives imu1's time offset, saying it came from the raw rates (eq. T5)."""
    proc = run("simulate", "--imus", "2", "--plan", "six", "--seed", "0", "-o",
               tmp_path / "s.h5")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    (tmp_path / "c.toml").write_text('[accel]\nsolver = "labelled"\n', encoding="utf-8")
    proc = run("calibrate", tmp_path / "s.h5", "--no-store", "--config", tmp_path / "c.toml",
               "-o", tmp_path / "s.json")  # fmt: skip
    assert proc.returncode in (0, 1), proc.stderr
    line = next(x for x in proc.stdout.splitlines() if x.strip().startswith("imu1: rotated"))
    assert "time offset" in line and "(from the raw rates: a gyro not calibrated" in line, line
    # both accelerometers labelled: the rotation is near zero by construction, and said so
    assert "both accelerometers calibrated into the frame of the labels" in line, line
    entry = json.loads((tmp_path / "s.json").read_text(encoding="utf-8"))["imus"]["imu1"]
    assert entry["time_offset_std_s"] > 0 and "eq. T5" in entry["set"]["offset_method"]


def test_simulate_imus_refuses_what_it_does_not_simulate(tmp_path):
    for args, words in ((["--plan", "qureshi-axes"], "pose plans"),
                        (["--mag"], "does not combine with --mag"),
                        (["--imus", "0"], "from 1 to"),
                        (["--imus", "1", "--imu-offset", "3"], "goes with --imus")):  # fmt: skip
        base = ["--imus", "3"] if "--imus" not in args else []
        proc = run("simulate", *base, *args, "-o", tmp_path / "x.h5")
        assert proc.returncode == 2 and words in proc.stderr, (args, proc.stderr)


def test_small_monte_carlo_errors_match_the_bounds():
    """Three seeds of 3 IMUs: every error within 4.5 reported std, and the reported std
    within 30 % of the Cramér-Rao bound (at a few seeds; the slow test checks coverage)."""
    rows = [one_seed(3, s) for s in (101, 102, 103)]
    for r in rows:
        assert np.all(np.abs(r["rot_err"]) <= 4.5 * r["rot_std"])
        assert np.all(np.abs(r["dt_err"]) <= 4.5 * r["dt_std"])
        np.testing.assert_allclose(r["rot_std"], r["rot_bound"], rtol=0.3)
        np.testing.assert_allclose(r["dt_std"], r["dt_bound"], rtol=0.3)


@pytest.mark.slow
def test_coverage_and_efficiency_over_seeds():
    """The 95 % intervals of every rotation component, time offset and accelerometer
    parameter cover the truth 93-97 % of the time, and the RMS errors are within 20 % of the
    Cramér-Rao bounds: 100 sets of 3 IMUs and 40 of 8 (fixed seeds: the same figures on every
    run; ``python -m bench --only multi`` prints them per set size)."""
    rows = [one_seed(3, 1000 + s) for s in range(100)] + [one_seed(8, 2000 + s)
                                                          for s in range(40)]  # fmt: skip
    res = summary(rows)
    for name in ("rotation", "time offset", "accel parameters"):
        r = res[name]
        assert 0.93 <= r["coverage"] <= 0.97, (name, r)
        assert r["ratio"] <= 1.2, (name, r)
    assert res["joint gain"] > 1.2  # fitting the set jointly beats each IMU alone


def test_labelled_response_is_the_fits_derivative():
    """The labelled fit's response to a pose's mean (what a set's rotations take its
    covariance with the pairs from, eq. R3) is the derivative of its estimate: a refit with one
    pose's mean moved by +-0.3 of its std (central differences) agrees to 1 % of the largest
    parameter change, in the frame's rotation too, where Gauss-Newton's response did not (the
    residuals' curvature along the frame's rotation, 6 deg placement)."""
    from imucal_cli.calibrate.common import static_poses
    from imucal_cli.estimators.accel.labelled import fit_labelled
    from imucal_cli.estimators.accel.labelled_response import pose_response

    session, _ = simulate_set(3, plan="qureshi18", seed=2, created=CREATED, jitter_deg=6.0)
    p = static_poses(session)
    res = fit_labelled(p.a_mean, p.up, session.gravity, p.cov_mean)
    for k, j in ((3, 1), (7, 0), (12, 2)):
        h = 0.3 * np.sqrt(p.cov_mean[k, j, j])
        moved = []
        for sign in (1, -1):
            a = p.a_mean.copy()
            a[k, j] += sign * h
            moved.append(fit_labelled(a, p.up, session.gravity, p.cov_mean,
                                      placement_deg=res.placement_deg).params)  # fmt: skip
        fd = (moved[0] - moved[1]) / (2 * h)
        scale = np.abs(fd).max()
        np.testing.assert_allclose(pose_response(res)[:, k, j], fd, atol=0.01 * scale)
        # the rotation's rows on their own scale (they are 10-1000 times smaller)
        np.testing.assert_allclose(pose_response(res)[9:, k, j], fd[9:],
                                   atol=0.01 * np.abs(fd[9:]).max())  # fmt: skip


def _labelled_set_z(seeds, plan: str = "qureshi18") -> tuple[np.ndarray, list[np.ndarray]]:
    """Each rotation component's error over its stated std (n, 3) of 3-IMU sets calibrated by
    the labelled solver, and each seed's rows of it (for the design effect)."""
    from bench.multi import labelled_seed

    per = [np.reshape(r["rot_err"] / r["rot_std"], (-1, 3))
           for r in (labelled_seed(3, s, plan) for s in seeds)]  # fmt: skip
    return np.concatenate(per), per


def test_labelled_set_rotations_std_matches_their_error():
    """Three 3-IMU qureshi18 sets calibrated by the labelled solver: each rotation's stated std
    is its error's (eq. R3). The placement, shared by the IMUs and counted once per IMU, made
    the std 10^3 times the error (mean (err/std)^2 1e-6); the calibrations' covariance with
    the pose means left out, 30 times (1e-3). 18 components (two IMUs share the reference):
    mean (err/std)^2 within [0.2, 3], chi^2_18 / 18's 99.9 % range widened for the sharing."""
    z, _ = _labelled_set_z((0, 1, 2))
    assert 0.2 <= float(np.mean(z**2)) <= 3.0, z
    assert np.all(np.abs(z) <= 4.5), z


def test_six_face_set_rotations_std_matches_their_error():
    """The same on six faces, where each labelled fit puts its calibrated means on the gravity
    sphere exactly (18 equations, 24 unknowns): the pairs' weights across each pair only (eq.
    R3's weights). With the inverse of the whole error covariance, whose variance along each
    pair nearly cancels, the errors were 10-160 times the stated std (mean (err/std)^2 near
    10^4); seeds 0-2 give 0.41 now."""
    z, _ = _labelled_set_z((0, 1, 2), "six")
    assert 0.2 <= float(np.mean(z**2)) <= 3.0, z
    assert np.all(np.abs(z) <= 4.5), z


def test_one_labelled_imu_never_computes_the_sets_response(monkeypatch):
    """The labelled fit's response to each pose's mean (eq. L7) is computed only where a set
    asks for it: a one-IMU calibration never calls it; its section's ``given_placement`` calls
    it once, on first access."""
    from imucal_cli.calibrate.accel import labelled as step

    calls = []
    original = step.pose_response
    monkeypatch.setattr(step, "pose_response", lambda res: calls.append(1) or original(res))
    session, _ = simulate_set(1, plan="qureshi18", seed=4, created=CREATED)
    cal = calibrate_set(session, config_from_dict({"accel": {"solver": "labelled"}}))
    assert calls == []
    gp = cal.accel.given_placement
    assert gp.response.shape == (12, len(gp.segments), 3) and gp.covariance.shape == (12, 12)
    assert calls == [1]
    gp.covariance  # noqa: B018 (computed once)
    assert calls == [1]


def test_six_face_set_gets_time_offsets_without_calibrated_gyros():
    """Six faces, 3 IMUs in raw counts: five turns do not determine the gyros (each one left
    out, no nominal sensitivity for a partial section), and the time offsets no longer need
    them (eq. T5: raw rates, the matrix between the gyros fitted with the offset). Each IMU
    gets one, within 3 std of the truth, its std near the bound's scale (tens of us), and
    its entry says how it was found; before, neither IMU got one."""
    session, truth = simulate_set(3, plan="six", seed=0, created=CREATED, rate_hz=100.0,
                                  hold_s=2.0)  # fmt: skip
    cal = calibrate_set(session, config_from_dict({"accel": {"solver": "labelled"}}))
    assert cal.gyro is None and "gyro" in cal.left_out
    assert set(cal.imus) == {"imu1", "imu2"}
    for key, entry in cal.imus.items():
        assert entry.gyro is None or entry.gyro.approach == "partial"
        assert entry.time_offset_s is not None, entry.warnings
        err = entry.time_offset_s - truth.imus[key].time_offset_s
        assert 0 < entry.time_offset_std_s < 2e-4, entry.time_offset_std_s
        assert abs(err) <= 3 * entry.time_offset_std_s, (key, err, entry.time_offset_std_s)
        assert "eq. T5" in entry.set.offset_method and entry.set.offset_rms_units == "raw"
        assert entry.set.offset_rms < 1.5 * entry.set.offset_rms_expected
        assert not entry.warnings


def test_a_gyro_calibrated_in_part_only_gets_its_offset_from_the_raw_rates(monkeypatch):
    """A gyro whose matrix is held at a prior (a partial section: approach "partial") is not
    calibrated in full: its time offset comes from the raw rates (eq. T5), within 3 std of the
    truth, while the fully calibrated IMU's keeps eq. T4 (no ``offset_method``). Here imu1's
    gyro section is marked partial after its own calibration."""
    from imucal_cli.calibrate import imu_set as set_module

    original = set_module.calibrate_session

    def marked(session, cfg, **kw):
        cal = original(session, cfg, **kw)
        if str(kw.get("name", "")).endswith(":imu1") and cal.gyro is not None:
            cal.gyro.approach = "partial"
        return cal

    monkeypatch.setattr(set_module, "calibrate_session", marked)
    session, truth = simulate_set(3, plan="qureshi18", seed=0, created=CREATED, rate_hz=100.0,
                                  hold_s=2.0)  # fmt: skip
    cal = calibrate_set(session, config_from_dict({"accel": {"solver": "labelled"}}))
    one, two = cal.imus["imu1"], cal.imus["imu2"]
    assert one.gyro.approach == "partial" and two.gyro.approach != "partial"
    assert "eq. T5" in one.set.offset_method and two.set.offset_method is None
    for key, entry in cal.imus.items():
        err = entry.time_offset_s - truth.imus[key].time_offset_s
        assert abs(err) <= 3 * entry.time_offset_std_s, (key, err, entry.time_offset_std_s)


def _six_face_offset_z(seeds) -> list[np.ndarray]:
    """Each seed's time offsets' errors over their std (3-IMU six-face sets, labelled)."""
    from bench.multi import labelled_seed

    return [np.ravel(r["dt_err"] / r["dt_std"]) for r in (labelled_seed(3, s, "six")
                                                           for s in seeds)]  # fmt: skip


@pytest.mark.slow
def test_six_face_time_offsets_cover_over_seeds():
    """80 six-face sets: every IMU gets a time offset (before, those whose gyros were not
    calibrated got none: 91 of 320 over 160 seeds had one), its 95 % intervals cover the truth
    within 3 standard errors of 95 % (the binomial times the seeds' design effect, Kish) and
    the RMS of error/std is 0.8-1.2."""
    from bench.live_table import design_effect

    per = _six_face_offset_z(range(80))
    assert all(len(p) == 2 for p in per)
    z = np.concatenate(per)
    hits = np.abs(z) <= 1.959964
    deff = design_effect([np.abs(p) <= 1.959964 for p in per])
    se = np.sqrt(0.95 * 0.05 * deff / len(hits))
    assert abs(float(np.mean(hits)) - 0.95) <= 3 * se, (np.mean(hits), deff)
    assert 0.8 <= float(np.sqrt(np.mean(z**2))) <= 1.2


@pytest.mark.slow
@pytest.mark.parametrize("plan", ["qureshi18", "six"])
def test_labelled_set_rotations_cover_over_seeds(plan):
    """80 sets as above per plan: the 95 % intervals of each rotation component cover the
    truth (the identity) within 3 standard errors of 95 % (160 intervals per component, the
    standard error binomial times the seeds' design effect, Kish: the two IMUs of a seed share
    the reference), and the RMS of error/std is 0.8-1.2 per component (``bench --only
    multi`` prints the figures over more seeds). Six faces before eq. R3's weights: 7.7 %."""
    from bench.live_table import design_effect

    z, per = _labelled_set_z(range(80), plan)
    for c in range(3):
        hits = np.abs(z[:, c]) <= 1.959964
        deff = design_effect([np.abs(p[:, c]) <= 1.959964 for p in per])
        se = np.sqrt(0.95 * 0.05 * deff / len(hits))
        assert abs(float(np.mean(hits)) - 0.95) <= 3 * se, (plan, c, np.mean(hits), deff)
        assert 0.8 <= float(np.sqrt(np.mean(z[:, c] ** 2))) <= 1.2, (plan, c)


def test_a_g_sensitive_gyros_rates_take_the_g_term_out_with_its_accelerometer():
    """The set's time offset and still noise use the calibrated rates: a gyro calibrated with
    g_sensitivity (a long session of many poses fits one) has it taken out with the calibrated
    accelerometer of the same samples (it raised "needs the calibrated accelerometer")."""
    from types import SimpleNamespace

    from imucal_cli.calibrate.set_parts import calibrated_rates, still_noise
    from imucal_cli.model.section import SensorCalibration

    rng = np.random.default_rng(3)
    raw = SimpleNamespace(gyro=rng.normal(0, 50, (40, 3)), accel=rng.normal(0, 800, (40, 3)),
                          static_segments=lambda: [SimpleNamespace(start=0, stop=40)])  # fmt: skip
    acc = SensorCalibration(solver="gravity", units="m/s^2", bias=np.full(3, 5.0),
                            matrix=np.eye(3) / 830)  # fmt: skip
    g = np.array([[0.3, 0.0, 0.1], [0.0, -0.2, 0.0], [0.05, 0.0, 0.4]])  # counts per m/s^2
    gyr = SensorCalibration(solver="gyro-full", units="rad/s", bias=np.array([18.0, -49, -33]),
                            matrix=np.eye(3) / 915, g_sensitivity=g)  # fmt: skip
    a = (raw.accel - acc.bias) @ acc.matrix.T
    want = (raw.gyro - gyr.bias - a @ g.T) @ gyr.matrix.T
    np.testing.assert_allclose(calibrated_rates(raw, gyr, acc), want, rtol=1e-12)
    np.testing.assert_allclose(calibrated_rates(raw, gyr, acc, slice(5, 9)), want[5:9],
                               rtol=1e-12)  # fmt: skip
    assert np.isfinite(still_noise(raw, gyr, acc)) and still_noise(raw, gyr, acc) > 0
