"""Issues 9.4, 9.6, 10.3: a session calibrates what it determines, says what it left out and
why, and the default solvers are the most accurate the session supports.

* gyro-axes (3 labelled faces, a known 360-degree turn about each): the accel cannot be
  determined; the gyro is, by the known-angle solver on the labelled axes, without an
  accelerometer;
* hk-gyro (Hwangbo & Kanade IV-B): the gyro by the factorization, the accel left out;
* hwangbo-iron (6 faces, then hk-gyro): the labelled accel fit with the second mounting's
  unlabelled poses by their magnitude, not a gravity fit without a spare equation.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.errors import DesignError
from imucal_cli.estimators.accel.crb import gravity_crb, labelled_crb
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.model.parts import By
from imucal_cli.simulate.play import simulate_plan
from imucal_cli.use.report.build import build_report
from tests.cli_helpers import run
from tests.test_gyro_known import _ferraris_like

CREATED = "2026-01-01T00:00:00Z"


def _cfg(accel: str, gyro: str):
    return config_from_dict({"accel": {"solver": accel}, "gyro": {"solver": gyro}})


def test_labelled_bound_without_labels_is_the_gravity_bound_and_labels_only_help():
    """(L5) with an infinite placement on every pose is the gravity-magnitude bound on bias,
    gains and axes; labelling some poses lowers it, labelling all lowers it further."""
    from imucal_cli.estimators.accel.gravity import _UPPER, params_to_model
    from imucal_cli.estimators.accel.labelled_model import jacobian, public_from_theta

    rng = np.random.default_rng(0)
    K = np.triu(np.eye(3) / 835.0 + rng.normal(0, 2e-5, (3, 3)))
    B, g = rng.normal(0, 50, 3), 9.80665
    u = rng.normal(size=(12, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    cov = np.tile(np.eye(3) * 8.35**2 / 200, (12, 1, 1))
    theta = np.r_[B, K[_UPPER]]
    _, M = params_to_model(theta)
    T = jacobian(public_from_theta, np.r_[theta, np.zeros(3)])[:9, :9]
    grav = np.diag(T @ gravity_crb(M, B, u, g, cov) @ T.T)
    none = np.diag(labelled_crb(M, B, u, g, cov, np.full(12, np.inf)))[:9]
    some = np.diag(labelled_crb(M, B, u, g, cov, np.where(np.arange(12) < 6, 0.5, np.inf)))[:9]
    every = np.diag(labelled_crb(M, B, u, g, cov, 0.5))[:9]
    np.testing.assert_allclose(none, grav, rtol=1e-6)
    assert np.all(some < grav) and np.all(every < some)


@pytest.mark.parametrize("seed", [1, 2])
def test_known_angle_gyro_needs_no_accelerometer_on_labelled_axes(seed):
    """Turns about body-fixed labelled axes integrate to angle * axis whatever the attitude:
    the known-angle solver runs with no accelerometer, the frame the labels', the std from
    the assumed placement (said: 3 turns leave no spare equation)."""
    session, b_true, M_true = _ferraris_like(seed)
    cal = calibrate_session(session, _cfg("none", "known"))
    gyro = cal.gyro
    assert cal.accel is None and gyro.solver == "gyro-known"
    assert "no accelerometer calibration" in gyro.frame
    x = np.array([p.value for p in gyro.parameters[:12]])
    std = np.array([p.std for p in gyro.parameters[:12]])
    z = (x - np.r_[b_true, M_true.ravel()]) / std
    assert np.all(np.abs(z) < 4.5), z
    assert any("0 spare equations" in w and "assumed" in w for w in gyro.warnings)
    assert gyro.blocking == []  # said, not refused


def test_known_angle_gyro_without_accelerometer_refuses_unlabelled_axes():
    session, _, _ = _ferraris_like(3)
    segs = [replace(s, axis=None) if s.kind == "rotation" else s for s in session.segments]
    with pytest.raises(DesignError, match="0 of 3 turns of known angle have a labelled axis"):
        calibrate_session(replace(session, segments=segs), _cfg("none", "known"))


def test_gyro_axes_calibrates_the_gyro_and_says_why_the_accel_is_partial():
    session, _ = simulate_plan("gyro-axes", seed=3, created=CREATED)
    cal = calibrate_session(session, Config())
    # issue 27.3: the 3 faces calibrate the accelerometer in part (it was left out before)
    assert cal.accel.solver == "partial" and cal.complete is False
    assert (cal.gyro.choice.solver, cal.gyro.choice.by) == ("known", By.AUTO)
    note = " ".join(cal.accel.notes)
    # what the user has (an earlier calibration) before a new capture (9.6)
    assert note.index("--prior CAL.json") < note.index("plan six")
    assert "3 faces" in note and "3 of them labelled" in note
    assert build_report(cal)["left_out"] == {}
    # an accel solver asked for by name still refuses, naming --accel
    with pytest.raises(DesignError, match="--accel CAL.json"):
        calibrate_session(session, _cfg("gravity", "auto"))


def test_hk_gyro_auto_uses_the_factorization_with_or_without_the_accel():
    session, truth = simulate_plan("hk-gyro", seed=4, created=CREATED)
    cal = calibrate_session(session, Config())
    assert cal.accel.solver == "partial" and cal.accel_note is None  # issue 27.3
    assert cal.gyro.choice.solver == "factorization"
    given = calibrate_session(session, Config(), accel=truth.accel)
    assert given.gyro.choice.solver == "factorization"
    assert given.accel_note is None


def test_hwangbo_iron_uses_its_labels_and_the_other_mounting_by_magnitude():
    session, _ = simulate_plan("hwangbo-iron", seed=5, created=CREATED)
    n_lab = sum(s.up is not None for s in session.static_segments())
    n = len(session.static_segments())
    assert 0 < n_lab < n
    cal = calibrate_session(session, Config())
    x = cal.accel
    assert x.choice.solver == "labelled", x.choice
    assert f"{n_lab} of {n} poses labelled" in x.choice.reason
    assert x.coverage.n_poses == n  # the unlabelled poses are in the fit
    assert cal.gyro.choice.solver == "factorization"
    # the gravity fit, asked for: 9 distinct directions for 9 parameters, said out loud (10.3)
    grav = calibrate_session(session, _cfg("gravity", "none")).accel
    assert grav.spare_equations == 0
    spare = [w for w in grav.warnings if "0 spare equations" in w]
    assert spare and "9 distinct directions" in spare[0] and 'solver = "labelled"' in spare[0]


def test_cli_says_the_accel_was_left_out(tmp_path):
    session = tmp_path / "s.h5"
    sim = run("simulate", "--plan", "gyro-axes", "--seed", 2, "-o", session)
    assert sim.returncode == 0, sim.stderr
    # issue 27.3: calibrated in part, said so (not left out any more)
    proc = run("calibrate", session, "-o", tmp_path / "s.cal.json")
    assert proc.returncode == 0, proc.stderr
    assert "accel: partial" in proc.stdout and "(partial: accel in part assumed" in proc.stdout
    proc = run("calibrate", session, "-o", tmp_path / "j.cal.json", "--json", "--no-store")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["complete"] is False and doc["left_out"] == {}
    assert doc["calibration"]["accel"]["partial"]["assumed"]
    report = run("report", tmp_path / "s.cal.json", "--json")
    assert report.returncode == 0, report.stderr
    assert json.loads(report.stdout)["left_out"] == {}


def test_a_prior_no_single_parameter_rests_on_is_not_called_assumed(tmp_path):
    """qureshi-axes:2: 7 directions for 9 parameters, each parameter narrowed by the data to
    under half its prior std, yet 2 combinations rest on the prior.  The summary said
    'assumed: none' and then 'accel in part assumed'; it now says what leans on the prior."""
    session = tmp_path / "q2.h5"
    sim = run("simulate", "--plan", "qureshi-axes:2", "--seed", 1, "-o", session)
    assert sim.returncode == 0, sim.stderr
    proc = run("calibrate", session, "--no-store", "-o", tmp_path / "q2.cal.json")
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "accel: partial" in out and "): none;" not in out
    assert "on the prior: no parameter alone" in out and "accel in part on its prior" in out
    assert "accel in part assumed" not in out
