"""``bench adaptive``'s coverage verdict (the bench's own code, :mod:`bench.adaptive`): the
coverage's interval takes the parts as clusters (a part's 18 terms share its noise and its
design), and the captures run several at a time keep the parts' order."""

from __future__ import annotations

import io
import threading

import numpy as np
import pytest
from rich.console import Console

from bench import adaptive


def test_coverage_interval_takes_the_parts_as_clusters():
    """Misses that come together in a few parts widen the interval beyond the binomial one of
    the terms as independent trials; spread evenly, the interval is the parts' own scatter."""
    together = np.ones((20, 18), bool)
    together[:2] = False  # two parts miss every term: 36 misses, 90 % coverage
    spread = np.ones((20, 18), bool)
    spread[np.arange(20), np.arange(20) % 18] = False
    spread[np.arange(16), (np.arange(16) + 5) % 18] = False  # 36 misses, 1 or 2 a part
    for hits in (together, spread):
        mean, low, high = adaptive.coverage_interval(hits)
        assert mean == pytest.approx(np.mean(hits))
        per = hits.mean(axis=1)
        half = 1.96 * per.std(ddof=1) / np.sqrt(len(per))  # the arithmetic, not a tolerance
        assert (low, high) == pytest.approx((mean - half, min(mean + half, 1.0)))
    binomial = 1.96 * np.sqrt(0.9 * 0.1 / together.size)
    mean, low, _ = adaptive.coverage_interval(together)
    assert mean - low > 3 * binomial  # 13.5 % against 3.1 % (above: clipped at 100 %)
    mean, low, _ = adaptive.coverage_interval(spread)
    assert mean - low < binomial  # fewer misses in a part than chance would put there


def test_coverage_interval_clipped_and_single_part():
    assert adaptive.coverage_interval(np.ones((5, 18), bool)) == (1.0, 1.0, 1.0)
    assert adaptive.coverage_interval(np.ones((1, 18), bool)) == (1.0, 0.0, 1.0)


def test_captures_at_a_time_keep_the_parts_order(monkeypatch):
    """Three captures run together (``jobs`` at a time: each waits for the other two) and each
    part's seconds stay in its place."""
    seeds = [7, 8, 9]
    started, gate = [], threading.Barrier(3, timeout=30)

    def fake(seed, folder):
        started.append(seed)
        gate.wait()  # all three running together, or this times out
        return {"summary": {"duration_s": float(seed), "complete": True},
                "session": folder / "absent.h5"}, 0.0  # fmt: skip

    monkeypatch.setattr(adaptive, "_captured", fake)
    console = Console(file=io.StringIO(), width=200)
    seconds, hits, lost = adaptive._adaptive(console, seeds, jobs=3)
    assert seconds == [7.0, 8.0, 9.0]
    assert sorted(started) == seeds
    assert hits == [] and lost == 3  # no session file: counted as not calibrated
