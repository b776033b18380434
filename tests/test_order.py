"""solvers/order.py against numpy: the same numbers, bit for bit, and the same types."""

import subprocess
import sys
import warnings

import numpy as np
import pytest

from imucal_cli.solvers.order import distinct, median, nanmedian, quantile


def _cases(seed, n_cases=1500):
    rng = np.random.default_rng(seed)
    for _ in range(n_cases):
        n = int(rng.integers(1, 40))
        shape = (n,) if rng.random() < 0.6 else (n, int(rng.integers(1, 4)))
        x = rng.normal(size=shape) * 10 ** rng.uniform(-3, 3)
        if rng.random() < 0.5:
            x = np.round(x)  # ties, as counts have
        if rng.random() < 0.1:
            x.flat[rng.integers(x.size)] = np.nan
        if rng.random() < 0.05:
            x.flat[rng.integers(x.size)] = np.inf
        yield rng, x


def _same(a, b):
    """The same type, shape and values, NaN where NaN and the sign of zeros too."""
    a, b = (np.asarray(v) for v in (a, b)) if type(a) is type(b) else (None, np.zeros(1))
    return (a is not None and a.shape == b.shape and a.dtype == b.dtype
            and np.array_equal(a, b, equal_nan=True)
            and np.array_equal(np.signbit(a), np.signbit(b)))  # fmt: skip


@pytest.mark.parametrize("axis", [None, 0])
def test_median_is_numpys(axis):
    for _, x in _cases(1):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            assert _same(median(x, axis=axis), np.median(x, axis=axis)), (x, axis)


def test_quantile_and_nanmedian_are_numpys():
    for rng, x in _cases(2):
        q = float(rng.choice([0.0, 1.0, 0.5, 0.01, 0.99, rng.random()]))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            assert _same(quantile(x, q), np.quantile(x, q)), (x, q)
            assert _same(nanmedian(x), np.nanmedian(x)), x


def test_distinct_is_numpys_unique():
    rng = np.random.default_rng(3)
    for _ in range(500):
        x = rng.integers(-5, 5, size=int(rng.integers(0, 50)))
        assert _same(distinct(x), np.unique(x))
        f = x.astype(float)
        if len(f) and rng.random() < 0.3:
            f[0] = np.nan
        assert _same(distinct(f), np.unique(f))


def test_a_calibration_does_not_load_numpys_masked_arrays(tmp_path):
    """What they are for: ``numpy.ma`` (0.01 s of start-up) is not imported by a calibration."""
    from imucal_cli.formats.session import write_session
    from imucal_cli.simulate.triad import simulate

    session, _ = simulate("qureshi18", seed=2, created="2026-01-01T00:00:00Z")
    write_session(tmp_path / "s.h5", session)
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "from imucal_cli.formats.config import load_config\n"
        "from imucal_cli.pipeline.batch import calibrate_file\n"
        "calibrate_file(Path('s.h5'), load_config(None), output=Path('s.json'), store=False)\n"
        "print('numpy.ma' in sys.modules)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "False"


def test_signed_zeros_integers_and_other_float_types_as_numpy():
    cases = [np.array([-0.0]), np.array([-0.0, -0.0]), np.array([-0.0, 1.0, -0.0]),
             np.array([[-0.0, 1.0, -0.0], [2.0, -0.0, -5.0]]),
             np.array([3, 1, 2, 8], dtype=np.int16),
             np.array([1.5, -2.25, 7.0, 0.1], dtype=np.float32)]  # fmt: skip
    for x in cases:
        for axis in (None, 0, -1):
            assert _same(median(x, axis=axis), np.median(x, axis=axis)), (x, axis)
        assert _same(nanmedian(x), np.nanmedian(x)), x
        assert _same(quantile(x, 0.3), np.quantile(x, 0.3)), x
