"""Segmentation: still periods and rotations found in simulated streams, against their truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from imucal_cli.design.segmentation import (
    Interval,
    estimate_noise,
    find_rotations,
    find_static,
    still_threshold,
    window_variance,
)
from imucal_cli.design.steady_turns import RATE_TOLERANCE, mean_rate_statistic, window_means
from imucal_cli.simulate.triad import simulate_stream


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
    from imucal_cli.design.segmentation import window_variance

    var = window_variance(rng.normal(0, 1, (200_000, 3)), 50)
    rate = np.mean(var.mean(axis=1) > still_threshold(50, 3, 0.01))
    assert 0.007 < rate < 0.013


def _steady_turn_log(rate_dps: float, seed: int = 7):
    """A vehicle's log in SI units at 100 Hz, with the simulator's noise (0.01 m/s^2, 0.005
    rad/s per sample): three still periods of 10 s, between them a turn about the vertical at a
    steady ``rate_dps`` for 10 s (either way), reached and left by 0.5 s ramps (1 - cos) / 2.
    Gravity stays on z and the gyro's variance within a window is its noise (the ramps add
    (rate / noise)^2 / 12 at most, under the tolerance): the variance test alone calls it still.
    Returns time, accel, gyro, the true bias (rad/s) and a mask of the still samples."""
    rng = np.random.default_rng(seed)
    still, steady, ramp = 1000, 1000, 50
    up = (1 - np.cos(np.pi * np.arange(1, ramp + 1) / (ramp + 1))) / 2
    turn = np.r_[up, np.ones(steady), up[::-1]]
    parts, mask = [np.zeros(still)], [np.ones(still, bool)]
    for sign in (1.0, -1.0):
        parts += [sign * np.radians(rate_dps) * turn, np.zeros(still)]
        mask += [np.zeros(len(turn), bool), np.ones(still, bool)]
    rate_z, is_still = np.concatenate(parts), np.concatenate(mask)
    n = len(rate_z)
    bias = np.array([0.02, -0.01, 0.03])  # rad/s, about 1 deg/s
    gyro = bias + np.c_[np.zeros((n, 2)), rate_z] + rng.normal(0, 0.005, (n, 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.01, (n, 3))
    return np.arange(n) / 100.0, accel, gyro, bias, is_still


@pytest.mark.parametrize("rate_dps", [2.0, 5.0])
def test_a_slow_steady_turn_about_the_vertical_is_not_still(rate_dps):
    """Issue 27: a slow steady yaw (2-5 deg/s for 10 s) between still periods is a turn, not a
    still period whose mean the calibration would read as the gyro's bias."""
    time, accel, gyro, bias, is_still = _steady_turn_log(rate_dps)
    window = 50
    # the premise: the window variance alone takes the whole log for one still period
    assert find_static(time, accel, gyro, mean_rate=False) == [Interval(0, len(time))]
    found = find_static(time, accel, gyro)
    truth = [Interval(a, b) for a, b in _runs_of(is_still)]
    assert len(found) == len(truth) == 3, found
    for f, t in zip(found, truth, strict=True):
        # each still period kept but for its trims (a window and its margin at a turn's end),
        # never into the steady part of the turn (past the 0.5 s ramp)
        assert f.start <= t.start + 2 * window and f.stop >= t.stop - 2 * window, (f, t)
        assert f.start >= t.start - window and f.stop <= t.stop + window, (f, t)
    # the bias from the still samples found: within 4 std of the mean of N samples of noise
    # (the turn's rate, 2-5 deg/s = 0.035-0.087 rad/s, would be 50-130 std)
    samples = np.concatenate([gyro[f.start : f.stop] for f in found])
    std = 0.005 / np.sqrt(len(samples))
    np.testing.assert_array_less(np.abs(samples.mean(axis=0) - bias), 4 * std)


