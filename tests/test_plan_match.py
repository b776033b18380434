"""Which step each still period and motion of an unattended capture is (capture/plan_match.py):
the matches the order alone fixes (issue 24.1, bench live: hwangbo-iron captured unattended
left the re-mounted unit's poses and sweeps unlabelled, without their ``mounting``, and
calibrate chose the known-angle gyro solver where the file's session gets the factorization)."""

from __future__ import annotations

import numpy as np

from imucal_cli.capture.plan_match import Matches, order_fixed
from imucal_cli.plans import Plan, Step

UP = np.array([0.0, 0.0, 1.0])
#: checked pose, two free poses with a turn between, checked pose
PLAN = Plan("t", (Step("static", "a", up=UP), Step("rotation", "turn 1"),
                  Step("static", "free 1"), Step("rotation", "turn 2"),
                  Step("static", "free 2"), Step("static", "b", up=-UP)))  # fmt: skip


def test_a_stretch_with_as_many_still_periods_as_steps_is_fixed():
    # still periods: a, free 1, free 2, b; motions between them: turn 1, turn 2, the move
    m = Matches(still=[0, 2, 4, 5], motion=[1, 3, None], directions_used=True, ordered=True,
                checked={(0, 0), (0, 3)})  # fmt: skip
    assert order_fixed(PLAN, m) == {(0, 1), (0, 2), (1, 0), (1, 1)}


def test_one_still_period_more_fixes_nothing_there():
    # a pause within turn 1: five still periods where the plan has four static steps; the
    # alignment counted one of them as a free pose, which one the data cannot say
    m = Matches(still=[0, None, 2, 4, 5], motion=[None, 1, 3, None], directions_used=True,
                ordered=True, checked={(0, 0), (0, 4)})  # fmt: skip
    assert order_fixed(PLAN, m) == set()
    m = Matches(still=[0, 2, 4, 4, 5], motion=[1, 3, None, None], directions_used=True,
                ordered=True, checked={(0, 0), (0, 4)})  # fmt: skip
    assert order_fixed(PLAN, m) == set()


def test_nothing_is_fixed_without_a_checked_still_period():
    # directions not usable (an unsigned ADC): every still period only counted
    m = Matches(still=[0, 2, 4, 5], motion=[1, 3, None], directions_used=False, ordered=True,
                checked=set())  # fmt: skip
    assert order_fixed(PLAN, m) == set()


def test_a_pose_plan_matched_in_any_order_is_never_fixed_by_order():
    m = Matches(still=[0, 2], motion=[None], directions_used=True)
    assert order_fixed(PLAN, m) == set()


def test_hwangbo_iron_captured_unattended_calibrates_with_the_factorization():
    """The plan's 2 mountings: the second's poses (no ``up``: the unit is re-mounted askew)
    and sweeps (their axis unknown in the sensor frame) are labelled by the order between
    the checked poses of mounting 1 and the ruler's, with their ``mounting``; calibrate then
    chooses the factorization gyro solver, as for the session simulated to a file."""
    from bench.captured import as_captured
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import Config
    from imucal_cli.simulate.play import simulate_plan

    session, _ = simulate_plan("hwangbo-iron", seed=2)
    captured = as_captured(session, "hwangbo-iron")
    mountings = [s.extra.get("mounting") for s in captured.segments if s.label]
    assert mountings.count(2) == len([s for s in session.segments if
                                      s.extra.get("mounting") == 2])  # fmt: skip
    file_cal, captured_cal = calibrate_session(session, Config()), calibrate_session(captured,
                                                                                     Config())
    assert file_cal.gyro.solver == "factorization"
    assert captured_cal.gyro.solver == file_cal.gyro.solver
