"""Vectorised steps of the gyro calibration against straightforward per-segment references."""

from types import SimpleNamespace

import numpy as np
import pytest

from imucal_cli.formats.calibration import SensorCalibration
from imucal_cli.formats.session import Segment
from imucal_cli.numerics.segmented import segment_moments, stacked_rows
from imucal_cli.pipeline.gyro import still_periods


def _reference_moments(x, start, stop):
    mean = np.array([x[a:b].mean(axis=0) for a, b in zip(start, stop, strict=True)])
    ss = np.array([((x[a:b] - x[a:b].mean(axis=0)) ** 2).sum(axis=0)
                   for a, b in zip(start, stop, strict=True)])  # fmt: skip
    return mean, ss


def _reference_still_periods(session, accel_cal, g, statics):
    """The per-period loop that :func:`still_periods` replaced."""
    a_means, z_means, counts, raw_means, a_var, z_var = [], [], [], [], 0.0, 0.0
    for s in statics:
        z = session.gyro[s.start : s.stop]
        a = accel_cal.apply(session.accel[s.start : s.stop])
        a_means.append(a.mean(axis=0))
        raw_means.append(session.accel[s.start : s.stop].mean(axis=0))
        z_means.append(z.mean(axis=0))
        counts.append(len(z))
        if len(z) > 1:
            a_var += np.mean(np.var(a, axis=0)) * len(a)
            z_var += np.mean(np.var(z, axis=0)) * len(z)
    dof = max(sum(n - 1 for n in counts), 1)
    a_sigma, z_sigma = np.sqrt(a_var / dof), np.sqrt(z_var / dof)
    g_sigma = [max(a_sigma / (g * np.sqrt(n)), 1e-6) for n in counts]
    z_sig = [z_sigma / np.sqrt(n) for n in counts]
    return (np.array(a_means), np.array(g_sigma), np.array(z_means), np.array(z_sig),
            np.array(raw_means), z_sigma)  # fmt: skip


CASES = {
    "unequal": ([0, 7, 30, 31], [5, 30, 31, 60]),  # includes a one-row segment
    "single": ([3], [50]),
    "whole": ([0], [60]),
    "unordered, overlapping": ([40, 0, 10], [60, 25, 45]),
    "one row each": ([0, 1, 2], [1, 2, 3]),
}


@pytest.mark.parametrize("case", CASES)
def test_segment_moments_match_per_segment_numpy(case):
    rng = np.random.default_rng(7)
    x = rng.normal(1e3, 5.0, (60, 4))  # a large mean: the two-pass variance keeps its digits
    start, stop = CASES[case]
    rows, counts = stacked_rows(start, stop)
    np.testing.assert_array_equal(counts, np.subtract(stop, start))
    ref_rows = [np.arange(a, b) for a, b in zip(start, stop, strict=True)]
    np.testing.assert_array_equal(rows, np.concatenate(ref_rows))
    mean, ss = segment_moments(x[rows], counts)
    ref_mean, ref_ss = _reference_moments(x, start, stop)
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-14)
    np.testing.assert_allclose(ss, ref_ss, rtol=1e-10, atol=1e-20)
    only_mean, none = segment_moments(x[rows], counts, deviations=False)
    assert none is None
    np.testing.assert_array_equal(only_mean, mean)
    # The deviations of an affine map of the rows.
    A = rng.normal(0, 1, (3, 4))
    mapped_mean, mapped_ss = segment_moments(x[rows], counts, matrix=A)
    np.testing.assert_array_equal(mapped_mean, mean)
    _, ref_mapped = _reference_moments(x @ A.T + 5.0, start, stop)
    np.testing.assert_allclose(mapped_ss, ref_mapped, rtol=1e-9, atol=1e-12 * ref_mapped.max())


def test_segment_moments_of_constant_segments_are_exact():
    x = np.repeat(np.array([[1.5, -2.0], [3.25, 0.0]]), [4, 9], axis=0)
    mean, ss = segment_moments(x, np.array([4, 9]))
    np.testing.assert_array_equal(mean, [[1.5, -2.0], [3.25, 0.0]])
    np.testing.assert_array_equal(ss, 0.0)


def test_no_segments_and_empty_segments():
    rows, counts = stacked_rows([], [])
    assert rows.shape == (0,) and counts.shape == (0,)
    mean, ss = segment_moments(np.zeros((0, 3)), counts)
    assert mean.shape == ss.shape == (0, 3)
    with pytest.raises(ValueError):
        stacked_rows([0, 5], [5, 5])


