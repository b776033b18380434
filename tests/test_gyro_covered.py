"""Issue 10.2 (gyro): no gyro result whose error its stated std does not cover is saved silently.

The shipped six-face session used to save a gyro gain 21 std off its truth, exit 0: its 5
moves between faces are measured against gravity directions from an accelerometer that six
faces determine only to about 1.5 degrees, and that uncertainty was not in the gyro's std.
Now it is (propagated), and a gyro the design does not determine to ``[gyro] max_rate_std`` is
left out by ``auto`` (with the cause and what would work) or refused without ``--force``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bench.gyro_table import COVERED, SESSIONS, SHIPPED, plan_rows, row
from imucal_cli.calibrate.session import calibrate_session, suspect_error
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import read_session
from tests.cli_helpers import run


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_session_gyro_error_is_covered_by_its_std(name):
    r = row(name, SESSIONS / f"{name}.h5", SESSIONS / f"{name}.truth.json")
    assert r.z_params < COVERED and np.all(np.abs(r.z_gains) < COVERED), (r.z_params, r.z_gains)
    # Saved exactly when its rates are determined to 5 % (the default max_rate_std).
    assert r.saved == (r.rate_std <= 0.05), (r.saved, r.rate_std, r.note)


@pytest.mark.parametrize("plan", ["free:12", "qureshi-axes:6"])
def test_plan_gyro_error_is_covered_by_its_std(plan):
    (r,) = plan_rows(plan, [5])
    assert r.saved, r.note
    assert r.z_params < COVERED and np.all(np.abs(r.z_gains) < COVERED), (r.z_params, r.z_gains)
    assert r.rate_std < 0.01  # far better than the limit


def test_six_faces_gyro_is_not_saved_silently(tmp_path):
    """auto leaves the gyro out saying why and what would work; the accel is saved, exit 0."""
    out = tmp_path / "six.cal.json"
    proc = run("calibrate", SESSIONS / "six-seed3.h5", "-o", out, "--no-store")
    assert proc.returncode == 0, proc.stderr
    assert "gyro not calibrated" in proc.stdout and "--accel CAL.json" in proc.stdout
    assert "accelerometer calibration" in proc.stdout
    # Asked for explicitly, the full model says the same and is not saved without --force.
    session = read_session(SESSIONS / "six-seed3.h5")
    cfg = Config()
    cal = calibrate_session(session, replace(cfg, gyro=replace(cfg.gyro, solver="full")))
    err = suspect_error(cal)
    assert err is not None and "max_rate_std" in str(err)
    share = cal.gyro.rate_std
    assert share.accel_calibration > share.noise  # the cause it names


def test_accel_sections_state_the_covariance_of_bias_and_matrix():
    """What the gyro propagates: the covariance of (bias, matrix) agrees with the solver's own
    parameter std where the parameters are entries of the matrix (gravity, 9 parameters:
    the lower triangle is the gauge, with no variance)."""
    session = read_session(SESSIONS / "qureshi18-seed1.h5")
    acc = calibrate_session(session, Config()).accel
    C = np.array(acc.covariance.values)
    std = np.sqrt(np.diag(C))
    params = {p.name: p.std for p in acc.parameters}
    assert std[:3] == pytest.approx([params[f"b_{a}"] for a in "xyz"], rel=1e-4)
    assert np.all(std[[6, 9, 10]] == 0)  # m_yx, m_zx, m_zy: upper-triangular gauge
    assert np.all(std[[3, 4, 5, 7, 8, 11]] > 0)


def test_a_fast_turn_is_integrated_from_the_still_period_it_leaves():
    """At 50 Hz a quick hand turn (0.5-1 s at up to 400 deg/s) already moves at its first
    and last samples: integrated from its own first sample to its last, it lost the rotation
    of the interval from the last still sample to the first moving one at each end (0.1 % of
    the turn), and the gains came out that much too large, 4-5 std off on a quiet part (a
    sweep's free:12 at 50 Hz, seed 7310: 4.6 std, exit 0). The turn's window now reaches the
    still periods' edge samples (the attitude is the still period's up to its last sample)."""
    from bench.gyro_table import truth_in_frame
    from imucal_cli.simulate.rotations import simulate_gyro_rotations

    session, truth = simulate_gyro_rotations("free:12", seed=7310, rate_hz=50.0,
                                             peak_rate_dps=400.0, still_s=2.0,
                                             accel_noise=0.002, gyro_noise=0.001,
                                             created="2026-01-01T00:00:00Z")  # fmt: skip
    cal = calibrate_session(session, Config())
    g = cal.gyro
    assert g is not None and g.solver == "gyro-full"
    x = np.array([p.value for p in g.parameters[:12]])
    std = np.array([p.std for p in g.parameters[:12]])
    z = (x - truth_in_frame(cal.accel, truth)) / std
    # the gains' diagonal: before, all three +2..+5 std (one sign: the turns came out short)
    assert np.max(np.abs(z)) < COVERED, np.round(z, 2)
    assert abs(np.mean(z[[3, 7, 11]])) < 2.0, np.round(z[[3, 7, 11]], 2)
