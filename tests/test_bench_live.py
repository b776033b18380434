"""``bench live`` in short (issue 24.1): the user's path, served, captured and calibrated.

``imucal simulate --serve`` as the device, ``imucal capture`` guided (a scripted person in a
pseudo-terminal, Enter at the device after each recorded pose) and unattended, beside two
CPU-burning processes, then ``imucal calibrate SESSION`` with no config, graded against the
truth of the served part (the bench's own code: :mod:`bench.live`).

What one seed can show is checked against what the noise allows: every capture complete and
calibrated, the same sensors as from the file, the device's samples those of the simulated
pass (the served part is the simulated one), and each fit's error within its bound: the RMS
of 12 error/bound ratios of an efficient fit is sqrt(chi^2(12) / 12), above 2 with a chance of
3e-6.  The 10 % comparison with the file needs many seeds: ``python -m bench --only live``
(``test_live_plans_slow`` runs more plans).
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from bench import live
from bench.live_grade import Graded

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")

#: RMS of p error/bound ratios above which an efficient fit is implausible (p = 9..13:
#: chi^2(p) / p > 4 has a chance below 1e-5).
MAX_RMS = 2.0


def _check(rows, plans) -> None:
    assert len(rows) == len(plans) * len(live.MODES)
    for row in rows:
        assert (row.attempted, row.complete, row.calibrated) == (1, 1, 1), (row.plan, row.why)
        # a sensor the session cannot determine is left out (six faces: the gyro), never one
        # the same plan simulated to a file calibrates
        assert row.saved.startswith("accel"), (row.plan, row.mode, row.saved)
        assert not any("fewer sensors" in w for w in row.why), row.why
        assert np.isfinite(row.live) and row.live < MAX_RMS, (row.plan, row.mode, row.live)
        assert row.sections, row.why
        if row.mode == "unattended":  # the device's timer streams the simulated pass itself
            assert row.served == "100.0 %", (row.plan, row.served)


def test_live_six_guided_and_unattended_beside_burners(tmp_path):
    """Six faces, a pose held 2.5 s on the device's timer (1 s moves): both captures at
    once, beside two CPU burners."""
    plans = [live.LivePlan("six", hold_s=2.5, move_s=1.0)]
    lines: list[str] = []
    rows = live.run_live(plans, seeds=[3], jobs=2, n_burners=2, folder=tmp_path,
                         say=lines.append)  # fmt: skip
    _check(rows, plans)
    accel = [r.sections["accel"] for r in rows]
    assert all(solver.startswith("labelled") for solver, *_ in accel)
    assert any("[2/2]" in line for line in lines)  # progress said per capture
    session = tmp_path / "six-s3-guided.h5"
    assert session.exists() and session.with_suffix(".cal.json").exists()


def test_the_person_reads_a_live_screen():
    """What the scripted person reads: the capture's messages between rich's cursor moves,
    a control sequence split between two reads, a pose taken counted once."""
    from bench.live_run import _Screen

    frame = b"\x1b[?25l\r\x1b[2K[step 2/6] Turn the unit\r\n\x1b[2Kdone 1/6\x1b[1A\x1b[2K"
    taken = b"\x1b[1mrecorded face -Z up (measured up -Z) (2 of 6)\x1b[0m\r\n"
    turn = b"recorded turn about +X (4.1 s, 359 deg measured)\r\n"
    stream = frame + taken + frame + turn + frame + b"every step done; Keep turning the unit slowly"
    screen = _Screen()
    for i in range(0, len(stream), 7):  # arriving in pieces, sequences cut anywhere
        screen.feed(stream[i : i + 7])
    assert screen.poses == 1 and screen.more_field
    assert "\x1b" not in screen.tail and "recorded face -Z up" in screen.tail


def test_grading_finds_a_wrong_truth(tmp_path):
    """The grading is not blind: the file reference graded against another seed's part is
    far outside its bound."""
    from imucal_cli.formats.config import Config
    from imucal_cli.pipeline.calibrate import calibrate_session

    plan = live.LivePlan("qureshi18")
    session, truth = live.simulated(plan, 1)
    _, other = live.simulated(plan, 2)
    cal = calibrate_session(session, Config())
    right = live.grade(session, cal, truth)
    wrong = live.grade(session, cal, other)
    for name in ("accel", "gyro"):
        assert isinstance(right[name], Graded) and isinstance(wrong[name], Graded)
        assert np.sqrt(np.mean(right[name].z2)) < MAX_RMS
        assert np.sqrt(np.mean(wrong[name].z2)) > 10 * MAX_RMS


@pytest.mark.slow
def test_live_plans_slow(tmp_path):
    """More plans, one seed each, guided and unattended, the device on its defaults."""
    plans = [p for p in live.PLANS if p.plan in ("qureshi18", "random:12", "free:12")]
    rows = live.run_live(plans, seeds=[5], jobs=3, n_burners=2, folder=tmp_path,
                         say=lambda _: None)  # fmt: skip
    _check(rows, plans)
