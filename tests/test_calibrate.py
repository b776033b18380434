"""`imucal calibrate` end to end: recovery against the simulator's truth, independence from the
raw units, the 12-parameter variant, refusals with advice, and exit codes."""

from __future__ import annotations

import json
import subprocess

import h5py
import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session, static_poses
from imucal_cli.errors import ConfigError, DesignError
from imucal_cli.estimators.accel.gravity import model_to_params
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.formats.session import read_session, write_session
from imucal_cli.simulate.triad import simulate

from .cli_helpers import run, run_process

CREATED = "2026-01-01T00:00:00Z"


def assert_one_line_error(proc: subprocess.CompletedProcess, code: int, *words: str) -> None:
    assert proc.returncode == code, (proc.returncode, proc.stdout, proc.stderr)
    err = proc.stderr.strip()
    assert "Traceback" not in proc.stderr
    assert len(err.splitlines()) == 1, err
    assert err.startswith("imucal: error:")
    for w in words:
        assert w in err, (w, err)


def gauge(T):
    Q, R = np.linalg.qr(T)
    D = np.diag(np.sign(np.diag(R)))
    return D @ R


@pytest.fixture(scope="module")
def sim18(tmp_path_factory):
    path = tmp_path_factory.mktemp("s") / "q18.h5"
    session, truth = simulate(plan="qureshi18", seed=3, created=CREATED)
    write_session(path, session)
    return path, truth


def test_recovers_truth_within_its_reported_uncertainty(sim18):
    path, truth = sim18
    cal = calibrate_session(read_session(path), Config())
    acc = cal.accel
    x_true = model_to_params(truth.accel.bias, gauge(truth.accel.matrix))
    x = np.array([p.value for p in acc.parameters])
    std = np.array([p.std for p in acc.parameters])
    # Tolerance from the noise: the reported std agrees with the bound (tested in the solver
    # tests), so each error must be within 4.5 sigma (p ~ 1e-5 per parameter).
    assert np.all(np.abs(x - x_true) < 4.5 * std), (x - x_true) / std
    # The std itself is what the noise implies: sigma_b ~ sigma / sqrt(n_poses * samples / 3)
    sens = np.mean(truth.accel.sensitivity)
    sigma_counts = truth.accel.noise * sens
    expected_bias_std = sigma_counts / np.sqrt(18 * 200 / 3)
    assert np.allclose(std[:3], expected_bias_std, rtol=0.35)
    # Calibrated magnitudes match g to the noise of a pose mean.
    assert acc.rms_after < 3 * truth.accel.noise / np.sqrt(200)
    assert acc.rms_before > 20 * acc.rms_after
    assert acc.rms_loo > acc.rms_after
    assert acc.warnings == []
    assert cal.sensor == "sim-16bit seed 3"
    assert acc.model == "calibrated = matrix @ (raw - bias)"
    assert acc.units_in == "counts" and acc.units == "m/s^2"


def test_same_answer_whatever_the_raw_units(tmp_path):
    """Counts and m/s^2 sessions of one seed describe one experiment: the calibrated pose
    vectors agree to within the quantisation and noise of a pose mean."""
    out = {}
    for units in ("counts", "m/s^2"):
        session, _ = simulate(plan="qureshi18", seed=11, units=units, created=CREATED)
        cal = calibrate_session(session, Config())
        poses = static_poses(session)
        out[units] = (cal, cal.accel.apply(poses.a_mean))
    (cal_c, f_c), (cal_s, f_s) = out["counts"], out["m/s^2"]
    # pose-mean noise 0.01/sqrt(200) = 0.0007 m/s^2, quantisation ~0.0012/sqrt(12*200)
    assert np.max(np.abs(f_c - f_s)) < 5 * 0.01 / np.sqrt(200)
    gains_c = np.array(cal_c.accel.sensitivity)
    gains_s = np.array(cal_s.accel.sensitivity)
    np.testing.assert_allclose(gains_c / gains_c.mean(), gains_s / gains_s.mean(), atol=2e-4)
    np.testing.assert_allclose(
        list(cal_c.accel.misalignment_deg.values()),
        list(cal_s.accel.misalignment_deg.values()),
        atol=0.02,
    )


def test_unlabelled_random_session_calibrates():
    session, truth = simulate(plan="random:24", seed=5, created=CREATED)
    assert all(s.up is None for s in session.static_segments())
    cal = calibrate_session(session, Config())
    assert cal.accel.fit.init in ("ellipsoid", "sphere")
    x_true = model_to_params(truth.accel.bias, gauge(truth.accel.matrix))
    x = np.array([p.value for p in cal.accel.parameters])
    std = np.array([p.std for p in cal.accel.parameters])
    assert np.all(np.abs(x - x_true) < 4.5 * std)


