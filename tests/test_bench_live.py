"""``bench live`` in short (issue 24.1): the user's path, served, captured and calibrated.

``imucal simulate --serve`` as the device, ``imucal capture`` guided (a scripted person in a
pseudo-terminal, Enter at the device after each recorded pose) and unattended, then
``imucal calibrate SESSION`` with no config, graded against the truth of the served part (the
bench's own code: :mod:`bench.live`; the slow test and the bench add two CPU burners).

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


def test_live_six_guided_and_unattended(tmp_path, monkeypatch):
    """Six faces, a pose held 1.6 s on the device's timer (0.7 s moves), 1 s by the guided
    capture (--hold 1): both captures at once.  Nothing waits a fixed time: the person and
    the harness act on what the processes print, so a loaded machine only makes it slower
    (about 30 s of CPU in all; the CPU burners are the bench's and the slow test's: in
    ``make test`` the suite's other worker loads the second core)."""
    plans = [live.LivePlan("six", hold_s=1.6, move_s=0.7, capture=("--hold", "1"))]
    lines: list[str] = []
    monkeypatch.setattr(live, "PERSON_DRAWS", 3)  # the guided reference's path, 3 draws not 12
    rows = live.run_live(plans, seeds=[3], jobs=2, n_burners=0, folder=tmp_path,
                         say=lines.append)  # fmt: skip
    _check(rows, plans)
    accel = [r.sections["accel"] for r in rows]
    assert all(solver.startswith("labelled") for solver, *_ in accel)
    assert any("[2/2]" in line for line in lines)  # progress said per capture
    session = tmp_path / "six-s3-guided.h5"
    assert session.exists() and session.with_suffix(".cal.json").exists()
    # the file held as the guided capture holds (its pairing) streams the captured windows
    from imucal_cli.formats.session import read_session

    captured = read_session(session)
    held = live.held_as_guided(live.simulated(plans[0], 3)[0], 1.0)

    def still_rows(s):
        return {tuple(s.accel[i]) for g in s.static_segments() for i in range(g.start, g.stop)}

    got, emulated = still_rows(captured), still_rows(held)
    assert len(got & emulated) >= 0.8 * len(got), (len(got & emulated), len(got))
    # --regrade: the kept capture calibrated again gives the row the run gave (the unattended
    # one: its file reference is computed here, where the guided one's person draws need a
    # process of their own beside, 10 s more; the guided log is read as that one is, by
    # test_a_kept_capture_that_failed_says_so_when_graded_again)
    again = live.regrade(tmp_path, plans, {"guided": [], "unattended": [3]}, file_seeds=[3],
                         say=lines.append)  # fmt: skip
    assert any("1 kept captures calibrated again" in line for line in lines), lines
    first, second = ([r for r in got if r.mode == "unattended"] for got in (rows, again))
    _check(first + second, plans)  # as many rows: the run's and the regrade's unattended
    assert second[0].plan == first[0].plan
    assert second[0].live == pytest.approx(first[0].live, rel=1e-6)
    assert second[0].cover_live == first[0].cover_live


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
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import Config

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


def _graded(rng, scale=1.0, half=1.96, p=12):
    err = rng.standard_normal(p) * scale
    return {"accel": Graded("accel", "gravity, 9", [f"p{i}" for i in range(p)], err,
                            np.ones(p), np.full(p, half), np.ones(p))}


class _Job:
    def __init__(self, seed, graded, cal_exit=0):
        from types import SimpleNamespace

        self.seed, self.graded = seed, graded
        self.capture = SimpleNamespace(exit_code=0, wall_s=10.0)
        self.calibrate = SimpleNamespace(exit_code=cal_exit, left_out={}, sections=["accel"])
        self.served_equal = None

    def what_went_wrong(self):
        return "" if self.calibrate.exit_code == 0 else "imucal: error: refused"


def test_the_verdict_names_what_fails_and_whose_it_is():
    """The table is not blind: live errors twice the file's fail on error/bound; intervals
    that hold the truth half as often as stated fail on coverage, and are the solver's when
    the file's own intervals miss 95 % over all its seeds; a calibration the file of the
    same seed refuses too is the solver's."""
    from bench.live_table import make_row

    rng = np.random.default_rng(0)
    seeds = range(30)
    files = {s: _graded(rng) for s in seeds}
    same = make_row("p", "guided", [_Job(s, files[s]) for s in seeds], files, rng)
    assert same.ok and abs(same.ratio - 1) < 1e-12
    worse = make_row("p", "guided", [_Job(s, _graded(rng, 2.0)) for s in seeds], files, rng)
    assert not worse.ok and any("error/bound" in w for w in worse.why)
    narrow = {s: _graded(rng, half=0.7) for s in seeds}  # about 52 % coverage
    row = make_row("p", "unattended", [_Job(s, narrow[s]) for s in seeds], narrow, rng)
    assert any("does not hold 95 %" in w and "[solver" in w for w in row.why), row.why
    files[3] = {"error": "DesignError: refused"}
    row = make_row("p", "guided", [_Job(3, {}, cal_exit=1)], files, rng)
    assert any("seed 3" in w and "[solver" in w for w in row.why), row.why


def test_coverage_tests_are_family_wise_and_unlucky_seeds_are_the_seeds():
    """Each row's two coverage tests are made at the table's family-wise 95 % (Bonferroni:
    z 3.28 for 24 rows, 1.96 for one test): a path that loses nothing fails a 24-row table by
    chance at most one time in twenty, not 91 %.  A live coverage short of 95 % that the file
    of the same seeds shares interval by interval, while the file over all its seeds holds
    95 %, is a note (those seeds' draw); the same shortfall where the file of the same seeds
    holds 95 % fails (the path's), and so does a live path whose intervals are narrower than
    the file's on seeds where the file's are short too (paired, not within an unpaired
    tolerance)."""
    from bench.live_table import family_z, make_row

    assert family_z(1) == pytest.approx(1.96, abs=1e-3)
    assert family_z(48) == pytest.approx(3.28, abs=5e-3)
    assert make_row("p", "unattended", [], {}, None, family=48).z == family_z(48)
    rng = np.random.default_rng(3)
    files = {s: _graded(rng) for s in range(40)}  # 95 % over all seeds
    unlucky = {s: _graded(rng, half=1.0) for s in range(3)}  # about 68 % on seeds 0-2
    for s in unlucky:
        files[s] = unlucky[s]
    jobs = [_Job(s, unlucky[s]) for s in range(3)]
    row = make_row("p", "unattended", jobs, files, rng, family=24)
    assert row.ok, row.why
    assert any("these seeds' draw" in n for n in row.notes), row.notes
    held = {s: _graded(rng) for s in range(40)}  # the file of the same seeds holds 95 %
    row = make_row("p", "guided", jobs, files, rng, same_of=held, family=24)
    assert not row.ok and any("does not hold 95 %" in w for w in row.why), row.why
    assert not any("[solver" in w for w in row.why)
    # the same errors as the unlucky file's, the intervals 40 % narrower: worse than the file
    narrower = {s: {"accel": _narrowed(unlucky[s]["accel"], 0.6)} for s in unlucky}
    row = make_row("p", "unattended", [_Job(s, narrower[s]) for s in range(3)], files, rng,
                   family=24)  # fmt: skip
    assert not row.ok and any("does not hold 95 %" in w for w in row.why), (row.why, row.notes)


def _narrowed(sec, factor):
    from dataclasses import replace

    return replace(sec, std=sec.std * factor, half=sec.half * factor)


def test_the_ratio_interval_of_seeds_with_nothing_graded_in_both_is_nan():
    """Seeds whose live and file calibrations share no graded sensor (a plan saved only in
    part on one side) give no ratio interval, not a crash of the whole table (the bench's
    run of 99 captures ended in numpy's quantile of an empty array)."""
    from types import SimpleNamespace

    from bench.live_table import _bootstrap

    pairs = [(SimpleNamespace(graded={}), {}) for _ in range(4)]
    lo, hi = _bootstrap(pairs, [set()] * 4, np.random.default_rng(0))
    assert np.isnan(lo) and np.isnan(hi)


def _guided_stream(session, hold_s: float, settle: int = 16, reaction: int = 85):
    """What the device streams to a guided person who holds each pose ``hold_s`` and moves on
    ``reaction`` samples after the capture took it (``bench.live_run.capture_guided``), with
    the segments a capture writes: each pose's ``hold_s`` from ``settle`` samples into the
    hold, the rest of the hold never streamed (the stream compacted, the clock continuous),
    the move between two poses a rotation segment; no capture, so nothing lost."""
    import dataclasses

    from imucal_cli.model.session import Segment

    rate = float(session.sample_rate_hz)
    pose = int(round(hold_s * rate))
    segs = sorted(session.segments, key=lambda s: s.start)
    keep = np.ones(len(session.time), bool)
    for s in segs:
        if s.kind == "static":
            keep[s.start + (settle if s.start else 0) + pose + reaction : s.stop] = False
    at = np.cumsum(keep) - 1
    out: list = []
    for s in segs:
        first = s.start + (settle if s.kind == "static" and s.start else 0)
        last = first + pose - 1 if s.kind == "static" else s.stop - 1
        new = dataclasses.replace(s, start=int(at[first]), stop=int(at[last]) + 1)
        if s.kind == "static" and out and out[-1].kind == "static":
            out.append(Segment(f"m{s.name}", "rotation", out[-1].stop + reaction // 2, new.start,
                               label=f"turn to {s.label}"))  # fmt: skip
        out.append(new)
    return dataclasses.replace(session, time=np.arange(keep.sum()) / rate,
                               accel=session.accel[keep], gyro=session.gyro[keep],
                               temperature=None, segments=out)  # fmt: skip


def test_a_guided_capture_is_paired_with_the_file_held_as_it_holds():
    """qureshi-axes:6, seeds 1 and 3 of those where the bench's guided row failed (+11 %,
    issue 24.1): a guided stream that loses nothing (the file's own samples, each pose held
    the capture's 2 s, no capture) fails the 10 % target against the file of the same seeds
    as simulated (4 s holds: another noise draw, whose own sampling error the ratio then
    carries: +20 % here), and meets it paired with the file held as the guided capture holds
    (the hold's own part, :func:`held_factor`, said in a note).  Over 40 seeds the three
    designs' error/bound are 1.009 (stream), 0.996 (held) and 1.000 (file)."""
    from bench.live_table import held_factor, make_row

    plan = live.LivePlan("qureshi-axes:6")
    seeds, every = [1, 3], list(range(12))
    hold = live.guided_hold_s(plan)
    assert hold == 2.0
    files = live.file_reference(plan, every)[0]
    held = live.file_reference(plan, every, hold)[0]
    assert abs(held_factor(files, held) - 1) < 0.10  # the same expectation, within 12 seeds'
    jobs = []
    for s in seeds:
        session, truth = live.simulated(plan, s)
        streamed = _guided_stream(session, hold)
        cal = live.calibrate_session(streamed, live.Config())
        jobs.append(_Job(s, live.grade(streamed, cal, truth)))
    rng = np.random.default_rng(0)
    old = make_row("qureshi-axes:6", "guided", jobs, files, rng)
    assert old.ratio > 1.10 and not old.ok, old.ratio
    paired = make_row("qureshi-axes:6", "guided", jobs, files, rng, same_of=held)
    assert abs(paired.ratio - 1) <= 0.10, paired.ratio
    assert paired.ok, paired.why
    assert any("the hold's part" in n for n in paired.notes), paired.notes


def test_a_kept_capture_that_failed_says_so_when_graded_again(tmp_path):
    """``--regrade`` reads each capture from its log as the run wrote it (:meth:`Job.log`): a
    killed capture and one that exited 1 keep their own words, and a folder with nothing
    kept is refused in one line."""
    plan = live.LivePlan("six")
    killed = live.Job(plan, 0, "guided", 10.0)
    killed.capture = live.live_run.CaptureRun("guided", tmp_path / "a.h5", exit_code=None,
                                              wall_s=300.0, error="killed after 300 s")  # fmt: skip
    failed = live.Job(plan, 1, "unattended", 10.0)
    failed.capture = live.live_run.CaptureRun(
        "unattended", tmp_path / "b.h5", exit_code=1, wall_s=5.0,
        text="reading /dev/pts/9\nimucal: error: the device stopped sending (ended: stalled)")
    for job, name in ((killed, "a"), (failed, "b")):
        (tmp_path / f"{name}.log").write_text(job.log())
        again = live.Job(plan, job.seed, job.mode, 0.0)
        again.capture = live.kept_capture(job.mode, tmp_path / f"{name}.h5",
                                          tmp_path / f"{name}.log")  # fmt: skip
        assert again.capture.exit_code == job.capture.exit_code
        assert again.capture.wall_s == pytest.approx(job.capture.wall_s)
        assert again.what_went_wrong() == job.what_went_wrong() != ""
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SystemExit, match="no kept captures"):
        live.kept_jobs(empty, [plan], {"guided": [0]})


