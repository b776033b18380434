"""Gyroscope calibration from hand rotations (issue 5): the three solvers recover the truth of
simulated sessions within their reported uncertainty, the angle is measured exactly about any
axis, rotations are found in an unsegmented stream, and bad designs are refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.special import stdtrit

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.errors import ConfigError, DesignError
from imucal_cli.estimators.gyro.axes import (
    fit_axis_dynamic,
    fit_axis_static,
    rotation_angle_about_axis,
)
from imucal_cli.estimators.gyro.full import integrate_rotations
from imucal_cli.formats.config import config_from_dict
from imucal_cli.simulate.rotations import simulate_gyro_rotations
from imucal_cli.simulate.triad import simulate

CREATED = "2026-01-01T00:00:00Z"


def cfg(solver: str, **gyro):
    return config_from_dict({"gyro": {"solver": solver, **gyro}})


@pytest.fixture(scope="module")
def axes_session():
    return simulate_gyro_rotations(plan="qureshi-axes", seed=2, created=CREATED)


def gyro_truth_in_accel_frame(cal, truth):
    """The true gyro matrix expressed in the frame the calibrated accelerometer defines."""
    R = cal.accel.matrix @ np.linalg.inv(truth.accel.matrix)  # fixture -> accel frame
    U, _, Vt = np.linalg.svd(R)
    return (U @ Vt) @ truth.gyro.matrix


def test_angle_about_any_axis_is_exact():
    rng = np.random.default_rng(0)
    for _ in range(50):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(-np.pi, np.pi)
        g0 = rng.normal(size=3)
        # The body turns by +angle about axis: gravity, seen from the body, turns by -angle.
        g1 = Rotation.from_rotvec(-angle * axis).apply(g0)
        got, lev = rotation_angle_about_axis(g0, g1, axis)
        if lev > 0.05:
            assert got == pytest.approx(angle, abs=1e-9)


def test_per_axis_fits_are_exact_without_noise():
    T = np.array([1.0, 1.5, 2.0, 2.5])
    angle = np.radians([30.0, -80.0, 120.0, -170.0])
    k, b = 1 / 938.0, 12.5
    x = angle / k + b * T
    s = fit_axis_static(x, T, angle, b)
    d = fit_axis_dynamic(x, T, angle)
    assert s.k == pytest.approx(k, rel=1e-12) and d.k == pytest.approx(k, rel=1e-12)
    assert d.b == pytest.approx(b, rel=1e-9)


def test_per_axis_std_carry_the_accelerometer_and_t_intervals():
    """The accelerometer calibration's error moves every measured angle together and does not
    show in the residuals: a common 1 % error in the angles (covariance ``(0.01 a)(0.01
    a)^T``) is a 1 % error of ``k``, in its std; the 95 % half-widths are Student t on the
    residuals' few degrees of freedom (per-axis coverage of the truth over 30 qureshi-axes
    sessions: 86 % static, 81 % dynamic with 1.96 std; 91 and 89 % now)."""
    rng = np.random.default_rng(3)
    T = np.array([1.0, 1.5, 2.0, 2.5, 1.2, 1.8])
    angle = np.radians([30.0, -80.0, 120.0, -170.0, 60.0, 90.0])
    k, b = 1 / 938.0, 12.5
    x = angle / k + b * T + rng.normal(0, 0.5, 6)
    common = 0.01 * angle
    for fit in (lambda c: fit_axis_static(x, T, angle, b, angle_cov=c),
                lambda c: fit_axis_dynamic(x, T, angle, angle_cov=c)):
        plain, with_accel = fit(None), fit(np.outer(common, common))
        extra = np.sqrt(with_accel.k_std**2 - plain.k_std**2)
        assert extra == pytest.approx(0.01 * abs(plain.k), rel=0.05), (extra, plain.k)
        dof = len(x) - (1 if plain.approach == "static" else 2)
        assert plain.k_ci95 == pytest.approx(stdtrit(dof, 0.975) * plain.k_std, rel=1e-9)
        # the known part's dof are infinite: the quantile falls toward 1.96
        q = with_accel.k_ci95 / with_accel.k_std
        assert 1.959 < q < plain.k_ci95 / plain.k_std, q


def test_rk4_integration_of_a_constant_rate():
    t = np.linspace(0, 2, 201)
    w = np.tile([0.3, -0.2, 0.5], (201, 1))
    R = integrate_rotations([t], [w])[0]
    np.testing.assert_allclose(R, Rotation.from_rotvec(2 * w[0]).as_matrix(), atol=1e-10)


@pytest.mark.parametrize("solver", ["static", "dynamic", "full"])
def test_solvers_recover_scale_and_bias(axes_session, solver):
    session, truth = axes_session
    cal = calibrate_session(session, cfg(solver))
    g = cal.gyro
    assert g.solver == f"gyro-{solver}" and g.units == "rad/s"
    std_b = np.array([p.std for p in g.parameters[:3]])
    assert np.all(np.abs(g.bias - truth.gyro.bias) < 4.5 * std_b)
    M_true = gyro_truth_in_accel_frame(cal, truth)
    scale_err = np.abs(np.diag(g.matrix) / np.diag(M_true) - 1)
    # The per-axis model ignores misalignment (~0.5 deg here): its scale is good to ~0.1 %.
    assert np.all(scale_err < (2e-3 if solver != "full" else 5e-4)), scale_err
    rot = g.rotations
    assert len(rot) >= 3 * 15 and all(np.isfinite(r.angle_error_deg) for r in rot)
    assert g.rotation_rms_deg < 0.5


def test_full_model_recovers_misalignment_from_free_rotations():
    session, truth = simulate_gyro_rotations(plan="free:24", seed=3, created=CREATED)
    # Free rotations: the accelerometer is calibrated from the still periods themselves.
    cal = calibrate_session(session, cfg("full"))
    g = cal.gyro
    M_true = gyro_truth_in_accel_frame(cal, truth)
    std = np.array([p.std for p in g.parameters[3:]]).reshape(3, 3)
    assert np.all(np.abs(g.matrix - M_true) < 4.5 * std + 1e-12)


def test_rotations_are_found_in_an_unsegmented_stream(axes_session):
    session, truth = axes_session
    bare = replace(session, segments=[])
    cal = calibrate_session(
        bare, config_from_dict({"accel": {"solver": "gravity"}, "gyro": {"solver": "full"}})
    )
    assert any("found in the stream" in n for n in cal.gyro.notes)
    M_true = gyro_truth_in_accel_frame(cal, truth)
    assert np.all(np.abs(np.diag(cal.gyro.matrix) / np.diag(M_true) - 1) < 1e-3)


def test_a_session_without_rotations_is_refused():
    session, _ = simulate(plan="qureshi18", seed=1, created=CREATED)
    session.segments = [s for s in session.segments if s.kind == "static"]
    # Found in the stream instead: the simulator's moves between poses are rotations with still
    # data around them, so this calibrates; remove the moves' samples' gyro signal to refuse
    # (noise only: an exactly constant gyro is a stuck sensor, refused as such, issue 24.6).
    session.gyro = np.random.default_rng(0).normal(0.0, 3.0, session.gyro.shape)
    with pytest.raises(DesignError, match="rotation"):
        calibrate_session(session, cfg("full"))


def test_rotations_without_still_data_around_them_are_refused(axes_session):
    session, _ = axes_session
    cut = replace(
        session,
        segments=[s for s in session.segments if s.kind == "rotation"][:5]
        + [s for s in session.segments if s.kind == "static"][:0],
    )
    with pytest.raises(DesignError):
        calibrate_session(
            cut, config_from_dict({"accel": {"solver": "gravity"}, "gyro": {"solver": "static"}})
        )


def test_clipped_rotations_are_left_out_with_a_warning(axes_session):
    session, _ = axes_session
    gyro = session.gyro.copy()
    turn = session.rotation_segments()[0]
    gyro[turn.start + 5, 0] = 32767  # one sample at the end of the 16-bit range
    clipped = replace(session, gyro=gyro)
    g = calibrate_session(clipped, cfg("static")).gyro
    assert any("range" in w for w in g.warnings)


def test_gyro_solver_needs_an_accelerometer_calibration(axes_session):
    session, _ = axes_session
    with pytest.raises(ConfigError, match="accelerometer"):
        calibrate_session(
            session, config_from_dict({"accel": {"solver": "none"}, "gyro": {"solver": "dynamic"}})
        )


def test_rates_beyond_the_configured_range_are_left_out(axes_session):
    session, _ = axes_session
    peak = np.abs(session.gyro).max()
    g = calibrate_session(
        session, config_from_dict({"gyro": {"solver": "full", "range": [-0.6 * peak, 0.6 * peak]}})
    ).gyro
    assert any("range" in w for w in g.warnings)
    assert len(g.rotations) < len(session.rotation_segments())


def test_per_axis_solvers_refuse_turns_that_are_not_about_one_axis():
    """A pose session's moves turn between faces and edges: the per-axis model cannot use
    them, and says so instead of saving wrong gains."""
    session, _ = simulate(plan="qureshi18", seed=3, created=CREATED)
    with pytest.raises(DesignError, match="not about one sensor axis"):
        calibrate_session(session, cfg("static"))
    # The full model takes them.
    g = calibrate_session(session, cfg("full")).gyro
    assert g.rotation_rms_deg < 0.5
