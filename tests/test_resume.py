"""`imucal capture --resume SESSION` (issue 12.2): an interrupted capture goes on in the same
file; new samples follow the old ones, the plan's progress comes from the segments there."""

from __future__ import annotations

import os
import time

import h5py
import numpy as np
import pytest

from imucal_cli.capture.guided import GuidedOptions, GuidedState, ScriptedKeys, run_guided
from imucal_cli.capture.recorder import Recorder
from imucal_cli.capture.stream import LineProtocol
from imucal_cli.capture.unattended import run_unattended
from imucal_cli.formats.columns import ColumnSpec
from imucal_cli.formats.session import read_session
from imucal_cli.plans import load_plan

from .cli_helpers import assert_one_line_error, run
from .test_capture import ScriptedSource, lines_of


def _proto() -> LineProtocol:
    return LineProtocol(ColumnSpec.parse("t,ax,ay,az,gx,gy,gz"))


def _interrupted(path, chunks, stop_after: int, labels=("face +Z up", "face -Z up")):
    """A capture that got ``stop_after`` chunks, with a static segment per label, then stopped."""
    rec = Recorder(path, ScriptedSource(chunks[:stop_after], then="gone"), _proto())
    for _ in rec.blocks():
        pass
    per = rec.n_samples // (len(labels) + 1)
    for i, label in enumerate(labels):
        rec.add_segment("static", i * per, i * per + per // 2, label=label,
                        up=[0, 0, 1 if "+" in label else -1])  # fmt: skip
    rec.close()
    return rec.n_samples


def test_recorder_continues_a_session(tmp_path):
    chunks, n = lines_of()
    path = tmp_path / "r.h5"
    first = _interrupted(path, chunks, 10)
    before = read_session(path)
    os.utime(path, (time.time() - 3.0, time.time() - 3.0))  # stopped 3 s ago
    rec = Recorder(path, ScriptedSource(chunks[:8], then="gone"), _proto(), resume=True)
    assert rec.resumed_from == first and rec.n_samples == first
    got = sum(len(b) for b in rec.blocks())
    rec.add_segment("static", first + 10, first + 60, label="face +X up", up=[1, 0, 0])
    rec.close()
    s = read_session(path)
    assert len(s.time) == first + got and rec.n_samples == first + got
    np.testing.assert_array_equal(s.accel[:first], before.accel)  # the old samples, untouched
    assert np.all(np.diff(s.time) > 0)  # the device clock restarted: shifted after the old ones
    gap = s.time[first] - s.time[first - 1]
    assert 2.5 < gap < 10  # about the time the capture was stopped
    # the host's arrival times (/raw/host_time) go on too, after the same gap
    assert s.host_time is not None and len(s.host_time) == len(s.time)
    np.testing.assert_array_equal(s.host_time[:first], before.host_time)
    assert np.all(np.diff(s.host_time) >= 0)  # arrival per block: non-decreasing
    assert 2.5 < s.host_time[first] - s.host_time[first - 1] < 10
    assert [x.label for x in s.segments] == ["face +Z up", "face -Z up", "face +X up"]
    with h5py.File(path) as f:
        assert f.attrs["resumed"] == 1 and "capture_log" not in f


def test_resume_refuses_a_session_not_written_by_a_capture(tmp_path):
    """Another tool's session (fixed-size datasets, as the spec allows) cannot grow."""
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": "imucal-session", "format_version": 1,
                        "created": "2026-01-01T00:00:00Z"})  # fmt: skip
        f["raw/time"] = np.arange(50) / 100.0
        f["raw/accel"] = np.ones((50, 3))
        f.create_group("segments")
    assert len(read_session(path).time) == 50
    with pytest.raises(Exception, match="cannot be continued"):
        Recorder(path, ScriptedSource([]), _proto(), resume=True)


def test_guided_state_takes_the_progress_from_the_segments():
    from .test_guided import FACES

    state = GuidedState(load_plan("six"), GuidedOptions(accel_units="counts"), 500,
                        lambda *a, **k: None)  # fmt: skip
    mean_up = {"face +Z up": [0, 0, 8192.0], "face -Z up": [0, 0, -8192.0]}
    state.resume([("static", k, np.array(v)) for k, v in mean_up.items()]
                 + [("rotation", "turn to face -Z up", None)])  # fmt: skip
    assert state.status[:2] == ["done", "done"] and state.prompt().step == 2
    told = " ".join(m.text for m in state.drain())
    assert "resumed: 2 of 6 steps already in the session" in told and "face +X up" in told
    # a pose near one already in the file is refused, as if it had been taken in this run
    index, refusal = state_match(state, FACES["face +Z up"])
    assert refusal is not None and "too close to face +Z up" in refusal
    summary = state.summary(type("R", (), {"n_samples": 500, "end_reason": "", "stats": {}})())
    assert summary.done == ["face +Z up", "face -Z up"] and len(summary.missing) == 4


