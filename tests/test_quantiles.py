"""solvers/quantiles.py against scipy.special: chi-square, normal, Student t and F."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.special as sp

from imucal_cli.solvers import quantiles as q

DOFS = [1, 2, 3, 5.5, 9, 30, 100, 1000, 1e4]
PROBS = [1e-12, 1e-6, 0.01, 0.025, 0.5, 0.975, 0.99, 1 - 1e-9]


@pytest.mark.parametrize("dof", DOFS)
def test_chi2_and_t_quantiles(dof):
    for p in PROBS:
        assert q.chdtri(dof, p) == pytest.approx(sp.chdtri(dof, p), rel=1e-11)
        assert q.stdtrit(dof, p) == pytest.approx(sp.stdtrit(dof, p), rel=1e-11, abs=1e-300)
        assert q.chi2_ppf(p, dof) == pytest.approx(2 * sp.gammaincinv(dof / 2, p), rel=1e-11)
    tail = 1e-11 if dof <= 1000 else 1e-9  # lgamma's cancellation at large dof
    for x in [0.01, 0.5, 1, 3, 10, 100]:
        assert q.chdtrc(dof, x * dof / 3) == pytest.approx(sp.chdtrc(dof, x * dof / 3), rel=tail)
        assert q.fdtrc(9, dof, x) == pytest.approx(sp.fdtrc(9, dof, x), rel=1e-9)


def test_large_dof_and_normal():
    # the Cornish-Fisher expansion serves huge dof (the incomplete beta's lgamma cancellation
    # once limited them to about 1e-9 relative)
    for p in (0.01, 0.975):
        assert q.stdtrit(1e6, p) == pytest.approx(sp.stdtrit(1e6, p), rel=1e-14)
    for p in [1e-300, 1e-20, 1e-8, 0.001, 0.3, 0.5, 0.7, 0.999, 1 - 1e-12]:
        assert q.ndtri(p) == pytest.approx(sp.ndtri(p), rel=1e-12, abs=1e-15)
    assert q.ndtri(0.0) == -np.inf and q.stdtrit(3, 0.5) == 0.0


def test_arrays_broadcast_like_scipy():
    dof = np.array([1.0, 4.0, 17.0])
    np.testing.assert_allclose(q.chdtri(dof, 0.05), sp.chdtri(dof, 0.05), rtol=1e-11)
    np.testing.assert_allclose(q.stdtrit(np.minimum(dof, 1e6), 0.975),
                               sp.stdtrit(dof, 0.975), rtol=1e-11)  # fmt: skip
    assert isinstance(q.chdtri(3, 0.5), float) and q.chdtri(dof, 0.5).shape == (3,)


def test_t_expansion_where_used():
    """The t quantile's Cornish-Fisher expansion, wherever it serves (df >= 1000 and its
    last term small), agrees with scipy.stats.t.ppf to rounding (target 1e-10; it is about
    1e-15), and leaves the far tails at df near 1000 to Newton."""
    from scipy.stats import t as student_t

    probs = [1e-12, 1e-9, 1e-6, 1e-3, 0.01, 0.025, 0.1, 0.3, 0.7, 0.9, 0.975, 0.99, 0.999,
             1 - 1e-6, 1 - 1e-9]  # fmt: skip
    used = 0
    for df in [1000, 1500, 3000, 1e4, 34627.07678841758, 1e5, 1e6, 1e7, 1e9]:
        for p in probs:
            if q._t_upper_expansion(min(p, 1 - p), df) is None:
                continue
            used += 1
            assert q.stdtrit(df, p) == pytest.approx(student_t.ppf(p, df), rel=1e-14)
    assert used > 100
    assert q._t_upper_expansion(1e-12, 1000) is None  # far tail at df 1000: Newton
    assert q._t_upper_expansion(0.025, 999) is None
