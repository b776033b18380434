"""`imucal calibrate` with the factorization solver, on simulated sessions of the paper's
designs: recovery within the reported uncertainty, the frame chosen on purpose, and designs
that cannot work refused with what to capture."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.errors import DesignError
from imucal_cli.estimators.accel.crb import invariant_summary
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.config import config_from_dict
from imucal_cli.formats.session import write_session
from imucal_cli.simulate.redundant import simulate_hk_gyro, simulate_redundant_accel
from imucal_cli.simulate.triad import simulate

from .cli_helpers import run

CREATED = "2026-01-01T00:00:00Z"
ACCEL = config_from_dict({"accel": {"solver": "factorization"}})
GYRO = config_from_dict({"accel": {"solver": "none"}, "gyro": {"solver": "factorization"}})


def invariants_and_std(sec):
    """(biases, gains) and their reported standard deviations, in raw units."""
    n = len(sec.bias)
    values = np.r_[sec.bias, sec.sensitivity]
    std = np.array([p.std for p in sec.parameters], float)
    return values, std, n


def true_invariants(truth_sec, per_unit: float):
    S = np.linalg.pinv(truth_sec.matrix).T  # columns s_j, raw units per output unit
    v = invariant_summary(S, truth_sec.bias)
    n = len(truth_sec.bias)
    return np.r_[v[:n], v[n : 2 * n] / per_unit], v[2 * n :]


def test_redundant_unit_recovers_biases_gains_and_angles():
    session, truth = simulate_redundant_accel(seed=3, sigma_counts=0.7, created=CREATED)
    acc = calibrate_session(session, ACCEL).accel
    values, std, n = invariants_and_std(acc)
    assert n == 4 and acc.matrix.shape == (3, 4)
    expected, angles = true_invariants(truth.accel, 1.0)  # truth matrix is already in m/s^2
    assert np.all(np.abs(values - expected) < 4.5 * std), (values - expected) / std
    got = np.array(acc.factorization.angles_deg)
    iu = np.triu_indices(4, 1)
    angle_std = np.array(acc.factorization.angles_std_deg)[iu]
    assert np.all(np.abs(got[iu] - angles) < 4.5 * angle_std)
    fz = acc.factorization
    assert fz.configuration == "redundant" and fz.case == "magnitude-only"
    assert "canonical" in acc.factorization.rotation  # unlabelled: the frame is a convention


def test_labelled_iron_sessions_are_aligned_to_the_fixture():
    session, truth = simulate_redundant_accel(seed=4, labelled=True, created=CREATED)
    acc = calibrate_session(session, ACCEL).accel
    assert "labelled up" in acc.factorization.rotation
    assert acc.factorization.case == "general"
    err = np.abs(acc.matrix - truth.accel.matrix).max() / np.abs(truth.accel.matrix).max()
    assert err < 5e-3


def test_triad_from_opposite_pairs_matches_the_truth_within_its_std():
    session, truth = simulate(plan="qureshi18", seed=5, created=CREATED)
    acc = calibrate_session(session, ACCEL).accel
    values, std, _ = invariants_and_std(acc)
    gains = np.linalg.norm(np.linalg.inv(truth.accel.matrix), axis=1)
    expected = np.r_[truth.accel.bias, gains]
    assert np.all(np.abs(values - expected) < 4.5 * std), (values - expected) / std
    assert any("opposite pair" in note for note in acc.notes)
    # Hand placement (2 degrees) is found in the data, not assumed away.
    assert 0.5 < acc.factorization.fixture_tolerance_deg < 4.0


def test_gyroscope_procedure_of_section_IV_B():
    session, truth = simulate_hk_gyro(seed=6, created=CREATED)
    gyr = calibrate_session(session, GYRO).gyro
    values, std, _ = invariants_and_std(gyr)
    gains = np.linalg.norm(np.linalg.inv(truth.gyro.matrix), axis=1)
    expected = np.r_[truth.gyro.bias, gains]
    assert np.all(np.abs(values - expected) < 4.5 * std), (values - expected) / std
    # The frame: the known turn along its axis, mounting 1's turns along theirs.
    err = np.abs(gyr.matrix - truth.gyro.matrix).max() / np.abs(truth.gyro.matrix).max()
    assert err < 0.01
    turn = gyr.rotations[0]
    assert turn.known_angle_deg == 90.0 and abs(turn.angle_error_deg) < 0.05


def test_one_mounting_is_refused_with_advice():
    session, _ = simulate_hk_gyro(seed=7, mountings=1, created=CREATED)
    with pytest.raises(DesignError, match="not independent enough"):
        calibrate_session(session, GYRO)


def test_no_known_turn_is_refused_with_advice():
    session, _ = simulate_hk_gyro(seed=8, created=CREATED)
    session.segments = [replace(s, angle_deg=None) for s in session.segments]
    with pytest.raises(DesignError, match="known angle"):
        calibrate_session(session, GYRO)


def test_triad_without_an_opposite_pair_is_refused_through_the_cli(tmp_path):
    session, _ = simulate(plan="qureshi18", seed=9, created=CREATED)
    keep = {"face +X up", "face +Y up", "face +Z up"}
    session.segments = [
        s if (s.kind != "static" or s.label in keep) else replace(s, up=None)
        for s in session.segments
    ]
    path = tmp_path / "s.h5"
    write_session(path, session)
    cfg = tmp_path / "f.toml"
    cfg.write_text('[accel]\nsolver = "factorization"\n')
    proc = run("calibrate", path, "-c", cfg)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "opposite" in proc.stderr


def test_cli_writes_a_redundant_calibration(tmp_path):
    session, _ = simulate_redundant_accel(seed=10, created=CREATED)
    path = tmp_path / "r.h5"
    write_session(path, session)
    cfg = tmp_path / "f.toml"
    cfg.write_text('[accel]\nsolver = "factorization"\n[accel.factorization]\nuse = "samples"\n')
    proc = run("calibrate", path, "-c", cfg)
    assert proc.returncode == 0, proc.stderr
    cal = read_calibration(tmp_path / "r.cal.json")
    assert cal.accel.solver == "factorization" and np.shape(cal.accel.matrix) == (3, 4)
    assert cal.accel.factorization.use == "samples"


@pytest.mark.parametrize("solver, name", [("gravity", "gravity solver"),
                                          ("labelled", "labelled-pose solver")])  # fmt: skip
def test_triad_solvers_refuse_a_redundant_unit_naming_the_factorization(solver, name):
    session, _ = simulate_redundant_accel(seed=5, labelled=True, created=CREATED)
    cfg = config_from_dict({"accel": {"solver": solver}, "gyro": {"solver": "none"}})
    with pytest.raises(DesignError, match=f"the {name} calibrates a triad .* has 4: .*factoriz"):
        calibrate_session(session, cfg)
