"""`imucal simulate`: every numeric option within a physical bound, refused in one line.

Audit: ``--accel-noise 1e300`` (also ``--sigma-counts``, ``--mag-noise``) wrote a session of
saturated counts, exit 0; ``--rate``/``--hold``/``--still``/``--move``/``--tumble 1e300`` were
refused with a 300-digit sample count; ``--serve`` took ``--duration``/``--stall-after``/
``--vanish-after`` of NaN or -1 and ``--serve --person`` an ``--accel-noise`` of NaN and
served; ``--serve --person --jitter-deg 1e300`` was a traceback; ``--serve --hold -1`` said
"each pose held -1 s" before its error (two lines).
"""

from __future__ import annotations

import inspect
import json
import subprocess
import sys
import types
import typing
from pathlib import Path

import pytest

from imucal_cli.cli.simulate_checks import BOUNDS

from .cli_helpers import assert_one_line_error, run

ROOT = Path(__file__).resolve().parents[1]

#: Integer options with a range of their own (checked by the simulators), and --clock-ppm.
CHECKED_ELSEWHERE = {"seed", "rotations_per_axis", "orientations", "samples", "mountings",
                     "imus", "serve_imu", "clock_ppm"}  # fmt: skip


def _numeric_options() -> dict[str, object]:
    """simulate's options whose type is a number (float or int, maybe None): their defaults."""
    from imucal_cli.cli.simulate import simulate

    hints = typing.get_type_hints(simulate)
    defaults = {n: p.default for n, p in inspect.signature(simulate).parameters.items()}
    numeric = {}
    for name, hint in hints.items():
        kinds = set(typing.get_args(hint)) if isinstance(hint, types.UnionType) else {hint}
        if kinds - {type(None)} and kinds - {type(None)} <= {int, float}:
            numeric[name] = defaults[name]
    return numeric


def test_every_numeric_option_has_a_bound():
    """A numeric option added to simulate without a bound fails here."""
    numeric = _numeric_options()
    assert {"accel_noise", "rate", "seed", "mag_noise"} <= set(numeric)  # the hints were read
    assert set(numeric) - set(BOUNDS) - CHECKED_ELSEWHERE == set()
    assert set(BOUNDS) <= set(numeric)  # no bound of an option that is gone


def test_the_defaults_and_real_parts_are_inside_the_bounds():
    """The bounds are generous: every default, and the figures of real parts, pass."""
    for name, default in _numeric_options().items():
        if name in BOUNDS and default is not None:
            BOUNDS[name].check(default)
    real = {"rate": 32_000.0, "accel_noise": 0.5, "mag_noise": 2.0, "sigma_counts": 1.5,
            "baud": 3_000_000, "field_ut": 65.0, "hold": 3600.0, "duration": 86_400.0}
    for name, value in real.items():
        BOUNDS[name].check(value)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--accel-noise", "1e300"], ["--accel-noise", "10 m/s^2", "1e+300"]),
        (["--accel-noise", "100"], ["--accel-noise", "10 m/s^2"]),
        (["--accel-noise", "nan"], ["--accel-noise", "finite"]),
        (["--accel-noise", "inf"], ["--accel-noise", "finite"]),
        (["--accel-noise", "-1"], ["--accel-noise", "from 0"]),
        (["--rate", "1e300"], ["--rate", "100000 Hz"]),
        (["--hold", "1e300"], ["--hold", "86400 s"]),
        (["--move", "1e300"], ["--move", "86400 s"]),
        (["--plan", "qureshi-axes", "--still", "1e300"], ["--still", "86400 s"]),
        (["--plan", "hk-redundant", "--sigma-counts", "1e300"], ["--sigma-counts", "100 counts"]),
        (["--mag", "--plan", "six", "--mag-noise", "1e300"], ["--mag-noise", "100 uT"]),
        (["--mag", "--plan", "six", "--tumble", "1e300"], ["--tumble", "86400 s"]),
        (["--imus", "2", "--plan", "six", "--imu-offset", "-1"], ["--imu-offset", "1000 ms",
                                                                   "got -1"]),
    ],
)
def test_absurd_numbers_are_refused_in_one_line(tmp_path, args, words):
    out = tmp_path / "x.h5"
    assert_one_line_error(run("simulate", *args, "-o", out), *words)
    assert not out.exists() and not (tmp_path / "x.truth.json").exists()


SERVE_REFUSALS = [
        (["--plan", "six", "--duration", "nan"], ["--duration", "finite"]),
        (["--plan", "six", "--stall-after", "-1"], ["--stall-after", "from 0"]),
        (["--plan", "six", "--vanish-after", "nan"], ["--vanish-after"]),
        (["--plan", "six", "--baud", "99999999999"], ["--baud", "12000000"]),
        (["--plan", "six", "--accel-noise", "1e300"], ["--accel-noise"]),
        (["--plan", "six", "--hold", "-1"], ["--hold"]),  # said "each pose held -1 s" first
        (["--plan", "six", "--rate", "0.001"], ["hold 4 s at 0.001 Hz"]),  # a plan's own check
        (["--plan", "six", "--imus", "2", "--serve-imu", "5"], ["--serve-imu", "0 to 1"]),
        (["--person", "--accel-noise", "nan"], ["--accel-noise"]),
        (["--person", "--jitter-deg", "1e300"], ["--jitter-deg", "45 deg"]),  # a traceback
]  # fmt: skip


@pytest.fixture(scope="module")
def serve_refusals() -> list[subprocess.CompletedProcess]:
    """``imucal simulate --serve ARGS`` of every case of :data:`SERVE_REFUSALS`, one after the
    other in one process of their own (:func:`cli_helpers.run` there: one interpreter, not
    ten): a serve that started would keep that process until the timeout, failing them all.
    The program's own exit path with a one-line error is ``test_no_such_port``'s."""
    script = ("import json, sys\nfrom tests.cli_helpers import run\n"
              "procs = [run('simulate', '--serve', *a) for a in json.loads(sys.argv[1])]\n"
              "print(json.dumps([[p.returncode, p.stdout, p.stderr] for p in procs]))\n")
    cases = json.dumps([args for args, _ in SERVE_REFUSALS])
    proc = subprocess.run([sys.executable, "-c", script, cases], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return [subprocess.CompletedProcess(args, code, out, err) for (args, _), (code, out, err)
            in zip(SERVE_REFUSALS, json.loads(proc.stdout), strict=True)]  # fmt: skip


@pytest.mark.parametrize("case", range(len(SERVE_REFUSALS)),
                         ids=[" ".join(args) for args, _ in SERVE_REFUSALS])  # fmt: skip
def test_serve_refuses_before_it_serves(serve_refusals, case):
    """A refused --serve never opens its port: one line, nothing on stdout (a serve that
    started would run until the timeout)."""
    proc, words = serve_refusals[case], SERVE_REFUSALS[case][1]
    assert_one_line_error(proc, *words)
    assert proc.stdout == ""


@pytest.mark.parametrize("plan", ["still:1e300", "warmup:1e9", "still:20000"])
def test_a_plans_minutes_are_bounded(tmp_path, plan):
    """``--plan still:1e300`` was refused with a 300-digit sample count; capture takes the same
    plans. A week is the longest hold (10080 minutes)."""
    out = tmp_path / "x.h5"
    assert_one_line_error(run("simulate", "--plan", plan, "-o", out), "MINUTES", "10080")
    assert_one_line_error(run("capture", "--port", tmp_path / "nope", "--plan", plan,
                              "--no-prompt", "-o", out), "MINUTES", "10080")  # fmt: skip
    assert not out.exists()