def test_12_parameter_variant_from_config_is_close_to_the_full_truth():
    session, truth = simulate(plan="qureshi18", seed=8, jitter_deg=0.5, created=CREATED)
    cfg = config_from_dict({"accel": {"gravity": {"model": "12"}}})
    acc = calibrate_session(session, cfg).accel
    assert acc.variant == "12-parameter" and len(acc.parameters) == 12
    # The rotation is known to ~jitter/sqrt(18); the matrix error is that angle times the gain.
    err = np.abs(acc.matrix - truth.accel.matrix).max() / np.abs(truth.accel.matrix).max()
    assert err < 3 * np.radians(0.5) / np.sqrt(18) + 1e-4
    assert acc.rotation_std_deg < 0.5


def test_cli_writes_json_beside_the_session_and_stores_it(sim18, tmp_path):
    src, _ = sim18
    path = tmp_path / "copy.h5"
    path.write_bytes(src.read_bytes())
    proc = run("calibrate", path)
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "copy.cal.json"
    cal = read_calibration(out)
    assert cal.accel.solver == "gravity"
    assert "before" in proc.stdout and "after" in proc.stdout and "m/s^2" in proc.stdout
    with h5py.File(path, "r") as f:
        stored = json.loads(f["calibrations"][sorted(f["calibrations"])[-1]].attrs["json"])
    assert stored["accel"]["bias"] == pytest.approx(list(cal.accel.bias))
    assert json.loads(out.read_text())["toolkit_version"]


def test_cli_config_and_output_options(sim18, tmp_path):
    path, _ = sim18
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        '[accel]\nsolver = "gravity"\n[accel.gravity]\nmodel = "12"\nleave_one_out = false\n'
    )
    out = tmp_path / "x.json"
    proc = run("calibrate", path, "--config", cfg, "--output", out, "--no-store")
    assert proc.returncode == 0, proc.stderr
    acc = read_calibration(out).accel
    assert acc.variant == "12-parameter" and acc.rms_loo is None


@pytest.mark.parametrize(
    "content, words",
    [
        ('[accel]\nsolver = "magic"\n', ["solver", "magic"]),
        ("[accel]\nsolvr = 'gravity'\n", ["unknown key", "solvr"]),
        ('[accel.gravity]\nmodel = "10"\n', ["model"]),
        ("[accel.gravity]\nmax_iterations = 'many'\n", ["max_iterations"]),
        ("gravity = 3.7\n", ["gravity"]),
        ("[accel\n", ["not valid TOML"]),
    ],
)
def test_bad_config_is_exit_2(sim18, tmp_path, content, words):
    path, _ = sim18
    cfg = tmp_path / "bad.toml"
    cfg.write_text(content)
    assert_one_line_error(run("calibrate", path, "--config", cfg, "--no-store"), 2, *words)


def test_bad_inputs_are_exit_2(tmp_path, sim18):
    src, _ = sim18
    # the installed program itself once (its exit path); the rest in process (cli_helpers.run)
    assert_one_line_error(run_process("calibrate", tmp_path / "nope.h5"), 2, "nope.h5")
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5")
    assert_one_line_error(run("calibrate", junk), 2, "junk.h5")
    assert_one_line_error(run("calibrate", src, "--config", tmp_path / "none.toml"), 2, "none.toml")
    assert_one_line_error(run("calibrate", src, "--model", "7", "--no-store"), 2, "model")
    # NaN inside a static segment
    nan = tmp_path / "nan.h5"
    nan.write_bytes(src.read_bytes())
    with h5py.File(nan, "r+") as f:
        seg = f["segments/0000"].attrs
        f["raw/accel"][int(seg["start"]) + 3, 1] = np.nan
    assert_one_line_error(run("calibrate", nan), 2, "nan.h5")


def test_too_few_poses_refused_with_advice(tmp_path):
    """The gravity solver, asked for explicitly, refuses six faces naming its model and
    what would work: the labelled solver on these labels, or the edges."""
    session, _ = simulate(plan="six", seed=1, created=CREATED)
    path = tmp_path / "six.h5"
    write_session(path, session)
    cfg = tmp_path / "g.toml"
    cfg.write_text('[accel]\nsolver = "gravity"\n')
    assert_one_line_error(
        run("calibrate", path, "--config", cfg), 2, "6 distinct", "at least 9", "edges"
    )


def test_six_labelled_faces_calibrate_by_default_and_say_why(tmp_path):
    session, _ = simulate(plan="six", seed=1, created=CREATED)
    path = tmp_path / "six.h5"
    write_session(path, session)
    proc = run("calibrate", path, "--no-store")
    assert proc.returncode == 0, proc.stderr
    assert "labelled" in proc.stdout and "solver chosen" in proc.stdout
    cal = read_calibration(tmp_path / "six.cal.json")
    assert cal.accel.solver == "labelled"
    assert cal.accel.choice.by == "auto"


