"""Guided capture: a fake recorder plays a simulated stream block by block (no real time),
scripted keys stand in for the person."""

from __future__ import annotations

import io
import re
from dataclasses import replace

import numpy as np
import pytest
from rich.console import Console
from scipy.spatial.transform import Rotation

from imucal_cli.capture.guided import (
    GuidedOptions,
    GuidedState,
    ScriptedKeys,
    StdinKeys,
    estimate_direction,
    instruction,
    parse_command,
    run_guided,
)
from imucal_cli.formats.columns import SampleBlock
from imucal_cli.plans import Plan, Step, load_plan
from imucal_cli.simulate.triad import G0, random_imu

RATE = 100.0
GYRO_SCALE = 16.4 * 180.0 / np.pi  # counts per rad/s, nominal


# --------------------------------------------------------------------------------------------
# A stream with poses in any order
# --------------------------------------------------------------------------------------------


def _orientation(up, heading: float) -> Rotation:
    """Body -> world rotation that puts body vector ``up`` on world +Z, then a heading."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    ez = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, ez)
    s, c = np.linalg.norm(axis), float(up @ ez)
    if s < 1e-12:
        base = Rotation.identity() if c > 0 else Rotation.from_rotvec([np.pi, 0.0, 0.0])
    else:
        base = Rotation.from_rotvec(axis / s * np.arctan2(s, c))
    return Rotation.from_rotvec([0.0, 0.0, heading]) * base


class Stream:
    """Holds (orientation, seconds) joined by smooth turns of ``move_s``; raw counts."""

    def __init__(self, holds, *, seed=0, move_s=1.5, rate_hz=RATE):
        rng = np.random.default_rng(seed)
        self.truth = random_imu(rng, "counts")
        force, rate, self.holds, self.moves = [], [], [], []
        n = 0
        for k, (orient, hold_s) in enumerate(holds):
            m = int(round(hold_s * rate_hz))
            up = orient.inv().apply([0.0, 0.0, 1.0])
            force.append(np.tile(G0 * up, (m, 1)))
            rate.append(np.zeros((m, 3)))
            self.holds.append((n, n + m, up))
            n += m
            if k + 1 == len(holds):
                break
            nxt = holds[k + 1][0]
            rv = (orient.inv() * nxt).as_rotvec()
            nm = int(round(move_s * rate_hz))
            dur = (nm + 1) / rate_hz
            tau = np.arange(1, nm + 1) / (nm + 1)
            s = tau**3 * (10 - 15 * tau + 6 * tau**2)
            ds = 30 * tau**2 * (1 - tau) ** 2 / dur
            att = orient * Rotation.from_rotvec(s[:, None] * rv)
            force.append(att.inv().apply(np.tile([0.0, 0.0, G0], (nm, 1))))
            rate.append(ds[:, None] * rv)
            self.moves.append((n, n + nm, rv))
            n += nm
        force, rate = np.vstack(force), np.vstack(rate)
        noise = np.random.default_rng(seed + 1000)
        self.time = np.arange(n) / rate_hz
        self.accel = self.truth.accel_raw(force, noise.standard_normal((n, 3)) * 0.01)
        self.gyro = self.truth.gyro_raw(rate, noise.standard_normal((n, 3)) * 0.005)

    def hold_containing(self, start, stop):
        for a, b, up in self.holds:
            if a <= start and stop <= b:
                return a, b, up
        return None


def poses(ups, hold_s=3.0, seed=0, lead_s=1.0):
    """A stream holding each face of ``ups`` in turn (the first one ``lead_s`` longer)."""
    rng = np.random.default_rng(seed + 7)
    holds = [
        (_orientation(u, rng.uniform(0, 2 * np.pi)), hold_s + (lead_s if i == 0 else 0.0))
        for i, u in enumerate(ups)
    ]
    return Stream(holds, seed=seed)


class FakeRecorder:
    """Plays a stream block by block, records segments like the real recorder (time order)."""

    def __init__(self, stream: Stream, block: int = 10, units=("counts", "counts")):
        self.s = stream
        self.block = block
        self._n = 0
        self._stop = False
        self.segments: list[dict] = []
        self.accel_units, self.gyro_units = units
        self.end_reason = ""
        self.end_kind = None
        self.stats = {"lines": 0}

    @property
    def n_samples(self) -> int:
        return self._n

    def blocks(self, tick_s: float = 0.1):
        n = len(self.s.time)
        for i in range(0, n, self.block):
            if self._stop:
                self.end_kind, self.end_reason = "done", "done"
                return
            j = min(i + self.block, n)
            self._n = j
            self.stats["lines"] = j
            yield SampleBlock(self.s.time[i:j], self.s.accel[i:j], self.s.gyro[i:j])
            yield SampleBlock.empty()
        self.end_kind, self.end_reason = "device-gone", "the device is gone"

    def add_segment(self, kind, start, stop, *, label=None, up=None, axis=None, angle_deg=None):
        assert 0 <= start < stop <= self._n
        if self.segments:
            assert start >= self.segments[-1]["start"], "segments must come in time order"
        self.segments.append(
            dict(
                kind=kind,
                start=start,
                stop=stop,
                label=label,
                up=up,
                axis=axis,
                angle_deg=angle_deg,
            )  # fmt: skip
        )
        return f"{len(self.segments) - 1:04d}"

    def stop(self) -> None:
        self._stop = True


def _console():
    return Console(record=True, width=140, file=io.StringIO(), force_terminal=False)


E = np.eye(3)
FACES = {
    f"face {s}{a} up": sign * E[i] for i, a in enumerate("XYZ") for s, sign in (("+", 1), ("-", -1))
}  # noqa: E501


def _check_statics(rec, stream, hold_s=2.0):
    """Every static segment lies inside a true hold, lasts hold_s and has the right label."""
    statics = [s for s in rec.segments if s["kind"] == "static"]
    for seg in statics:
        hit = stream.hold_containing(seg["start"], seg["stop"])
        assert hit is not None, seg
        assert seg["stop"] - seg["start"] == int(round(hold_s * RATE))
        assert np.allclose(seg["up"], FACES[seg["label"]])
        assert np.degrees(np.arccos(np.clip(hit[2] @ seg["up"], -1, 1))) < 5.0
    return statics


# --------------------------------------------------------------------------------------------
# Tests
# --------------------------------------------------------------------------------------------


def test_six_in_shuffled_order():
    order = ["face -Y up", "face +Z up", "face +X up", "face -Z up", "face -X up", "face +Y up"]
    stream = poses([FACES[k] for k in order])
    rec, console = FakeRecorder(stream), _console()
    summary = run_guided(rec, load_plan("six"), console=console, keys=ScriptedKeys([]))
    assert summary.complete and summary.missing == [] and summary.skipped == []
    assert summary.done == order
    statics = _check_statics(rec, stream)
    assert [s["label"] for s in statics] == order
    out = console.export_text()
    assert "Put face +Z up and hold still" in out and "Put face -X up and hold still" in out
    assert "left: " in out and "left: nothing" in out
    assert "recorded face -Y up" in out and "(1 of 6)" in out
    assert "coverage:" in out and "largest gap" in out
    assert "noise learned" in out
    assert len(out.splitlines()) < 80  # plain output: no line per block
    assert summary.end_reason.startswith("every step")
    assert rec._stop


def test_repeated_pose_is_refused():
    order = ["face +Z up", "face -Z up", "face +Z up", "face +X up"]
    stream = poses([FACES[k] for k in order])
    rec, console = FakeRecorder(stream), _console()
    summary = run_guided(rec, load_plan("six"), console=console, keys=ScriptedKeys([]))
    out = console.export_text()
    assert "too close to face +Z up, already taken" in out
    assert summary.done == ["face +Z up", "face -Z up", "face +X up"]
    assert not summary.complete
    assert set(summary.missing) == {"face -X up", "face +Y up", "face -Y up"}
    assert summary.end_reason == "the device is gone"
    _check_statics(rec, stream)


def test_hold_interrupted_by_motion_restarts_with_a_warning():
    rng = np.random.default_rng(3)
    a = _orientation(FACES["face +Z up"], 0.3)
    b = _orientation(FACES["face +X up"], 1.0)
    wiggle = b * Rotation.from_rotvec([0.0, 0.35, 0.0])
    del rng
    holds = [(a, 4.0), (b, 1.2), (wiggle, 0.0), (b, 3.0)]
    stream = Stream(holds, move_s=0.6)
    rec, console = FakeRecorder(stream), _console()
    summary = run_guided(rec, load_plan("six"), console=console, keys=ScriptedKeys([]))
    out = console.export_text()
    assert "the unit moved during the hold: hold it again" in out
    assert summary.done == ["face +Z up", "face +X up"]
    statics = _check_statics(rec, stream)
    last_hold = stream.holds[-1]
    assert statics[-1]["start"] >= last_hold[0]


def test_skip_redo_quit():
    order = ["face +X up", "face -Z up", "face -Z up", "face +Y up", "face -Y up"]
    stream = poses([FACES[k] for k in order])
    rec = FakeRecorder(stream)
    console = _console()
    h = stream.holds
    redo_at = (h[1][1] + h[2][0]) // 2  # while turning between the two -Z holds
    quit_at = h[4][0] + 50  # before the -Y hold is complete
    keys = ScriptedKeys(
        ["s", (redo_at, "r"), (quit_at, "q")], n_samples=lambda: rec.n_samples
    )  # s skips the current step, face +Z up
    summary = run_guided(rec, load_plan("six"), console=console, keys=keys)
    out = console.export_text()
    assert keys.released == ["s", "r", "q"]
    assert "skipped face +Z up" in out
    assert "redo: face -Z up removed" in out
    assert summary.skipped == ["face +Z up"]
    assert summary.done == ["face +X up", "face -Z up", "face +Y up"]
    assert set(summary.missing) == {"face -X up", "face -Y up"}
    assert not summary.complete
    assert summary.end_reason == "finished by the person (q)"
    statics = _check_statics(rec, stream)
    # the first -Z hold was dropped: the saved one is the second
    minus_z = [s for s in statics if s["label"] == "face -Z up"]
    assert len(minus_z) == 1 and minus_z[0]["start"] >= h[2][0]
    assert summary.samples == rec.n_samples < len(stream.time)


def test_pick_a_step_and_unknown_command():
    stream = poses([FACES["face -X up"], FACES["face +Y up"]])
    rec, console = FakeRecorder(stream), _console()
    keys = ScriptedKeys(["face -x", "nonsense", "1"])
    summary = run_guided(rec, load_plan("six"), console=console, keys=keys)
    out = console.export_text()
    assert "next: face -X up" in out
    assert "unknown command 'nonsense'" in out
    assert summary.done == ["face -X up", "face +Y up"]


def test_rotation_steps_are_labelled_with_axis_and_angle():
    plan = Plan(
        "turns",
        (
            Step("static", "face +Z up", up=E[2]),
            Step("rotation", "turn about +X", axis=E[0], angle_deg=90.0),
            Step("static", "face +Y up", up=E[1]),
            Step("rotation", "turn about +Y", axis=E[1]),
            Step("static", "hold still after the turns"),
        ),
    )
    r0 = _orientation(E[2], 0.4)
    r1 = r0 * Rotation.from_rotvec([np.pi / 2, 0, 0])
    r2 = r1 * Rotation.from_rotvec([0, -np.pi / 3, 0])
    stream = Stream([(r0, 4.0), (r1, 3.0), (r2, 3.0)])
    rec, console = FakeRecorder(stream), _console()
    summary = run_guided(rec, plan, console=console, keys=ScriptedKeys([]), gyro_scale=GYRO_SCALE)
    out = console.export_text()
    assert summary.complete, out
    assert "Turn about +X by 90 degrees, then hold still" in out
    kinds = [s["kind"] for s in rec.segments]
    assert kinds == ["static", "rotation", "static", "rotation", "static"]
    for seg, (a, b, _) in zip(
        [s for s in rec.segments if s["kind"] == "rotation"], stream.moves, strict=True
    ):
        assert a - 3 <= seg["start"] <= a + 20 and b - 20 <= seg["stop"] <= b + 3, (seg, a, b)
    turn_x, turn_y = rec.segments[1], rec.segments[3]
    assert np.allclose(turn_x["axis"], E[0]) and turn_x["angle_deg"] == 90.0
    assert turn_x["label"] == "turn about +X"
    assert np.allclose(turn_y["axis"], E[1]) and turn_y["angle_deg"] is None
    assert "deg measured" in out
    measured = [float(w) for w in __import__("re").findall(r"(\d+) deg measured", out)]
    assert abs(measured[0] - 90) < 5 and abs(measured[1] - 60) < 5
    # the static steps around the turns are inside the true holds
    assert rec.segments[2]["label"] == "face +Y up"
    assert stream.hold_containing(rec.segments[2]["start"], rec.segments[2]["stop"])
    assert stream.hold_containing(rec.segments[4]["start"], rec.segments[4]["stop"])


def test_terminal_mode_renders_live():
    stream = poses([FACES["face +Z up"], FACES["face -Z up"]], hold_s=2.5)
    rec = FakeRecorder(stream)
    buf = io.StringIO()
    console = Console(file=buf, force_terminal=True, width=120, record=True)
    summary = run_guided(
        rec, load_plan("six"), console=console, keys=ScriptedKeys([]), refresh_hz=1000
    )
    out = console.export_text()
    assert summary.done == ["face +Z up", "face -Z up"]
    assert "STILL" in out and "MOVING" in out
    assert "recorded face -Z up" in out


def test_last_live_frame_is_erased_before_the_summary():
    """In a terminal the live view goes when the capture ends (issue 12): the summary printed
    next is not under a stale frame."""
    stream = poses([FACES["face +Z up"], FACES["face -Z up"]], hold_s=2.5)
    buf = io.StringIO()
    console = Console(file=buf, force_terminal=True, width=120)
    run_guided(FakeRecorder(stream), load_plan("six"), console=console, keys=ScriptedKeys([]),
               refresh_hz=1000)  # fmt: skip
    console.print("SUMMARY")
    raw = buf.getvalue()
    stop = raw.rindex("\x1b[?25h")  # the live view stops (the cursor comes back)
    frame = raw[:stop].split("\x1b[2K")[-1]  # the last frame drawn
    assert "commands:" in frame and frame.count("\n") >= 2
    erase = "\r" + "\x1b[1A\x1b[2K" * frame.count("\n")
    assert raw[stop:].startswith("\x1b[?25h" + erase), repr(raw[stop : stop + 80])
    assert "commands:" not in raw[stop:] and raw.rstrip().endswith("SUMMARY")


def test_parse_command_and_keys():
    plan = load_plan("six")
    assert parse_command("", plan).action == "continue"
    assert parse_command(" R ", plan).action == "redo"
    assert parse_command("skip", plan).action == "skip"
    assert parse_command("q", plan).action == "quit"
    assert parse_command("3", plan).step == 2
    assert parse_command("99", plan).action == "unknown"
    assert parse_command("face -y up", plan).step == 5
    assert parse_command("face", plan).action == "unknown"  # ambiguous
    keys = StdinKeys(io.StringIO("r\n\nface +Z up\n"))
    keys._thread.join(timeout=5)
    assert [keys.get(), keys.get(), keys.get(), keys.get()] == ["r", "", "face +Z up", None]
    n = [0]
    scripted = ScriptedKeys(["a", (5, "b"), (lambda: True, "c")], n_samples=lambda: n[0])
    assert scripted.get() == "a" and scripted.get() is None
    n[0] = 5
    assert scripted.get() == "b" and scripted.get() == "c" and scripted.get() is None


def test_instruction_words():
    plan = load_plan("qureshi18")
    assert instruction(plan.steps[0]) == "Put face +Z up and hold still"
    assert instruction(plan.steps[6]).startswith("Put edge ")
    iron = load_plan("hwangbo-iron")
    ruler = next(s for s in iron.steps if s.angle_deg == 90.0)
    assert instruction(ruler) == "Turn about +Z by 90 degrees, then hold still"
    axes = load_plan("gyro-axes")
    assert instruction(axes.steps[1]) == "Turn about +Z by 360 degrees, then hold still"
    assert "new orientation" in instruction(load_plan("random:9").steps[0])


def test_estimate_direction():
    d = estimate_direction(np.array([10.0, -20.0, 8200.0]), "counts")
    assert np.allclose(d, [0, 0, 1], atol=0.01)
    # unsigned 12-bit ADC, +-2 g: mid-scale 2048, 512 counts per g
    d = estimate_direction(np.array([2048.0, 2048.0 - 512, 2050.0]), "counts", data_min=1500)
    assert np.allclose(d, [0, -1, 0], atol=0.01)
    assert estimate_direction(np.array([1.6, 1.65, 1.9]), "V") is None
    d = estimate_direction(np.array([1.65, 1.65, 1.95]), "V", nominal_bias=1.65)
    assert np.allclose(d, [0, 0, 1])
    assert estimate_direction(np.ones(4), "counts") is None
    m = np.array([[1.0, -1.0, 0, 0], [0, 0, 1.0, -1.0], [1.0, 1.0, 1.0, 1.0]])
    d = estimate_direction(np.array([1.0, 1.0, 1.0, 1.0]), "g", nominal_scale=m)
    assert np.allclose(d, [0, 0, 1])


@pytest.mark.parametrize("block", [1, 37])
def test_block_sizes(block):
    order = ["face +Y up", "face -X up"]
    stream = poses([FACES[k] for k in order])
    rec = FakeRecorder(stream, block=block)
    summary = run_guided(rec, load_plan("six"), console=_console(), keys=ScriptedKeys([]))
    assert summary.done == order
    _check_statics(rec, stream)


# --------------------------------------------------------------------------------------------
# The state machine alone: blocks and commands in, prompts, messages and segments out
# --------------------------------------------------------------------------------------------


def test_state_machine_without_a_screen():

    order = ["face +Z up", "face -Y up"]
    stream = poses([FACES[k] for k in order])
    segments = []
    state = GuidedState(
        Plan("two", [Step("static", k, up=FACES[k]) for k in order]),
        GuidedOptions(accel_units="counts"),
        0,
        lambda kind, start, stop, **kw: segments.append((kind, start, stop, kw["label"])),
    )
    first = state.prompt()
    assert (first.step, first.phase, first.n_steps) == (0, "wait", 2)
    assert "Put face +Z up and hold still" in first.text
    phases, told = [], []
    for i in range(0, len(stream.time), 10):
        state.on_block(SampleBlock(*(x[i : i + 10] for x in (stream.time, stream.accel,
                                                             stream.gyro))))  # fmt: skip
        p = state.prompt()
        if not phases or phases[-1] != p.phase:
            phases.append(p.phase)
        if p.phase == "hold":
            assert 0.0 <= p.held_s <= p.hold_s == 2.0
        told += [m.text for m in state.drain()]
        if state.end_reason:
            break
    assert phases[:3] == ["wait", "hold", "move"] and phases[-1] == "done"
    assert any(t.startswith("recorded face +Z up") for t in told)
    assert any(t.startswith("noise learned") for t in told)
    summary = state.summary(FakeRecorder(stream))
    assert summary.complete and summary.done == order
    # the last pose stays pending (redo-able) until the end: segments arrive in time order
    assert [s[0] for s in segments if s[0] == "static"] == ["static", "static"]
    assert [s[3] for s in segments if s[0] == "static"] == order


def test_state_machine_redo_and_skip_by_command():

    state = GuidedState(load_plan("six"), GuidedOptions(), 0, lambda *a, **k: None)
    state.on_command("s")
    assert state.status[0] == "skipped" and state.prompt().step == 1
    state.on_command("r")
    assert "nothing to redo" in state.drain()[-1].text
    serial = state.prompt().serial
    state.on_command("3")
    assert state.prompt().step == 2 and state.prompt().serial == serial
    state.on_command("q")
    assert state.end_reason.startswith("finished by the person")


# --------------------------------------------------------------------------------------------
# Turns between poses, how long to hold, countdown (issue 12.3)
# --------------------------------------------------------------------------------------------


def test_turns_between_poses_are_rotation_segments():
    order = ["face +Z up", "face -Y up", "face +X up"]
    stream = poses([FACES[k] for k in order])
    rec = FakeRecorder(stream)
    summary = run_guided(rec, load_plan("six"), console=_console(), keys=ScriptedKeys([]))
    assert summary.done == order
    kinds = [s["kind"] for s in rec.segments]
    assert kinds == ["static", "rotation", "static", "rotation", "static"]
    turns = [s for s in rec.segments if s["kind"] == "rotation"]
    for i, (seg, (a, b, _)) in enumerate(zip(turns, stream.moves, strict=True)):
        assert seg["label"] == f"turn to {order[i + 1]}"
        # the segment holds the whole motion (the detector's windows widen it a little)
        assert seg["start"] <= a and b <= seg["stop"] and seg["stop"] - seg["start"] < 2 * (b - a)
        assert seg["axis"] is None and seg["angle_deg"] is None  # not known: nothing claimed
    _check_statics(rec, stream)


def test_redo_keeps_the_turn_into_the_pose_taken_again():
    order = ["face +Z up", "face -Z up", "face -Z up", "face +X up"]
    stream = poses([FACES[k] for k in order], hold_s=3.0)
    rec = FakeRecorder(stream)
    second = stream.holds[1][0]
    keys = ScriptedKeys([(second + 280, "r")], n_samples=lambda: rec.n_samples)
    run_guided(rec, load_plan("six"), console=_console(), keys=keys)
    turns = [s for s in rec.segments if s["kind"] == "rotation"]
    statics = [s for s in rec.segments if s["kind"] == "static"]
    assert [s["label"] for s in statics][:3] == ["face +Z up", "face -Z up", "face +X up"]
    # the turn into -Z starts where the unit left +Z, though -Z was redone after a re-seat
    assert turns[0]["label"] == "turn to face -Z up"
    assert turns[0]["start"] <= stream.moves[0][0] and turns[0]["stop"] <= statics[1]["start"]
    assert statics[1]["start"] >= stream.holds[2][0]  # the redone hold is the second seat


def test_screen_says_how_long_to_hold_and_counts_down():
    from imucal_cli.capture.guided.screen import countdown_tick

    stream = poses([FACES["face +Z up"], FACES["face -X up"]], hold_s=3.0)
    console = _console()
    plan = Plan("two", [Step("static", k, up=FACES[k]) for k in ("face +Z up", "face -X up")])
    run_guided(FakeRecorder(stream), plan, console=console, keys=ScriptedKeys([]), hold_s=2.5)
    out = console.export_text()
    assert "plan two: 2 poses; hold each pose still 2.5 s" in out and "5 s of holding" in out
    assert out.count("Put face +Z up and hold still for 2.5 s") == 1  # the first prompt once
    assert "still: holding 2.5 s ..." in out and "  2 s left" in out and "  1 s left" in out
    assert [countdown_tick(x, 2.5) for x in (2.5, 2.2, 1.5, 0.4, 0.0)] == [None, None, 2, 1, None]
    assert [countdown_tick(x, 600) for x in (599, 300.5, 59)] == [None, 360, 60]


def test_a_warm_up_is_held_two_minutes_without_a_false_restart():
    """Issue 24.1 (bench live, warm-up guided): the 2-minute hold of ``warmup:2`` is 1,900
    windows; at the 2-s hold's false-alarm rate per window, the served warm-up of seed 0 was
    called moving twice (at 91 s and 151 s) and its hold restarted.  A plan with longer holds
    tests each window at a smaller false-alarm rate: held from the first sample, no restart
    (the windows are judged on a grid whatever the blocks: tests/test_stillness.py)."""
    from imucal_cli.simulate.play import simulate_plan
    from imucal_cli.simulate.temperature import parse_ramp

    plan = load_plan("warmup:2")
    s, _ = simulate_plan("warmup:2", seed=0, temperature=parse_ramp("5:40"))
    rec, console = FakeRecorder(s), _console()
    summary = run_guided(rec, plan, console=console, keys=ScriptedKeys([]))
    out = console.export_text()
    assert summary.complete and "moved during the hold" not in out
    (seg,) = rec.segments
    assert seg["start"] == 0 and seg["stop"] == 12000  # 120 s at 100 Hz
    assert re.search(r"false alarm\s+1\.66667e-06\s+per window", out)  # 1e-4 x 2 s / 120 s


def test_options_have_one_set_of_defaults_and_a_wrong_name_is_refused():
    """``run_guided`` takes :class:`GuidedOptions` (and any of its fields by name), so its
    defaults are the dataclass's, never a second copy that can drift; a misspelt option is a
    TypeError, not silently ignored; units left unset become the recorder's."""
    stream = poses([FACES[k] for k in ["face +Z up", "face -Z up"]])
    with pytest.raises(TypeError, match="hold_sec"):
        run_guided(FakeRecorder(stream), load_plan("six"), console=_console(),
                   keys=ScriptedKeys([]), hold_sec=3.0)  # fmt: skip
    seen = {}

    class Spy(GuidedState):
        def __init__(self, plan, opt, *args):
            seen["opt"] = opt
            super().__init__(plan, opt, *args)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("imucal_cli.capture.guided.GuidedState", Spy)
        run_guided(FakeRecorder(stream, units=("g", "deg/s")), load_plan("six"),
                   console=_console(), keys=ScriptedKeys(["q"]),
                   options=GuidedOptions(settle_s=0.7), hold_s=3)  # fmt: skip
    opt = seen["opt"]
    expected = replace(GuidedOptions(), settle_s=0.7, hold_s=3.0, accel_units="g",
                       gyro_units="deg/s")  # fmt: skip
    assert opt == expected and isinstance(opt.hold_s, float)