def test_every_row_of_the_bench_has_files_of_its_own():
    """Two rows of one plan (qureshi18, and qureshi18 with i2cdevlib lines) wrote the same
    session and calibration: the second capture refused the first's file and its row had
    nothing to grade.  Each plan, mode and seed has its own file name."""
    stems = [live.Job(p, 5, m, 1.0).stem for p in live.PLANS for m in live.MODES]
    assert len(set(stems)) == len(stems), stems


def test_a_host_stamped_capture_is_matched_to_the_served_pass_in_order():
    """Lines without device time (i2cdevlib) are stamped from the port's open: by time none
    of the captured samples met the pass's (the row said 'served 0.0 %'); in order from where
    the first one stands they all do, and a different part still shows."""
    from dataclasses import replace

    from imucal_cli.simulate.play import simulate_plan

    file, _ = simulate_plan("six", seed=2)
    k = 137  # the capture began there; its host stamps start 12.3 ms after the open
    live_ = replace(file, time=file.time[k:] - file.time[k] + 0.0123, accel=file.accel[k:],
                    gyro=file.gyro[k:], segments=[])  # fmt: skip
    assert live._served_equal(live_, file) == 1.0
    other, _ = simulate_plan("six", seed=3)
    assert live._served_equal(replace(live_, accel=other.accel[k:]), file) < 0.5


