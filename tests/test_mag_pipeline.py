"""The magnetometer end to end: the simulated part and its truth, the [mag] step beside the
accelerometer (alignment, field given or not, solver choices), refusals with their advice,
the report, and the command line."""

from __future__ import annotations

import copy
import dataclasses
import json
import re

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session, suspect_error
from imucal_cli.errors import DesignError
from imucal_cli.formats.calibration import calibration_from_json, calibration_to_json
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.formats.session import write_session
from imucal_cli.model.calibration import LOCAL_FIELD
from imucal_cli.model.mag import MagCalibration, Readings
from imucal_cli.simulate.magnetometer import earth_field, simulate_mag
from imucal_cli.simulate.triad import simulate
from imucal_cli.use.report.build import build_report
from tests.cli_helpers import assert_one_line_error, run

FAST = {"hold_s": 1.0, "tumble_s": 3.0}


@pytest.fixture(scope="module")
def sim():
    session, truth = simulate_mag("qureshi18", 3, **FAST)
    return session, truth, calibrate_session(session, Config())


def _accel_frame(cal, truth) -> np.ndarray:
    """``Q``: the fixture frame (truth) into the accelerometer's calibrated frame."""
    A = truth.accel.matrix  # raw -> fixture frame
    Q = cal.accel.matrix @ np.linalg.inv(A)
    U, _, Vt = np.linalg.svd(Q)
    return U @ Vt


# ---------------------------------------------------------------------------- the simulator


def test_simulated_magnetometer_reads_the_field_through_its_truth():
    session, truth = simulate_mag("random:10", 1, **FAST)
    assert session.mag.shape == (len(session.time), 3) and session.mag_units == "counts"
    assert session.magnetic_field_uT == 48.0 and np.all(session.mag == np.rint(session.mag))
    h = truth.mag.apply(session.mag)
    assert abs(np.linalg.norm(h, axis=1).mean() - 48.0) < 0.05
    assert truth.mag.units == "uT" and truth.mag.layout == "ak8963"
    again, _ = simulate_mag("random:10", 1, **FAST)
    assert np.array_equal(again.mag, session.mag) and np.array_equal(again.accel, session.accel)
    # the same part whatever the units; gauss has no quantisation
    g_session, g_truth = simulate_mag("random:10", 1, mag_units="gauss", **FAST)
    assert np.allclose(g_truth.mag.bias * 100.0, truth.mag.bias / (1 / 0.15), rtol=1e-12)
    assert g_session.mag_units == "gauss" and not np.all(g_session.mag == np.rint(g_session.mag))


def test_without_tumbles_the_accelerometer_is_the_triad_simulators():
    session, _ = simulate_mag("six", 4, tumble_s=0.0)
    plain, _ = simulate("six", 4)
    assert np.array_equal(session.accel, plain.accel) and np.array_equal(session.gyro, plain.gyro)


def test_still_poses_read_the_field_of_their_attitude():
    session, truth = simulate_mag("six", 5, tumble_s=0.0, mag_noise=0.0, units="m/s^2",
                                  mag_units="uT")  # fmt: skip
    seg = session.static_segments()[0]  # face +Z up: gravity along +z of the fixture
    h = truth.mag.apply(session.mag[seg.start : seg.stop]).mean(axis=0)
    up = truth.accel.apply(session.accel[seg.start : seg.stop]).mean(axis=0)
    cos = h @ up / np.linalg.norm(h) / np.linalg.norm(up)
    assert np.degrees(np.arcsin(-cos)) == pytest.approx(60.0, abs=0.01)  # the inclination
    assert np.linalg.norm(earth_field(48.0, 60.0)) == pytest.approx(48.0)


# ---------------------------------------------------------------------------- calibrate


def test_calibration_recovers_the_part_in_the_accelerometer_frame(sim):
    session, truth, cal = sim
    mag = cal.mag
    assert mag is not None and mag.solver == "magnetometer" and mag.units == "uT"
    x = mag
    assert x.aligned and x.field_uT == 48.0 and x.warnings == []
    assert x.axes[0].startswith("x -> +Y") and x.axes[2].startswith("z -> -Z")
    std = {p.name: p.std for p in x.parameters}
    err = mag.bias - truth.mag.bias
    assert np.all(np.abs(err) < 5 * np.array([std["b_x"], std["b_y"], std["b_z"]])), err
    assert abs(x.inclination_deg - 60.0) < max(5 * x.inclination_std_deg, 0.02)
    # the calibrated field of any reading points where the truth says, in the accel frame
    expected = _accel_frame(cal, truth) @ truth.mag.matrix
    raw = session.mag[::50]
    a = (raw - mag.bias) @ mag.matrix.T
    b = (raw - truth.mag.bias) @ expected.T
    ang = np.degrees(np.arccos(np.clip(np.sum(a * b, 1) / np.linalg.norm(a, axis=1)
                                       / np.linalg.norm(b, axis=1), -1, 1)))  # fmt: skip
    assert ang.max() < 0.1, ang.max()
    assert x.quality.verdict == "pass" and x.coverage.fraction > 0.9
    assert 0.3 < x.rms_after < 0.5 and 0.3 < x.rms_held_out < 0.55  # noise 0.4 uT


