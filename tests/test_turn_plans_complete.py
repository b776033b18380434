"""What a qureshi-axes session determines alone (issue 24.7d).

Qureshi & Golnaraghi's Fig. 2 is a gyro procedure: hand turns about x and y with +Z up, then
about z with +X up, each measured by the accelerometer "already calibrated" from poses. Its
still periods are poses too: from 3 turns per axis on they point in 9 or more directions, and
the session calibrates the accelerometer and the gyro (complete); with 2 per axis (the plan's
minimum, 6 turns: enough for the gyro's 9 matrix terms) they point in 8, so the gyro needs an
earlier accelerometer calibration (``--accel CAL.json``), with which the session is complete.
Alone, nothing calibrates, and the refusal says what the turns are for and what to capture
(it spoke of poses and plan random:12 only).
"""

from __future__ import annotations

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.config import Config
from imucal_cli.simulate.play import simulate_plan

from .cli_helpers import run

CREATED = "2026-01-01T00:00:00Z"


def test_three_turns_per_axis_calibrate_both():
    session, _ = simulate_plan("qureshi-axes:3", seed=0, created=CREATED)
    cal = calibrate_session(session, Config())
    assert cal.accel.solver == "gravity" and cal.gyro.solver == "gyro-full"
    assert cal.complete is True and not cal.left_out


def test_two_per_axis_calibrate_the_gyro_with_an_earlier_accelerometer(tmp_path):
    session, truth = simulate_plan("qureshi-axes:2", seed=0, created=CREATED)
    # issue 27.3: the accelerometer calibrated in part; the gyro left out, saying why
    alone = calibrate_session(session, Config())
    assert alone.accel.solver == "partial" and alone.gyro is None
    text = alone.left_out["gyro"]
    assert "its 6 turns between still periods calibrate the gyro" in text
    assert "point in 8 distinct directions" in text and "--accel CAL.json" in text
    assert "qureshi-axes:3 or more" in text
    cal = calibrate_session(session, Config(), accel=truth.accel)
    assert cal.gyro.solver == "gyro-full"
    assert cal.complete is True and not cal.left_out
    # the user's path: the session file, calibrate alone (exit 2), then with --accel (exit 0)
    from imucal_cli.formats.session import write_session

    h5, accel = tmp_path / "qa2.h5", tmp_path / "accel.cal.json"
    write_session(h5, session)
    write_calibration(accel, truth)
    proc = run("calibrate", h5, "--no-store", "-o", tmp_path / "a.cal.json")
    assert proc.returncode == 0, proc.stderr
    assert "its 6 turns between still periods calibrate the gyro" in proc.stdout
    assert "--accel CAL.json" in proc.stdout and "accel: partial" in proc.stdout
    proc = run("calibrate", h5, "--no-store", "--accel", accel, "--json", "-o",
               tmp_path / "b.cal.json")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert '"complete": true' in proc.stdout