def _fixed(value: float, p: int = 12) -> dict:
    """One seed graded with every parameter's error/bound ``value`` (an accelerometer)."""
    names = [f"p{i}" for i in range(p)]
    ones = np.ones(p)
    return {"accel": Graded("accel", "gravity, 9", names, value * ones, ones, 1.96 * ones, ones)}


def test_a_guided_row_is_judged_within_the_person_spread_only_where_it_is_measured():
    """The error/bound verdict of a row with the person's draws (``draws_of``): the target
    band (10 %) stays where the person's timing does not spread the ratio, so a live path 12 %
    worse than the draws' mean fails and one 8 % worse passes; where the timing spreads it
    (the draws of a seed 0.8-1.2), the band is that 95 % interval, so a live capture that is
    one of the draws passes at -17 %, and twice the draws still fails."""
    from bench.live_table import make_row

    rng = np.random.default_rng(3)
    seeds = [0, 1]
    held = {s: _fixed(1.0) for s in seeds}
    steady = {s: [_fixed(1.0) for _ in range(12)] for s in seeds}
    for worse, ok in ((1.12, False), (1.08, True), (0.88, False)):
        jobs = [_Job(s, _fixed(worse)) for s in seeds]
        row = make_row("p", "guided", jobs, held, rng, same_of=held, draws_of=steady)
        assert row.band == pytest.approx((0.9, 1.1)), row.band
        assert row.ratio == pytest.approx(worse) and row.ok is ok, (worse, row.why)
    values = np.linspace(0.8, 1.2, 12)
    spread = {s: [_fixed(v) for v in values] for s in seeds}
    row = make_row("p", "guided", [_Job(s, _fixed(values[1])) for s in seeds], held, rng,
                   same_of=held, draws_of=spread)  # fmt: skip
    assert row.band[0] < 0.85 and row.band[1] > 1.1, row.band
    assert row.ratio < 0.9 and row.ok, row.why  # outside 10 %, inside the person's spread
    assert any("the person's timing" in n for n in row.notes), row.notes
    twice = make_row("p", "guided", [_Job(s, _fixed(2.0)) for s in seeds], held, rng,
                     same_of=held, draws_of=spread)  # fmt: skip
    assert not twice.ok and any("band" in w for w in twice.why), twice.why
    # without draws (unattended, a warm-up): the target alone, as before
    row = make_row("p", "unattended", [_Job(s, _fixed(0.85)) for s in seeds], held, rng)
    assert row.band == pytest.approx((0.9, 1.1)) and not row.ok


