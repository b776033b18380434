"""``bench mad``'s comparison of the held-out transitions (issue 24.5): MaD Lab's figures
recorded per transition, and the paired difference shown beside the verdict."""

from __future__ import annotations

import numpy as np
import pytest

from bench.mad import MAD_LOO_DEG, paired


def test_the_recorded_reference_is_mad_labs_figure():
    assert len(MAD_LOO_DEG) == 12
    assert abs(np.sqrt(np.mean(np.square(MAD_LOO_DEG))) - 0.6716) < 1e-4


def test_the_paired_difference_is_the_difference_of_mean_squares():
    theirs = np.asarray(MAD_LOO_DEG)
    ours = theirs + 0.2
    diff, se = paired(ours, theirs)
    assert diff == pytest.approx(np.mean(ours**2) - np.mean(theirs**2))
    d = ours**2 - theirs**2
    assert se == pytest.approx(np.std(d, ddof=1) / np.sqrt(12)) and diff > 3 * se


def test_transitions_that_do_not_pair_are_refused():
    with pytest.raises(ValueError, match="11 transitions against 12"):
        paired(np.ones(11), np.asarray(MAD_LOO_DEG))


def test_a_common_rotation_of_the_accelerometer_frame_is_told_from_disagreement():
    """``accel_frames``: two calibrations whose directions differ by one rotation (the frame
    the labels choose) differ by that rotation and by nothing within it; a direction moved on
    its own shows within the frame."""
    from scipy.spatial.transform import Rotation

    from bench.mad import accel_frames

    up = np.vstack([np.eye(3), -np.eye(3), np.eye(3)[[0, 0, 1, 2]]])
    rng = np.random.default_rng(3)
    up = up + 0.003 * rng.standard_normal(up.shape)  # placements off the labels
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    turn = Rotation.from_rotvec(np.radians(0.07) * np.array([0.3, 0.2, -0.93]) / 1.0)
    theirs = turn.apply(up)
    worst, frame, within = accel_frames(up, theirs)
    assert frame == pytest.approx(np.degrees(turn.magnitude()), rel=1e-6)
    assert within < 1e-9 and 0 < worst <= frame + 1e-9
    moved = theirs.copy()
    moved[4] = Rotation.from_rotvec(np.radians([0.05, 0.0, 0.0])).apply(moved[4])
    worst, frame, within = accel_frames(up, moved)
    assert 0.03 < within < 0.06  # one of 10 directions off by 0.05 deg: the fit shares a little
    assert abs(frame - np.degrees(turn.magnitude())) < 0.01


def test_the_labelled_table_says_how_many_transitions_each_predicts_better():
    from rich.console import Console

    from bench.mad import _loo_table
    from imucal_cli.model.gyro import KnownTurnCheck

    theirs = np.asarray(MAD_LOO_DEG)
    ours = theirs + np.where(np.arange(12) < 5, 0.01, -0.01)  # worse on 5, better on 7
    console = Console(record=True, width=250)
    r = {"ours": ours, "mad": theirs, "known": [False] * 7 + [True, False, True, False, True],
         "turns": [], "check": KnownTurnCheck(), "swapped": np.column_stack([ours, theirs]),
         "frame": (0.106, 0.068, 0.049), "frame_std": 0.118}  # fmt: skip
    ok = _loo_table(console, r)
    text = console.export_text()
    assert "7 of 12" in text and "5 of 12" in text
    assert "0.068 (our frame's std 0.12 per axis, 0.2 in 3-D)" in text
    rms = np.sqrt(np.mean(ours**2)), np.sqrt(np.mean(theirs**2))
    assert f"{rms[0]:.4f}; {rms[1]:.4f}" in text
    assert ok == (rms[0] <= rms[1])


def test_without_mad_labs_package_the_table_says_how_to_install_it():
    """The caption names the extra as typed (rich markup would swallow ``[bench]``)."""
    from rich.console import Console

    from bench.mad import _loo_table
    from imucal_cli.model.gyro import KnownTurnCheck

    console = Console(record=True, width=400)
    r = {"ours": np.asarray(MAD_LOO_DEG), "mad": None, "known": [False] * 12, "turns": [],
         "check": KnownTurnCheck()}  # fmt: skip
    _loo_table(console, r)
    assert "pip install -e '.[bench]'" in console.export_text()