def test_a_knock_after_a_pose_does_not_start_the_turn_inside_its_window():
    """A knock (or a false alarm) just after a pose is taken ends the still run at the start
    of the detector's first moving window, which can begin inside the pose's window: the turn
    into the next pose then started there, overlapping the pose (bench live, random:12 seed
    5 guided: 15 samples), and calibrate skipped that turn as having no still period ending
    before it.  The turn starts where the pose's window ends; every knock 0-40 samples after
    the window (the detector's 25-sample windows straddle it for some)."""
    order = ["face +Z up", "face -Y up", "face +X up"]
    rec = FakeRecorder(poses([FACES[k] for k in order]))
    run_guided(rec, load_plan("six"), console=_console(), keys=ScriptedKeys([]))
    stop = rec.segments[0]["stop"]
    straddled = 0
    for off in range(0, 41, 3):
        stream = poses([FACES[k] for k in order])
        stream.gyro[stop + off : stop + off + 2] += 400  # two samples of a knock
        rec = FakeRecorder(stream)
        run_guided(rec, load_plan("six"), console=_console(), keys=ScriptedKeys([]))
        segs = rec.segments
        for a, b in zip(segs, segs[1:], strict=False):
            if a["kind"] == "static" and b["kind"] == "rotation":
                assert b["start"] >= a["stop"], (off, a, b)
                straddled += b["start"] == a["stop"] == stop
    assert straddled >= 3  # the knocks that ended the run inside the window now start there
