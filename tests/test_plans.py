"""The one plan registry (issue 9.4): capture, simulate (file and --serve) and the virtual device
know the same plans, a simulated session is the plan's steps, and a mounting reaches the file."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.capture.recorder import Recorder
from imucal_cli.capture.unattended import run_unattended
from imucal_cli.errors import ImucalError, InputError
from imucal_cli.formats.session import read_session
from imucal_cli.plans import BUILTIN_PLANS, PLANS, find_plan, load_plan, plan_help
from imucal_cli.simulate.device import stream_arrays
from imucal_cli.simulate.play import simulate_plan
from imucal_cli.simulate.served_lines import format_lines as _format
from imucal_cli.simulate.served_lines import line_columns as _columns
from tests.test_capture import ScriptedSource, proto

CREATED = "2026-01-01T00:00:00Z"

# One concrete name per registry entry (the arguments kept small: these run in every test).
EXAMPLES = {
    "six": "six",
    "qureshi18": "qureshi18",
    "random:N": "random:12",
    "ferraris": "ferraris",
    "gyro-axes": "gyro-axes",
    "hwangbo-iron": "hwangbo-iron",
    "hk-gyro": "hk-gyro",
    "hk-redundant": "hk-redundant",
    "qureshi-axes[:N]": "qureshi-axes:2",
    "free:N": "free:5",
    "still:MINUTES": "still:0.2",
    "warmup:MINUTES": "warmup:0.2",
}
FAST = {"hold_s": None, "still_s": 1.0}


def test_the_registry_names_every_plan_the_issue_lists():
    keys = {spec.key for spec in PLANS}
    wanted = {"six", "qureshi18", "random", "gyro-axes", "hwangbo-iron", "qureshi-axes", "free",
              "still"}  # fmt: skip
    assert wanted <= keys and set(EXAMPLES) == set(BUILTIN_PLANS)
    assert {spec.simulator for spec in PLANS} == {"poses", "rotations", "iron", "redundant",
                                                  "steps"}  # fmt: skip
    for name in BUILTIN_PLANS:
        assert name in plan_help()


@pytest.mark.parametrize("name", list(EXAMPLES.values()))
def test_a_simulated_session_is_the_plans_steps(name):
    """Every static and labelled rotation segment is a step of the plan, in plan order, with
    its attributes (up, axis, angle, mounting): what capture would have written."""
    plan = load_plan(name)
    session, truth = simulate_plan(name, seed=1, created=CREATED, **FAST)
    # the moves between poses are turns "turn to POSE" as a capture records them, no step
    turns = {s.label for s in plan.steps if s.kind == "rotation"}
    segments = [s for s in session.segments if s.kind == "static" or s.label in turns]
    moves = [s for s in session.segments if s not in segments]
    assert all(s.label.startswith("turn to ") and s.angle_deg is None for s in moves), moves
    assert len(segments) == len(plan.steps)
    for seg, step in zip(segments, plan.steps, strict=True):
        assert (seg.kind, seg.label, seg.angle_deg) == (step.kind, step.label, step.angle_deg)
        for a, b in ((seg.up, step.up), (seg.axis, step.axis)):
            assert (a is None) == (b is None) and (a is None or np.allclose(a, b))
        assert seg.extra.get("mounting") == step.mounting
    assert truth.plan.startswith(find_plan(name)[0].key)
    # the serve path streams exactly these samples
    t, a, g = stream_arrays(name, seed=1, rate_hz=None, **FAST)
    np.testing.assert_array_equal(a, session.accel)
    assert (g is None) == (session.gyro is None)


def test_plan_arguments_and_refusals():
    assert load_plan("qureshi-axes").name == "qureshi-axes"
    assert len(load_plan("qureshi-axes").rotation_steps) == 54
    assert len(load_plan("qureshi-axes:4").rotation_steps) == 12
    assert load_plan("random:009").name == "random:9"
    assert load_plan("still:0.5").steps[0].hold_s == 30.0
    for bad, words in (("free", "say how many"), ("six:2", "takes no argument"),
                       ("qureshi-axes:0", "between 2 and"),
                       ("free:4", "at least 5: the gyro's 12-parameter model needs 5 turns"),
                       ("qureshi-axes:1", "at least 2: 3 N turns"), ("random:x", "between 9 and"),
                       ("random:8", "at least 9: the gravity-magnitude model has 9 param"),
                       ("still:-1", "positive number"), ("seven", "is unknown")):  # fmt: skip
        with pytest.raises(InputError, match=words):
            load_plan(bad)
    with pytest.raises(InputError, match="disagree"):
        simulate_plan("qureshi-axes:3", rotations_per_axis=5)


def test_hwangbo_iron_is_the_faces_then_the_gyro_procedure_in_two_mountings():
    plan = load_plan("hwangbo-iron")
    assert [s.label for s in plan.steps[:6]] == [s.label for s in load_plan("six").steps]
    assert [s.label for s in plan.steps[6:]] == [s.label for s in load_plan("hk-gyro").steps]
    mounting2 = [s for s in plan.steps if s.mounting == 2]
    assert mounting2 and all(s.up is None for s in mounting2)  # not square to the iron
    assert all(s.mounting in (1, 2) for s in plan.steps)


def test_gyro_axes_turns_are_full_turns_on_the_table_about_each_face_normal():
    session, truth = simulate_plan("gyro-axes", seed=2, created=CREATED)
    turns = [s for s in session.rotation_segments() if s.angle_deg is not None]
    assert [s.angle_deg for s in turns] == [360.0] * 3
    # the moves between faces (from the still period after each turn) are turns too, as a
    # capture records them (no angle)
    assert [s.label for s in session.rotation_segments() if s.angle_deg is None] == [
        "turn to face +X up, against a ruler", "turn to face +Y up, against a ruler"]
    extra = truth.gyro
    np.testing.assert_allclose(extra.true_angle_deg, [360.0] * 3)
    # the true axis is the vertical of the placed unit: its labelled face normal within the
    # placement error (2 deg RMS), not exactly it
    cos = np.sum(np.array(extra.true_axis) * np.array([s.axis for s in turns]), axis=1)
    err = np.degrees(np.arccos(np.clip(np.abs(cos), 0.0, 1.0)))
    assert np.all(err < 8.0) and np.any(err > 0.01)
    w = truth.gyro.apply(session.gyro)  # calibrated rate integrates to the true rotation
    for seg, rv in zip(turns, extra.true_rotvec, strict=True):
        got = w[seg.start - 1 : seg.stop + 1].sum(axis=0) / session.sample_rate_hz
        np.testing.assert_allclose(got, rv, atol=0.02)


def test_unattended_capture_of_a_mounting_plan_stores_the_mounting(tmp_path):
    t, a, g = stream_arrays("hk-gyro", seed=3, rate_hz=100.0, hold_s=1.5, move_s=1.0)
    lines = _format(t, a, g, False, True)
    chunks = [b"".join(lines[i : i + 100]) for i in range(0, len(lines), 100)]
    rec = Recorder(tmp_path / "iron.h5", ScriptedSource(chunks), proto())
    summary = run_unattended(rec, load_plan("hk-gyro"))
    rec.close()
    assert summary.complete, summary.missing
    session = read_session(tmp_path / "iron.h5")
    labelled = [s for s in session.segments if s.label]
    steps = {st.label: st for st in load_plan("hk-gyro").steps}
    # mounting 1 by the data (directions, axes), mounting 2 by the order between them
    assert {s.extra.get("mounting") for s in labelled} == {1, 2}
    assert all(s.extra.get("mounting") == steps[s.label].mounting for s in labelled)
    assert len(labelled) == len(steps)
    ruler = [s for s in labelled if s.angle_deg == 90.0]
    assert len(ruler) == 1 and ruler[0].kind == "rotation"


def test_serve_formats_any_channels():
    t = np.arange(3) / 50.0
    assert _columns(np.zeros((3, 4)), None, True) == "t,ax,ay,az,a4,temp"
    line = _format(t, np.full((3, 4), 1023.0), None, False, True)[1]
    assert line == b"0.0200,1023,1023,1023,1023\n"


def test_simulate_command_writes_the_new_plans(tmp_path):
    from typer.testing import CliRunner

    from imucal_cli.cli import app

    for name in ("gyro-axes", "still:0.05", "hwangbo-iron"):
        out = tmp_path / f"{name.replace(':', '-')}.h5"
        res = CliRunner().invoke(app, ["simulate", "--plan", name, "-o", str(out)])
        assert res.exit_code == 0, res.output
        session = read_session(out)
        moves = [s for s in session.segments if s.label.startswith("turn to ")]
        assert len(session.segments) - len(moves) == len(load_plan(name).steps)


# Names each command must treat alike: every registry plan (with and without its argument,
# in other cases, with spaces), a TOML plan file, and the refusals.
SAME_NAMES = [*EXAMPLES.values(), "SIX", " qureshi18 ", "Random:5", "qureshi-axes", "still:1",
              "free", "six:2", "random:x", "random:0", "still:-1", "seven", "qureshi-axes:0",
              "missing.toml", "PLAN_FILE"]  # fmt: skip


def test_capture_and_simulate_accept_exactly_the_same_plan_names(tmp_path):
    """``capture --plan X`` (guided and --no-prompt) and ``simulate --plan X`` (file and
    --serve) accept the same names and refuse the others with the same message.  The output
    goes to a folder that does not exist, which every command checks after the plan: an
    accepted plan ends there, before any port is opened or any sample simulated."""
    from typer.testing import CliRunner

    from imucal_cli.cli import app

    plan_file = tmp_path / "mine.toml"
    plan_file.write_text('name = "mine"\n[[step]]\nkind = "static"\nlabel = "flat"\n'
                         'up = [0, 0, 1]\n')  # fmt: skip
    out = str(tmp_path / "no-such-folder" / "x.h5")
    commands = {
        "capture": ["capture", "--port", str(tmp_path / "no-port"), "-o", out],
        "capture --no-prompt": [
            "capture",
            "--port",
            str(tmp_path / "no-port"),
            "--no-prompt",
            "-o",
            out,
        ],  # fmt: skip
        "simulate": ["simulate", "-o", out],
    }
    accepted = {}
    for name in SAME_NAMES:
        name = str(plan_file) if name == "PLAN_FILE" else name
        errors = {}
        for what, args in commands.items():
            res = CliRunner().invoke(app, [*args, "--plan", name])
            assert isinstance(res.exception, ImucalError), (what, name, res.output)
            errors[what] = str(res.exception)
        refused = {what: "does not exist" not in e for what, e in errors.items()}
        assert len(set(refused.values())) == 1, (name, errors)
        if any(refused.values()):  # the same refusal, word for word
            assert len(set(errors.values())) == 1, (name, errors)
        accepted[name] = not any(refused.values())
    assert all(accepted[n] for n in EXAMPLES.values())
    assert accepted["SIX"] and accepted[str(plan_file)] and not accepted["seven"]
    # --serve takes the same path: the plan is checked before the pseudo-terminal opens
    res = CliRunner().invoke(app, ["simulate", "--serve", "--plan", "seven"])
    assert isinstance(res.exception, InputError) and "is unknown" in str(res.exception)
