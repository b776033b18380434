"""The shipped example sessions: each calibrates to its truth, or is refused as the README says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import read_session

SESSIONS = Path(__file__).resolve().parent.parent / "sessions"


@pytest.mark.parametrize("name", ["qureshi18-seed1", "qureshi18-seed1-si", "random30-seed2"])
def test_example_calibrates_to_its_truth(name):
    session = read_session(SESSIONS / f"{name}.h5")
    truth = read_calibration(SESSIONS / f"{name}.truth.json")
    cal = calibrate_session(session, Config())
    # Gravity magnitude fixes the matrix up to a rotation: compare what it determines, the
    # calibrated magnitude of any specific force, here on unit vectors in every direction.
    dirs = np.random.default_rng(0).normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    raw = (9.80665 * dirs) @ np.linalg.inv(truth.accel.matrix).T + truth.accel.bias
    mag = np.linalg.norm(cal.accel.apply(raw), axis=1)
    # 18+ poses of 200 samples at 0.01 m/s^2: the magnitude is known to ~1e-3 m/s^2.
    assert np.max(np.abs(mag - 9.80665)) < 4e-3
    assert cal.accel.warnings == []


def test_six_faces_example_calibrates_with_the_labelled_solver():
    """Issue 9.1: the shipped six-face session (6 directions, too few for the 9-parameter
    gravity model) calibrates by default, with the labelled-pose solver, and says why."""
    session = read_session(SESSIONS / "six-seed3.h5")
    truth = read_calibration(SESSIONS / "six-seed3.truth.json")
    acc = calibrate_session(session, Config()).accel
    assert acc.solver == "labelled"
    assert acc.choice.by == "auto" and "too few" in acc.choice.reason
    # Saved, with the one thing six faces cannot do said out loud (issue 10.3): no face is
    # checked by the others (its held-out error is many times the fit error).
    assert acc.blocking == [] and acc.outliers == []
    assert [w.split(" ")[0] for w in acc.warnings] == ["held-out"], acc.warnings
    # The fixture-frame matrix: every entry within 4.5 std of the truth (std from the fit).
    from imucal_cli.estimators.accel.labelled import public_params

    x_true = public_params(truth.accel.bias, np.linalg.inv(truth.accel.matrix))
    x = np.array([p.value for p in acc.parameters])
    std = np.array([p.std for p in acc.parameters])
    assert np.all(np.abs(x - x_true) < 4.5 * std), (x - x_true) / std


def test_six_faces_without_labels_are_refused_naming_the_labelling_step():
    from dataclasses import replace

    session = read_session(SESSIONS / "six-seed3.h5")
    session = replace(session, segments=[replace(s, up=None) for s in session.segments])
    # issue 27.3: calibrated in part (the angles between the axes assumed), naming the
    # labelling step that would determine the whole model
    sec = calibrate_session(session, Config()).accel
    assert sec.solver == "partial" and "imucal label" in " ".join(sec.notes)
