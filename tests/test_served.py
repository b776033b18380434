"""tests/served.py serves the virtual device in a thread with the keywords
``imucal simulate --serve ARGS`` gives :func:`serve`: what the thread sets is what the command
sets, and what it leaves out the command leaves at :func:`serve`'s and ``simulate_plan``'s
defaults (so the two cannot drift apart unseen)."""

from __future__ import annotations

import inspect

import pytest

from imucal_cli.cli import simulate as command
from imucal_cli.simulate.device import ServeResult, serve
from imucal_cli.simulate.play import simulate_plan

from .cli_helpers import run
from .served import serve_options

ARGS = [
    [],
    ["--plan", "six", "--rate", "200", "--hold", "1.5", "--move", "0.8", "--malformed-every",
     "97"],
    ["--garbage", "--vanish-after", "2"],
    ["--plan", "six", "--loop", "--stall-after", "0", "--baud", "460800", "--protocol",
     "motioncal", "--seed", "3", "--no-temp", "--duration", "5"],
    ["--plan", "random:9", "--imus", "3", "--serve-imu", "1", "--imu-offset", "8", "--baud",
     "460800"],
    ["--plan", "six", "--imus", "2", "--imu-rotation", "3"],
]  # fmt: skip
CALLBACKS = {"announce", "status", "next_pose", "plan_options"}


def _defaults(function) -> dict:
    return {k: p.default for k, p in inspect.signature(function).parameters.items()}


@pytest.mark.parametrize("args", ARGS, ids=lambda a: " ".join(a) or "defaults")
def test_the_thread_serves_what_the_command_serves(monkeypatch, args):
    seen: dict = {}

    def fake(plan, rate_hz, baud, **kw):
        seen.update(plan=plan, rate_hz=rate_hz, baud=baud, **kw)
        return ServeResult(path="/dev/null")

    monkeypatch.setattr(command, "serve", fake)
    proc = run("simulate", "--serve", *args)
    assert proc.returncode == 0, proc.stderr
    mine = serve_options(args)
    theirs = {k: seen[k] for k in mine if k != "plan_options"}
    assert theirs == {k: v for k, v in mine.items() if k != "plan_options"}
    for key, value in mine.get("plan_options", {}).items():  # a set's: the command's too
        assert seen["plan_options"][key] == value, (key, value)
    defaults = _defaults(serve)
    left = {k: v for k, v in seen.items() if k not in mine and k not in CALLBACKS}
    assert left == {k: defaults[k] for k in left}
    plan_defaults = _defaults(simulate_plan)
    for key, value in seen["plan_options"].items():
        if key in mine.get("plan_options", {}):  # a set's (compared above)
            continue
        assert value is None or value == plan_defaults[key], (key, value)


def test_an_option_the_thread_does_not_know_is_refused():
    with pytest.raises(ValueError, match="--person"):
        serve_options(["--person"])


@pytest.mark.parametrize(("rate", "baud", "warned"),
                         [(400.0, 115200, "--baud 230400"), (100.0, 115200, None)])  # fmt: skip
def test_a_stream_too_fast_for_its_baud_rate_is_said(rate, baud, warned):
    """Lines that need more than the baud rate carries fall behind the plan; a capture
    without a time column would stamp them at the slower pace they arrive (issue 28's
    three-IMU lines at 200 Hz ran at 60 % on 115200 baud), so the server says so and what
    baud rate would carry them."""
    import threading

    said = []
    cancel = threading.Event()
    cancel.set()  # said before the port opens; the serve then ends at once
    serve("six", rate, baud, announce=lambda path: None, status=said.append, cancel=cancel,
          wait_reader_s=0.1)  # fmt: skip
    warnings = [m for m in said if m.startswith("warning: lines of")]
    if warned is None:
        assert not warnings, said
    else:
        assert len(warnings) == 1 and warned in warnings[0], said
        assert "% of the plan's pace" in warnings[0]