@pytest.mark.parametrize("chunk", [1 << 16, 30, 1])  # one chunk; several; a segment each
@pytest.mark.parametrize("case", ["unequal", "single", "unordered, overlapping"])
def test_still_periods_match_the_per_period_loop(monkeypatch, case, chunk):
    import imucal_cli.numerics.segmented

    monkeypatch.setattr(imucal_cli.numerics.segmented, "CHUNK_ROWS", chunk)
    rng = np.random.default_rng(3)
    n = 60
    session = SimpleNamespace(gyro=rng.normal(30.0, 4.0, (n, 3)),
                              accel=rng.normal([100.0, -50.0, 2000.0], 3.0, (n, 3)),
                              gravity=9.81)  # fmt: skip
    matrix = np.diag([4.9e-3, 5.0e-3, 4.8e-3]) + rng.normal(0, 1e-5, (3, 3))
    acc = SensorCalibration("x", "m/s^2", rng.normal(0, 10, 3), matrix)
    start, stop = CASES[case]
    statics = [Segment(f"s{i}", "static", a, b)
               for i, (a, b) in enumerate(zip(start, stop, strict=True))]  # fmt: skip
    stills, z_sigma = still_periods(session, acc, SimpleNamespace(gravity=None), statics)
    a_means, g_sigma, z_means, z_sig, raw_means, ref_sigma = _reference_still_periods(
        session, acc, 9.81, statics)
    np.testing.assert_allclose([s.g for s in stills], a_means, rtol=1e-13)
    np.testing.assert_allclose([s.g_sigma for s in stills], g_sigma, rtol=1e-12)
    np.testing.assert_allclose([s.z_mean for s in stills], z_means, rtol=1e-13)
    np.testing.assert_allclose([s.z_sigma for s in stills], z_sig, rtol=1e-12)
    np.testing.assert_allclose([s.a_raw for s in stills], raw_means, rtol=1e-13)
    np.testing.assert_allclose(z_sigma, ref_sigma, rtol=1e-12)
    assert [s.segment for s in stills] == statics

    bare, bare_sigma = still_periods(session, None, SimpleNamespace(gravity=None), statics)
    assert np.isnan([s.g for s in bare]).all() and np.isnan([s.a_raw for s in bare]).all()
    assert np.isnan([s.g_sigma for s in bare]).all()
    np.testing.assert_allclose([s.z_mean for s in bare], z_means, rtol=1e-13)
    assert bare_sigma == z_sigma


def _reference_turns(t, z, b0, clock):
    """The per-turn loop that :class:`imucal_cli.solvers.gyro_start._Turns` replaced: the
    block integrals of the coarse integrator and each turn's raw integral."""
    from imucal_cli.solvers.gyro_start import COARSE_RATE_HZ

    steps, coarse_t, x = [], [], np.zeros((len(t), 3))
    dt = np.median(np.concatenate([np.diff(tk) for tk in t]))
    m = max(1, int(round(1 / (COARSE_RATE_HZ * max(clock * dt, 1e-12)))))
    for k, (tk, zk) in enumerate(zip(t, z, strict=True)):
        h = clock * np.diff(tk)[:, None]
        d = np.asarray(zk, float) - b0
        cum = np.vstack([np.zeros(3), np.cumsum(h * (d[:-1] + d[1:]) / 2, axis=0)])
        keep = np.unique(np.r_[np.arange(0, len(tk), m), len(tk) - 1])
        steps.append(np.diff(cum[keep], axis=0, prepend=np.zeros((1, 3))))
        coarse_t.append(tk[keep])
        x[k] = cum[-1]
    return np.concatenate(steps).T, coarse_t, x


TURN_LENGTHS = {
    "unequal": [37, 2, 4, 5, 120, 9],  # shorter and longer than a block, and 2 samples
    "single": [61],
    "last row on a block start": [5, 9, 13],  # kept once, as every m-th row and as the last
}


