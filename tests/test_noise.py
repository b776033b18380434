"""`imucal noise`: Allan deviation figures on synthetic still recordings of known noise, the
refusals (raw counts without a calibration, too short, not still), and the still:MINUTES
capture plan in the guided and unattended modes."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from imucal_cli.capture.guided import ScriptedKeys, run_guided
from imucal_cli.capture.unattended import _Buffer, _PlanWatcher
from imucal_cli.cli import main
from imucal_cli.design.allan import axis_noise
from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.columns import SampleBlock
from imucal_cli.formats.session import Segment, Session, read_session, write_session
from imucal_cli.model.calibration import Calibration, SensorCalibration
from imucal_cli.plans import Plan, Step, load_plan
from imucal_cli.use.noise import analyse_noise

from .test_guided import FakeRecorder, _console, poses

RATE = 100.0
G0 = 9.80665
CREATED = "2026-01-01T00:00:00Z"


def _cli(argv, monkeypatch, capsys):
    """Run the CLI; typer returns normally on success (code 0)."""
    monkeypatch.setattr("sys.argv", ["imucal", *argv])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code or 0
    out = capsys.readouterr()
    return code, out.out, out.err


def still_session(
    minutes=5.0, accel_sigma=0.01, gyro_sigma=0.002, seed=0, units=("m/s^2", "rad/s"),
    segments=None,
) -> tuple[Session, float, float]:  # fmt: skip
    """A still unit, +Z up: white noise of known std per sample. Returns the session and the
    true random walks N = sigma / sqrt(rate) (accel, gyro)."""
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * RATE)
    time = np.arange(n) / RATE
    accel = np.array([0.0, 0.0, G0]) + accel_sigma * rng.standard_normal((n, 3))
    gyro = gyro_sigma * rng.standard_normal((n, 3))
    if units[0] == "counts":
        accel = np.round(accel * 800.0)
    if units[1] == "counts":
        gyro = np.round(gyro * 939.7)
    session = Session(time, accel, gyro, None, segments or [], CREATED, sensor="synthetic #1",
                      accel_units=units[0], gyro_units=units[1])  # fmt: skip
    return session, accel_sigma / np.sqrt(RATE), gyro_sigma / np.sqrt(RATE)


# --------------------------------------------------------------------------------------------
# The numerics


def test_white_noise_random_walk_within_ten_percent():
    rng = np.random.default_rng(1)
    for sigma in (0.02, 3e-4):
        y = sigma * rng.standard_normal(int(10 * 60 * RATE))
        a = axis_noise(y, RATE)
        assert a.random_walk == pytest.approx(sigma / np.sqrt(RATE), rel=0.1)
        assert a.random_walk_taus[0] == pytest.approx(1 / RATE)
        # White noise keeps falling: the minimum is at the longest tau, B an upper bound only.
        assert a.bias_instability_bound and a.notes
        assert a.rate_random_walk is None


def test_white_plus_rate_random_walk():
    # K is optional: the +1/2 region needs a decade of taus, so K is large here (crossing at
    # ~12 s for a 20-min recording) and the seed fixed.
    rng = np.random.default_rng(3)
    n, sigma, K = int(20 * 60 * RATE), 0.02, 3e-4
    y = sigma * rng.standard_normal(n) + np.cumsum(K / np.sqrt(RATE) * rng.standard_normal(n))
    a = axis_noise(y, RATE)
    assert a.random_walk == pytest.approx(sigma / np.sqrt(RATE), rel=0.1)
    assert a.rate_random_walk == pytest.approx(K, rel=0.35)
    # The floor between the two slopes, interior: a real minimum, not a bound.
    assert not a.bias_instability_bound
    assert a.random_walk_taus[1] < a.bias_instability_tau_s < a.rate_random_walk_taus[0]
    # At the crossing of N/sqrt(tau) and K sqrt(tau/3) the curve is about sqrt(2) x either.
    tau_x = np.sqrt(3) * sigma / np.sqrt(RATE) / K
    floor = np.sqrt(2) * sigma / np.sqrt(RATE) / np.sqrt(tau_x)
    assert 0.664 * a.bias_instability == pytest.approx(floor, rel=0.4)


def test_too_few_samples_refused():
    with pytest.raises(InputError, match="too few"):
        axis_noise(np.zeros(50), RATE)


# --------------------------------------------------------------------------------------------
# The noise step and the command


def test_noise_step_on_a_still_session(tmp_path):
    session, n_acc, n_gyr = still_session()
    write_session(tmp_path / "still.h5", session)
    result = analyse_noise(read_session(tmp_path / "still.h5"))
    assert result.span.startswith("whole recording") and result.still_fraction > 0.9
    assert not result.warnings
    accel, gyro = result.sensors
    for a in accel.noise:
        assert a.random_walk == pytest.approx(n_acc, rel=0.1)
    for a in gyro.noise:
        assert a.random_walk == pytest.approx(n_gyr, rel=0.1)
    d = result.to_dict()
    row = d["sensors"]["gyro"]["axes"][0]
    assert row["arw_deg_per_sqrt_h"] == pytest.approx(row["arw_rad_per_sqrt_s"] * 180 / np.pi * 60)
    assert row["bias_instability_deg_h"] == pytest.approx(
        row["bias_instability_rad_s"] * 180 / np.pi * 3600
    )
    acc = d["sensors"]["accel"]["axes"][0]
    assert acc["vrw_ug_per_sqrt_hz"] == pytest.approx(acc["vrw_m_s_per_sqrt_s"] / G0 * 1e6)
    assert d["longest_tau_s"] == pytest.approx(30.0, rel=0.05)  # a tenth of 5 min
    assert "tens of minutes" in d["limits"]


def test_longest_static_segment_is_used():
    segs = [
        Segment("0000", "static", 0, 3000, label="short"),
        Segment("0001", "static", 3000, 27000, label="hold still for 4 min (noise)"),
    ]
    session, _, _ = still_session(segments=segs)
    result = analyse_noise(session)
    assert (result.start, result.stop) == (3000, 27000) and "0001" in result.span


def test_counts_need_a_calibration(tmp_path, monkeypatch, capsys):
    session, n_acc, _ = still_session(minutes=2, units=("counts", "counts"))
    path = tmp_path / "c.h5"
    write_session(path, session)
    code, out, err = _cli(["noise", str(path)], monkeypatch, capsys)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "--calibration" in err and "counts" in err
    # With a calibration (1/800 m/s^2 per count on the accel only) the accel is analysed and
    # the gyro, still in counts, skipped with a warning.
    cal = Calibration(
        accel=SensorCalibration("gravity", "m/s^2", np.zeros(3), np.eye(3) / 800.0),
        created=CREATED,
    )
    write_calibration(tmp_path / "c.cal.json", cal)
    code, out, err = _cli(
        ["noise", str(path), "--calibration", str(tmp_path / "c.cal.json"), "--json"],
        monkeypatch, capsys,
    )  # fmt: skip
    assert code == 0, err
    d = json.loads(out)
    assert d["format"] == "imucal-noise" and d["format_version"] == 1  # README schema
    assert list(d["sensors"]) == ["accel"] and "calibration" in d["sensors"]["accel"]["basis"]
    assert any("gyro in counts skipped" in w for w in d["warnings"])
    assert not any("made on" in w for w in d["warnings"])  # the calibration names no unit
    for row in d["sensors"]["accel"]["axes"]:
        assert row["vrw_m_s_per_sqrt_s"] == pytest.approx(n_acc, rel=0.12)  # + quantisation
    # another unit's calibration (its sensor not the session's) gave figures silently (audit)
    write_calibration(tmp_path / "other.json", dataclasses.replace(cal, sensor="MPU-6050 #99"))
    code, out, err = _cli(["noise", str(path), "-c", str(tmp_path / "other.json"), "--json"],
                          monkeypatch, capsys)  # fmt: skip
    assert code == 0, err
    assert any("was made on 'MPU-6050 #99'" in w and "'synthetic #1'" in w
               for w in json.loads(out)["warnings"])  # fmt: skip


def test_not_still_is_warned_and_mostly_moving_refused():
    session, _, _ = still_session(minutes=3)
    n = len(session.time)
    t = session.time
    # Rock the unit for 20 % of the time: a 0.5 Hz tilt of a few degrees on the accel and gyro.
    moving = (t > 60) & (t < 60 + 0.2 * t[-1])
    wobble = 0.5 * np.sin(2 * np.pi * 0.5 * t[moving])
    session.accel[moving, 0] += G0 * wobble
    session.gyro[moving, 0] += 2.0 * np.cos(2 * np.pi * 0.5 * t[moving])
    result = analyse_noise(session)
    assert any("moved" in w for w in result.warnings)
    assert 0.6 < result.still_fraction < 0.9
    moving = t > 0.3 * t[-1]
    session.accel[moving, 1] += G0 * 0.5 * np.sin(2 * np.pi * 0.5 * t[moving])
    session.gyro[moving, 1] += 2.0 * np.cos(2 * np.pi * 0.5 * t[moving])
    assert n == len(session.time)
    with pytest.raises(InputError, match="not still"):
        analyse_noise(session)


def test_too_short_recording_refused():
    session, _, _ = still_session(minutes=0.1)
    with pytest.raises(InputError, match="too short"):
        analyse_noise(session)


def test_a_stuck_axis_is_named_not_called_too_short():
    """Audit: an axis reading one value through a minute was refused as 'only 0 averaging
    times: the recording is too short'."""
    session, _, _ = still_session(minutes=1.0)
    session.gyro[:, 1] = 0.0125
    with pytest.raises(InputError, match="gyro axis y reads one value .* stuck or dead axis"):
        analyse_noise(session)


