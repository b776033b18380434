"""Issue 27.2: the next pose that helps most (solvers/next_pose.py), in words a person follows
(capture/guided/words.py), read back by the simulated person (simulate/live.py); and how long
a hold lasts."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imucal_cli.capture.guided.words import instruction, pose_name, turn_instruction
from imucal_cli.planning import information as di
from imucal_cli.planning.next_pose import (
    ANGLES_DEG,
    MIN_SHRINK_PER_S,
    candidates,
    hold_length,
    plan_hold,
    propose,
    ratios,
)
from imucal_cli.plans import load_plan
from imucal_cli.simulate.live import LiveUnit, Person, parse_instruction
from imucal_cli.simulate.sensor import draw_part

G = 9.80665
RATE = 100.0
FACES = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], float)


def part(seed: int = 4):
    imu, _, _ = draw_part(seed, "counts", 0.01, 0.005)
    a, g = imu.accel.truth({}), imu.gyro.truth({})
    return (di.Fit(a.matrix, a.bias, g.matrix, g.bias, G),
            di.Noise(0.01 * np.linalg.norm(imu.accel.S, axis=1).mean(),
                     0.005 * np.linalg.norm(imu.gyro.S, axis=1).mean(), RATE))  # fmt: skip


def test_candidates_are_turns_about_the_units_axes_gravity_sees():
    up = np.array([0.0, 0.0, 1.0])
    cands = candidates(up)
    # +Z is vertical: only turns about X and Y, each way, 45/90/135 and one 180
    assert len(cands) == 2 * (2 * (len(ANGLES_DEG) - 1) + 1)
    for c in cands:
        assert abs(c.axis @ up) < 0.5
        R = Rotation.from_rotvec(np.radians(c.angle_deg) * c.axis).as_matrix()
        assert R.T @ up == pytest.approx(c.up_after)  # the body's up after turning
    tilted = candidates(np.array([0.0, 1.0, 1.0]) / np.sqrt(2))  # an edge: every axis 45 deg
    assert len(tilted) == 3 * (2 * (len(ANGLES_DEG) - 1) + 1)


def test_every_proposal_reads_back_as_the_same_turn():
    """The words are the contract between the guide and the person: every candidate from a
    face, an edge and a tilt, said and read back, is the same axis and angle, and the person
    doing it brings the unit's up where the guide predicts (to the placement error)."""
    for up in (FACES[0], FACES[3], np.array([1.0, 0, 1]) / np.sqrt(2), np.array([1.0, 0.4, 0.2])):
        for c in candidates(up / np.linalg.norm(up)):
            line = f"step 7: {turn_instruction(c.axis, c.angle_deg, c.up_after)}"
            ins = parse_instruction(line)
            assert ins is not None and ins.kind == "turn", line
            assert ins.axis == pytest.approx(c.axis) and ins.angle_deg == c.angle_deg


def test_a_person_following_a_proposal_ends_where_it_says():
    unit = LiveUnit(1, jitter_deg=0.0)
    person = Person(unit, np.random.default_rng(0), jitter_deg=0.0)
    unit.samples(50)
    c = candidates(unit.up)[3]
    person.read("recorded face +Z up (pose 1)")
    person.read("next: " + turn_instruction(c.axis, c.angle_deg, c.up_after))
    unit.samples(500)
    assert unit.up == pytest.approx(c.up_after, abs=1e-9)
    assert "face" in pose_name(c.up_after) or "edge" in pose_name(c.up_after)


@pytest.mark.parametrize("plan", ["six", "qureshi18"])
def test_a_person_follows_a_plans_words(plan):
    """A plan's static steps ("Put face -X up ...") bring the unit's up onto the label."""
    unit = LiveUnit(2, jitter_deg=0.0)
    person = Person(unit, np.random.default_rng(0), jitter_deg=0.0)
    for k, step in enumerate(load_plan(plan).steps[1:5], start=2):
        person.read("recorded something")
        person.read(f"step {k - 1}: {instruction(step)} for 2 s")  # the live view, stale
        person.read(f"step {k}: {instruction(step)} for 2 s")
        unit.samples(400)
        assert unit.up == pytest.approx(step.up / np.linalg.norm(step.up), abs=1e-9)


def test_pose_names():
    assert pose_name(np.array([0, 0, -1.0])) == "face -Z up"
    assert pose_name(np.array([1.0, 0, -1.0])) == "edge +X-Z up"
    name = pose_name(Rotation.from_rotvec([0.3, 0, 0]).apply([0, 0, 1.0]))
    assert name == "tilted 17 deg from face +Z up towards -Y"


def chain(fit, noise, ups, axes, angles, n=100):
    poses = [di.Pose(np.asarray(u, float) / np.linalg.norm(u), n) for u in ups]
    turns = [di.Turn(k, k + 1, np.asarray(a, float), ang, 1.5)
             for k, (a, ang) in enumerate(zip(axes, angles, strict=True))]  # fmt: skip
    return poses, turns