def test_poses_all_near_one_direction_refused(tmp_path):
    session, _ = simulate(plan="random:12", seed=2, created=CREATED)
    # Rebuild the stream so every pose is within ~15 degrees of +Z: squeeze the raw samples
    # of each static segment toward the +Z pose's mean.
    accel = session.accel.copy()
    statics = session.static_segments()
    top = np.argmax([accel[s.start : s.stop, 2].mean() for s in statics])
    ref = accel[statics[top].start : statics[top].stop].mean(axis=0)
    for s in statics:
        m = accel[s.start : s.stop].mean(axis=0)
        accel[s.start : s.stop] += (ref + 0.2 * (m - ref)) - m
    session.accel = accel
    with pytest.raises(DesignError, match="turn the unit over|distinct"):
        calibrate_session(session, Config())


def test_non_convergence_is_exit_1(sim18, tmp_path):
    path, _ = sim18
    cfg = tmp_path / "c.toml"
    cfg.write_text('[accel.gravity]\nmax_iterations = 1\ninit = "updown"\n')
    bad = tmp_path / "moved.h5"
    bad.write_bytes(path.read_bytes())
    with h5py.File(bad, "r+") as f:  # poses that do not lie on any ellipsoid
        a = f["raw/accel"][...]
        rng = np.random.default_rng(0)
        for name in f["segments"]:
            s = f["segments"][name].attrs
            a[s["start"] : s["stop"]] += rng.normal(0, 1500, 3)
        f["raw/accel"][...] = a
    assert_one_line_error(run("calibrate", bad, "--config", cfg, "--no-store"), 1, "converge")


def test_result_outside_physical_sense_is_not_saved_without_force(tmp_path):
    session, _ = simulate(plan="qureshi18", seed=4, units="m/s^2", created=CREATED)
    path = tmp_path / "si.h5"
    write_session(path, session)
    cfg = tmp_path / "c.toml"
    cfg.write_text("[accel]\nnominal_sensitivity = 1.5\n")  # datasheet says 1.5, data say ~1
    out = tmp_path / "si.json"
    assert_one_line_error(
        run("calibrate", path, "--config", cfg, "--output", out, "--no-store"),
        1,
        "physical sense",
        "--force",
    )
    assert not out.exists()
    proc = run("calibrate", path, "--config", cfg, "--output", out, "--no-store", "--force")
    assert proc.returncode == 0 and "warning" in proc.stdout
    assert len(read_calibration(out).accel.warnings) == 3


def test_bias_outside_the_range_is_flagged(tmp_path):
    session, _ = simulate(plan="qureshi18", seed=4, created=CREATED)
    # Biases of this part are tens of mg (hundreds of counts): a +-10 count range excludes them.
    cfg = config_from_dict({"accel": {"range": [-10, 10]}})
    warnings = calibrate_session(session, cfg).accel.warnings
    assert any("outside the sensor's range" in w for w in warnings)


def test_config_validation_in_process():
    with pytest.raises(ConfigError, match="weighting"):
        config_from_dict({"accel": {"gravity": {"weighting": "heavy"}}})
    assert config_from_dict({"accel": {"gravity": {"model": 12}}}).accel.gravity.model == "12"


@pytest.mark.parametrize(("n_seeds", "band"), [
    (20, (0.90, 0.99)),  # 180 (partly correlated) trials: binomial sd ~1.6 %
    pytest.param(60, (0.92, 0.98), marks=pytest.mark.slow),  # 540: sd ~0.9 %
])  # fmt: skip
def test_reported_intervals_are_honest_over_simulated_seeds(n_seeds, band):
    """Through the whole path (simulated stream, segment statistics, solver): the 95 %
    intervals cover the truth about 95 % of the time (within about 3 binomial sd)."""
    hits = []
    for seed in range(n_seeds):
        session, truth = simulate(plan="qureshi18", seed=1000 + seed, created=CREATED)
        acc = calibrate_session(
            session, config_from_dict({"accel": {"gravity": {"leave_one_out": False}}})
        ).accel
        x_true = model_to_params(truth.accel.bias, gauge(truth.accel.matrix))
        x = np.array([p.value for p in acc.parameters])
        std = np.array([p.std for p in acc.parameters])
        hits.append(np.abs(x - x_true) <= 1.96 * std)
    covered = np.mean(hits)
    assert band[0] <= covered <= band[1], covered


def test_accel_from_a_session_without_a_stored_calibration_is_one_line(tmp_path, sim18):
    """``--accel SESSION.h5`` takes the newest stored accelerometer section; a session with
    none is a one-line error naming the file."""
    src, _ = sim18
    bare = tmp_path / "bare.h5"
    write_session(bare, simulate(plan="six", seed=2, created=CREATED)[0])  # nothing stored
    assert_one_line_error(run("calibrate", src, "--accel", bare, "--no-store"), 2, "bare.h5",
                          "no stored calibration with an accelerometer section")  # fmt: skip
