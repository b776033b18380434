"""Issue 24.6: g-sensitivity and every other fitted term of a captured session: 95 %
intervals that cover the truth 93-97 % of the time (over 100 seeds, slow), and no entry far
off in the sessions a fast run checks. Before: 61 % of the g-sensitivity's entries covered,
3 of 10 sessions with an entry more than 5 std off, exit 0."""

from __future__ import annotations

import numpy as np
import pytest

from bench.captured import as_captured, ferraris_plan
from bench.trust_gyro import _truth_x
from imucal_cli.formats.config import Config
from imucal_cli.pipeline.calibrate import calibrate_session, suspect_error
from imucal_cli.simulate.play import simulate_plan

G_LEVEL = 5e-4


def _z(plan: str, seed: int) -> np.ndarray:
    """Error / std of the 21 terms of a captured g-sensitive session (NaN when refused)."""
    session, truth = simulate_plan(plan, seed=seed, created="2026-01-01T00:00:00Z",
                                   g_sensitivity=G_LEVEL)  # fmt: skip
    cal = calibrate_session(as_captured(session, plan), Config())
    if suspect_error(cal) is not None:
        return np.full(21, np.nan)
    g = cal.gyro
    est = np.array([p["value"] for p in g.extra["parameters"]])
    std = np.array([p["std"] for p in g.extra["parameters"]])
    if len(est) < 21:  # g-sensitivity left out: its truth is not zero
        est, std = np.r_[est, np.zeros(9)], np.r_[std, np.zeros(9)]
    x = _truth_x(cal, truth, np.asarray(truth.gyro.extra["g_sensitivity"]))
    return np.abs(est - x) / np.maximum(std, 1e-300)


@pytest.fixture(scope="module")
def plan(tmp_path_factory) -> str:
    return str(ferraris_plan(tmp_path_factory.mktemp("plan")))


@pytest.mark.parametrize("name", ["ferraris", "free:24"])
def test_a_few_captured_sessions_hold_their_truth(plan, name):
    """Three sessions (63 terms each): none refused, none more than 4.5 std off (about 4e-4
    of a false alarm over all of them)."""
    plan = plan if name == "ferraris" else name
    z = np.array([_z(plan, seed) for seed in (11, 12, 13)])
    assert np.all(np.isfinite(z)) and np.all(z < 4.5), z


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ferraris", "free:24", "qureshi-axes"])
def test_coverage_over_100_seeds(plan, name):
    """100 captured sessions: the g-sensitivity's 900 entries covered 93-97 % of the time (its
    binomial std is 0.7 %), every term 93-98 % (the matrix's cross-axis terms of the
    Ferraris protocol are stated about 1.3 times too wide: they carry the accelerometer's
    strains, which six faces leave to the labels), no saved session with a term more than
    5 std off."""
    plan = plan if name == "ferraris" else name
    z = np.array([_z(plan, 300 + seed) for seed in range(100)])
    saved = np.all(np.isfinite(z), axis=1)
    assert saved.sum() >= 95
    z = z[saved]
    assert 0.93 <= np.mean(z[:, 12:] <= 1.96) <= 0.97
    assert 0.93 <= np.mean(z <= 1.96) <= 0.98
    assert not np.any(z > 5.0)
