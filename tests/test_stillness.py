"""Online stillness detector and turn helpers: synthetic noise and simulated streams."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from imucal_cli.design.stillness import (
    StillnessDetector,
    integrate_rate,
    motion_span,
    rate_to_deg_s,
    still_level_threshold,
)
from imucal_cli.simulate.triad import simulate_stream


def _feed(det, time, accel, gyro=None, block=10):
    states = []
    for i in range(0, len(time), block):
        g = None if gyro is None else gyro[i : i + block]
        st = det.update(time[i : i + block], accel[i : i + block], g)
        states.append((i, min(i + block, len(time)), st))
    return states


def test_threshold_is_the_chi_square_quantile():
    n, c, alpha = 25, 6, 1e-4
    dof = c * (n - 1)
    assert still_level_threshold(n, c, alpha) == pytest.approx(
        np.sqrt(stats.chi2.ppf(1 - alpha, dof) / dof)
    )


@pytest.mark.parametrize("minutes", [3, pytest.param(10, marks=pytest.mark.slow)])
def test_pure_noise_learns_sigma_and_rarely_moves(minutes):
    rng = np.random.default_rng(0)
    n = minutes * 6000  # at 100 Hz
    t = np.arange(n) / 100.0
    sigma_a, sigma_g = np.array([5.0, 7.0, 3.0]), np.array([2.0, 2.0, 4.0])
    a = 1000.0 + rng.standard_normal((n, 3)) * sigma_a
    g = rng.standard_normal((n, 3)) * sigma_g
    det = StillnessDetector()
    states = _feed(det, t, a, g)
    sd = det.noise_std()
    assert np.allclose(sd["accel"], sigma_a, rtol=0.03)
    assert np.allclose(sd["gyro"], sigma_g, rtol=0.03)
    evaluations = (n - det.window) / (det.window // 4)
    moved = sum(s.moved for _, _, s in states)
    # about alpha per (overlapping) window: expect << 1 false alarm in 10 minutes
    assert moved <= max(2, 10 * evaluations * det.alpha)
    ready = [s for _, _, s in states if s.noise_ready]
    assert ready[-1].still and ready[-1].still_for_s > 0.8 * minutes * 60
    assert 0.8 < np.median([s.level for s in ready]) < 1.2


def test_the_verdict_does_not_depend_on_the_blocks():
    """Windows are judged on a fixed grid: a host that reads one sample at a time tests no
    more windows (so no more false alarms) than one reading ten (before, every block's last
    sample was judged too: up to a quarter window's samples more tests)."""
    rng = np.random.default_rng(5)
    n = 6000
    t = np.arange(n) / 100.0
    a = 1000.0 + rng.standard_normal((n, 3)) * 5.0
    a[3000:3050] += 200.0  # a bump
    runs = {}
    for block in (1, 3, 10):
        states = _feed(StillnessDetector(), t, a, block=block)
        runs[block] = [r for _, _, st in states for r in st.ended_runs]
    assert runs[1] == runs[3] == runs[10] and len(runs[1]) >= 1

def test_quantised_quiet_data_is_still():
    rng = np.random.default_rng(1)
    n = 20_000
    t = np.arange(n) / 100.0
    a = np.rint(100.0 + rng.standard_normal((n, 3)) * 0.4)
    det = StillnessDetector()
    states = _feed(det, t, a)
    moved = sum(s.moved for _, _, s in states)
    assert moved / len(states) < 0.01
    assert det.noise_std()["accel"].min() >= np.sqrt(1 / 12) - 1e-12


def test_noise_ready_only_after_enough_windows():
    det = StillnessDetector(window_s=0.25, min_noise_windows=8)
    rng = np.random.default_rng(2)
    t = np.arange(100) / 100.0
    st = det.update(t, rng.standard_normal((100, 3)))
    assert not st.noise_ready and not st.still and np.isnan(st.level)
    st = det.update(t + 1.0, rng.standard_normal((100, 3)))
    assert st.noise_ready


@pytest.mark.parametrize(("seed", "units", "block"), [(1, "counts", 10), (2, "m/s^2", 7)])
def test_simulated_holds_and_moves(seed, units, block):
    s = simulate_stream(plan="qureshi18", seed=seed, rate_hz=100, hold_s=3.0, units=units)
    det = StillnessDetector()
    states = _feed(det, s.time, s.accel, s.gyro, block=block)
    n = det.window
    holds = [g for g in s.segments if g.kind == "static"]
    moves = [g for g in s.segments if g.kind == "rotation"]
    ended = [r for _, _, st in states for r in st.ended_runs]
    # one still run ends at every move, a little before it starts, never after
    assert len(ended) == len(moves)
    for (a, b), mv, hold in zip(ended, moves, holds[:-1], strict=True):
        assert mv.start - 2 * n <= b <= mv.start, (b, mv)
        assert a <= max(hold.start, 0) + 2 * n
    # every still run starts inside the next hold, within two windows of its start
    starts = []
    for _, _, st in states:
        if st.still_start is not None and (not starts or st.still_start != starts[-1]):
            starts.append(st.still_start)
    for hold, start in zip(holds[1:], starts[1:], strict=True):
        assert hold.start <= start <= hold.start + 2 * n
    # moving detected within a window of each move's start, no alarm inside holds
    for mv in moves:
        flagged = [i0 for i0, i1, st in states if st.moved and i1 >= mv.start]
        assert flagged and flagged[0] <= mv.start + n
    for i0, i1, st in states:
        if st.moved:
            assert any(m.start - n <= i1 and i0 <= m.stop + n for m in moves), (i0, i1)


def test_motion_span_and_integral_match_the_truth():
    s = simulate_stream(plan="six", seed=4, rate_hz=100, hold_s=2.0)
    sd = s.truth.gyro_noise * np.linalg.norm(s.truth.gyro_S, axis=1)
    moves = [g for g in s.segments if g.kind == "rotation"]
    for k, mv in enumerate(moves):
        lo, hi = mv.start - 150, mv.stop + 150
        rest = s.gyro[lo : mv.start - 20].mean(axis=0)
        span = motion_span(s.gyro[lo:hi], rest, sd)
        assert span is not None
        a, b = lo + span[0], lo + span[1]
        assert mv.start - 3 <= a <= mv.start + 25 and mv.stop - 25 <= b <= mv.stop + 3
        got = integrate_rate(s.time, s.gyro, rest, a, b)
        want = s.truth.gyro_S @ s.rotvec[k]
        assert np.linalg.norm(got - want) < 0.02 * np.linalg.norm(want)
    quiet = np.random.default_rng(0).standard_normal((2000, 3)) * sd
    assert motion_span(quiet, np.zeros(3), sd, alpha=1e-6) is None


def test_rate_units():
    assert rate_to_deg_s("deg/s") == 1.0
    assert rate_to_deg_s("rad/s") == pytest.approx(57.29577951)
    assert rate_to_deg_s("counts") is None
    assert rate_to_deg_s("counts", 16.4 * 180 / np.pi) == pytest.approx(1 / 16.4)


def test_bad_arguments():
    with pytest.raises(ValueError):
        StillnessDetector(window_s=0)
    with pytest.raises(ValueError):
        StillnessDetector(alpha=2)
    det = StillnessDetector()
    with pytest.raises(ValueError):
        det.update(np.arange(3.0), None, None)


def test_known_noise_skips_learning():
    rng = np.random.default_rng(5)
    t = np.arange(50) / 100.0
    det = StillnessDetector(noise_std={"accel": 1.0})
    st = det.update(t, rng.standard_normal((50, 3)))
    assert st.noise_ready and st.still
    st = det.update(t + 0.5, rng.standard_normal((50, 3)) * 20)
    assert st.moved and not st.still
