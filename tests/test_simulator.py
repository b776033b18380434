"""The simulator: plans, truth, determinism, units independence, noise and jitter statistics,
and the `imucal simulate` command.

Statistical tolerances are derived from the simulated noise and quantisation (z-scores and
chi-square bounds at a false-alarm probability of 1e-4 or below); the draws are fixed by seeds,
so every test is deterministic.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import imucal_cli.formats.calibration as calibration_mod
import imucal_cli.formats.session as session_mod
from imucal_cli.errors import InputError
from imucal_cli.plans import plan_poses
from imucal_cli.simulate.triad import (
    ACCEL_LSB_PER_G,
    G0,
    GYRO_LSB_PER_DPS,
    random_imu,
    simulate,
    simulate_stream,
)

Z_MAX = 4.5  # |z| bound per check: two-sided p = 6.8e-6
P_CHI2 = 1e-4  # two-sided chi-square bounds at this tail probability each


def _static(stream):
    return [s for s in stream.segments if s.kind == "static"]


def _calibrated_means(stream):
    """Truth-calibrated mean specific force of each static segment, (K, 3) m/s^2."""
    t = stream.truth
    m = np.linalg.inv(t.accel_S)
    return np.array(
        [m @ (stream.accel[s.start : s.stop].mean(0) - t.accel_b) for s in _static(stream)]
    )


def _mean_cov(stream, seg):
    """Covariance (3, 3) of a static segment's calibrated mean, m/s^2: input-referred white
    noise plus quantisation (uniform, variance 1/12 LSB^2 per channel; the noise spans several
    LSB, so the rounding error is close to independent of the signal)."""
    t = stream.truth
    m = np.linalg.inv(t.accel_S)
    n = seg.stop - seg.start
    cov = np.diag(t.accel_noise**2)
    if t.quantise:
        cov = cov + m @ m.T / 12.0
    return cov / n


def _angle_deg(u, v):
    u, v = np.atleast_2d(u), np.atleast_2d(v)
    cross = np.linalg.norm(np.cross(u, v), axis=1)
    return np.degrees(np.arctan2(cross, np.sum(u * v, axis=1)))


# ------------------------------------------------------------------------------------------
# Plans
# ------------------------------------------------------------------------------------------


def test_six_plan_is_the_faces():
    poses = plan_poses("six")
    assert [label for label, _ in poses] == [
        "face +Z up",
        "face -Z up",
        "face +X up",
        "face -X up",
        "face +Y up",
        "face -Y up",
    ]
    ups = np.array([u for _, u in poses])
    np.testing.assert_array_equal(np.abs(ups).sum(0), [2, 2, 2])
    np.testing.assert_array_equal(ups.sum(0), [0, 0, 0])


def test_qureshi18_plan_is_faces_and_45_degree_edges():
    poses = plan_poses("qureshi18")
    labels = [label for label, _ in poses]
    ups = np.array([u for _, u in poses])
    assert len(poses) == 18 and len(set(labels)) == 18
    assert sum(label.startswith("face ") for label in labels) == 6
    assert sum(label.startswith("edge ") for label in labels) == 12
    assert "edge +X+Z up" in labels and "edge -Y+Z up" in labels
    np.testing.assert_allclose(np.linalg.norm(ups, axis=1), 1.0)
    edges = ups[6:]
    np.testing.assert_allclose(np.sort(np.abs(edges), axis=1)[:, 1:], np.sqrt(0.5))
    np.testing.assert_array_equal(np.sort(np.abs(edges), axis=1)[:, 0], 0.0)
    # "edge +X+Z up" points half way between +X and +Z
    np.testing.assert_allclose(ups[labels.index("edge +X+Z up")], [np.sqrt(0.5), 0, np.sqrt(0.5)])
    # every pair of poses is at least 45 degrees apart
    ang = _angle_deg(np.repeat(ups, 18, axis=0), np.tile(ups, (18, 1))).reshape(18, 18)
    assert ang[~np.eye(18, dtype=bool)].min() == pytest.approx(45.0)


def test_random_plan_is_unlabelled():
    poses = plan_poses("random:9")
    assert [label for label, _ in poses] == [f"pose {k}" for k in range(1, 10)]
    assert all(up is None for _, up in poses)


@pytest.mark.parametrize("plan", ["seven", "random:0", "random:", "random:x", "random:-3", ""])
def test_bad_plans_are_refused(plan):
    with pytest.raises(InputError, match="plan"):
        plan_poses(plan)


# ------------------------------------------------------------------------------------------
# The part
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(20))
def test_random_imu_is_a_cheap_16_bit_part(seed):
    t = random_imu(np.random.default_rng(seed), "counts")
    assert t.accel_units == t.gyro_units == "counts" and t.quantise
    assert t.accel_nominal == pytest.approx(8192 / 9.80665)
    assert np.all(np.abs(t.accel_scale_error) <= 0.03)
    assert np.all((np.abs(t.gyro_scale_error) >= 0.01) & (np.abs(t.gyro_scale_error) <= 0.03))
    assert np.all(np.abs(t.accel_bias_g) <= 0.05)
    assert np.all(np.abs(t.gyro_bias_dps) <= 3.0)
    np.testing.assert_allclose(t.accel_b, t.accel_bias_g * ACCEL_LSB_PER_G)
    np.testing.assert_allclose(t.gyro_b, t.gyro_bias_dps * GYRO_LSB_PER_DPS)
    for S, err in ((t.accel_S, t.accel_scale_error), (t.gyro_S, t.gyro_scale_error)):
        gain = np.linalg.norm(S, axis=1)
        nominal = t.accel_nominal if S is t.accel_S else t.gyro_nominal
        np.testing.assert_allclose(gain, nominal * (1 + err))
        n = S / gain[:, None]
        off90 = np.degrees(np.arcsin(np.abs(n @ n.T)[np.triu_indices(3, 1)]))
        assert off90.max() <= 1.0 + 1e-9  # axes leaning <= 0.5 deg each
        # each sensitivity axis within (0.5 + 1) deg of its fixture axis
        assert _angle_deg(n, np.eye(3)).max() <= 1.5 + 1e-9
        # a general matrix: misaligned both above and below the diagonal
        assert np.all(np.abs(S[np.triu_indices(3, 1)]) > 0)
        assert np.all(np.abs(S[np.tril_indices(3, -1)]) > 0)
    assert np.degrees(np.linalg.norm(t.mount_rotvec)) <= 1.0


def test_same_generator_state_gives_the_same_part_in_both_units():
    c = random_imu(np.random.default_rng(5), "counts")
    s = random_imu(np.random.default_rng(5), "m/s^2")
    assert (s.accel_units, s.gyro_units, s.quantise) == ("m/s^2", "rad/s", False)
    np.testing.assert_array_equal(c.accel_scale_error, s.accel_scale_error)
    np.testing.assert_array_equal(c.accel_bias_g, s.accel_bias_g)
    np.testing.assert_array_equal(c.mount_rotvec, s.mount_rotvec)
    np.testing.assert_allclose(c.accel_S / c.accel_nominal, s.accel_S, rtol=1e-13)
    np.testing.assert_allclose(c.gyro_S / c.gyro_nominal, s.gyro_S, rtol=1e-13)
    np.testing.assert_allclose(s.accel_b, s.accel_bias_g * G0)
    np.testing.assert_allclose(s.gyro_b, np.radians(s.gyro_bias_dps))


# ------------------------------------------------------------------------------------------
# The stream
# ------------------------------------------------------------------------------------------


def test_same_seed_same_stream_bit_for_bit():
    a = simulate_stream(seed=3)
    b = simulate_stream(seed=3)
    for name in ("time", "accel", "gyro", "true_up", "rotvec"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert [(s.start, s.stop, s.label) for s in a.segments] == [
        (s.start, s.stop, s.label) for s in b.segments
    ]
    c = simulate_stream(seed=4)
    assert not np.array_equal(a.accel, c.accel)
    assert not np.array_equal(a.truth.accel_S, c.truth.accel_S)


def test_stream_layout():
    st = simulate_stream(plan="qureshi18", rate_hz=100.0, hold_s=2.0)
    n = len(st.time)
    np.testing.assert_array_equal(st.time, np.arange(n) / 100.0)
    assert st.accel.shape == st.gyro.shape == (n, 3)
    kinds = [s.kind for s in st.segments]
    assert kinds == ["static", "rotation"] * 17 + ["static"]
    assert [s.name for s in st.segments] == [f"{i:04d}" for i in range(35)]
    assert st.segments[0].start > 0  # a still lead-in before the first hold
    for a, b in zip(st.segments, st.segments[1:], strict=False):
        assert a.stop == b.start  # continuous: hold, move, hold, ...
    assert st.segments[-1].stop == n
    static = _static(st)
    assert all(s.stop - s.start == 200 for s in static)
    assert [s.label for s in static] == [label for label, _ in plan_poses("qureshi18")]
    for s, (_, up) in zip(static, plan_poses("qureshi18"), strict=True):
        np.testing.assert_array_equal(s.up, up)
    for s in st.segments:
        if s.kind == "rotation":
            assert s.up is None and s.label.startswith("turn to ")
            # the unit really moves in every rotation segment
            assert np.abs(st.rate[s.start : s.stop]).max() > 0.1
        else:
            assert np.all(st.rate[s.start : s.stop] == 0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_defaults_never_clip_and_counts_are_integers(seed):
    st = simulate_stream(seed=seed)
    for raw in (st.accel, st.gyro):
        assert np.all(raw == np.rint(raw))
        assert raw.max() < 32767 and raw.min() > -32768
    # 1 g sits near 8192 counts, as on a +-4 g part
    assert 7500 < np.abs(st.accel).max() < 9500


@pytest.mark.parametrize("seed", [0, 7])
def test_units_describe_the_same_experiment(seed):
    """Same seed in counts and in m/s^2: the truth-calibrated streams agree sample by sample
    within the rounding to counts (at most half an LSB per channel)."""
    c = simulate_stream(seed=seed, units="counts")
    s = simulate_stream(seed=seed, units="m/s^2")
    assert (s.truth.accel_units, s.truth.gyro_units) == ("m/s^2", "rad/s")
    np.testing.assert_array_equal(c.true_up, s.true_up)
    np.testing.assert_array_equal(c.rotvec, s.rotvec)
    for raw_c, raw_s, S_c, b_c, S_s, b_s in (
        (c.accel, s.accel, c.truth.accel_S, c.truth.accel_b, s.truth.accel_S, s.truth.accel_b),
        (c.gyro, s.gyro, c.truth.gyro_S, c.truth.gyro_b, s.truth.gyro_S, s.truth.gyro_b),
    ):
        m_c = np.linalg.inv(S_c)
        cal_c = (raw_c - b_c) @ m_c.T
        cal_s = (raw_s - b_s) @ np.linalg.inv(S_s).T
        half_lsb = 0.5 * np.abs(m_c).sum(axis=1)  # worst-case rounding effect per output axis
        assert np.all(np.abs(cal_c - cal_s) <= half_lsb * (1 + 1e-9) + 1e-9)
        # ... and they are not trivially equal: the rounding is really there
        assert np.abs(cal_c - cal_s).max() > 0.1 * half_lsb.min()


@pytest.mark.parametrize("units", ["counts", "m/s^2"])
def test_truth_gives_gravity_magnitude_within_the_noise(units):
    """|matrix @ (mean raw - bias)| == g within the noise of a mean of M samples.

    The magnitude error of a pose is the projection of the mean's error on the up direction:
    variance u^T C u with C = (sigma^2 I + quantisation) / M.  Each pose must be within
    Z_MAX sigma and the z-scores of all poses must have unit variance (chi-square bounds):
    the noise is neither missing nor too large.
    """
    z = []
    for seed in (1, 2, 3):
        st = simulate_stream(seed=seed, units=units, gravity=9.81)
        for seg, mean, u in zip(_static(st), _calibrated_means(st), st.true_up, strict=True):
            sigma = np.sqrt(u @ _mean_cov(st, seg) @ u)
            z.append((np.linalg.norm(mean) - 9.81) / sigma)
    z = np.array(z)
    assert np.abs(z).max() < Z_MAX
    k = len(z)
    assert stats.chi2.ppf(P_CHI2, k) < np.sum(z**2) < stats.chi2.ppf(1 - P_CHI2, k)


def test_truth_gives_the_true_up_direction():
    """The calibrated mean points along the recorded true up, to within the noise across it."""
    st = simulate_stream(seed=11)
    for seg, mean, u in zip(_static(st), _calibrated_means(st), st.true_up, strict=True):
        err = mean - 9.80665 * u
        cov = _mean_cov(st, seg)
        assert err @ np.linalg.solve(cov, err) < stats.chi2.ppf(1 - 1e-6, 3)


def test_no_jitter_means_the_labelled_pose():
    st = simulate_stream(seed=2, jitter_deg=0.0)
    for seg, mean in zip(_static(st), _calibrated_means(st), strict=True):
        sigma_across = np.sqrt(np.trace(_mean_cov(st, seg))) / 9.80665  # rad
        assert np.radians(_angle_deg(mean, seg.up)[0]) < Z_MAX * sigma_across


def test_jitter_is_the_rms_angle_to_the_labelled_up():
    """The tilt of each pose is 2 iid normal components of std jitter/sqrt(2), so the sum of
    squared angles / (jitter^2 / 2) over K poses is chi-square with 2K degrees of freedom.
    The noise adds about 0.004 deg per pose, negligible against 3 deg."""
    jitter = 3.0
    angles = []
    for seed in (0, 1, 2):
        st = simulate_stream(seed=seed, jitter_deg=jitter)
        means = _calibrated_means(st)
        ups = np.array([s.up for s in _static(st)])
        angles.append(_angle_deg(means, ups))
        np.testing.assert_allclose(_angle_deg(st.true_up, ups), st.tilt_deg, atol=1e-9)
    angles = np.concatenate(angles)
    dof = 2 * len(angles)
    stat = np.sum(angles**2) / (jitter**2 / 2)
    assert stats.chi2.ppf(P_CHI2, dof) < stat < stats.chi2.ppf(1 - P_CHI2, dof)
    # the same bounds stated on the RMS angle: about 0.76 .. 1.26 jitter for 54 poses
    rms = np.sqrt(np.mean(angles**2))
    lo, hi = (np.sqrt(stats.chi2.ppf(p, dof) / dof) for p in (P_CHI2, 1 - P_CHI2))
    assert lo * jitter < rms < hi * jitter


def test_random_plan_directions_cover_the_sphere():
    st = simulate_stream(plan="random:300", seed=4, hold_s=0.1, move_s=0.05, rate_hz=100.0)
    static = _static(st)
    assert len(static) == 300
    assert all(s.up is None for s in static)
    assert [s.label for s in static] == [f"pose {k}" for k in range(1, 301)]
    # uniform on the sphere: each component has mean 0 and variance 1/3
    m = st.true_up.mean(axis=0)
    assert np.all(np.abs(m) < Z_MAX * np.sqrt(1 / 3 / 300))
    np.testing.assert_allclose(np.linalg.norm(_calibrated_means(st), axis=1), G0, atol=0.01)


def test_gyro_integrates_to_the_true_rotation_and_reads_zero_when_still():
    st = simulate_stream(seed=6)
    t = st.truth
    m = np.linalg.inv(t.gyro_S)
    dt = 1.0 / st.options["rate_hz"]
    moves = [s for s in st.segments if s.kind == "rotation"]
    assert len(moves) == 17
    sigma_q = np.sqrt(np.diag(m @ m.T) / 12.0)  # rad/s per sample from rounding
    for seg, rv in zip(moves, st.rotvec, strict=True):
        # the noiseless rate integrates to the rotation (smootherstep: no end effects)
        np.testing.assert_allclose(st.rate[seg.start : seg.stop].sum(0) * dt, rv, atol=1e-9)
        w = (st.gyro[seg.start : seg.stop] - t.gyro_b) @ m.T
        n = seg.stop - seg.start
        sigma = np.sqrt(t.gyro_noise**2 + sigma_q**2) * np.sqrt(n) * dt
        assert np.all(np.abs(w.sum(0) * dt - rv) < Z_MAX * sigma)
    # moves are a hand's pace: below 300 deg/s, far from the 2000 deg/s range
    assert np.degrees(np.abs(st.rate).max()) < 300
    for seg in _static(st):
        w = (st.gyro[seg.start : seg.stop] - t.gyro_b) @ m.T
        sigma = np.sqrt(t.gyro_noise**2 + sigma_q**2) / np.sqrt(seg.stop - seg.start)
        assert np.all(np.abs(w.mean(0)) < Z_MAX * sigma)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rate_hz": 0.0}, "rate"),
        ({"rate_hz": -100.0}, "rate"),
        ({"rate_hz": float("nan")}, "rate"),
        ({"hold_s": 0.05}, "at least 10"),
        ({"hold_s": -1.0}, "hold"),
        ({"accel_noise": -0.01}, "accel noise"),
        ({"jitter_deg": -1.0}, "jitter"),
        ({"units": "g"}, "units"),
        ({"seed": -1}, "seed"),
        ({"plan": "random:0"}, "plan"),
    ],
)
def test_bad_values_are_refused(kwargs, match):
    with pytest.raises(InputError, match=match):
        simulate_stream(**kwargs)


# ------------------------------------------------------------------------------------------
# Session, truth file and command
# ------------------------------------------------------------------------------------------


def test_simulate_returns_a_session_and_its_truth():
    session, truth = simulate(plan="qureshi18", seed=1)
    assert session.source == "simulator"
    assert session.sensor == "sim-16bit seed 1"
    assert session.sample_rate_hz == 100.0 and session.gravity == 9.80665
    assert (session.accel_units, session.gyro_units) == ("counts", "counts")
    static = [s for s in session.segments if s.kind == "static"]
    assert len(static) == 18 and static[0].label == "face +Z up"
    np.testing.assert_array_equal(static[0].up, [0, 0, 1])
    assert truth.accel.solver == truth.gyro.solver == "truth"
    assert truth.seed == 1 and truth.plan == "qureshi18"
    assert truth.jitter_deg == 2.0
    assert len(truth.accel.true_up) == 18
    assert truth.accel.noise == 0.01 and truth.gyro.noise == 0.005
    st = simulate_stream(plan="qureshi18", seed=1)
    np.testing.assert_array_equal(session.accel, st.accel)
    np.testing.assert_allclose(np.asarray(truth.accel.matrix), np.linalg.inv(st.truth.accel_S))
    np.testing.assert_allclose(np.asarray(truth.accel.bias), st.truth.accel_b)


def _run_main(monkeypatch, capsys, args):
    from imucal_cli.cli import main

    monkeypatch.setattr(sys, "argv", ["imucal", *args])
    with pytest.raises(SystemExit) as exc:
        main()
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_command_writes_session_and_truth(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run.h5"
    code, stdout, err = _run_main(
        monkeypatch, capsys, ["simulate", "--seed", "2", "--output", str(out)]
    )
    assert code in (0, None), err
    truth_file = tmp_path / "run.truth.json"
    assert out.exists() and truth_file.exists()
    assert len(stdout.strip().splitlines()) == 2  # one line per file

    session = session_mod.read_session(out)
    truth = calibration_mod.read_calibration(truth_file)
    st = simulate_stream(seed=2)
    np.testing.assert_array_equal(np.asarray(session.accel), st.accel)
    np.testing.assert_array_equal(np.asarray(session.gyro), st.gyro)
    assert sum(s.kind == "static" for s in session.segments) == 18
    assert session.source == "simulator" and session.sensor == "sim-16bit seed 2"
    assert truth.accel.solver == "truth" and truth.accel.units == "m/s^2"
    raw = json.loads(truth_file.read_text())
    assert raw["format"] == "imucal-calibration" and raw["session"] == "run.h5"
    assert len(raw["accel"]["true_up"]) == 18

    # the truth read back from disk turns the static means into g
    m, b = np.asarray(truth.accel.matrix), np.asarray(truth.accel.bias)
    acc = np.asarray(session.accel)
    for seg in session.segments:
        if seg.kind == "static":
            mag = np.linalg.norm(m @ (acc[seg.start : seg.stop].mean(0) - b))
            assert abs(mag - 9.80665) < 0.005  # ~7 sigma of a 200-sample mean (0.0007)

    # refuses to overwrite, then overwrites with --force
    code, _, err = _run_main(monkeypatch, capsys, ["simulate", "--output", str(out)])
    assert code == 2 and "exists" in err and "--force" in err
    code, _, err = _run_main(
        monkeypatch, capsys, ["simulate", "--output", str(out), "--force", "--units", "m/s^2"]
    )
    assert code in (0, None), err
    assert session_mod.read_session(out).accel_units == "m/s^2"


def test_command_default_output_name(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run_main(monkeypatch, capsys, ["simulate", "--plan", "random:9", "--seed", "3"])
    assert code in (0, None), err
    assert (tmp_path / "sim-random-9-seed3.h5").exists()
    assert (tmp_path / "sim-random-9-seed3.truth.json").exists()
    session = session_mod.read_session(tmp_path / "sim-random-9-seed3.h5")
    assert all(s.up is None for s in session.segments)


@pytest.mark.parametrize(
    "args",
    [
        ["--plan", "seven"],
        ["--plan", "random:0"],
        ["--accel-noise", "-0.1"],
        ["--rate", "0"],
        ["--rate", "-5"],
        ["--hold", "0.05"],
        ["--jitter-deg", "-1"],
        ["--units", "g"],
        ["--seed", "-1"],
    ],
)
def test_bad_options_exit_2_with_one_line(tmp_path, monkeypatch, capsys, args):
    out = tmp_path / "x.h5"
    code, _, err = _run_main(monkeypatch, capsys, ["simulate", "--output", str(out), *args])
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imucal: error: "), err
    assert "Traceback" not in err
    assert not out.exists()


def test_help_explains_options_with_units():
    from typer.testing import CliRunner

    from imucal_cli.cli import app

    res = CliRunner().invoke(app, ["simulate", "--help"], env={"COLUMNS": "200"})
    assert res.exit_code == 0
    text = " ".join(res.output.split())
    for opt in (
        "--plan",
        "--seed",
        "--rate",
        "--hold",
        "--accel-noise",
        "--jitter-deg",
        "--units",
        "--output",
        "--force",
    ):
        assert opt in text
    for unit in ("Hz", "m/s^2", "degrees", "s (at least 10 samples)", "qureshi18", "random:N"):
        assert unit in text


def test_console_script_end_to_end(tmp_path):
    """The installed entry point, as a user runs it: success, then a one-line refusal."""
    out = tmp_path / "e2e.h5"
    cmd = [sys.executable, "-m", "imucal_cli", "simulate", "--plan", "six", "-o", str(out)]
    ok = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert out.exists() and Path(str(out).replace(".h5", ".truth.json")).exists()
    bad = subprocess.run([*cmd, "--force", "--hold", "0.01"], capture_output=True, text=True)
    assert bad.returncode == 2
    assert len(bad.stderr.strip().splitlines()) == 1 and "Traceback" not in bad.stderr
