"""Segmentation: still periods and rotations found in simulated streams, against their truth."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.simulate.triad import simulate_stream
from imucal_cli.solvers.segmentation import (
    Interval,
    estimate_noise,
    find_rotations,
    find_static,
    still_threshold,
)


def truth_static(stream) -> list[Interval]:
    """True holds; the first includes the still lead-in before it."""
    holds = [s for s in stream.segments if s.kind == "static"]
    out = [Interval(s.start, s.stop) for s in holds]
    out[0] = Interval(0, out[0].stop)
    return out


def assert_matches(found: list[Interval], truth: list[Interval], window: int) -> None:
    assert len(found) == len(truth), (found, truth)
    for f, t in zip(found, truth, strict=True):
        assert abs(f.start - t.start) <= window, (f, t)
        assert abs(f.stop - t.stop) <= window, (f, t)
        # never more than a tenth of a window into the motion (its first samples are gentler
        # than the noise at high noise levels)
        assert f.start >= t.start - window // 10 and f.stop <= t.stop + window // 10, (f, t)


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"accel_noise": 0.001, "gyro_noise": 0.0005},
        {"accel_noise": 0.05, "gyro_noise": 0.02},
        {"rate_hz": 400.0},
        {"rate_hz": 50.0},
        {"units": "m/s^2"},
        {"plan": "random:12", "seed": 4, "hold_s": 1.5},
    ],
)
def test_every_hold_found_within_a_window(options):
    stream = simulate_stream(**{"seed": 1, **options})
    window = int(round(0.5 * stream.options["rate_hz"]))
    found = find_static(stream.time, stream.accel, stream.gyro)
    assert_matches(found, truth_static(stream), window)
    # accel alone finds the same holds
    assert_matches(find_static(stream.time, stream.accel), truth_static(stream), window)


def test_rotations_are_the_moves_between_holds():
    stream = simulate_stream(seed=2)
    found = find_static(stream.time, stream.accel, stream.gyro)
    rotations = find_rotations(stream.time, stream.gyro, found)
    moves = [s for s in stream.segments if s.kind == "rotation"]
    assert len(rotations) == len(moves)
    for r, m, a, b in zip(rotations, moves, found[:-1], found[1:], strict=True):
        assert (r.start, r.stop) == (a.stop, b.start)
        assert r.start <= m.start and r.stop >= m.stop


def test_no_rotation_where_the_gyro_did_not_move():
    rng = np.random.default_rng(0)
    n = 1000
    time = np.arange(n) / 100.0
    gyro = rng.normal(0.0, 0.01, (n, 3))
    assert find_rotations(time, gyro, [Interval(0, 400), Interval(600, 1000)]) == []


def test_quantised_noise_below_one_count():
    stream = simulate_stream(seed=3, accel_noise=0.0002, gyro_noise=0.0002)  # 0.17 counts
    noise = estimate_noise(stream.time, stream.accel, stream.gyro)
    assert np.all(noise.accel_step == 1.0)
    assert np.all(noise.accel >= 1 / np.sqrt(12) - 1e-12)
    found = find_static(stream.time, stream.accel, stream.gyro)
    assert_matches(found, truth_static(stream), 50)


def test_noise_estimate_is_the_sensor_noise():
    stream = simulate_stream(seed=5, units="m/s^2", accel_noise=0.02, gyro_noise=0.004)
    noise = estimate_noise(stream.time, stream.accel, stream.gyro)
    S_a = np.linalg.norm(stream.truth.accel_S, axis=1)
    # Each noise std is within 15 % of the truth (about 1000 still samples).
    np.testing.assert_allclose(noise.accel, 0.02 * S_a, rtol=0.15)
    np.testing.assert_allclose(
        noise.gyro, 0.004 * np.linalg.norm(stream.truth.gyro_S, axis=1), rtol=0.15
    )


def test_one_long_still_period():
    rng = np.random.default_rng(1)
    n = 6000
    time = np.arange(n) / 100.0
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.01, (n, 3))
    gyro = rng.normal(0, 0.005, (n, 3))
    assert find_static(time, accel, gyro) == [Interval(0, n)]
    counts = np.rint(np.array([10.0, -20.0, 8192.0]) + rng.normal(0, 0.3, (n, 3)))
    assert find_static(time, counts) == [Interval(0, n)]


def test_no_still_period():
    # The unit tumbles continuously: gravity sweeps the sphere, the gyro never rests.
    n = 6000
    time = np.arange(n) / 100.0
    rng = np.random.default_rng(2)
    phase = 2 * np.pi * 0.2 * time
    up = np.stack([np.sin(phase) * np.cos(0.3 * phase), np.cos(phase), np.sin(0.3 * phase)], 1)
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    accel = 9.81 * up + rng.normal(0, 0.01, (n, 3))
    gyro = np.stack([np.full(n, 1.3), np.sin(phase), np.cos(phase)], 1) + rng.normal(
        0, 0.005, (n, 3)
    )
    assert find_static(time, accel, gyro) == []
    assert find_static(time, accel) == []


def test_hour_long_recording_segments_every_hold():
    # (Its speed is measured by `make bench`, not asserted here.)
    n = 360_000
    rng = np.random.default_rng(3)
    time = np.arange(n) / 100.0
    accel = rng.normal(0, 5.0, (n, 3)) + 8000.0
    gyro = rng.normal(0, 5.0, (n, 3))
    for k in range(0, n, 500):  # a 1.5 s move every 5 s
        accel[k + 350 : k + 500] += 2000.0 * np.sin(np.linspace(0, np.pi, 150))[:, None]
    found = find_static(time, accel, gyro)
    assert len(found) == n // 500


def test_threshold_is_a_chi_square_quantile():
    from scipy import stats

    k = still_threshold(50, 3, 1e-3)
    assert k == pytest.approx(stats.chi2.ppf(0.999, 147) / 147)
    # pure white noise: about alpha of the windows exceed k
    rng = np.random.default_rng(4)
    from imucal_cli.solvers.segmentation import window_variance

    var = window_variance(rng.normal(0, 1, (200_000, 3)), 50)
    rate = np.mean(var.mean(axis=1) > still_threshold(50, 3, 0.01))
    assert 0.007 < rate < 0.013
