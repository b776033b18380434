"""Issue 24.6: a pose labelled 5 degrees or more wrong is named when the design can tell.

The labelled-pose solver estimated the placement error from all poses: one pose far off its
label inflated it (2 to 4 degrees) and every std with it, so that the wrong label was hidden
(named in 2 of 10 six-face sessions, errors up to 20 times the bound). Each pose's placement
is now judged against the spread of the others (:func:`imucal_cli.estimators.accel.labelled_checks.
placement_outliers`)."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session, suspect_error
from imucal_cli.formats.config import config_from_dict
from imucal_cli.simulate import faults
from imucal_cli.simulate.triad import simulate

CREATED = "2026-01-01T00:00:00Z"
CFG = config_from_dict({"accel": {"solver": "labelled"}, "gyro": {"solver": "none"}})


def _named(cal, seg) -> bool:
    x = cal.accel
    return any(o.segment == seg.name for o in x.outliers) or any(
        f"segment {seg.name}" in w for w in x.blocking)


def _false_alarm(cal) -> bool:
    x = cal.accel
    return any(o.action == "label ignored" for o in x.outliers) or any(
        "disagree with each other" in w for w in x.warnings)


def _errors_over_std(cal, truth) -> float:
    from bench.trust import _truth, _values

    v, s = _values(cal.accel)
    return float(np.max(np.abs(v - _truth(truth)) / s))


def test_a_pose_of_qureshi18_off_its_label_loses_the_label():
    """18 poses tell each pose apart: a pose 20 degrees off its label is named, its label
    ignored (its magnitude kept), and the fit then holds the truth within 4 of its std."""
    session, truth = simulate(plan="qureshi18", seed=101, created=CREATED)
    k = 7
    seg = session.static_segments()[k]
    cal = calibrate_session(faults.wrong_label(session, k, 20.0), CFG)
    hit = [o for o in cal.accel.outliers if o.segment == seg.name]
    assert hit and hit[0].action == "label ignored" and "label" in hit[0].cause
    assert _errors_over_std(cal, truth) < 4.0
    assert suspect_error(cal) is None


def test_six_faces_name_the_pair_and_refuse():
    """Six faces cannot tell which of two opposite faces is off (the fit shares their
    disagreement): both are named in a warning that stops the save."""
    session, _ = simulate(plan="six", seed=102, created=CREATED)
    k = 0
    cal = calibrate_session(faults.wrong_label(session, k, 20.0), CFG)
    problem = suspect_error(cal)
    assert problem is not None and "disagree with each other" in str(problem)
    assert f"segment {session.static_segments()[k].name}" in str(problem)


@pytest.mark.parametrize("plan", ["six", "qureshi18"])
def test_clean_sessions_raise_no_alarm(plan):
    for seed in range(3):
        session, _ = simulate(plan=plan, seed=600 + seed, created=CREATED)
        assert not _false_alarm(calibrate_session(session, CFG))


@pytest.mark.slow
@pytest.mark.parametrize("plan,angle,jitter,least", [
    ("qureshi18", 10.0, 2.0, 17), ("qureshi18", 5.0, 0.5, 19), ("six", 20.0, 2.0, 18),
    ("six", 10.0, 0.5, 19),
])  # fmt: skip
def test_detection_rates(plan, angle, jitter, least):
    """Over 20 seeds: a label ``angle`` degrees wrong with placements of ``jitter`` degrees
    RMS is named in at least ``least`` sessions where the design can tell it (a wrong label
    beyond the family-wise threshold of the others' spread), and clean sessions of the same
    plan raise no alarm in 20."""
    named = false = 0
    for seed in range(20):
        session, _ = simulate(plan=plan, seed=700 + seed, created=CREATED, jitter_deg=jitter)
        k = seed % len(session.static_segments())
        seg = session.static_segments()[k]
        named += _named(calibrate_session(faults.wrong_label(session, k, angle), CFG), seg)
        false += _false_alarm(calibrate_session(session, CFG))
    assert named >= least and false == 0, (named, false)


def test_the_holds_of_one_placement_lose_their_labels_together():
    """A pose 20 degrees off its label, held twice in a row (a turn on the table between):
    the two holds are one placement (``labelled_holds``), so both lose their label; it was a
    warning that stopped the save, 'disagree with each other ... cannot tell which'."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from imucal_cli.calibrate.accel.labelled import fit_poses, misplaced_labels
    from imucal_cli.calibrate.common import static_poses

    session, _ = simulate(plan="qureshi18", seed=101, created=CREATED)
    P = static_poses(session)
    k = 7
    idx = np.r_[np.arange(k + 1), k, np.arange(k + 1, len(P.segments))]
    B = P.subset(idx)
    a = B.a_mean.copy()  # the second hold: the same gravity, its own noise
    a[k + 1] = a[k] + np.random.default_rng(0).standard_normal(3) @ np.linalg.cholesky(
        B.cov_mean[k]).T
    segs = list(B.segments)
    segs[k + 1] = replace(segs[k + 1], name=segs[k + 1].name + "b")
    axis = np.cross(B.up[k], [1.0, 0, 0] if abs(B.up[k][0]) < 0.9 else [0, 1.0, 0])
    up = B.up.copy()
    up[k] = up[k + 1] = Rotation.from_rotvec(np.radians(20) * axis / np.linalg.norm(axis)).apply(
        B.up[k])
    B = replace(B, a_mean=a, up=up, segments=segs)
    res = fit_poses(B, 9.80665, CFG)
    assert res.fit.runs is not None and res.fit.runs.index[k] == res.fit.runs.index[k + 1]
    _, used, found, blocking = misplaced_labels(res, B, 9.80665, CFG)
    assert blocking is None
    assert sorted(o.segment for o in found) == sorted([segs[k].name, segs[k + 1].name])
    assert all(o.action == "label ignored" for o in found)
    assert np.isnan(used.up[[k, k + 1]]).all()
    assert np.isfinite(np.delete(used.up, [k, k + 1], axis=0)).all()
