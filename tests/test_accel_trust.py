"""Issue 10, accelerometer side: faults injected into simulated sessions are found, named and
kept from moving the result (10.6), a fit far above the noise is refused (10.2), too few spare
equations are said out loud (10.3), units are inferred and stated (10.4)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session, suspect_error
from imucal_cli.formats.config import config_from_dict
from imucal_cli.formats.session import write_session
from imucal_cli.simulate import faults
from imucal_cli.simulate.triad import simulate
from imucal_cli.use.report.build import build_report

from .cli_helpers import run

CREATED = "2026-01-01T00:00:00Z"
BAD = 4  # the spoiled hold (index among the static segments)


def _cfg(solver: str, outliers: str = "exclude"):
    return config_from_dict(
        {"accel": {"solver": solver, "outliers": outliers}, "gyro": {"solver": "none"}}
    )


def _params(cal) -> tuple[np.ndarray, np.ndarray]:
    rows = cal.accel.parameters
    return np.array([r.value for r in rows]), np.array([r.std for r in rows])


@pytest.fixture(scope="module")
def q18():
    return simulate(plan="qureshi18", seed=11, created=CREATED)


def _without_hold(session, k):
    """The session with static hold ``k`` turned into an unlabelled rotation-free gap."""
    seg = session.static_segments()[k]
    return replace(session, segments=[s for s in session.segments if s is not seg])


@pytest.mark.parametrize("solver", ["gravity", "labelled"])
@pytest.mark.parametrize("offset", [0.5, 0.05])
@pytest.mark.parametrize("bad", [BAD, 12])  # a face, and an edge pose of high leverage
def test_a_bumped_pose_is_named_and_left_out(q18, solver, offset, bad):
    """An edge pose's bump drags the whole fit (every other pose's statistic rises with it):
    it is still found, from the variance left without it (design/outliers.py)."""
    session, truth = q18
    bumped = faults.bump(session, truth, bad, offset)
    seg = session.static_segments()[bad]
    cal = calibrate_session(bumped, _cfg(solver))
    x = cal.accel
    assert [o.segment for o in x.outliers] == [seg.name]
    assert x.outliers[0].action == "left out"
    text = " ".join(x.warnings)
    assert f"segment {seg.name} ({seg.label})" in text and "bump" in text
    assert next(p for p in x.poses if p.segment == seg.name).excluded is True
    # exactly the fit of the session without that hold: the bump moves nothing
    clean = calibrate_session(_without_hold(session, bad), _cfg(solver))
    p, std = _params(cal)
    p0, _ = _params(clean)
    assert np.all(np.abs(p - p0) < 0.05 * std)
    assert suspect_error(cal) is None


def test_a_kept_bump_spoils_the_fit_and_is_refused_unless_forced(q18, tmp_path):
    """outliers = "keep": the bump stays in; parameters move many std and the residuals are
    far above the measured noise: calibrate refuses (exit 1) naming the segment."""
    session, truth = q18
    bumped = faults.bump(session, truth, BAD, 0.5)
    seg = session.static_segments()[BAD]
    cal = calibrate_session(bumped, _cfg("gravity", "keep"))
    p, _ = _params(cal)
    p0, std0 = _params(calibrate_session(session, _cfg("gravity")))
    assert np.max(np.abs(p - p0) / std0) > 20
    err = suspect_error(cal)
    assert err is not None and err.exit_code == 1 and seg.name in str(err)
    path = tmp_path / "bumped.h5"
    write_session(path, bumped)
    (tmp_path / "keep.toml").write_text('[accel]\nsolver = "gravity"\noutliers = "keep"\n')
    args = ("calibrate", path, "--config", tmp_path / "keep.toml", "-o", tmp_path / "c.json")
    proc = run(*args)
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr and seg.name in proc.stderr
    assert "noise" in proc.stderr
    assert run(*args, "--force").returncode == 0


def test_a_downweighted_bump_moves_no_parameter_by_its_std(q18):
    session, truth = q18
    cal = calibrate_session(faults.bump(session, truth, BAD, 0.5), _cfg("gravity", "downweight"))
    assert cal.accel.outliers[0].action == "down-weighted"
    p, std = _params(cal)
    p0, _ = _params(calibrate_session(session, _cfg("gravity")))
    assert np.all(np.abs(p - p0) < 1.5 * std)


def test_spike_samples_are_left_out_of_the_mean_and_named(q18):
    session, truth = q18
    seg = session.static_segments()[BAD]
    cal = calibrate_session(faults.spike(session, truth, BAD), _cfg("gravity"))
    x = cal.accel
    assert any(seg.name in n and "spike" in n for n in x.notes)
    assert x.outliers == []
    p, std = _params(cal)
    p0, _ = _params(calibrate_session(session, _cfg("gravity")))
    assert np.all(np.abs(p - p0) < 0.3 * std)


@pytest.mark.parametrize("solver", ["gravity", "labelled"])
def test_slow_motion_in_a_hold_is_found_and_named(q18, solver):
    session, truth = q18
    seg = session.static_segments()[BAD]
    cal = calibrate_session(faults.slow_motion(session, truth, BAD, 3.0), _cfg(solver))
    x = cal.accel
    assert [o.segment for o in x.outliers] == [seg.name]
    assert "moved during the hold" in x.outliers[0].cause
    assert x.notes == []  # its drift is motion, not spike samples


@pytest.mark.parametrize("plan, solver", [("qureshi18", "gravity"), ("qureshi18", "labelled"),
                                          ("six", "labelled")])  # fmt: skip
def test_a_pose_labelled_178_degrees_wrong_is_flagged(plan, solver):
    session, truth = simulate(plan=plan, seed=11, created=CREATED)
    seg = session.static_segments()[BAD]
    cal = calibrate_session(faults.wrong_label(session, BAD, 178.0), _cfg(solver))
    x = cal.accel
    wrong = [w for w in x.warnings if f"segment {seg.name}" in w and "label" in w]
    assert wrong and "deg from its label" in wrong[0], x.warnings
    if solver == "labelled":  # the label is dropped, the fit goes on
        assert x.outliers[0].action == "label ignored"
        p, std = _params(cal)
        t = np.r_[truth.accel.bias]
        assert np.all(np.abs(p[:3] - t) < 5 * std[:3])


def test_clean_sessions_flag_nothing():
    for plan, seed in (("qureshi18", 1), ("qureshi18", 2), ("random:30", 3)):
        session, _ = simulate(plan=plan, seed=seed, created=CREATED)
        x = calibrate_session(session, _cfg("auto")).accel
        assert x.outliers == [] and x.blocking == [], (plan, x.warnings)


def test_nine_poses_are_an_exact_fit_said_out_loud():
    """The "132362209158488 x" case: 9 poses for 9 parameters: no spare equation, warned,
    and the report gives no improvement factor for a residual below the noise."""
    session, _ = simulate(plan="qureshi18", seed=5, created=CREATED)
    keep = session.static_segments()[:9]
    nine = replace(session, segments=[s for s in session.segments if s.kind != "static"
                                      or s in keep])  # fmt: skip
    cal = calibrate_session(nine, _cfg("gravity"))
    x = cal.accel
    assert x.spare_equations == 0 and x.rms_after_below_noise is True
    assert any("0 spare equations" in w and "capture" in w for w in x.warnings)
    assert suspect_error(cal) is None  # said, not refused
    rms = build_report(cal)["sensors"]["accel"]["rms"]
    assert rms["improvement"] is None and "below what the noise allows" in rms["after_note"]


def test_six_faces_say_what_their_held_out_error_means():
    session, _ = simulate(plan="six", seed=3, created=CREATED)
    x = calibrate_session(session, _cfg("auto")).accel
    held = [w for w in x.warnings if w.startswith("held-out error")]
    assert held and "no pose is checked by the others" in held[0] and "qureshi18" in held[0]


def test_units_not_stated_are_inferred_and_said():
    session, _ = simulate(plan="qureshi18", seed=6, created=CREATED)
    x = calibrate_session(replace(session, accel_units=None), _cfg("gravity")).accel
    assert x.units_in == "counts"
    note = [w for w in x.warnings if "does not state the accelerometer units" in w]
    assert note and "--accel-units" in note[0] and "taken as counts" in note[0]
    si, _ = simulate(plan="qureshi18", seed=6, created=CREATED, units="m/s^2")
    x = calibrate_session(replace(si, accel_units=None), _cfg("gravity")).accel
    assert x.units_in == "m/s^2"


def test_deletion_diagnostics_batched_equal_the_per_group_formula():
    """The vectorised deletion (groups of one size) is the module docstring's formula."""
    from imucal_cli.design.outliers import deletion

    rng = np.random.default_rng(1)
    for L in (1, 3):
        N, p = 12, 7
        J, r = rng.normal(size=(N * L, p)), rng.normal(size=N * L)
        P = np.linalg.inv(J.T @ J)
        groups = [np.arange(k * L, (k + 1) * L) for k in range(N)]
        d = deletion(J, r, groups, P)
        for k, rows in enumerate(groups):
            A = np.eye(L) - J[rows] @ P @ J[rows].T
            T = r[rows] @ np.linalg.solve(A, r[rows])
            dx = P @ J[rows].T @ np.linalg.solve(A, r[rows])
            assert d.T[k] == pytest.approx(T, rel=1e-9) and d.rank[k] == L
            np.testing.assert_allclose(d.dx[k], dx, rtol=1e-8, atol=1e-12)
