"""imucal_cli/numerics/ against the published test cases of the libraries they stand beside
and against the libraries themselves (the Allan accumulator's comparison with allantools'
oadev, block by block and beyond every term, is in test_noise_stream.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from imucal_cli.errors import InputError
from imucal_cli.numerics.allan import AllanAccumulator, allan_deviation
from imucal_cli.numerics.blocks import check_all_given, check_not_more
from imucal_cli.numerics.segmented import moments_in_chunks, segment_moments, stacked_rows

#: NIST SP 1065 (Riley, Handbook of Frequency Stability Analysis, 2008) section 12.3, p. 108:
#: the overlapping Allan deviation of the 1000-point NBS14 frequency data at averaging
#: factors 1, 10, 100, as allantools' own test suite (tests/nbs14) checks its oadev.
NBS14_1000_OADEV = {1: 2.922319e-01, 10: 9.159953e-02, 100: 3.241343e-02}


def nbs14_1000() -> np.ndarray:
    """The 1000-point test data: the Park-Miller generator ``n_{i+1} = 16807 n_i mod
    (2^31 - 1)`` from ``n_0 = 1234567890``, divided by ``2^31 - 1`` (NIST SP 1065, 12.3)."""
    n = [1234567890]
    for _ in range(999):
        n.append(16807 * n[-1] % 2147483647)
    assert n[1:4] == [395529916, 1209410747, 633705974]  # the first three, as published
    return np.array(n, float) / 2147483647


@pytest.mark.parametrize("block", [1000, 97])
def test_allan_accumulator_gives_the_published_nbs14_deviations(block):
    y = nbs14_1000()
    acc = AllanAccumulator(len(y), 1.0, 1)
    for a in range(0, len(y), block):
        acc.add(y[a : a + block])
    curve = acc.curves()[0]
    for m, published in NBS14_1000_OADEV.items():
        (i,) = np.flatnonzero(curve.tau_s == m)
        assert curve.adev[i] == pytest.approx(published, rel=1e-6)  # 7 digits as published
        assert curve.n[i] == len(y) + 1 - 2 * m  # every overlapping term
    assert allan_deviation(y, 1.0).adev[0] == pytest.approx(NBS14_1000_OADEV[1], rel=1e-6)


def test_segment_moments_are_scipy_ndimage_labelled_statistics():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(5000, 3)) * [1.0, 30.0, 1e-3] + [0.0, 1e4, -2.0]
    edges = np.sort(rng.choice(np.arange(1, 4999), size=60, replace=False))
    start, stop = edges[0::2], edges[1::2]
    rows, counts = stacked_rows(start, stop)
    labels = np.repeat(np.arange(len(counts)), counts)
    index = np.arange(len(counts))
    A = rng.normal(size=(2, 3))
    mean, ss = segment_moments(x[rows], counts)
    _, ss_mapped = segment_moments(x[rows], counts, matrix=A)
    for c in range(3):
        np.testing.assert_allclose(mean[:, c], ndimage.mean(x[rows, c], labels, index),
                                   rtol=1e-12, atol=1e-12 * np.abs(x[:, c]).max())  # fmt: skip
        var = ndimage.variance(x[rows, c], labels, index)
        np.testing.assert_allclose(ss[:, c], var * counts, rtol=1e-9)
    mapped = x[rows] @ A.T
    for d in range(2):
        var = ndimage.variance(mapped[:, d], labels, index)
        np.testing.assert_allclose(ss_mapped[:, d], var * counts, rtol=1e-9)
    chunked = moments_in_chunks(x, start, stop)
    np.testing.assert_allclose(chunked[0], mean, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(chunked[1], ss, rtol=1e-12)


def test_block_checks():
    check_not_more(90, 10, 100)
    check_all_given(100, 100)
    with pytest.raises(InputError, match="more than the 100 samples announced"):
        check_not_more(95, 10, 100)
    with pytest.raises(InputError, match="95 of the 100 samples announced were given"):
        check_all_given(95, 100)
