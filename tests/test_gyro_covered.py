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
