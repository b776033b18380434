"""Hand rotations for gyroscope calibration (Qureshi & Golnaraghi III-B, IV-B.2) and
``imucal simulate --plan qureshi-axes|free:N``.

Noisy checks use tolerances from the simulated noise and quantisation (|z| <= 4.5, two-sided
p = 6.8e-6 per check); noise-free runs (``units="m/s^2"``, zero noise) check the geometry to
numerical precision.  Every draw is fixed by a seed, so the tests are deterministic.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import imucal_cli.formats.calibration as calibration_mod
import imucal_cli.formats.session as session_mod
from imucal_cli.errors import InputError
from imucal_cli.simulate.rotations import (
    MIN_TURN_DEG,
    SMOOTHERSTEP_PEAK,
    is_gyro_plan,
    parse_gyro_plan,
    simulate_gyro_rotations,
)
from imucal_cli.simulate.triad import G0, simulate

Z_MAX = 4.5
CREATED = "2026-01-01T00:00:00Z"


@pytest.fixture(scope="module")
def axes_run():
    return simulate_gyro_rotations(seed=7, created=CREATED)


@pytest.fixture(scope="module")
def clean_run():
    """Noise-free, unquantised: the geometry to numerical precision."""
    return simulate_gyro_rotations(
        seed=11, units="m/s^2", accel_noise=0.0, gyro_noise=0.0, created=CREATED
    )


@pytest.fixture(scope="module")
def free_run():
    return simulate_gyro_rotations(plan="free:12", seed=3, created=CREATED)


def _calibrated(session, truth):
    a, g = truth.accel, truth.gyro
    return (session.accel - a.bias) @ a.matrix.T, (session.gyro - g.bias) @ g.matrix.T


def _neighbours(session, name):
    """The static segments just before and after the rotation segment ``name``."""
    k = [s.name for s in session.segments].index(name)
    before, turn, after = session.segments[k - 1 : k + 2]
    assert before.kind == "static" and turn.kind == "rotation" and after.kind == "static"
    assert before.stop == turn.start and turn.stop == after.start
    return before, turn, after


def _simpson_weights(n_points: int, dt: float) -> np.ndarray:
    """Composite Simpson weights for an odd number of equally spaced points."""
    assert n_points % 2 == 1 and n_points >= 3
    w = np.full(n_points, 2.0)
    w[1::2] = 4.0
    w[0] = w[-1] = 1.0
    return w * dt / 3.0


def _turn_integral(session, rate, turn):
    """Simpson integral of ``rate`` over a turn, from the last still sample before it to the
    first still sample after it (one more still sample if needed for an even interval count).

    Returns the integral (3,) and the square root of the sum of squared weights (s), the
    factor that turns a per-sample white noise std into the integral's std.
    """
    lo, hi = turn.start - 1, turn.stop + 1  # both ends: zero true rate
    if (hi - lo) % 2 == 0:
        hi += 1
    dt = 1.0 / session.sample_rate_hz
    w = _simpson_weights(hi - lo, dt)
    return w @ rate[lo:hi], float(np.sqrt(w @ w))


def _quantisation_std(matrix: np.ndarray, quantised: bool) -> np.ndarray:
    """Std of rounding raw channels to integers, after the calibration matrix (per output)."""
    if not quantised:
        return np.zeros(3)
    return np.sqrt((matrix**2).sum(axis=1) / 12.0)


# --------------------------------------------------------------------------------------------
# Plan and determinism
# --------------------------------------------------------------------------------------------


def test_same_seed_same_session_and_same_part_as_the_pose_simulator(axes_run):
    session, truth = axes_run
    again, truth2 = simulate_gyro_rotations(seed=7, created=CREATED)
    np.testing.assert_array_equal(session.accel, again.accel)
    np.testing.assert_array_equal(session.gyro, again.gyro)
    assert session.segments == again.segments
    assert truth.to_dict() == truth2.to_dict()
    other, _ = simulate_gyro_rotations(seed=8, created=CREATED)
    assert other.gyro.shape != session.gyro.shape or not np.array_equal(other.gyro, session.gyro)
    # one seed, one physical part: the accelerometer of a pose session calibrates this one
    _, pose_truth = simulate(plan="six", seed=7, created=CREATED)
    np.testing.assert_array_equal(truth.accel.matrix, pose_truth.accel.matrix)
    np.testing.assert_array_equal(truth.gyro.matrix, pose_truth.gyro.matrix)
    np.testing.assert_array_equal(truth.gyro.bias, pose_truth.gyro.bias)
    assert session.sensor == "sim-16bit seed 7" and session.source == "simulator"


def test_qureshi_axes_segments(axes_run):
    session, truth = axes_run
    segs = session.segments
    rot = session.rotation_segments()
    static = session.static_segments()
    assert len(rot) == 3 * 18 and len(static) == 3 * 19
    assert [s.name for s in segs] == [f"{k:04d}" for k in range(len(segs))]
    assert all(a.stop <= b.start for a, b in zip(segs, segs[1:], strict=False))
    for k, axis in enumerate("xyz"):
        turns = rot[18 * k : 18 * (k + 1)]
        stills = static[19 * k : 19 * (k + 1)]
        assert [s.label for s in turns] == [f"turn {j} about {axis}" for j in range(1, 19)]
        face = "+X" if axis == "z" else "+Z"
        assert stills[0].label == f"still before {axis} turn 1, {face} up"
        assert [s.label for s in stills[1:-1]] == [
            f"still before {axis} turn {j}" for j in range(2, 19)
        ]
        assert stills[-1].label == f"still after {axis} turn 18"
        for t in turns:
            np.testing.assert_array_equal(t.axis, np.eye(3)["xyz".index(axis)])
            assert t.angle_deg is None and t.up is None
        up = [1.0, 0.0, 0.0] if axis == "z" else [0.0, 0.0, 1.0]
        np.testing.assert_array_equal(stills[0].up, up)
        assert all(s.up is None and s.axis is None for s in stills[1:])
        assert all(s.n_samples == 500 for s in stills)  # 5 s at 100 Hz
    extra = truth.gyro
    assert extra.turn_segments == [s.name for s in rot]
    assert extra.turn_labels == [s.label for s in rot]
    assert extra.turn_axis_names == [a for a in "xyz" for _ in range(18)]
    assert truth.accel.segments == [s.name for s in static]


def test_angles_within_180_distinct_and_peak_rates_bounded(axes_run):
    _, truth = axes_run
    extra = truth.gyro
    angles = np.array(extra.true_angle_deg).reshape(3, 18)
    assert np.all(np.abs(angles) <= 180.0) and np.all(np.abs(angles) >= MIN_TURN_DEG)
    for per_axis in angles:
        gaps = np.abs(per_axis[:, None] - per_axis[None, :]) + 1000.0 * np.eye(18)
        assert gaps.min() >= 10.0 - 1e-9  # 18 different turns, as in the paper
        assert (per_axis > 0).any() and (per_axis < 0).any()
    peak = np.array(extra.peak_rate_dps)
    assert np.all(peak <= 150.0 + 1e-9) and np.all(peak > 0.0)
    dur = np.array(extra.duration_s)
    np.testing.assert_allclose(peak, SMOOTHERSTEP_PEAK * np.abs(angles.ravel()) / dur)
    rv = np.array(extra.true_rotvec)
    np.testing.assert_allclose(np.degrees(np.linalg.norm(rv, axis=1)), np.abs(angles.ravel()))
    axis_err = np.array(extra.axis_error_deg)
    assert np.all(axis_err < 12.0) and np.median(axis_err) > 0.5  # a hand is never exact


def test_free_plan(free_run):
    session, truth = free_run
    rot = session.rotation_segments()
    static = session.static_segments()
    assert len(rot) == 12 and len(static) == 13
    assert all(s.axis is None and s.angle_deg is None for s in rot)
    assert [s.label for s in rot] == [f"turn {k}" for k in range(1, 13)]
    assert static[0].label == "still before turn 1, +Z up"
    np.testing.assert_array_equal(static[0].up, [0.0, 0.0, 1.0])
    assert all(s.up is None for s in static[1:]) and static[-1].label == "still after turn 12"
    extra = truth.gyro
    assert extra.nominal_axis == [None] * 12 and extra.axis_error_deg == [None] * 12
    axes = np.array(extra.true_axis)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0)
    assert np.linalg.svd(axes, compute_uv=False)[-1] > 0.3  # axes span all directions
    angles = np.array(extra.true_angle_deg)
    assert np.all((np.abs(angles) >= MIN_TURN_DEG) & (np.abs(angles) <= 180.0))
    assert truth.plan == "free:12"
    same, _ = simulate_gyro_rotations(plan="free", count=12, seed=3, created=CREATED)
    np.testing.assert_array_equal(same.gyro, session.gyro)


# --------------------------------------------------------------------------------------------
# Physics: gyro integral, gravity before/after, stillness, z horizontal
# --------------------------------------------------------------------------------------------


def test_gyro_integral_is_the_true_rotation_vector_exactly(clean_run):
    session, truth = clean_run
    _, w = _calibrated(session, truth)
    extra = truth.gyro
    for name, rv in zip(extra.turn_segments, extra.true_rotvec, strict=True):
        _, turn, _ = _neighbours(session, name)
        integral, _ = _turn_integral(session, w, turn)
        np.testing.assert_allclose(integral, rv, atol=1e-6, rtol=0)  # Simpson error ~1e-7


def test_gyro_integral_matches_within_noise(axes_run, free_run):
    for session, truth in (axes_run, free_run):
        _, w = _calibrated(session, truth)
        g = truth.gyro
        sample_std = np.hypot(
            g.noise, _quantisation_std(g.matrix, g.quantised)
        )  # rad/s per output axis
        for name, rv in zip(g.turn_segments, g.true_rotvec, strict=True):
            _, turn, _ = _neighbours(session, name)
            integral, wnorm = _turn_integral(session, w, turn)
            z = (integral - np.array(rv)) / (sample_std * wnorm)
            assert np.abs(z).max() < Z_MAX, (name, z)


def test_gravity_before_and_after_each_turn_is_related_by_the_rotation(axes_run, clean_run):
    for (session, truth), exact in ((axes_run, False), (clean_run, True)):
        f, _ = _calibrated(session, truth)
        a = truth.accel
        sample_std = np.hypot(a.noise, _quantisation_std(a.matrix, a.quantised))
        ext = truth.gyro
        for name, rv, angle in zip(
            ext.turn_segments, ext.true_rotvec, ext.true_angle_deg, strict=True
        ):
            before, turn, after = _neighbours(session, name)
            fb = f[before.start : before.stop].mean(axis=0)
            fa = f[after.start : after.stop].mean(axis=0)
            # R_after = R_before Exp(rv): the body-frame gravity reading turns by -rv
            predicted = Rotation.from_rotvec(rv).inv().apply(fb)
            if exact:
                np.testing.assert_allclose(fa, predicted, atol=1e-9)
            else:
                std = sample_std * np.sqrt(1.0 / after.n_samples + 1.0 / before.n_samples)
                assert np.abs((fa - predicted) / std).max() < Z_MAX, name
            # the accelerometer measures the turn: signed angle about the nominal axis
            e = turn.axis
            pb, pa = fb - (fb @ e) * e, fa - (fa @ e) * e
            measured = np.degrees(np.arctan2(np.cross(pb, pa) @ e, pb @ pa))
            assert abs((-measured - angle + 180.0) % 360.0 - 180.0) < 1.0, name
        # still periods read gravity
        for s in session.static_segments():
            mag = np.linalg.norm(f[s.start : s.stop].mean(axis=0))
            assert abs(mag - G0) < (1e-9 if exact else 0.01)


def test_still_periods_are_still_and_turns_move(axes_run, clean_run):
    session, truth = clean_run
    for s in session.static_segments():
        still = session.gyro[s.start : s.stop]
        np.testing.assert_array_equal(still, np.broadcast_to(truth.gyro.bias, still.shape))
        assert np.ptp(session.accel[s.start : s.stop], axis=0).max() < 1e-12
    for s in session.rotation_segments():
        raw = session.gyro[s.start : s.stop]
        assert np.all(np.linalg.norm(raw - truth.gyro.bias, axis=1) > 0.0)
    # noisy: still gyro readings are noise around zero rate
    session, truth = axes_run
    _, w = _calibrated(session, truth)
    g = truth.gyro
    sample_std = np.hypot(g.noise, _quantisation_std(g.matrix, True))
    for s in session.static_segments():
        mean = w[s.start : s.stop].mean(axis=0)
        assert np.abs(mean / (sample_std / np.sqrt(s.n_samples))).max() < Z_MAX
    peak = np.array(g.peak_rate_dps)
    for s, p in zip(session.rotation_segments(), peak, strict=True):
        assert np.degrees(np.linalg.norm(w[s.start : s.stop], axis=1)).max() < p * 1.02 + 1.0


def test_turn_axes_are_horizontal(axes_run):
    """x and y turned with z up, z turned with z horizontal (+X up): the axis stays level."""
    session, truth = axes_run
    ups = np.array(truth.accel.true_up)  # per still, fixture frame
    labels = truth.accel.labels
    for k, axis in enumerate("xyz"):
        rows = [j for j, lab in enumerate(labels) if f" {axis} turn " in lab]
        assert len(rows) == 19
        elevation = np.degrees(np.arcsin(np.abs(ups[rows, k])))
        assert elevation.max() < 15.0, (axis, elevation.max())
    z_first = next(j for j, lab in enumerate(labels) if lab.startswith("still before z turn 1"))
    assert ups[z_first] @ [1.0, 0.0, 0.0] > np.cos(np.radians(10.0))  # on its side, +X up
    nominal = np.array([a for a in truth.gyro.nominal_axis])
    true_axis = np.array(truth.gyro.true_axis)
    assert np.all(np.sum(nominal * true_axis, axis=1) > np.cos(np.radians(12.0)))


# --------------------------------------------------------------------------------------------
# Files and the command
# --------------------------------------------------------------------------------------------


def test_round_trip(tmp_path, axes_run, free_run):
    for name, (session, truth) in (("axes", axes_run), ("free", free_run)):
        path = tmp_path / f"{name}.h5"
        session_mod.write_session(path, session)
        back = session_mod.read_session(path)
        np.testing.assert_array_equal(back.accel, session.accel)
        np.testing.assert_array_equal(back.gyro, session.gyro)
        np.testing.assert_array_equal(back.time, session.time)
        assert back.segments == session.segments
        assert back.gyro_units == "counts" and back.sample_rate_hz == 100.0
        tpath = tmp_path / f"{name}.truth.json"
        calibration_mod.write_calibration(tpath, truth)
        tback = calibration_mod.read_calibration(tpath)
        assert tback.to_dict() == json.loads(json.dumps(truth.to_dict()))


def test_plan_names_and_refusals():
    assert is_gyro_plan("qureshi-axes") and is_gyro_plan(" Free:3 ") and is_gyro_plan("free")
    assert not is_gyro_plan("qureshi18") and not is_gyro_plan("hk-gyro")
    assert parse_gyro_plan("free:4") == ("free", 4)
    for kwargs in (
        {"plan": "free"},
        {"plan": "free:0"},
        {"plan": "free:3", "count": 4},
        {"plan": "six"},
        {"rotations_per_axis": 0},
        {"peak_rate_dps": 0.0},
        {"peak_rate_dps": 5000.0},
        {"still_s": 0.05},
        {"units": "g"},
        {"seed": -1},
        {"axis_jitter_deg": 50.0},
    ):
        with pytest.raises(InputError):
            simulate_gyro_rotations(**kwargs)


def _run_main(monkeypatch, capsys, args):
    from imucal_cli.cli import main

    monkeypatch.setattr(sys, "argv", ["imucal", *args])
    with pytest.raises(SystemExit) as exc:
        main()
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_command_writes_both_plans(tmp_path, monkeypatch, capsys):
    out = tmp_path / "axes.h5"
    args = ["simulate", "--plan", "qureshi-axes", "--seed", "4", "--rotations-per-axis", "6"]
    args += ["--peak-rate", "90", "--still", "2", "-o", str(out)]
    code, _, err = _run_main(monkeypatch, capsys, args)
    assert code in (0, None), err
    session = session_mod.read_session(out)
    truth = calibration_mod.read_calibration(tmp_path / "axes.truth.json")
    expected, _ = simulate_gyro_rotations(
        seed=4, rotations_per_axis=6, peak_rate_dps=90.0, still_s=2.0
    )
    np.testing.assert_array_equal(session.gyro, expected.gyro)
    assert len(session.rotation_segments()) == 18
    assert max(truth.gyro.peak_rate_dps) <= 90.0 and truth.session == "axes.h5"

    free = tmp_path / "free.h5"
    args = ["simulate", "--plan", "free:5", "--units", "m/s^2", "--accel-noise", "0.02"]
    code, _, err = _run_main(monkeypatch, capsys, [*args, "-o", str(free)])
    assert code in (0, None), err
    session = session_mod.read_session(free)
    assert len(session.rotation_segments()) == 5 and session.gyro_units == "rad/s"
    truth = calibration_mod.read_calibration(tmp_path / "free.truth.json")
    assert truth.accel.noise == 0.02 and len(truth.gyro.true_rotvec) == 5


def test_command_refuses_bad_gyro_options(tmp_path, monkeypatch, capsys):
    out = tmp_path / "bad.h5"
    for args in (
        ["--plan", "free:0"],
        ["--plan", "qureshi-axes", "--peak-rate", "-3"],
        ["--plan", "qureshi-axes", "--still", "0.01"],
        ["--plan", "qureshi-axes:0"],
        ["--plan", "qureshi-axes:4", "--rotations-per-axis", "5"],
    ):
        code, _, err = _run_main(monkeypatch, capsys, ["simulate", *args, "-o", str(out)])
        assert code == 2, args
        assert err.startswith("imucal: error: ") and len(err.strip().splitlines()) == 1
        assert not out.exists()