def state_match(state, up):
    from imucal_cli.capture.guided.matching import match_hold

    return match_hold(np.asarray(up, float), state.current(), state.candidates(), state.steps,
                      state.taken_poses(), min_separation_deg=15.0, match_tolerance_deg=20.0,
                      is_pose=state.is_pose)  # fmt: skip


def test_guided_capture_resumed_records_only_the_steps_left(tmp_path):
    """The stream shows every face again; the faces already in the file are refused, the
    others recorded after the old samples; the session ends complete."""
    from .test_guided import FACES, FakeRecorder, _console, poses

    stream = poses([FACES[k] for k in ("face +Z up", "face +X up", "face -Z up")])
    rec = FakeRecorder(stream)
    rec._n = 0
    plan = load_plan("six")
    done = [("static", "face +Z up", stream.truth.accel_raw(np.array([[0, 0, 9.8]]), 0)[0]),
            ("static", "face -X up", None), ("static", "face +Y up", None),
            ("static", "face -Y up", None)]  # fmt: skip
    summary = run_guided(rec, plan, console=_console(), keys=ScriptedKeys([]), done_before=done)
    assert summary.complete, summary
    assert [s["label"] for s in rec.segments if s["kind"] == "static"] == [
        "face +X up",
        "face -Z up",
    ]
    assert sorted(summary.done) == sorted(f"face {s}{a} up" for a in "XYZ" for s in "+-")


def test_unattended_resume_looks_only_for_the_steps_left(tmp_path):
    chunks, _ = lines_of(plan="six", hold=2.0, move=1.5)
    path = tmp_path / "u.h5"
    first = _interrupted(path, chunks, 4, labels=("face +Z up",))
    rec = Recorder(path, ScriptedSource(chunks, then="gone"), _proto(), resume=True)
    summary = run_unattended(rec, load_plan("six"), done_before=["face +Z up"])
    rec.close()
    s = read_session(path)
    assert summary.complete and summary.done[0] == "face +Z up", summary
    labels = [x.label for x in s.segments if x.kind == "static" and x.label]
    assert labels == ["face +Z up", "face -Z up", "face +X up", "face -X up", "face +Y up",
                      "face -Y up"]  # the +Z shown again is not taken twice  # fmt: skip
    assert all(x.start >= first for x in s.segments[1:])  # the new ones follow the old samples


def test_cli_resume_refusals(tmp_path):
    proc = run("capture", "--port", "/dev/null-x", "--resume", tmp_path / "none.h5")
    assert_one_line_error(proc, "no such session to resume")
    (tmp_path / "s.h5").write_bytes(b"")
    proc = run("capture", "--port", "/dev/null-x", "--resume", tmp_path / "s.h5", "--force")
    assert_one_line_error(proc, "--resume keeps what SESSION holds")
    proc = run("capture", "--port", "/dev/null-x", "-o", tmp_path / "s.h5")
    assert_one_line_error(proc, "--resume")  # the advice for an existing file names --resume


def test_unattended_resume_of_unlabelled_poses_counts_the_poses_recorded(tmp_path):
    """``random:N`` unattended: its poses are counted, not identified, so the first capture
    leaves its still periods unlabelled; resumed, each of them fills a pose, and only the
    poses left are looked for (before: the whole plan again, every pose recorded twice)."""
    from imucal_cli.cli.capture import _done_before

    chunks, _ = lines_of(plan="random:9", hold=2.0, move=1.5)
    path = tmp_path / "r.h5"
    cut = len(chunks) // 2
    rec = Recorder(path, ScriptedSource(chunks[:cut], then="gone"), _proto())
    first = run_unattended(rec, load_plan("random:9"))
    rec.close()
    n_first = sum(1 for x in read_session(path).segments if x.kind == "static")
    assert 2 <= n_first < 9 and not first.complete
    before = _done_before(path, guided=False)
    assert before == [None] * n_first  # counted poses, no labels
    said = []
    rec = Recorder(path, ScriptedSource(chunks[cut:], then="gone"), _proto(), resume=True)
    summary = run_unattended(rec, load_plan("random:9"), done_before=before,
                             on_status=said.append)  # fmt: skip
    rec.close()
    assert f"resumed: {n_first} steps already in the session, {9 - n_first} left" in said
    assert summary.complete and len(summary.done) == 9, summary
    assert summary.done == [f"pose {k}" for k in range(1, 10)]
    statics = [x for x in read_session(path).segments if x.kind == "static"]
    assert len(statics) >= 9 and all(x.label is None for x in statics[:n_first])