#: What the guided captures of random:12 seeds 0 and 1 took (bench live --keep, 2026-11-29,
#: beside 2 CPU burners): each pose's window start after the hold began and the samples
#: streamed after the window until the move (the person's reaction), at 100 Hz; the first
#: pose's window starts at the stream's first sample.
CAPTURED_TIMING = {
    0: ([0, 20, 18, 18, 20, 20, 20, 19, 20, 15, 16, 16],
        [81, 58, 82, 62, 122, 110, 63, 110, 121, 114, 84, 80]),
    1: ([0, 16, 16, 18, 15, 16, 19, 17, 16, 21, 20, 16],
        [73, 48, 82, 79, 54, 111, 77, 120, 103, 110, 60, 80]),
}  # fmt: skip


def test_random12_guided_is_judged_against_the_person_drawn_not_one_timing():
    """random:12 guided failed bench live --quick on seeds 0-1 at -13 % (live 0.899 against the
    held file's 1.035; gyro 0.87-0.90 against 1.109).  The captures lose nothing: the file's
    samples cut at the captures' own window starts and reactions (:data:`CAPTURED_TIMING`)
    give the live figure (0.894).  The difference is the person's timing: the still samples
    after each window are integrated with the turn, and the held file at the mean timing is
    one draw of it (seed 0's gyro 1.386, its draws' mean about 1.14).  Against the draws'
    mean the row is within 10 %; the same stream with every error 1.3 times larger fails."""
    from dataclasses import replace

    from bench.live_table import make_row

    plan = live.LivePlan("random:12")
    hold = live.guided_hold_s(plan)
    jobs, worse = [], []
    for seed, (detect, reaction) in CAPTURED_TIMING.items():
        session, truth = live.simulated(plan, seed)
        streamed = live.held_as_guided(session, hold, reaction_s=np.array(reaction) / 100,
                                       detect_s=np.array(detect) / 100)  # fmt: skip
        graded = live._file_graded(plan, seed, streamed, truth)
        jobs.append(_Job(seed, graded))
        worse.append(_Job(seed, {k: replace(g, err=1.3 * g.err) for k, g in graded.items()}))
    seeds = sorted(CAPTURED_TIMING)
    held = live.file_reference(plan, seeds, hold)[0]
    draws = live.file_reference(plan, seeds, hold, live.PERSON_DRAWS)[0]
    assert all(len(draws[s]) == live.PERSON_DRAWS for s in seeds)
    rng = np.random.default_rng(0)
    one = make_row("random:12", "guided", jobs, held, rng, same_of=held)
    assert one.ratio < 0.90 and not one.ok, (one.ratio, one.why)  # the old pairing's FAIL
    row = make_row("random:12", "guided", jobs, held, rng, same_of=held, draws_of=draws)
    assert abs(row.ratio - 1) <= 0.10 and row.ok, (row.ratio, row.why)
    assert row.file_same > row.live  # the draws' mean, not the live figure
    bad = make_row("random:12", "guided", worse, held, rng, same_of=held, draws_of=draws)
    assert not bad.ok and bad.ratio > bad.band[1], (bad.ratio, bad.band)


