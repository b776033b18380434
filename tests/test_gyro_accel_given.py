"""A gyro-only session calibrated with an accelerometer calibrated earlier (issue 9.5), and
the refusal that says so when the session cannot calibrate its accelerometer (issue 9.6)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from imucal_cli.formats.session import write_session
from imucal_cli.simulate.rotations import simulate_gyro_rotations
from imucal_cli.simulate.triad import simulate

from .cli_helpers import assert_one_line_error, run

CREATED = "2026-01-01T00:00:00Z"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """One part (seed 3): a pose session, and a gyro session of 6 turns (7 still poses: too
    few for the accelerometer's 9-parameter model)."""
    d = tmp_path_factory.mktemp("given")
    poses, _ = simulate(plan="qureshi18", seed=3, created=CREATED)
    gyro, truth = simulate_gyro_rotations(plan="free:6", seed=3, created=CREATED)
    write_session(d / "poses.h5", poses)
    write_session(d / "gyro.h5", gyro)
    proc = run("calibrate", d / "poses.h5", "-o", d / "poses.cal.json")
    assert proc.returncode == 0, proc.stderr
    return d, truth


def test_a_gyro_session_that_cannot_calibrate_its_accelerometer_names_accel(files):
    d, _ = files
    proc = run("calibrate", d / "gyro.h5", "--no-store", "-o", d / "x.json")
    # issue 27.3: the accelerometer calibrated in part; the gyro, left out, names --accel
    assert proc.returncode == 0, proc.stderr
    assert "accel: partial" in proc.stdout
    assert "gyro not calibrated" in proc.stdout and "--accel CAL.json" in proc.stdout


@pytest.mark.parametrize("source", ["poses.cal.json", "poses.h5"])
def test_the_gyro_is_calibrated_with_the_given_accelerometer(files, source):
    d, truth = files
    out = d / f"gyro-{source}.json"
    proc = run("calibrate", d / "gyro.h5", "--accel", d / source, "--no-store", "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "warning" not in proc.stderr  # the same unit
    cal = json.loads(out.read_text())
    given = json.loads((d / "poses.cal.json").read_text())["accel"]
    # The accelerometer is copied as it was (not re-calibrated), and says where it came from.
    assert cal["accel"]["matrix"] == given["matrix"] and cal["accel"]["bias"] == given["bias"]
    assert "not re-calibrated" in cal["accel"]["notes"][0]
    g = cal["gyro"]
    assert g["solver"] == "gyro-full"
    std = np.array([p["std"] for p in g["parameters"][:3]])
    assert np.all(np.abs(np.array(g["bias"]) - truth.gyro.bias) < 4.5 * std)
    # Gains within 0.5 % of the truth (6 turns; the accelerometer's frame is the fixture's
    # to a degree).
    gains = 1 / np.linalg.norm(np.linalg.inv(np.array(g["matrix"])), axis=1)
    true = 1 / np.linalg.norm(np.linalg.inv(truth.gyro.matrix), axis=1)
    assert np.all(np.abs(gains / true - 1) < 5e-3)


def test_accel_from_a_file_without_one_is_refused(files, tmp_path):
    d, _ = files
    cal = json.loads((d / "poses.cal.json").read_text())
    del cal["accel"]
    cal["gyro"] = {"solver": "x", "units": "rad/s", "bias": [0, 0, 0],
                   "matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "residual_rms": 0}  # fmt: skip
    (tmp_path / "g.json").write_text(json.dumps(cal))
    proc = run("calibrate", d / "gyro.h5", "--accel", tmp_path / "g.json", "--no-store")
    assert_one_line_error(proc, "no accelerometer section")


@pytest.mark.parametrize("option", ["--accel", "--prior"])
def test_another_units_calibration_is_said(files, tmp_path, option):
    """Audit: --accel (or --prior) of another unit's calibration was used silently (the gyro's
    turns measured with another part's accelerometer: angle residuals 100 times larger)."""
    d, _ = files
    other = json.loads((d / "poses.cal.json").read_text())
    other["sensor"] = "MPU-6050 #99"
    (tmp_path / "other.json").write_text(json.dumps(other))
    proc = run("calibrate", d / "gyro.h5", option, tmp_path / "other.json", "--no-store",
               "-o", tmp_path / "o.json")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert f"imucal: warning: {option} " in proc.stderr
    assert "was made on 'MPU-6050 #99'" in proc.stderr and "belongs to one unit" in proc.stderr