def test_calibration_json_round_trip_keeps_the_mag_section(sim):
    _, _, cal = sim
    back = calibration_from_json(calibration_to_json(cal))
    assert np.allclose(back.mag.matrix, cal.mag.matrix) and back.mag.units == "uT"
    assert list(back.sections()) == ["accel", "gyro", "mag"]  # gyro auto uses the tumbles


def test_unknown_field_gives_output_in_units_of_the_local_field():
    session, truth = simulate_mag("random:12", 6, field_known=False, mag_units="uT", **FAST)
    cal = calibrate_session(session, Config())
    assert cal.mag.units == LOCAL_FIELD and cal.mag.field_uT is None
    h = cal.mag.apply(session.mag[::20])
    assert abs(np.linalg.norm(h, axis=1).mean() - 1.0) < 0.002
    # raw uT taken at face value: the estimate is the field within the part's gain errors
    assert abs(cal.mag.field_estimate_uT / 48.0 - 1) < 0.1
    cfg = config_from_dict({"mag": {"field_uT": 50.0}})
    assert calibrate_session(session, cfg).mag.units == "uT"


def test_solver_choices_and_sessions_without_an_accelerometer():
    session, _ = simulate_mag("random:12", 7, **FAST)
    off = calibrate_session(session, config_from_dict({"mag": {"solver": "none"}}))
    assert off.mag is None and off.accel is not None
    plain = calibrate_session(
        session, config_from_dict({"mag": {"solver": "ellipsoid"}, "accel": {"solver": "none"}})
    )
    assert plain.mag.solver == "mag-ellipsoid" and plain.accel is None
    assert np.allclose(plain.mag.matrix, plain.mag.matrix.T)
    alone = dataclasses.replace(session, accel=None, gyro=None, segments=[])
    cal = calibrate_session(alone, Config())
    assert cal.accel is None and cal.mag is not None and not cal.mag.aligned
    assert any("no accelerometer calibrated" in n for n in cal.mag.notes)


def test_repeated_and_missing_readings_are_left_out():
    session, _ = simulate_mag("random:12", 8, **FAST)
    mag = session.mag.copy()
    held = np.repeat(mag[::4], 4, axis=0)[: len(mag)]  # read 4 times faster than it updates
    held[100:110] = np.nan
    cal = calibrate_session(dataclasses.replace(session, mag=held), Config())
    left = cal.mag.readings.left_out
    assert left.nonfinite == 10 and left.repeated > 0.6 * len(mag)
    assert cal.mag.quality.verdict == "pass"


# ---------------------------------------------------------------------------- refusals


def test_too_little_of_the_sphere_is_refused_with_the_gap_to_fill():
    session, _ = simulate_mag("six", 2, tumble_s=0.0)
    with pytest.raises(DesignError, match=r"from \d+ % of the directions.*pointing its"):
        calibrate_session(session, config_from_dict({"accel": {"solver": "none"}}))


def test_a_field_that_changes_is_flagged_and_not_saved_without_force():
    session, truth = simulate_mag("qureshi18", 9, **FAST)
    mag = session.mag.copy()
    # steel near the path for 8 % of the recording: an extra 6 uT field along the body x axis
    lo, hi = int(0.40 * len(mag)), int(0.48 * len(mag))
    S = np.linalg.inv(truth.mag.matrix)
    mag[lo:hi] += np.rint(S @ np.array([6.0, 0.0, 0.0]))
    cal = calibrate_session(dataclasses.replace(session, mag=mag), Config())
    warnings = cal.mag.warnings
    assert any("the field changes from place to place" in w and " at " in w
               for w in warnings), warnings  # fmt: skip
    assert "field changes" in str(suspect_error(cal))


