"""Issue 27.3, its first half: which parameters, or combinations, a log's design determines
(solvers/determined.py, the null space of the Fisher information)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.planning import information as di
from imucal_cli.planning.determined import (
    ACCEL_NAMES,
    accel_determination,
    gyro_determination,
)
from imucal_cli.simulate.sensor import draw_part

Z = np.array([0.0, 0.0, 1.0])


def part():
    imu, _, _ = draw_part(3, "counts", 0.01, 0.005)
    a, g = imu.accel.truth({}), imu.gyro.truth({})
    return (di.Fit(a.matrix, a.bias, g.matrix, g.bias, 9.80665),
            di.Noise(0.01 * 835.0, 0.005 * 940.0, 100.0))  # fmt: skip


def main_terms(combo: dict) -> set:
    return {k for k, v in combo.items() if abs(v) > 0.1}


def test_a_vehicle_on_flat_ground():
    """Four still periods, always +Z up, turns about the vertical: the gyro's bias; of the
    accelerometer one combination, of its z bias and gain; of the gyro's matrix only how a
    turn about z leaks into x and y (the tilt it would show)."""
    fit, noise = part()
    poses = [di.Pose(Z, 300) for _ in range(4)]
    turns = [di.Turn(k, k + 1, Z, np.radians(90), 3.0) for k in range(3)]
    accel = accel_determination(fit, poses, noise)
    assert not accel.determined and len(accel.combinations) == 1
    assert main_terms(accel.combinations[0]) == {"b_z", "s_z"}
    gyro = gyro_determination(fit, poses, turns, noise)
    assert gyro.determined == ("b_x", "b_y", "b_z")
    assert set().union(*map(main_terms, gyro.combinations)) == {"m_xz", "m_yz"}
    assert 0 < gyro.std["b_x"] < 1.0  # raw counts: the still periods' mean to a fraction


def test_poses_all_about_one_axis_leave_the_other_out():
    """A robot pitching about y: gravity stays in the x-z plane; nothing of y is
    determined."""
    fit, noise = part()
    ups = [Rotation.from_rotvec([0, t, 0]).apply(Z) for t in np.radians([0, 30, -30, 60, -60])]
    accel = accel_determination(fit, [di.Pose(u, 300) for u in ups], noise)
    found = set().union(*map(main_terms, accel.combinations))
    assert found <= {"b_x", "b_z", "s_x", "s_z", "a_xz"} and not accel.determined


def test_enough_poses_determine_all_but_the_frame():
    fit, noise = part()
    ups = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0],
                    [1, 0, 1], [0, 1, 1], [1, 1, 0], [-1, 0, 1]], float)  # fmt: skip
    accel = accel_determination(fit, [di.Pose(u / np.linalg.norm(u), 300) for u in ups], noise)
    assert accel.determined == ACCEL_NAMES[:9] and accel.undetermined == ("r_x", "r_y", "r_z")
    with_labels = accel_determination(
        fit, [di.Pose(u / np.linalg.norm(u), 300, 2.0) for u in ups], noise)
    assert with_labels.complete and with_labels.std["r_x"] < 2.0  # degrees
