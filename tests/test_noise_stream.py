"""`imucal noise` in constant memory (issue 14): the Allan deviation summed block by block is
allantools' overlapping Allan deviation (exactly while every term fits, within its scatter
beyond), the still test given block by block finds find_static's still periods, and a
session read from its file block by block gives the figures of the session in memory."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.design.segmentation import estimate_noise, find_static
from imucal_cli.design.static_stream import StaticStream
from imucal_cli.errors import InputError
from imucal_cli.formats.session import open_samples, read_session, write_session
from imucal_cli.numerics.allan import MAX_TERMS, AllanAccumulator, allan_deviation, log_taus
from imucal_cli.simulate.triad import simulate
from imucal_cli.use.noise import analyse_noise

from .test_noise import G0, RATE, still_session

allantools = pytest.importorskip("allantools")


def _signal(n, seed=0):
    """White noise, a random walk of the rate and an offset (a bias instability stand-in)."""
    rng = np.random.default_rng(seed)
    return 0.3 + 0.01 * rng.standard_normal(n) + np.cumsum(1e-5 * rng.standard_normal(n))


@pytest.mark.parametrize("n", [100, 1000, 12345, 120_000])
def test_allan_deviation_is_allantools_oadev(n):
    y = _signal(n)
    tau, adev, err, terms = allantools.oadev(y, rate=RATE, data_type="freq",
                                             taus=log_taus(RATE, n))  # fmt: skip
    keep = np.isfinite(adev) & (adev > 0)
    curve = allan_deviation(y, RATE)
    assert np.array_equal(curve.tau_s, tau[keep])
    assert np.array_equal(curve.n, terms[keep])
    np.testing.assert_allclose(curve.adev, adev[keep], rtol=1e-12)
    np.testing.assert_allclose(curve.adev_err, err[keep], rtol=1e-12)


@pytest.mark.parametrize("block", [1, 37, 4096, 65_536])
def test_blocks_of_any_size_give_the_same_sums(block):
    n = 20_000 if block == 1 else 150_000
    y = np.column_stack([_signal(n, 1), _signal(n, 2)])
    whole = AllanAccumulator(n, RATE, 2, centre=y[:1000].mean(axis=0))
    whole.add(y)
    parts = AllanAccumulator(n, RATE, 2, centre=y[:1000].mean(axis=0))
    for a in range(0, n, block):
        parts.add(y[a : a + block])
    for c1, c2 in zip(whole.curves(), parts.curves(), strict=True):
        assert np.array_equal(c1.tau_s, c2.tau_s) and np.array_equal(c1.n, c2.n)
        np.testing.assert_allclose(c2.adev, c1.adev, rtol=1e-11)


def test_beyond_every_term_within_the_scatter():
    """A recording longer than MAX_TERMS: strided sums, within a few of allantools' stated
    errors of allantools' own curve, and fewer terms stated honestly."""
    n = 2 * MAX_TERMS + 50_000
    y = _signal(n, 3)
    tau, adev, err, terms = allantools.oadev(y, rate=RATE, data_type="freq",
                                             taus=log_taus(RATE, n))  # fmt: skip
    curve = allan_deviation(y, RATE)
    assert np.array_equal(curve.tau_s, tau)
    assert (curve.n <= terms).all() and (curve.n < terms).any() and curve.n.max() <= MAX_TERMS
    assert np.all(np.abs(curve.adev - adev) <= 4 * curve.adev_err)
    assert np.max(np.abs(curve.adev / adev - 1)) < 0.02


def test_accumulator_refusals():
    with pytest.raises(InputError, match="too few"):
        AllanAccumulator(50, RATE)
    acc = AllanAccumulator(200, RATE)
    with pytest.raises(InputError, match="NaN"):
        acc.add(np.r_[np.zeros(10), np.nan])
    acc = AllanAccumulator(200, RATE)
    acc.add(np.zeros(150))
    with pytest.raises(InputError, match="150 of the 200"):
        acc.curves()