def test_a_hold_near_steel_shows_in_the_gravity_field_angle():
    session, truth = simulate_mag("qureshi18", 10, **FAST)
    mag = session.mag.copy()
    seg = session.static_segments()[5]
    S = np.linalg.inv(truth.mag.matrix)
    h = truth.mag.apply(mag[seg.start : seg.stop])
    c, s = np.cos(0.1), np.sin(0.1)
    turned = h @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T
    mag[seg.start : seg.stop] = turned @ S.T + truth.mag.bias  # the field's direction 5.7 deg off
    cal = calibrate_session(dataclasses.replace(session, mag=mag), Config())
    assert any("angle between gravity and the field is" in w and seg.label in w
               for w in cal.mag.warnings)  # fmt: skip


def test_saturation_is_refused_with_cause_and_advice():
    session, _ = simulate_mag("random:12", 11, **FAST)
    mag = session.mag.copy()
    top = np.percentile(mag[:, 0], 90)
    mag[:, 0] = np.minimum(mag[:, 0], top)  # a flat top on x: 10 % of the readings
    # the magnetometer is left out, saying why (issue 24.2: the accelerometer is still saved)
    assert re.search("stuck at the end of the range .*channel x.*saturates",
                     _left_out_mag(dataclasses.replace(session, mag=mag), Config()))
    cfg = config_from_dict({"mag": {"range": [-100.0, 100.0]}})
    assert re.search(r"reach the range \[-100, 100\]", _left_out_mag(session, cfg))
    alone = config_from_dict({"accel": {"solver": "none"}, "gyro": {"solver": "none"},
                              "mag": {"range": [-100.0, 100.0]}})  # fmt: skip
    with pytest.raises(DesignError, match=r"reach the range \[-100, 100\]"):
        calibrate_session(session, alone)  # nothing else to save: refused
    few = session.mag.copy()
    few[:, 1] = np.minimum(few[:, 1], np.percentile(few[:, 1], 99))  # 1 %: left out
    cal = calibrate_session(dataclasses.replace(session, mag=few), Config())
    # the flat top's readings taken while the unit turned (a still hold at the top is not a
    # sign of clipping) are left out, and only those
    from imucal_cli.design.clipping import clipped_rows

    flagged = clipped_rows(few.astype(float))
    assert 0 < flagged.sum() and np.all(few[flagged, 1] == few[:, 1].max())
    assert cal.mag.readings.left_out.clipped == flagged.sum()


def test_config_keys_are_checked():
    for table, problem in [({"solver": "magneto"}, "solver"), ({"field_uT": -4}, "field_uT"),
                           ({"min_coverage": 1.5}, "min_coverage"),
                           ({"quality": {"max_gaps_pct": 0}}, "max_gaps_pct"),
                           ({"colour": 1}, "unknown key")]:  # fmt: skip
        with pytest.raises(Exception, match=problem):
            config_from_dict({"mag": table})


# ---------------------------------------------------------------------------- report and CLI


def test_report_shows_field_alignment_quality_and_a_recapture_verdict(sim):
    _, _, cal = sim
    rep = build_report(cal)["sensors"]["mag"]
    assert rep["mag"]["quality"]["verdict"] == "pass" and rep["rms"]["held_out"] is not None
    titles = [t["title"] for t in rep["tables"]]
    assert "field and alignment" in titles and any(t.startswith("quality") for t in titles)
    assert rep["maps"][0]["directions"] and rep["poses"] == []
    strict = copy.deepcopy(cal)
    q = strict.mag.quality
    q.checks[1].ok, q.verdict, q.failed = False, "recapture", ["variance"]
    rep2 = build_report(strict)["sensors"]["mag"]
    assert any("recapture" in w for w in rep2["warnings"])


def test_command_line_simulate_calibrate_report(tmp_path):
    out = tmp_path / "m.h5"
    proc = run("simulate", "--mag", "--plan", "random:12", "--seed", "2", "--hold", "1",
               "--tumble", "3", "-o", out)  # fmt: skip
    assert proc.returncode == 0 and "magnetometer in counts" in proc.stdout, proc.stderr
    proc = run("calibrate", out)
    assert proc.returncode == 0, proc.stderr
    assert "mag: magnetometer" in proc.stdout and "quality: pass" in proc.stdout
    second = tmp_path / "m2.h5"
    second.write_bytes(out.read_bytes())
    proc = run("calibrate", out, second, "--no-store", "--force")
    assert proc.returncode == 0 and "mag quality" in proc.stdout and "pass" in proc.stdout
    proc = run("report", tmp_path / "m.cal.json", "--json")
    assert json.loads(proc.stdout)["sensors"]["mag"]["mag"]["aligned"] is True
    proc = run("report", tmp_path / "m.cal.json")
    assert "quality of the fit" in proc.stdout and "coverage of measured field" in proc.stdout
    assert_one_line_error(run("simulate", "--mag", "--plan", "qureshi-axes", "-o",
                              tmp_path / "x.h5"), "--mag simulates pose plans")  # fmt: skip
    six = tmp_path / "six.h5"
    write_session(six, simulate_mag("six", 2, tumble_s=0.0)[0])
    cfg = tmp_path / "c.toml"
    cfg.write_text('[accel]\nsolver = "none"\n')
    assert_one_line_error(run("calibrate", six, "--config", cfg), "of the directions")


