"""The magnetometer's gaps figure against what the fit states where it missed the sphere:
:func:`magnitude_std` (the first-order spread of |B| along a direction) and the quality
verdict built on it (:func:`imucal_cli.calibrate.mag._quality_figures`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.estimators.mag.extrapolation import magnitude_std
from imucal_cli.estimators.mag.magnetometer import MagData, fit_magnetometer
from imucal_cli.estimators.mag.residuals import SYM_INDEX
from imucal_cli.formats.config import config_from_dict
from imucal_cli.simulate.magnetometer import simulate_mag
from imucal_cli.use.report.build import build_report


def _fit(align: bool):
    """A fit with its covariance, on a sphere of readings with a few poses (the solver's
    own problem, not a hand-made result)."""
    rng = np.random.default_rng(7)
    W = np.array([[1.05, 0.04, -0.02], [0.04, 0.95, 0.03], [-0.02, 0.03, 1.01]])
    b = np.array([20.0, -35.0, 12.0])
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = d @ np.linalg.inv(W).T * 48.0 + b + rng.normal(0, 0.4, (3000, 3))
    up = rng.normal(size=(8, 3))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    s = np.sin(np.radians(60.0))  # the field 60 deg below the horizontal: cos(up, B) = -s
    field = np.array([_field_dir(u, -s, rng) for u in up]) * 48.0
    poses = field @ np.linalg.inv(W).T + b
    data = MagData(samples=points, pose_mean=poses, up=up if align else None)
    return fit_magnetometer(data, 48.0, align=align)


def _field_dir(u: np.ndarray, cos_angle: float, rng) -> np.ndarray:
    t = np.cross(u, rng.normal(size=3))
    t /= np.linalg.norm(t)
    return cos_angle * u + np.sqrt(1 - cos_angle**2) * t


def _magnitudes(res, params: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """|W' (m - b')| for parameter draws (n, p), at the raw readings the fit maps onto the
    field along each direction."""
    m = res.field * np.linalg.solve(res.matrix, directions.T).T + res.bias
    out = []
    for x in params:
        b = x[:3]
        if res.aligned:
            W = x[3:12].reshape(3, 3)
        else:
            W = np.empty((3, 3))
            for v, (i, j) in zip(x[3:9], SYM_INDEX, strict=True):
                W[i, j] = W[j, i] = v
        out.append(np.linalg.norm((m - b) @ W.T, axis=1))
    return np.array(out)


@pytest.mark.parametrize("align", [True, False])
def test_magnitude_std_is_the_spread_of_the_magnitude_over_the_fits_covariance(align):
    res = _fit(align)
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(6, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    n = 4000
    draws = rng.multivariate_normal(res.params, res.cov, size=n)
    spread = _magnitudes(res, draws, dirs).std(axis=0)
    stated = magnitude_std(res, dirs)
    # a std estimated from n draws is within 5 of its own std (1/sqrt(2n)) of the truth;
    # the linearisation is exact to (std/F)^2, far below that
    assert np.all(np.abs(spread / stated - 1) < 5 / np.sqrt(2 * n)), (spread, stated)
    assert np.all(stated > 0)


def test_six_faces_with_a_tumble_passes_gaps_it_holds_by_the_fit():
    """`six --mag` leaves a quarter of the sphere unseen; the gravity-aligned poses hold the
    magnitude there far below the fit error, so MotionCal's gaps limit does not fail it."""
    session, _ = simulate_mag("six", 1002, hold_s=2.0, tumble_s=4.0)
    cal = calibrate_session(session, config_from_dict({"gyro": {"solver": "none"}}))
    gaps, *_, fit_error = cal.mag.quality.checks
    assert gaps.value_pct > gaps.limit_pct  # MotionCal's figure alone would say recapture
    assert gaps.held_pct is not None and gaps.held_pct < fit_error.value_pct
    assert gaps.ok and cal.mag.quality.verdict == "pass"
    assert "within the fit error" in gaps.meaning


def test_half_a_sphere_without_poses_is_still_recapture_and_says_how_far_it_holds():
    session, truth = simulate_mag("random:12", 8, hold_s=1.0, tumble_s=4.0)
    h = truth.mag.apply(session.mag)
    mag = session.mag.astype(float)
    mag[h[:, 2] / np.linalg.norm(h, axis=1) < 0.2] = np.nan  # the field never below +0.2 z
    cfg = config_from_dict({"mag": {"align": False}})
    cal = calibrate_session(dataclasses.replace(session, mag=mag), cfg)
    q = cal.mag.quality
    gaps, fit_error = q.checks[0], q.checks[3]
    assert q.verdict == "recapture" and q.failed == ["gaps"]
    assert gaps.held_pct > fit_error.value_pct
    rep = build_report(cal)["sensors"]["mag"]
    warning = next(w for w in rep["warnings"] if "magnetometer quality" in w)
    assert "held only to" in warning
