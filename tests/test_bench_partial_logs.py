"""``bench adaptive``'s logs in short (issue 27.4): a vehicle's and a robot's logs (a few still
periods around one axis, free turns, no labels, no segments) on 3 parts, calibrated as
``imucal calibrate`` does and graded against the truth (the bench's own code:
:mod:`bench.partial_logs`; 60 parts in ``python -m bench --only adaptive``).

What 3 parts can show is checked against what the noise allows: every log saves both sensors
in part, the gyro's bias measured by the still periods in every part with the std of the
still samples' mean, the matrix assumed; each measured value within 4 of its std (a miss of
one in 16,000 per interval), their RMS error/std below 2 (chi-square: the RMS of about 60
unit normals above 2 has a chance below 1e-9; the stated std of the accelerometer's carry the
prior's share, so its ratios are smaller); and what the fit measures is what the information
says the log determines.
"""

from __future__ import annotations

import io

import numpy as np
from rich.console import Console

from bench import partial_logs as pl

SEEDS = [2700, 2701, 2702]

#: The simulator's gyro noise, rad/s per sample (``imucal_cli.simulate.sensor``'s default).
GYRO_NOISE = 0.005


def _mine(graded, log, sensor, measured=True):
    return [g for g in graded if g.log == log and g.sensor == sensor and g.measured == measured]


def _check_gyro(graded, log) -> None:
    """The still periods measure the bias, nothing measures the matrix."""
    measured = _mine(graded, log.name, "gyro")
    assert sorted({g.name for g in measured}) == ["b_x", "b_y", "b_z"]
    assert len(measured) == 3 * len(SEEDS)
    assert {g.solver for g in measured} == {"gyro-partial"}
    assert {g.name for g in _mine(graded, log.name, "gyro", False)} == set(pl.GYRO_NAMES[3:])
    # the mean of the still samples: the noise over the root of their number (the still
    # periods less the segmentation's trims: 80-100 % of the plan's holds)
    stills = log.plan.count('kind = "static"') * log.hold_s * 100.0
    expected = np.degrees(GYRO_NOISE) / np.sqrt(stills)
    median = float(np.median([g.std for g in measured]))
    assert 0.9 * expected < median < 1.5 * expected, (log.name, median, expected)
    assert all(g.unit == "deg/s" for g in measured)


def test_logs_calibrate_what_they_determine(tmp_path):
    graded, lost, designs = pl.run_logs(SEEDS, tmp_path)
    assert lost == {log.name: [] for log in pl.LOGS}
    z = []
    for log in pl.LOGS:
        _check_gyro(graded, log)
        accel = _mine(graded, log.name, "accel")
        assumed = _mine(graded, log.name, "accel", False)
        assert accel and assumed  # one axis of tilts: part of the model, never all of it
        assert {g.solver for g in accel + assumed} == {"partial"}
        # every part measures the z bias (gravity near +z): in mg, within the prior's 60 mg
        b_z = [g for g in accel if g.name == "b_z"]
        assert len(b_z) == len(SEEDS) and all(0.5 < g.std < 30.0 for g in b_z), b_z
        for g in accel + _mine(graded, log.name, "gyro"):
            assert np.isfinite(g.error) and g.std > 0 and abs(g.error) < 4 * g.std, g
            z.append(g.error / g.std)
        # what the fit measures, the log's design determines (alone or in a combination)
        fit, poses, turns, noise = designs[log.name]
        d = pl.accel_determination(fit, poses, noise)
        informed = set(d.determined) | {k for c in d.combinations for k in c}
        assert {g.name for g in accel} <= informed, (log.name, d)
        assert {"b_x", "b_y", "b_z"} <= set(pl.gyro_determination(fit, poses, turns,
                                                                  noise).determined)  # fmt: skip
    assert np.sqrt(np.mean(np.square(z))) < 2.0, z


def test_logs_tables(tmp_path):
    graded, lost, designs = pl.run_logs(SEEDS[:2], tmp_path)
    out = io.StringIO()
    console = Console(file=out, width=200)
    checks = pl.logs_table(console, graded, lost, 2)
    pl.null_space_table(console, designs)
    text = out.getvalue()
    for log in pl.LOGS:
        assert text.count(log.name) >= 4  # fitted rows (3 gyro biases at least), null space
        assert f"{log.name}, gyro (gyro-partial): assumed in every part: m_xx" in text
    assert "2/2" in text and "deg/s" in text and " mg " in text
    assert checks["every log calibrated both sensors (0 failures)"]
    said = [k for k in checks if k.startswith("logs, gyro: measured intervals cover")]
    assert said and f"of {3 * len(pl.LOGS) * 2} " in said[0]


def test_a_slow_yaw_is_not_read_as_the_gyro_bias(tmp_path):
    """Issue 27: a vehicle's log yawing slowly (:data:`bench.partial_logs.SLOW_YAW`: three still
    periods of 10 s on flat ground, between them turns about the vertical of 30 and -25 degrees
    over 10 s each, 3 deg/s on average, 5.6 at the peak), without segments, calibrated as
    ``imucal calibrate`` does: the gyro's bias is the still periods' (within 4 std of the mean
    of their samples' noise, and of its own stated std), not the turns' rate (before: the whole
    log was one still period, b_z off by 0.1 deg/s, 17 of those std)."""
    log = pl.LOGS[-1]
    assert log.plan == pl.SLOW_YAW
    for seed in SEEDS[:2]:
        session, truth = pl.simulate_log(tmp_path, log.plan, seed, segments=False,
                                         hold_s=log.hold_s, move_s=log.move_s)  # fmt: skip
        cal = pl.calibrate_log(session, tmp_path, f"slow-yaw-{seed}")
        measured = [g for g in pl.grade("slow yaw", seed, cal, truth)
                    if g.sensor == "gyro" and g.measured]  # fmt: skip
        assert sorted(g.name for g in measured) == ["b_x", "b_y", "b_z"], measured
        # the still samples' mean: noise over the root of their number (the holds less the
        # segmentation's trims at the turns' gentle ends: at least 80 % of 3 x 10 s at 100 Hz)
        std = np.degrees(GYRO_NOISE) / np.sqrt(0.8 * 3 * 10.0 * 100.0)
        for g in measured:
            assert abs(g.error) < 4 * min(std, g.std), (seed, g)  # and within its own std