@pytest.mark.parametrize("case", TURN_LENGTHS)
@pytest.mark.parametrize("clock", [1.0, 1.0021])
def test_coarse_turns_match_the_per_turn_loop(case, clock):
    from imucal_cli.solvers.gyro_start import _Turns

    rng = np.random.default_rng(11)
    t, z, t0 = [], [], 0.0
    for n in TURN_LENGTHS[case]:
        t.append(t0 + np.cumsum(rng.uniform(0.0099, 0.0101, n)))  # 100 Hz with jitter
        z.append(rng.normal(0, 300.0, (n, 3)))
        t0 = t[-1][-1] + 5.0
    g = rng.normal(0, 1, (len(t), 3))
    b0 = np.array([1.5, -2.0, 0.25])
    turns = _Turns(t, z, g, -g, b0, clock)
    steps, coarse_t, x = _reference_turns(t, z, b0, clock)
    assert len(turns.coarse_t) == len(coarse_t)
    for a, b in zip(turns.coarse_t, coarse_t, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(turns.steps, steps, rtol=1e-12, atol=1e-12 * np.abs(steps).max())
    np.testing.assert_allclose(turns.x, x, rtol=1e-12, atol=1e-12 * np.abs(x).max())


def _reference_turns_between(time, stills, turns, gap):
    """The per-turn loop of :func:`turns_between`: a still period reached through continuous
    samples (their span at most 5 periods longer than their count makes it, no other turn),
    or within ``gap`` s."""
    start = np.array([s.segment.start for s in stills], dtype=np.int64)
    stop = np.array([s.segment.stop for s in stills], dtype=np.int64)
    t_start, t_end = time[start], time[stop - 1]
    period = np.median((time[50:] - time[:-50]) / 50)

    def reach(a: int, b: int, r) -> bool:  # samples a .. b continuous, no other turn in them
        lost = (time[b] - time[a]) - (b - a) * period > 5 * period
        return not lost and not any(o is not r and o.start < b and o.stop > a
                                    for o in turns)  # fmt: skip

    usable, skipped = [], []
    for r in turns:
        t0, t1 = time[r.start], time[r.stop - 1]
        before = np.flatnonzero((stop <= r.start + 1) & (
            (t0 - t_end <= gap) | [s <= r.start and reach(s - 1, r.start, r) for s in stop]))
        after = np.flatnonzero((start >= r.stop - 1) & (
            (t_start - t1 <= gap) | [s >= r.stop and reach(r.stop - 1, s, r) for s in start]))
        if len(before) and len(after):
            usable.append((r.name, int(before[-1]), int(after[0])))
        else:
            skipped.append(r.name)
    return usable, skipped


@pytest.mark.parametrize("pairs", [1 << 18, 7, 1])  # one chunk, several, one turn at a time
@pytest.mark.parametrize("order", ["sorted", "shuffled"])
def test_turns_between_match_the_per_turn_loop(monkeypatch, pairs, order):
    import imucal_cli.pipeline.gyro as pg

    monkeypatch.setattr(pg, "PAIRS", pairs)
    rng = np.random.default_rng(5)
    time = np.cumsum(rng.uniform(0.009, 0.011, 3000))
    time[1500:] += 20.0  # a long pause: the turns around it lack a near still period
    bounds = np.sort(rng.choice(np.arange(1, 3000), 40, replace=False))
    parts = list(zip(np.r_[0, bounds], np.r_[bounds, 3000], strict=True))
    # still periods shorter than the stillness around them (a guided capture's holds): bridges
    trim = rng.integers(0, 3, (len(parts[::2]), 2)) * rng.integers(0, 40, (len(parts[::2]), 2))
    statics = [Segment(f"s{i}", "static", int(a + min(t0, (b - a) // 3)),
                       int(b - min(t1, (b - a) // 3)))
               for i, ((a, b), (t0, t1)) in enumerate(zip(parts[::2], trim, strict=True))]
    turns = [Segment(f"r{i}", "rotation", int(a), int(b)) for i, (a, b) in enumerate(parts[1::2])]
    turns.append(Segment("first", "rotation", 0, 10))  # nothing before it
    if order == "shuffled":
        statics = [statics[i] for i in rng.permutation(len(statics))]
    stills = [SimpleNamespace(segment=s) for s in statics]
    session = SimpleNamespace(time=time)
    for gap in (0.0, 0.05, 3.0):
        usable, skipped = pg.turns_between(session, stills, turns, gap)
        ref_usable, ref_skipped = _reference_turns_between(time, stills, turns, gap)
        assert [(u.segment.name, u.before, u.after) for u in usable] == ref_usable
        assert skipped == ref_skipped
    assert pg.turns_between(session, [], turns, 3.0) == ([], [t.name for t in turns])
    assert pg.turns_between(session, stills, [], 3.0) == ([], [])


@pytest.mark.parametrize("limit", [None, (-900.0, 900.0), (-2000.0, 2000.0), (-1.0, 1.0)])
def test_clipped_turns_match_the_per_turn_check(limit):
    from imucal_cli.pipeline.gyro import Turn, _clipped

    rng = np.random.default_rng(9)
    gyro = rng.normal(0, 300.0, (500, 3))
    bounds = [(0, 7), (7, 8), (20, 90), (90, 300), (450, 500)]
    turns = [Turn(Segment(f"r{i}", "rotation", a, b), 0, 0) for i, (a, b) in enumerate(bounds)]
    got = _clipped(SimpleNamespace(gyro=gyro), turns, limit)
    ref = [limit is not None and bool(np.any((gyro[a:b] <= limit[0]) | (gyro[a:b] >= limit[1])))
           for a, b in bounds]  # fmt: skip
    assert got.tolist() == ref
    assert _clipped(SimpleNamespace(gyro=gyro), [], limit).tolist() == []


@pytest.mark.parametrize("n", [1, 2, 17, 4000])
def test_normalised_quaternion_pairs_match_the_einsum_norm(n):
    from imucal_cli.solvers.gyro_integration import _normalised

    rng = np.random.default_rng(n)
    q = rng.normal(size=(2, n)) + 1j * rng.normal(size=(2, n))
    re = q.view(float).reshape(2, -1, 2)
    ref = q / np.sqrt(np.einsum("cnk,cnk->n", re, re))
    out = _normalised(q.copy())
    np.testing.assert_allclose(out.view(float), ref.view(float), rtol=4e-16, atol=4e-16)
    np.testing.assert_allclose(np.abs(out[0]) ** 2 + np.abs(out[1]) ** 2, 1.0, rtol=1e-15)


@pytest.mark.parametrize("size", [0.0, 1e-12, 1e-4, 0.02, 0.2, 0.3, 2.0, 10.0])
def test_rotvec_quaternions_match_sin_and_cos(size):
    """The series of the half-angle factors equals numpy's sin and cos to rounding, below and
    above :data:`SERIES_MAX`, at zero and at the boundary."""
    from imucal_cli.solvers.gyro_integration import SERIES_MAX, _rotvec_pairs

    rng = np.random.default_rng(int(size * 1000))
    phi = rng.normal(0, size, (3, 3000))
    phi[:, 0] = 0.0
    phi[:, 1] = [SERIES_MAX, 0.0, 0.0]
    phi[:, 2] = [0.0, np.nextafter(SERIES_MAX, 1.0), 0.0]
    theta = np.linalg.norm(phi, axis=0)
    half = theta / 2
    s = np.divide(np.sin(half), theta, out=np.full_like(theta, 0.5), where=theta > 0)
    ref = np.array([np.cos(half), phi[0] * s, phi[1] * s, phi[2] * s])
    got = _rotvec_pairs(phi)
    np.testing.assert_allclose(got.view(float).reshape(2, -1, 2).transpose(0, 2, 1).reshape(4, -1),
                               ref, rtol=0, atol=3e-16)  # fmt: skip


@pytest.mark.parametrize("chunk", [1 << 16, 25, 1])
@pytest.mark.parametrize("case", CASES)
def test_moments_in_chunks_equal_the_whole(monkeypatch, case, chunk):
    import imucal_cli.numerics.segmented as pg

    rng = np.random.default_rng(2)
    x = rng.normal(0, 1, (60, 3))
    start, stop = (np.array(v) for v in CASES[case])
    rows, counts = stacked_rows(start, stop)
    whole = segment_moments(x[rows], counts, matrix=np.eye(2, 3))
    monkeypatch.setattr(pg, "CHUNK_ROWS", chunk)
    parts = pg.moments_in_chunks(x, start, stop, matrix=np.eye(2, 3))
    np.testing.assert_allclose(parts[0], whole[0], rtol=1e-15)
    np.testing.assert_allclose(parts[1], whole[1], rtol=1e-13)
    empty = pg.moments_in_chunks(x, np.zeros(0, int), np.zeros(0, int), matrix=np.eye(2, 3))
    assert empty[0].shape == (0, 3) and empty[1].shape == (0, 2)