def test_the_worst_gyro_gain_gets_a_turn_about_its_axis():
    """Turns about Y and Z so far, and two short ones about X: the gain of x is the gyro's
    worst term, and the proposal that shrinks it most is a turn about X."""
    fit, noise = part()
    edges = [FACES[i] + FACES[j] for i in range(6) for j in range(i + 1, 6)
             if abs(FACES[i] @ FACES[j]) < 0.5]  # fmt: skip
    ups = [*FACES, *edges]  # qureshi18's poses: the accelerometer well determined
    axes = [np.eye(3)[1 + k % 2] for k in range(17)]
    angles = [np.radians(90 if k % 3 else 135) for k in range(17)]
    for k in (0, 4):  # from +Z and from +Y up: two different views of the x axis
        axes[k], angles[k] = np.eye(3)[0], np.radians(45)
    poses, turns = chain(fit, noise, ups, axes, angles)
    limits = {("gyro", "gain"): 1e-4}
    now = di.design_std(fit, poses, turns, noise)
    assert np.argmax(now.gyro.gain) == 0  # x is the worst
    best = propose(fit, poses, turns, noise, limits, hold_n=50)
    assert abs(best[0].candidate.axis[0]) == 1.0
    assert best[0].score[0] < ratios(now, limits)[("gyro", "gain")]


def test_until_determined_the_ranking_is_by_the_information_gained():
    """One pose: nothing is determined by any single step; the proposal still turns the unit
    away from the vertical (the most it can learn), and its score says it is undetermined."""
    fit, noise = part()
    poses = [di.Pose(np.array([0, 0, 1.0]), 100)]
    out = propose(fit, poses, [], noise, {("accel", "misalignment"): 0.05}, hold_n=50)
    assert out[0].score[0] == np.inf and out[0].score[1] < out[-1].score[1]


def test_hold_length_stops_where_more_samples_no_longer_pay():
    """The hold ends at the first length where 0.25 s more shrinks the worst target, per
    second, less than the next step would (or than MIN_SHRINK_PER_S); or where it is met."""
    from imucal_cli.planning.next_pose import HOLD_STEP_S, _Base, score

    fit, noise = part()
    edges = [FACES[i] + FACES[j] for i in range(6) for j in range(i + 1, 6)
             if abs(FACES[i] @ FACES[j]) < 0.5]  # fmt: skip
    ups = [*FACES, *(edges[k] for k in (0, 2, 8, 11))]  # xz, yz and xy edges
    poses = [di.Pose(u / np.linalg.norm(u), 100) for u in ups]
    limits = {("accel", "misalignment"): 1e-4}
    base = _Base(fit, poses, [], noise)
    dn = int(HOLD_STEP_S * RATE)

    def shrink(n):  # per second, from n samples to n + dn
        worst = [score(ratios(base.with_last_held(m), limits))[0] for m in (n, n + dn)]
        return np.log(worst[0] / worst[1]) / HOLD_STEP_S

    for gain in (0.0, 0.3, 1.0):
        per_s = max(gain / 4.0, MIN_SHRINK_PER_S)
        n = hold_length(fit, poses, [], noise, limits, min_n=25, max_n=3000, step_gain=gain,
                        step_s=4.0)  # fmt: skip
        assert shrink(n) <= per_s
        assert n == 25 or shrink(n - dn) > per_s
    # a target the hold's samples reach: it holds until it is met, no longer
    lim = {("accel", "bias"): 0.9e-3 * G}  # 0.9 mg, in m/s^2
    n = hold_length(fit, poses, [], noise, lim, min_n=25, max_n=3000, step_gain=0.0,
                    step_s=4.0)  # fmt: skip
    assert score(ratios(base.with_last_held(n), lim))[0] <= 1.0
    assert n == 25 or score(ratios(base.with_last_held(n - dn), lim))[0] > 1.0


def test_the_gyro_bias_asks_for_longer_holds():
    """With only the gyro's bias to reach, holding is what shrinks it (the next step costs a
    move and gives one more short still): the planned hold is longer than the shortest."""
    fit, noise = part()
    poses = [di.Pose(u, 50, 2.0) for u in [*FACES, *FACES]]  # labelled: the accel known
    # each turn about an axis square to the pose's up (gravity sees it), every axis seen
    # from two sides: 11 turns
    axes = [np.roll(np.abs(p.up), 1 + k // 6) for k, p in enumerate(poses[:-1])]
    turns = [di.Turn(k, k + 1, axes[k], np.radians(90), 1.5) for k in range(11)]
    limits = {("gyro", "bias"): np.radians(0.005)}
    n = plan_hold(fit, poses, turns, noise, limits, min_n=50, max_n=3000, move_s=1.5,
                  step_s=4.0)  # fmt: skip
    assert n > 100
    # and the accelerometer's misalignment (the labels' 2 degrees): not a hold's to shrink
    n = plan_hold(fit, poses, turns, noise, {("accel", "misalignment"): 0.05}, min_n=50,
                  max_n=3000, move_s=1.5, step_s=4.0)  # fmt: skip
    assert n == 50
