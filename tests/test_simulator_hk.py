"""The Hwangbo-Kanade simulator designs: the redundant accelerometer unit (section V, Table I)
and the gyroscope procedure (section IV-B), and ``imucal simulate --plan hk-*``.

Tolerances come from the simulated noise and quantisation (z-scores at |z| <= 4.5, two-sided
p = 6.8e-6 per check); every draw is fixed by a seed, so the tests are deterministic.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

import imucal_cli.formats.calibration as calibration_mod
import imucal_cli.formats.session as session_mod
from imucal_cli.errors import InputError
from imucal_cli.simulate.redundant import (
    ADC_MAX,
    COUNTS_PER_VOLT,
    NOMINAL_AXES,
    QUANTISATION_COUNTS,
    pairwise_angles_deg,
    simulate_hk_gyro,
    simulate_redundant_accel,
)
from imucal_cli.simulate.triad import G0

from .test_virtual import process_factory  # noqa: F401

Z_MAX = 4.5
TABLE_I_ANGLES = {
    "s1s2": 90.0,
    "s1s3": 90.0,
    "s1s4": 45.0,
    "s2s3": 90.0,
    "s2s4": 90.0,
    "s3s4": 45.0,
}


@pytest.fixture(scope="module")
def redundant():
    return simulate_redundant_accel(seed=3, created="2026-01-01T00:00:00Z")


@pytest.fixture(scope="module")
def gyro_run():
    return simulate_hk_gyro(seed=5, created="2026-01-01T00:00:00Z")


def _mounting(label: str) -> int:
    assert label.startswith("mounting ")
    return int(label.split(":")[0].split()[1])


# --------------------------------------------------------------------------------------------
# Redundant accelerometer unit
# --------------------------------------------------------------------------------------------


def test_redundant_layout_matches_the_paper(redundant):
    session, truth = redundant
    assert session.accel.shape == (200, 4) and session.gyro is None
    assert session.accel_units == "counts" and session.sample_rate_hz == 50.0
    static = session.static_segments()
    assert len(static) == 20 and len(session.segments) == 20
    assert all(s.n_samples == 10 and s.up is None for s in static)
    assert [s.label for s in static] == [f"orientation {k}" for k in range(1, 21)]
    assert np.all(np.diff(session.time) > 0)

    acc = truth.accel
    assert acc.matrix.shape == (3, 4) and acc.bias.shape == (4,)
    ex = acc
    assert ex.angles_deg == pytest.approx(TABLE_I_ANGLES, abs=1e-9)
    assert list(ex.angles_deg) == list(TABLE_I_ANGLES)  # Table I order
    assert ex.gains_V_per_g == [1.0] * 4 and ex.bias_V == [2.5] * 4
    assert ex.counts_per_volt == pytest.approx(2047 / 5) == COUNTS_PER_VOLT
    np.testing.assert_allclose(acc.bias, 2.5 * 2047 / 5)
    S = np.array(ex.S_counts_per_g)
    np.testing.assert_allclose(S, COUNTS_PER_VOLT * NOMINAL_AXES)
    np.testing.assert_allclose(acc.matrix, G0 * np.linalg.pinv(S.T))
    np.testing.assert_allclose(acc.matrix @ S.T, G0 * np.eye(3), atol=1e-9)
    assert ex.noise_counts == 0.7
    assert ex.quantisation_counts == pytest.approx(1 / np.sqrt(12))
    assert np.array(ex.true_up).shape == (20, 3)


def test_redundant_is_deterministic_per_seed():
    a, ta = simulate_redundant_accel(seed=9, created="x")
    b, tb = simulate_redundant_accel(seed=9, created="x")
    c, _ = simulate_redundant_accel(seed=10, created="x")
    np.testing.assert_array_equal(a.accel, b.accel)
    np.testing.assert_array_equal(a.time, b.time)
    assert ta.to_dict() == tb.to_dict()
    assert not np.array_equal(a.accel, c.accel)
    # perturb draws only from the truth generator: same poses and noise draws
    p, tp = simulate_redundant_accel(seed=9, perturb=True, created="x")
    assert tp.accel.true_up == ta.accel.true_up
    assert tp.accel.gains_V_per_g != ta.accel.gains_V_per_g


@pytest.mark.parametrize("perturb", [False, True])
def test_truth_turns_every_pose_into_gravity(perturb):
    session, truth = simulate_redundant_accel(seed=4, perturb=perturb, samples=20)
    acc = truth.accel
    sigma = np.hypot(acc.noise_counts, QUANTISATION_COUNTS)
    cov = sigma**2 * acc.matrix @ acc.matrix.T  # per-sample calibrated noise, (m/s^2)^2
    true_up = np.array(acc.true_up)
    for seg, up in zip(session.static_segments(), true_up, strict=True):
        mean = acc.apply(session.accel[seg.start : seg.stop]).mean(axis=0)
        std = np.sqrt(up @ cov @ up / seg.n_samples)
        assert abs(np.linalg.norm(mean) - session.gravity) < Z_MAX * std
        # and it points along the true up (3 components, same bound per component)
        bound = Z_MAX * np.sqrt(np.diag(cov) / seg.n_samples)
        assert np.all(np.abs(mean - session.gravity * up) < bound)
    angles = acc.angles_deg
    assert angles == pairwise_angles_deg(np.array(acc.S_counts_per_g))
    for key, nominal in TABLE_I_ANGLES.items():
        assert abs(angles[key] - nominal) <= (2.0 if perturb else 1e-9)


def test_quantisation_adc_range_and_noise_level():
    # noise-free: exactly the rounded ADC codes of the documented model
    session, truth = simulate_redundant_accel(seed=1, sigma_counts=0.0, orientations=30)
    up = np.repeat(np.array(truth.accel.true_up), 10, axis=0)
    expected = np.rint(COUNTS_PER_VOLT * (2.5 + up @ NOMINAL_AXES))
    np.testing.assert_array_equal(session.accel, expected)
    # +1 g on s1 (face +X up) is 3.5 V: code rint(409.4 * 3.5) = 1433
    lab, _ = simulate_redundant_accel(labelled=True, sigma_counts=0.0)
    seg = next(s for s in lab.segments if s.label == "face +X up")
    assert lab.accel[seg.start, 0] == 1433.0

    # with noise: integers, in range, total noise sqrt(sigma^2 + 1/12)
    sigma = 0.7
    session, truth = simulate_redundant_accel(
        seed=2, sigma_counts=sigma, orientations=200, samples=50
    )
    raw = session.accel
    assert np.array_equal(raw, np.rint(raw)) and raw.min() >= 0 and raw.max() <= ADC_MAX
    up = np.repeat(np.array(truth.accel.true_up), 50, axis=0)
    resid = raw - (COUNTS_PER_VOLT * (2.5 + up @ NOMINAL_AXES))
    total = truth.accel.noise_total_counts
    assert total == pytest.approx(np.hypot(sigma, 1 / np.sqrt(12)))
    # 40000 residuals: the variance is known to 0.7 % (1 sigma); allow 5 %
    assert resid.var() == pytest.approx(total**2, rel=0.05)
    assert abs(resid.mean()) < Z_MAX * total / np.sqrt(resid.size)

    # an input beyond +-2.5 g saturates at the ADC ends
    big, _ = simulate_redundant_accel(seed=2, gravity=4.0 * G0, sigma_counts=0.0)
    assert big.accel.min() == 0.0 and big.accel.max() == ADC_MAX


def test_labelled_uses_the_block_faces_and_edges():
    session, truth = simulate_redundant_accel(labelled=True)
    static = session.static_segments()
    assert len(static) == 18
    assert static[0].label == "face +Z up" and static[-1].label.startswith("edge ")
    ups = np.array([s.up for s in static])
    np.testing.assert_allclose(ups, np.array(truth.accel.true_up))
    assert len({tuple(np.round(u, 6)) for u in ups}) == 18
    first6, _ = simulate_redundant_accel(labelled=True, orientations=6)
    assert [s.label for s in first6.segments] == [s.label for s in static[:6]]
    with pytest.raises(InputError, match="18 poses"):
        simulate_redundant_accel(labelled=True, orientations=20)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"sigma_counts": -1.0},
        {"orientations": 0},
        {"samples": 0},
        {"rate_hz": 0.0},
        {"seed": -1},
        {"orientations": 2.5},
    ],
)
def test_redundant_refuses_bad_values(kwargs):
    with pytest.raises(InputError):
        simulate_redundant_accel(**kwargs)


# --------------------------------------------------------------------------------------------
# Gyroscope procedure
# --------------------------------------------------------------------------------------------


def test_gyro_layout(gyro_run):
    session, truth = gyro_run
    rot = session.rotation_segments()
    assert len(rot) == 7  # 3 sweeps x 2 mountings + the ruler turn
    seg_mount = truth.gyro.segment_mounting
    assert set(seg_mount) == {s.name for s in session.segments}
    for s in session.segments:
        assert seg_mount[s.name] == _mounting(s.label)
        if s.kind == "static":
            assert (s.up is not None) == (seg_mount[s.name] == 1)
    sweeps = rot[:6]
    assert [s.label for s in sweeps] == [
        f"mounting {m}: sweep about {a}" for m in (1, 2) for a in ("+Z", "+X", "+Y")
    ]
    assert all(s.angle_deg is None for s in sweeps)
    ruler = rot[-1]
    assert ruler.angle_deg == 90.0 and seg_mount[ruler.name] == 1
    np.testing.assert_array_equal(ruler.axis, [0.0, 0.0, 1.0])
    assert truth.gyro.ruler.segment == ruler.name
    rv = truth.gyro.mounting_rotvec_deg
    assert rv[0] == [0.0, 0.0, 0.0] and np.linalg.norm(rv[1]) > 30.0


def test_gyro_is_deterministic_per_seed():
    a, ta = simulate_hk_gyro(seed=8, created="x")
    b, tb = simulate_hk_gyro(seed=8, created="x")
    c, _ = simulate_hk_gyro(seed=9, created="x")
    np.testing.assert_array_equal(a.gyro, b.gyro)
    np.testing.assert_array_equal(a.accel, b.accel)
    assert ta.to_dict() == tb.to_dict()
    assert not np.array_equal(a.gyro, c.gyro)


def test_still_means_are_the_bias(gyro_run):
    session, truth = gyro_run
    g = truth.gyro
    S = np.array(g.S)
    # raw noise per sample: S n with n ~ N(0, noise^2 I), plus rounding
    var = np.diag(S @ S.T) * g.noise ** 2 + 1.0 / 12.0
    for seg in session.static_segments():
        mean = session.gyro[seg.start : seg.stop].mean(axis=0)
        assert np.all(np.abs(mean - g.bias) < Z_MAX * np.sqrt(var / seg.n_samples)), seg.label


@pytest.mark.parametrize("units", ["counts", "m/s^2"])
def test_ruler_turn_integrates_to_the_stated_angle(units):
    session, truth = simulate_hk_gyro(seed=11, units=units)
    ruler = session.rotation_segments()[-1]
    dt = 1.0 / session.sample_rate_hz
    w = truth.gyro.apply(session.gyro[ruler.start : ruler.stop])
    integral = w.sum(axis=0) * dt  # rad, sensor frame (= iron frame in mounting 1)
    # noise of the integral: noise * sqrt(n) * dt per axis
    std = truth.gyro.noise * np.sqrt(ruler.n_samples) * dt
    expected = np.radians(ruler.angle_deg) * ruler.axis
    assert np.all(np.abs(integral - expected) < Z_MAX * std + 1e-5)
    assert np.degrees(np.linalg.norm(integral)) == pytest.approx(90.0, abs=0.1)


def test_sweeps_of_one_mounting_are_orthogonal_in_the_sensor_frame(gyro_run):
    session, truth = gyro_run
    seg_mount = truth.gyro.segment_mounting
    axes_truth = truth.gyro.sweep_axes_sensor
    found = {}
    for seg in session.rotation_segments()[:-1]:
        w = truth.gyro.apply(session.gyro[seg.start : seg.stop])
        axis = np.linalg.svd(w, full_matrices=False)[2][0]
        t = np.arange(seg.n_samples)
        phase = np.sin(2 * np.pi * (t + 1) / (seg.n_samples + 1) * 3)
        axis *= np.sign(phase @ (w @ axis))  # rate = +axis * peak * sin(...)
        assert np.abs(axis - axes_truth[seg.name]).max() < 1e-3
        found[seg.name] = axis
    names = list(found)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            dot = abs(found[a] @ found[b])
            if seg_mount[a] == seg_mount[b]:
                assert dot < 2e-3
    # mounting 2 turns the swept axes away from the sensor axes of mounting 1
    m1 = [found[n] for n in names if seg_mount[n] == 1]
    m2 = [found[n] for n in names if seg_mount[n] == 2]
    np.testing.assert_allclose(np.abs(m1), np.eye(3)[[2, 0, 1]], atol=2e-3)
    assert max(abs(a @ b) for a in m1 for b in m2) < np.cos(np.radians(15.0))


def test_accelerometer_sees_gravity_along_the_swept_axis(gyro_run):
    """Sweeps turn about the vertical: the accelerometer reads g along the sweep axis."""
    session, truth = gyro_run
    axes = truth.gyro.sweep_axes_sensor
    for seg in session.rotation_segments()[:-1]:
        f = truth.accel.apply(session.accel[seg.start : seg.stop])
        np.testing.assert_allclose(
            f.mean(axis=0), session.gravity * np.array(axes[seg.name]), atol=0.01
        )
        assert f.std(axis=0).max() < 3 * truth.accel.noise
    for seg in session.static_segments():
        if seg.up is not None:
            f = truth.accel.apply(session.accel[seg.start : seg.stop]).mean(axis=0)
            np.testing.assert_allclose(f, session.gravity * seg.up, atol=0.01)


def test_gyro_refuses_bad_values():
    for kwargs in ({"mountings": 0}, {"still_s": 0.01}, {"ruler_angle_deg": 0.0}, {"units": "g"}):
        with pytest.raises(InputError):
            simulate_hk_gyro(**kwargs)


# --------------------------------------------------------------------------------------------
# Files and the command
# --------------------------------------------------------------------------------------------


def test_sessions_and_truths_round_trip(tmp_path, redundant, gyro_run):
    for name, (session, truth) in {"red": redundant, "gyro": gyro_run}.items():
        path = tmp_path / f"{name}.h5"
        session_mod.write_session(path, session)
        back = session_mod.read_session(path)
        np.testing.assert_array_equal(back.accel, session.accel)
        np.testing.assert_array_equal(back.time, session.time)
        if session.gyro is None:
            assert back.gyro is None
        else:
            np.testing.assert_array_equal(back.gyro, session.gyro)
        assert back.segments == session.segments
        assert back.accel_units == session.accel_units
        tpath = tmp_path / f"{name}.truth.json"
        calibration_mod.write_calibration(tpath, truth)
        tback = calibration_mod.read_calibration(tpath)
        assert tback.to_dict() == json.loads(json.dumps(truth.to_dict()))


def _run_main(monkeypatch, capsys, args):
    from imucal_cli.cli import main

    monkeypatch.setattr(sys, "argv", ["imucal", *args])
    with pytest.raises(SystemExit) as exc:
        main()
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_command_writes_the_redundant_plan(tmp_path, monkeypatch, capsys):
    out = tmp_path / "red.h5"
    args = ["simulate", "--plan", "hk-redundant", "--seed", "3", "--sigma-counts", "1.5"]
    code, stdout, err = _run_main(
        monkeypatch, capsys, [*args, "--orientations", "12", "-o", str(out)]
    )
    assert code in (0, None), err
    session = session_mod.read_session(out)
    truth = calibration_mod.read_calibration(tmp_path / "red.truth.json")
    expected, _ = simulate_redundant_accel(seed=3, sigma_counts=1.5, orientations=12)
    np.testing.assert_array_equal(session.accel, expected.accel)
    assert session.accel.shape == (120, 4)
    assert truth.accel.matrix.shape == (3, 4) and truth.gyro is None
    assert truth.session == "red.h5" and truth.accel.noise_counts == 1.5

    lab = tmp_path / "lab.h5"
    code, _, err = _run_main(
        monkeypatch, capsys, ["simulate", "--plan", "hk-redundant", "--labelled", "-o", str(lab)]
    )
    assert code in (0, None), err
    assert all(s.up is not None for s in session_mod.read_session(lab).segments)


def test_command_writes_the_gyro_plan(tmp_path, monkeypatch, capsys):
    out = tmp_path / "gyro.h5"
    code, stdout, err = _run_main(
        monkeypatch,
        capsys,
        ["simulate", "--plan", "hk-gyro", "--seed", "4", "--mountings", "3", "-o", str(out)],
    )
    assert code in (0, None), err
    session = session_mod.read_session(out)
    truth = calibration_mod.read_calibration(tmp_path / "gyro.truth.json")
    expected, _ = simulate_hk_gyro(seed=4, mountings=3)
    np.testing.assert_array_equal(session.gyro, expected.gyro)
    assert len(session.rotation_segments()) == 10
    assert len(truth.gyro.mounting_rotvec_deg) == 3


def test_command_refuses_bad_hk_options(tmp_path, monkeypatch, capsys):
    out = tmp_path / "bad.h5"
    for args in (
        ["--plan", "hk-redundant", "--labelled", "--orientations", "19"],
        ["--plan", "hk-redundant", "--units", "m/s^2"],
        ["--plan", "hk-gyro", "--mountings", "0"],
    ):
        code, _, err = _run_main(monkeypatch, capsys, ["simulate", *args, "-o", str(out)])
        assert code == 2, args
        assert err.startswith("imucal: error: ") and len(err.strip().splitlines()) == 1
        assert not out.exists()


def test_the_served_redundant_unit_holds_and_moves_as_a_device_streams():
    """``simulate --serve --plan hk-redundant``: the paper's 10 readings per orientation with
    the recorder paused between them were served back to back (the time jumps dropped), one
    hold of 200 lines for 20 orientations ('pose 1/1'); served, each orientation is held
    ``hold_s`` and the unit moves to the next in ``move_s``, on one unbroken clock."""
    from imucal_cli.simulate.device import stream_with_holds

    time, accel, gyro, holds = stream_with_holds("hk-redundant", seed=1, rate_hz=100.0,
                                                 hold_s=1.2, move_s=0.5)  # fmt: skip
    assert gyro is None and accel.shape[1] == 4 and len(holds) == 20
    np.testing.assert_allclose(np.diff(time), 0.01, rtol=1e-9)
    noise = np.hypot(0.7, QUANTISATION_COUNTS)
    for h in holds[1:]:  # the lead is the first pose held longer
        assert 115 <= h.stop - h.start <= 125
        assert np.all(accel[h.start:h.stop].std(axis=0) < 3 * noise)
    for a, b in zip(holds, holds[1:], strict=False):  # the moves between: gravity turns
        move = accel[a.stop:b.start]
        assert len(move) == 50 and np.ptp(move, axis=0).max() > 20 * noise


@pytest.mark.slow
def test_the_redundant_unit_calibrates_through_the_virtual_port(tmp_path, process_factory):  # noqa: F811
    """The served unit captured unattended with ``--plan hk-redundant`` and calibrated: every
    orientation seen, the four channels' gains within the noise of the truth's."""
    from .cli_helpers import run
    from .test_virtual import start_capture

    server = process_factory("--plan", "hk-redundant", "--seed", "1", "--hold", "2.6",
                             "--move", "0.5")  # fmt: skip
    out = tmp_path / "red.h5"
    cap = start_capture(server.path, out, "--plan", "hk-redundant", "--columns",
                        "t,ax,ay,az,a4,temp", "--accel-units", "counts")  # fmt: skip
    _, stderr = cap.communicate(timeout=300)
    server.finish()
    assert cap.returncode == 0, stderr
    proc = run("calibrate", out, "--json", "--no-store")
    assert proc.returncode == 0, proc.stderr
    cal = json.loads(proc.stdout)["calibration"]["accel"]
    _, truth = simulate_redundant_accel(seed=1, samples=520, rate_hz=200.0, move_s=0.5)
    # each channel's sensitivity (a row of pinv(matrix), counts per m/s^2): its length does
    # not depend on the frame, which unlabelled orientations leave free
    gains = np.linalg.norm(np.linalg.pinv(np.array(cal["matrix"])), axis=1)
    true = np.linalg.norm(np.linalg.pinv(np.array(truth.accel.matrix)), axis=1)
    np.testing.assert_allclose(gains, true, rtol=2e-3)  # the paper's worst at 10 readings: 1.3e-3
    np.testing.assert_allclose(cal["bias"], truth.accel.bias, atol=0.5)  # counts


@pytest.mark.parametrize("hold", ["-1", "0", "nan"])
def test_the_redundant_units_hold_is_checked(tmp_path, hold):
    """``--hold`` now shapes hk-redundant's holds (served or written): a hold that is no
    time was taken as one reading per orientation."""
    from .cli_helpers import assert_one_line_error, run

    assert_one_line_error(run("simulate", "--plan", "hk-redundant", "--hold", hold, "-o",
                              tmp_path / "r.h5"), "hold")  # fmt: skip
