"""``bench adaptive``'s coverage verdict (the bench's own code, :mod:`bench.adaptive`): the
coverage's interval takes the parts as clusters (a part's 18 terms share its noise and its
design), and the captures run several at a time keep the parts' order."""

from __future__ import annotations

import io
import threading

import numpy as np
import pytest
from rich.console import Console
from scipy.stats import t as student_t

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
        t = student_t.ppf(0.975, len(per) - 1)  # 2.09 for 20 parts
        half = t * per.std(ddof=1) / np.sqrt(len(per))  # the arithmetic, not a tolerance
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
    """``jobs`` captures run together, never more (each of the first three waits for the
    other two; a fourth is not started while they wait), and each part's seconds stay in its
    place; a capture that ends without a summary is counted and the others go on."""
    seeds = list(range(6))
    lock, running, peak, started = threading.Lock(), [0], [0], []
    gate = threading.Barrier(3, timeout=30)

    def fake(seed, folder):
        with lock:
            started.append(seed)
            running[0] += 1
            peak[0] = max(peak[0], running[0])
        try:
            if seed < 3:
                gate.wait()  # the first three together, or this times out
            if seed == 4:
                raise RuntimeError("the capture ended without a summary")
            return {"summary": {"duration_s": float(seed), "complete": True},
                    "session": folder / "absent.h5"}, 0.0  # fmt: skip
        finally:
            with lock:
                running[0] -= 1

    monkeypatch.setattr(adaptive, "_captured", fake)
    out = io.StringIO()
    seconds, hits, lost = adaptive._adaptive(Console(file=out, width=200), seeds, jobs=3)
    assert peak[0] == 3 and sorted(started) == seeds
    assert seconds == [0.0, 1.0, 2.0, 3.0, None, 5.0]
    assert hits == [] and lost == 6  # no session file: not calibrated; part 4 failed
    assert "part 4: failed: the capture ended without a summary" in out.getvalue()


def test_an_interrupt_starts_no_more_captures(monkeypatch):
    """Ctrl-C (here: raised by the first part) ends the bench without starting the parts
    still queued (before, every queued part ran first: 10 minutes of captures)."""
    started = []

    def fake(seed, folder):
        started.append(seed)
        if seed == 0:
            raise KeyboardInterrupt
        return {"summary": {"duration_s": 1.0, "complete": True},
                "session": folder / "absent.h5"}, 0.0  # fmt: skip

    monkeypatch.setattr(adaptive, "_captured", fake)
    with pytest.raises(KeyboardInterrupt):
        adaptive._adaptive(Console(file=io.StringIO(), width=200), range(9), jobs=3)
    assert sorted(started) == [0, 1, 2]