def test_the_person_draws_cut_the_file_as_a_guided_capture_does():
    """Each draw's windows start within the capture's detection delays after each hold
    (the first at the stream's start), hold ``--hold`` s, and the still samples streamed
    after each window are the person's reaction plus the stream's latency; the draws differ;
    one timing per pose given as a list is the same as given once."""
    from bench import live_person, live_run

    session, _ = live.simulated(live.LivePlan("random:12"), 4)
    rate = session.sample_rate_hz
    cuts = live_person.person_draws(session, 2.0, 3, np.random.default_rng(1))
    lo_r, hi_r = (np.array(live_run.REACTION_S) + live_person.LATENCY_S) * rate
    lo_d, hi_d = np.array(live_person.DETECT_RANGE_S) * rate
    starts = []
    for cut in cuts:
        stills = cut.static_segments()
        assert [s.stop - s.start for s in stills] == [200] * 12
        assert stills[0].start == 0
        # streamed after a window: its reaction, the skipped rest, then the file's move
        for a, b, move in zip(stills[:-1], stills[1:], session.rotation_segments(),
                              strict=False):  # fmt: skip
            after = b.start - a.stop - (move.stop - move.start)
            assert lo_r + lo_d - 1 <= after <= hi_r + hi_d + 1, after
        starts.append([s.start for s in stills])
    assert starts[0] != starts[1]
    one = live.held_as_guided(session, 2.0, reaction_s=0.8, detect_s=0.17)
    each = live.held_as_guided(session, 2.0, reaction_s=[0.8] * 12, detect_s=[0.17] * 12)
    assert [(s.start, s.stop) for s in one.segments] == [(s.start, s.stop) for s in each.segments]
    assert np.array_equal(one.gyro, each.gyro)