def test_static_stream_refusals():
    session, _ = simulate("qureshi18", seed=3, created="2026-01-01T00:00:00Z")
    t, a, g = session.time, session.accel, session.gyro
    stream = StaticStream(1000, estimate_noise(t, a, g))
    stream.add(a[:600], g[:600])
    with pytest.raises(InputError, match="more than the 1000 samples announced"):
        stream.add(a[600:1001], g[600:1001])  # refused at once, not only at the end
    with pytest.raises(InputError, match="differ in length"):
        stream.add(a[600:700], g[600:699])
    stream.add(a[600:900], g[600:900])
    with pytest.raises(InputError, match="900 of the 1000"):
        stream.intervals()


def _static_stream(time, accel, gyro, block):
    noise = estimate_noise(time, accel, gyro)
    stream = StaticStream(len(time), noise, accel=accel is not None, gyro=gyro is not None)
    for a in range(0, len(time), block):
        stream.add(*[x[a : a + block] for x in (accel, gyro) if x is not None])
    return stream.intervals()


@pytest.mark.parametrize("block", [10, 49, 50, 51, 1000, 10**6])
def test_static_stream_finds_find_static_periods(block):
    session, _ = simulate("qureshi18", seed=3, created="2026-01-01T00:00:00Z")
    t, a, g = session.time, session.accel.copy(), session.gyro
    a[1000:1003, 1] = np.nan  # a dropout: the windows holding it are not still
    expected = find_static(t, a, g, mean_rate=False)  # the stream tests the variance alone
    assert len(expected) > 15
    assert _static_stream(t, a, g, block) == expected
    assert _static_stream(t, a, None, block) == find_static(t, a, None)


def test_static_stream_on_a_rocked_recording():
    session, _, _ = still_session(minutes=3)
    t = session.time
    moving = (t > 60) & (t < 60 + 0.2 * t[-1])
    session.accel[moving, 0] += G0 * 0.5 * np.sin(2 * np.pi * 0.5 * t[moving])
    session.gyro[moving, 0] += 2.0 * np.cos(2 * np.pi * 0.5 * t[moving])
    expected = find_static(t, session.accel, session.gyro, mean_rate=False)
    assert len(expected) == 2
    assert _static_stream(t, session.accel, session.gyro, 4096) == expected


def test_noise_from_the_file_block_by_block_as_in_memory(tmp_path, monkeypatch):
    """Longer than the noise sample and than one block: the file read in small blocks gives
    the figures of the session in memory."""
    import imucal_cli.use.noise as noise_step

    monkeypatch.setattr(noise_step, "NOISE_SAMPLES", 4096)
    session, _, _ = still_session(minutes=4, seed=4)
    write_session(tmp_path / "s.h5", session)
    in_memory = analyse_noise(read_session(tmp_path / "s.h5")).to_dict()
    with open_samples(tmp_path / "s.h5") as samples:
        blocks = samples.blocks
        monkeypatch.setattr(samples, "blocks", lambda *a, **k: blocks(*a, rows=5000))
        streamed = analyse_noise(samples).to_dict()
    assert streamed["still_fraction"] == in_memory["still_fraction"] > 0.9
    for kind in ("accel", "gyro"):
        for a, b in zip(in_memory["sensors"][kind]["axes"], streamed["sensors"][kind]["axes"],
                        strict=True):  # fmt: skip
            np.testing.assert_allclose(b["curve"]["adev"], a["curve"]["adev"], rtol=1e-9)
            assert b["curve"]["tau_s"] == a["curve"]["tau_s"]


def test_stream_checks_time_outside_the_span(tmp_path):
    """The samples outside the analysed segment are checked as read_session checks them."""
    import h5py

    from imucal_cli.errors import SessionError
    from imucal_cli.formats.session import Segment

    session, _, _ = still_session(minutes=1, segments=[Segment("0000", "static", 0, 5000)])
    write_session(tmp_path / "s.h5", session)
    with h5py.File(tmp_path / "s.h5", "r+") as f:
        f["raw/time"][5500] = f["raw/time"][5499]  # not increasing, after the segment
    with open_samples(tmp_path / "s.h5") as samples:
        with pytest.raises(SessionError, match="not strictly increasing"):
            analyse_noise(samples)