def test_a_ros_import_without_magnetometer_values_before_its_first_message():
    """A ROS import holds each MagneticField message until the next and leaves the rows before
    the first NaN: the step leaves those out and says so."""
    from imucal_cli.formats.importers.ros import hold_latest

    session, _ = simulate_mag("random:12", 11, **FAST)
    t = session.time
    sent = np.flatnonzero(t >= t[0] + 0.2 * (t[-1] - t[0]))[::5]  # 20 Hz, from 20 % on
    mag = hold_latest(t[sent] + 1e-4, session.mag[sent].astype(float), t)
    first = int(np.argmax(np.isfinite(mag).all(axis=1)))
    assert first > 0.15 * len(t)
    cal = calibrate_session(dataclasses.replace(session, mag=mag), Config())
    left = cal.mag.readings.left_out
    assert left.nonfinite == left.before_first == first
    assert any(f"{first} of {len(t)} rows have no magnetometer value" in n
               and "all before its first value" in n for n in cal.mag.notes)
    assert cal.mag.quality.verdict == "pass"
    from rich.text import Text

    from imucal_cli.cli.calibrate import mag_summary

    line = Text.assemble(*mag_summary(cal.mag)[0]).plain
    assert f"({first} rows without a value left out)" in line
    none = dataclasses.replace(session, mag=np.full_like(mag, np.nan))
    assert "no reading with a value" in _left_out_mag(none, Config())


def _left_out_mag(session, cfg) -> str:
    """Why the magnetometer was left out of a calibration that saved the rest."""
    cal = calibrate_session(session, cfg)
    assert cal.mag is None and cal.accel is not None and cal.complete is False
    note = cal.left_out["mag"]
    assert note == cal.mag_note and note.startswith("mag not calibrated: ")
    return note


def test_command_line_mag_without_hold_takes_the_default_hold(tmp_path):
    """``simulate --plan six --mag`` without ``--hold`` holds each pose the default 2 s (it
    crashed with a TypeError: hold None reached the simulator)."""
    from imucal_cli.formats.session import read_session

    out = tmp_path / "six.h5"
    proc = run("simulate", "--plan", "six", "--mag", "--seed", "4", "--tumble", "0", "-o", out)
    assert proc.returncode == 0, proc.stderr
    session = read_session(out)
    expected, _ = simulate_mag("six", 4, tumble_s=0.0, hold_s=2.0, rate_hz=100.0)
    np.testing.assert_array_equal(session.mag, expected.mag)
    np.testing.assert_array_equal(session.accel, expected.accel)
    assert [s.n_samples for s in session.static_segments()] == [200] * 6


def test_calibrate_summary_prints_the_config_section_name_in_brackets(monkeypatch, capsys):
    """``[mag]`` in a summary line is text, not a rich style tag that would vanish: on a
    terminal (styled by rich) as off it."""

    from imucal_cli.cli.calibrate import mag_summary
    from imucal_cli.cli.console import make_console, print_line

    sec = MagCalibration(
        "ellipsoid", LOCAL_FIELD, [1.0, 2.0, 3.0], readings=Readings(motion=500, poses=0),
        rms_after=0.01, field_uT=None, field_estimate_uT=48.0, units_in="counts",
    )  # fmt: skip
    lines = mag_summary(sec)
    monkeypatch.delenv("FORCE_COLOR", raising=False)
    monkeypatch.delenv("NO_COLOR", raising=False)
    monkeypatch.setenv("TERM", "xterm")
    for terminal in ("0", "1"):
        monkeypatch.setenv("TTY_COMPATIBLE", terminal)
        console = make_console()
        assert console.is_terminal == (terminal == "1")
        for line in lines:
            print_line(console, *line)
        out = capsys.readouterr().out
        assert "give [mag] field_uT for uT" in out
        assert ("\x1b[" in out) == (terminal == "1")  # styles on a terminal only
