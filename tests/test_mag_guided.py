"""Guided capture with a magnetometer: the live coverage of field directions, where to point the
unit next, and a capture that goes on after the plan until the magnetometer has seen enough."""

from __future__ import annotations

import io

import numpy as np
from rich.console import Console
from scipy.spatial.transform import Rotation

from imucal_cli.capture.guided import ScriptedKeys, run_guided
from imucal_cli.capture.guided.magnetic import MagCoverage
from imucal_cli.capture.guided.screen import Screen
from imucal_cli.capture.guided.state import GuidedOptions, GuidedState
from imucal_cli.formats.columns import SampleBlock
from imucal_cli.plans import load_plan
from imucal_cli.simulate.magnetometer import simulate_mag

HARD = np.array([120.0, -80.0, 40.0])


def readings(attitudes: Rotation, noise=1.0, seed=0) -> np.ndarray:
    """Raw readings of a 300-count field with hard iron, for the attitudes given."""
    h = attitudes.inv().apply([300.0 * np.cos(1.0), 0.0, -300.0 * np.sin(1.0)])
    return h + HARD + np.random.default_rng(seed).normal(0, noise, h.shape)


def test_coverage_learns_the_offset_then_counts_regions():
    cov = MagCoverage(goal=0.9)
    flat = Rotation.from_euler("z", np.linspace(0, 2 * np.pi, 200)[:, None])
    cov.update(readings(flat))  # one plane: the offset cannot be found yet
    assert not cov.ready and "learning its offset" in cov.status()
    everywhere = Rotation.random(3000, random_state=1)
    for chunk in np.array_split(readings(everywhere, seed=1), 30):
        cov.update(chunk)
    assert cov.ready and np.linalg.norm(cov.centre - HARD) < 2.0
    assert cov.fraction > 0.95 and cov.done and cov.status().endswith("enough")
    assert len(cov.map_directions()) == int(round(100 * cov.fraction))


def test_next_direction_points_into_the_gap_and_repeats_do_not_count():
    cov = MagCoverage()
    att = Rotation.random(4000, random_state=2)
    m = readings(att, seed=2)
    h = m - HARD
    cov.update(m[h[:, 2] < 100.0])  # the field never came along +z of the magnetometer
    assert cov.ready and cov.fraction < 0.9
    target = cov.next_direction()
    assert target[2] > 0.5
    assert "point the unit's +Z" in cov.status() and "deg from now" in cov.status()
    before = cov.counts.copy()
    cov.update(np.repeat(m[:1] * 0 + m[0], 50, axis=0))  # a magnetometer that did not update
    assert cov.counts.sum() - before.sum() <= 1
    cov.update(np.full((5, 3), np.nan))  # no reading: nothing happens
    assert cov.counts.sum() - before.sum() <= 1


class MagRecorder:
    """Plays a simulated session with a magnetometer block by block."""

    def __init__(self, session, block=10):
        self.s, self.block, self._n, self._stop = session, block, 0, False
        self.segments: list[dict] = []
        self.accel_units = self.gyro_units = "counts"
        self.end_reason, self.end_kind, self.stats = "", None, {"lines": 0}

    @property
    def n_samples(self):
        return self._n

    def blocks(self, tick_s=0.1):
        s = self.s
        for i in range(0, len(s.time), self.block):
            if self._stop:
                self.end_kind, self.end_reason = "done", "done"
                return
            j = min(i + self.block, len(s.time))
            self._n = j
            yield SampleBlock(s.time[i:j], s.accel[i:j], s.gyro[i:j], None, s.mag[i:j])
        self.end_kind, self.end_reason = "device-gone", "the device is gone"

    def add_segment(self, kind, start, stop, **kw):
        self.segments.append(dict(kind=kind, start=start, stop=stop, **kw))

    def stop(self):
        self._stop = True


def _console():
    return Console(record=True, width=140, file=io.StringIO(), force_terminal=False)


def test_guided_capture_tells_the_coverage_and_goes_on_until_it_is_enough():
    session, _ = simulate_mag("six", 4, tumble_s=2.0, hold_s=3.0)
    # a goal this stream cannot reach: every pose is taken, then the capture goes on, turning,
    # until the stream ends; the summary says the magnetometer has not seen enough
    rec, console = MagRecorder(session), _console()
    summary = run_guided(rec, load_plan("six"), console=console, keys=ScriptedKeys([]),
                         mag_goal=0.999)  # fmt: skip
    out = console.export_text()
    assert len(summary.done) == 6 and summary.end_reason == "the device is gone"
    assert "every step done; magnetometer:" in out and "missing directions" in out
    assert "% of the field directions seen" in out
    # a goal it reaches: the capture ends at the last pose, saying so
    rec2, console2 = MagRecorder(session), _console()
    summary2 = run_guided(rec2, load_plan("six"), console=console2, keys=ScriptedKeys([]),
                          mag_goal=0.3)  # fmt: skip
    assert summary2.complete and "the magnetometer saw" in summary2.end_reason
    assert rec2._stop


def test_the_live_screen_draws_the_field_map():
    session, _ = simulate_mag("six", 5, tumble_s=2.0, hold_s=3.0)
    state = GuidedState(load_plan("six"), GuidedOptions(), 0, lambda *a, **k: None)
    s = session
    for i in range(0, 3000, 10):
        j = slice(i, i + 10)
        state.on_block(SampleBlock(s.time[j], s.accel[j], s.gyro[j], None, s.mag[j]))
    console = Console(record=True, width=120, file=io.StringIO(), force_terminal=True)
    console.print(Screen(console).render(state))
    text = console.export_text()
    assert "magnetometer:" in text and "+Z side" in text