def _runs_of(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return [(int(a), int(b)) for a, b in edges.reshape(-1, 2)]


def test_steady_turn_statistic_against_the_noise():
    """The mean-rate statistic of :mod:`imucal_cli.design.steady_turns` on still white noise
    exceeds its chi-square bound with about the probability it states, and a 2 deg/s turn on
    the same noise exceeds the bound (with its tolerance) many times over."""
    rng = np.random.default_rng(8)
    n, sigma = 50, np.full(3, 0.005)
    x = rng.normal(0, 0.005, (100_000, 3))
    still = np.ones(len(x) - n + 1, bool)
    D = mean_rate_statistic(window_means(x, n), window_variance(x, n), sigma, still, n, 100)
    rate = np.mean(D > stats.chi2.isf(0.01, 3))
    # overlapping windows: about 2000 independent ones, so 1 % +- 3 binomial std of 2000
    assert 0.01 - 3 * np.sqrt(0.01 * 0.99 / 2000) < rate < 0.01 + 3 * np.sqrt(0.01 * 0.99 / 2000)
    # the same noise turning at 2 deg/s about z for its last 30 %, which the variance test
    # alone calls still too: every one of those windows is past the splitting bound
    turning = x.copy()
    turning[70_000:, 2] += np.radians(2.0)
    D2 = mean_rate_statistic(window_means(turning, n), window_variance(turning, n), sigma,
                             still, n, 100)  # fmt: skip
    bound = RATE_TOLERANCE * stats.chi2.isf(1e-4, 3)
    assert np.min(D2[70_000:]) > bound
    assert np.mean(D2[: 70_000 - n] > bound) < 0.01


def test_a_gyro_quantised_below_its_noise_keeps_every_still_period():
    """A gyro whose noise is under one count reads a constant at rest, and its bias may change
    by a count between poses: a window's mean is then off by up to half a count however long
    (second reader, 2026-11-29: 5 still periods became 2). Every one stays whole."""
    rng = np.random.default_rng(3)
    rate, n_still, n_move = 100.0, 300, 150
    parts = []
    for k in range(5):
        level = np.array([3.0, -2.0, 1.0]) + (k % 2)  # counts; a count's shift between poses
        still = np.round(level + rng.normal(0, 0.2, (n_still, 3)))
        move = np.round(level + 400 * np.sin(np.linspace(0, np.pi, n_move))[:, None]
                        * np.array([0.3, 1.0, 0.2]) + rng.normal(0, 0.2, (n_move, 3)))
        parts += [still, move]
    gyro = np.concatenate(parts[:-1])
    accel = np.tile([0.0, 0.0, 4096.0], (len(gyro), 1)) + np.round(rng.normal(0, 2, (len(gyro), 3)))
    t = np.arange(len(gyro)) / rate
    found = find_static(t, accel, gyro, min_still_s=1.0)
    assert len(found) == 5
    assert all(iv.stop - iv.start > 0.8 * n_still for iv in found)


@pytest.mark.parametrize("sensor", ["accel", "gyro"])
def test_one_damaged_huge_value_costs_its_own_hold_only(sensor):
    """A value no sensor reads (1e308: a flipped exponent bit in a log without checksums)
    in one hold: that hold is lost, every other one is found as without it, and no numpy
    overflow warning leaks (its square once overflowed and made every later window NaN)."""
    import warnings

    stream = simulate_stream(seed=1, units="m/s^2")
    window = int(round(0.5 * stream.options["rate_hz"]))
    truth = truth_static(stream)
    hit = truth[3]
    damaged = getattr(stream, sensor).copy()
    damaged[(hit.start + hit.stop) // 2, 0] = 1e308
    data = {"accel": stream.accel, "gyro": stream.gyro, sensor: damaged}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        found = find_static(stream.time, data["accel"], data["gyro"])
    assert_matches([f for f in found if f.stop <= hit.start or f.start >= hit.stop],
                   [t for t in truth if t is not hit], window)  # fmt: skip
