"""Turns of a known angle are integrated from rest to rest, at low sample rates too.

A known turn's segment runs from its first moving sample to its last; the unit rests up to
the still period's last sample, so the interval from there to the turn's first sample (and
from its last sample to the next still one) belongs to the turn. Integrated from its own first
sample, each turn lost ``h/2 (w_first + w_last)``: at 50 Hz with quick hand turns (0.5-1 s at
up to 400 deg/s) that is 0.05-0.1 % of the turn, and the known-angle solver's gains came out
that much too large, all of one sign (the full model's turns had the same loss, fixed before:
:func:`imucal_cli.calibrate.gyro.full.turn_windows`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from imucal_cli.calibrate.gyro.turn_windows import rest_to_rest
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.formats.config import config_from_dict
from imucal_cli.model.session import Segment
from imucal_cli.simulate.rotations import simulate_gyro_rotations
from tests.gyro_truth import diagonal_errors

CREATED = "2026-01-01T00:00:00Z"


def _labelled_turns(seed: int, rate_hz: float):
    """qureshi-axes:6 with quick turns, each labelled with its true angle, every axis exactly
    its label (no placement or axis error: the labels' frame is the body's)."""
    session, truth = simulate_gyro_rotations("qureshi-axes", seed=seed, rate_hz=rate_hz,
                                             rotations_per_axis=6, peak_rate_dps=400.0,
                                             still_s=1.0, jitter_deg=0.0, axis_jitter_deg=0.0,
                                             created=CREATED)  # fmt: skip
    angle = dict(zip(truth.gyro.turn_segments, truth.gyro.true_angle_deg, strict=True))
    segments = [replace(s, angle_deg=float(angle[s.name])) if s.name in angle else s
                for s in session.segments]  # fmt: skip
    return replace(session, segments=segments), truth


def test_known_turns_at_50_hz_leave_the_gains_unbiased():
    """Eight sessions at 50 Hz, 18 quick known turns each, angles known to 0.05 deg (a
    turntable; no accelerometer: the labels are the frame): the diagonal gains' mean z over
    the 24 (within 3 / sqrt(24) of 0 for unit-variance z; the stated std cover them, their
    scatter is 0.5). Integrated from each turn's first moving sample, they came out +2.4 std
    (40 seeds: +2.41 at 50 Hz, +0.29 at 100, 0.00 at 200); now -0.02, -0.03, -0.04."""
    # the axes are exactly their labels: stated (the default 2 deg placement would shorten
    # each turn's expected integral along its label by cos|eps|, tests/test_known_axis_error)
    cfg = config_from_dict({"accel": {"solver": "none", "labelled": {"placement_deg": 0.05}},
                            "gyro": {"known": {"angle_std_deg": 0.05}}})  # fmt: skip
    z = []
    for seed in range(8):
        session, truth = _labelled_turns(seed, 50.0)
        z.append(diagonal_errors(calibrate_session(session, cfg).gyro, truth)[0])
    z = np.array(z)
    assert abs(z.mean()) < 3 / np.sqrt(z.size), np.round(z.mean(axis=0), 2)
    assert np.all(np.abs(z) < 4.0), np.round(z, 2)


def test_a_known_turn_reaches_the_still_periods_it_touches():
    """The window of a turn between two still periods that touch it takes their edge samples;
    an end that meets no still period (a gap the turn finder owns, another turn, the
    session's end) stays where it is."""
    session, _ = _labelled_turns(0, 50.0)
    n = len(session.time)
    segs = sorted(session.segments, key=lambda s: s.start)
    turn = next(s for s in segs if s.kind == "rotation")
    assert rest_to_rest(session, turn) == slice(turn.start - 1, turn.stop + 1)
    apart = replace(session, segments=[
        replace(s, start=s.start + 3) if s.kind == "static" and s.start == turn.stop else s
        for s in segs])  # fmt: skip
    assert rest_to_rest(apart, turn) == slice(turn.start - 1, turn.stop)
    alone = replace(session, segments=[Segment("0000", "rotation", 0, n)])
    assert rest_to_rest(alone, alone.segments[0]) == slice(0, n)


@pytest.mark.parametrize("solver", ["static", "dynamic"])
def test_per_axis_gains_at_50_hz_are_unbiased(solver):
    """Qureshi & Golnaraghi's per-axis solvers integrate the same turns between still periods
    as the full model, over the same windows (:func:`~imucal_cli.calibrate.gyro.full.
    turn_windows`): eight qureshi-axes:6 sessions at 50 Hz with quick turns, the gains' mean z
    against the truth's diagonal within 3 of its own standard errors (the per-axis model
    ignores the misalignment, so its z scatter by 1.2-1.9, not 1). From each turn's first
    moving sample the gains came out 0.047 % large (20 seeds: pooled z +2.15; 200 Hz +0.03)."""
    from bench.trust_gyro import _truth_x

    cfg = config_from_dict({"gyro": {"solver": solver}})
    z = []
    for seed in range(8):
        session, truth = simulate_gyro_rotations("qureshi-axes", seed=seed, rate_hz=50.0,
                                                 rotations_per_axis=6, peak_rate_dps=400.0,
                                                 still_s=1.0, created=CREATED)  # fmt: skip
        cal = calibrate_session(session, cfg)
        assert cal.gyro is not None and cal.gyro.solver == f"gyro-{solver}"
        p = {q.name: q for q in cal.gyro.parameters}
        m = _truth_x(cal, truth)[3:].reshape(3, 3)
        z += [(p[f"k_{a}"].value - m[i, i]) / p[f"k_{a}"].std for i, a in enumerate("xyz")]
    z = np.array(z)
    assert abs(z.mean()) < 3 * z.std(ddof=1) / np.sqrt(z.size), np.round(z, 2)