def test_cli_table_and_plot(tmp_path, monkeypatch, capsys):
    pytest.importorskip("matplotlib")
    session, _, _ = still_session(minutes=2)
    write_session(tmp_path / "s.h5", session)
    png = tmp_path / "allan.png"
    code, out, err = _cli(["noise", str(tmp_path / "s.h5"), "--plot", str(png)],
                          monkeypatch, capsys)  # fmt: skip
    assert code == 0, err
    assert "ARW" in out and "deg/sqrt(h)" in out and "VRW" in out and "2.0 min" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


# --------------------------------------------------------------------------------------------
# The still:MINUTES plan


def test_still_plan_loads_with_its_duration():
    plan = load_plan("still:20")
    assert plan.name == "still:20" and len(plan.steps) == 1
    step = plan.steps[0]
    assert step.kind == "static" and step.up is None and step.hold_s == 1200.0
    assert "20 min" in step.label and "noise" in step.label
    assert load_plan("still:0.5").steps[0].hold_s == 30.0
    for bad in ("still:", "still:0", "still:-3", "still:abc"):
        with pytest.raises(InputError, match="MINUTES"):
            load_plan(bad)
    assert load_plan("six").steps[0].hold_s is None


def test_guided_still_plan_holds_its_full_duration():
    plan = load_plan("still:0.1")  # 6 s
    stream = poses([[0, 0, 1]], hold_s=7.0, lead_s=0.0)
    rec = FakeRecorder(stream)
    summary = run_guided(rec, plan, console=_console(), keys=ScriptedKeys([]), hold_s=2.0)
    assert summary.complete
    (seg,) = rec.segments
    assert seg["kind"] == "static" and seg["label"] == plan.steps[0].label
    assert seg["stop"] - seg["start"] == int(round(6.0 * 100))  # not the 2 s --hold
    # A recording shorter than the plan's hold does not complete it.
    short = FakeRecorder(poses([[0, 0, 1]], hold_s=4.0, lead_s=0.0))
    summary = run_guided(short, plan, console=_console(), keys=ScriptedKeys([]), hold_s=2.0)
    assert not summary.complete and not short.segments


def test_unattended_still_plan_waits_for_its_duration():
    plan = load_plan("still:0.1")  # 6 s
    rng = np.random.default_rng(0)

    def buffer(seconds):
        n = int(seconds * RATE)
        b = _Buffer()
        accel = np.array([0.0, 0.0, 1000.0]) + rng.standard_normal((n, 3))
        b.add(SampleBlock(np.arange(n) / RATE, accel, rng.standard_normal((n, 3))))
        return b

    assert not _PlanWatcher(plan, 1.0).update(buffer(4.0))
    assert _PlanWatcher(plan, 1.0).update(buffer(7.5))
    # Plans without their own hold still finish on a short still period.
    assert _PlanWatcher(Plan("one pose", (Step("static", "pose 1"),)), 1.0).update(buffer(4.0))
