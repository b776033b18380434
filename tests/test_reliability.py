"""Reliability suite, fast cases (issue 11.6): malformed sessions, configs and calibration JSONs
(more than 100 each, from ``tests/hostile.py``) and concurrent calibrations of one session.

Every case must be *handled*: a one-line ImucalError, or a read whose result is right; never
another exception (a traceback), never a hang, never a silently wrong value.  The
fuzzers (10,000 import files, capture faults, disk full) are in ``bench/reliability.py``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.errors import ImucalError
from imucal_cli.formats.calibration import calibration_from_json, calibration_to_json
from imucal_cli.formats.config import load_config
from imucal_cli.formats.session import read_session
from tests.cli_helpers import IMUCAL, run
from tests.hostile import BASE_SESSION, calibration_cases, config_cases, session_cases

SESSION_CASES = session_cases()
CONFIG_CASES = config_cases()
# A hang (HDF5 retrying a damaged file) lasts many minutes; this bound catches one without
# timing the machine.  bench/reliability.py measures the real figure (under 2 s).
LIMIT_S = 60.0


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("hostile")


def outcome(call) -> tuple[str, object, float]:
    """("error", message) / ("ok", value) / ("crash", exception), and the time it took."""
    start = time.monotonic()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            value = call()
    except ImucalError as exc:
        return "error", str(exc), time.monotonic() - start
    except Exception as exc:  # noqa: BLE001 - the suite counts what escapes
        return "crash", exc, time.monotonic() - start
    return "ok", value, time.monotonic() - start


def same_data(a, b) -> bool:
    def eq(x, y):
        return (x is None and y is None) or (
            x is not None and y is not None and x.shape == y.shape and np.array_equal(x, y)
        )

    return all(eq(getattr(a, k), getattr(b, k)) for k in ("time", "accel", "gyro", "temperature"))


@pytest.mark.parametrize(
    ("name", "make", "expect"), SESSION_CASES, ids=[c[0] for c in SESSION_CASES]
)
def test_malformed_session(folder, name, make, expect):
    path = make(folder)
    kind, value, seconds = outcome(lambda: read_session(path))
    assert kind != "crash", f"{name}: {type(value).__name__}: {value}"
    assert seconds < LIMIT_S, f"{name}: {seconds:.1f} s"
    if kind == "error":
        assert "\n" not in value and value.startswith(str(path)), value
        assert expect != "ok", f"{name}: refused a good file: {value}"
        return
    assert expect != "error", f"{name}: read without complaint (silently wrong)"
    if expect == "either":  # a flip the checksums did not see must have changed nothing
        original = read_session(folder / "base.h5")
        assert same_data(value, original), f"{name}: read different data without an error"
    for text in (value.sensor, value.source, *(s.label for s in value.segments)):
        assert text is None or ("\x1b" not in text and "\u202e" not in text)


def test_hostile_sessions_through_every_reader(folder, tmp_path):
    """The commands that read sessions give a one-line error, exit 2, within the limit."""
    picks = {"truncated to 1000 bytes", "truncated to 8 bytes", "external storage (another "
             "file's bytes)", "2e9 samples declared in a small file", "virtual dataset, source "
             "missing", "accel of 1e300", "time in 1e10 s steps"}  # fmt: skip
    cal = tmp_path / "c.json"
    assert run("calibrate", shutil.copy(BASE_SESSION, tmp_path / "s.h5"), "-o", cal,
               "--no-store", "--model", "12").returncode in (0, 1, 2)  # fmt: skip
    for name, make, _ in SESSION_CASES:
        if name not in picks:
            continue
        path = make(folder)
        commands = [("calibrate", path, "-o", tmp_path / "o.json", "--no-store"), ("noise", path),
                    ("report", path), ("apply", BASE_SESSION.with_suffix(".truth.json"), path,
                                       "-o", tmp_path / "o.csv")]  # fmt: skip
        for args in commands:
            start = time.monotonic()
            proc = run(*args)
            took = time.monotonic() - start
            assert proc.returncode == 2 and "Traceback" not in proc.stderr, (name, args, proc)
            assert len(proc.stderr.strip().splitlines()) == 1, (name, proc.stderr)
            assert took < LIMIT_S, (name, args[0], took)
        assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize(
    ("name", "content", "expect"), CONFIG_CASES, ids=[c[0] for c in CONFIG_CASES]
)
def test_malformed_config(tmp_path, name, content, expect):
    path = tmp_path / "c.toml"
    path.write_bytes(content)
    kind, value, _ = outcome(lambda: load_config(path))
    assert kind != "crash", f"{name}: {type(value).__name__}: {value}"
    if expect == "error":
        assert kind == "error", f"{name}: accepted"
        assert "\n" not in value and value.startswith(str(path)), value
    else:
        assert kind == "ok", f"{name}: {value}"


def _valid_calibration_text() -> str:
    """A full calibration (parameters, poses, coverage, ...) as calibrate writes it."""
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import Config

    session = read_session(BASE_SESSION.with_name("qureshi18-seed1.h5"))
    return calibration_to_json(calibrate_session(session, Config(), name="qureshi18-seed1.h5"))


CAL_CASES = calibration_cases(_valid_calibration_text())


@pytest.mark.parametrize(("name", "content", "expect"), CAL_CASES, ids=[c[0] for c in CAL_CASES])
def test_malformed_calibration_json(tmp_path, name, content, expect):
    from rich.console import Console

    from imucal_cli.formats.calibration import read_calibration
    from imucal_cli.use.export import export
    from imucal_cli.use.report.build import build_report
    from imucal_cli.use.report.render import render_report

    def rendered(cal) -> str:
        console = Console(record=True, width=100, file=open(os.devnull, "w"))  # noqa: SIM115
        render_report(build_report(cal), console)
        console.file.close()
        return console.export_text()

    path = tmp_path / "c.json"
    path.write_bytes(content)
    kind, value, seconds = outcome(lambda: read_calibration(path))
    assert kind != "crash", f"{name}: {type(value).__name__}: {value}"
    assert seconds < LIMIT_S
    if expect == "error":
        assert kind == "error", f"{name}: accepted"
        assert "\n" not in value, value
        return
    assert kind == "ok", f"{name}: {value}"
    # what reads must also report and export, or refuse on one line
    for use in (lambda: rendered(value), lambda: export(value, "yaml"),
                lambda: export(value, "c-header"), lambda: calibration_to_json(value)):  # fmt: skip
        kind2, out, _ = outcome(use)
        assert kind2 != "crash", f"{name}: {type(out).__name__}: {out}"
        if kind2 == "ok" and isinstance(out, str):
            assert "\x1b" not in out and "\u202e" not in out
    assert calibration_from_json(calibration_to_json(value)).to_dict() == value.to_dict()


def test_suite_sizes():
    assert len(SESSION_CASES) >= 100 and len(CONFIG_CASES) >= 100 and len(CAL_CASES) >= 100


def test_concurrent_calibrations_of_one_session(tmp_path):
    """Three calibrations of one session at once: all saved (exit 0), all stored under distinct
    names, the raw data untouched."""
    session = shutil.copy(Path(BASE_SESSION).with_name("qureshi18-seed1.h5"), tmp_path / "s.h5")
    before = read_session(session)
    procs = [
        subprocess.Popen([IMUCAL, "calibrate", str(session), "-o", str(tmp_path / f"c{i}.json")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i in range(3)
    ]  # fmt: skip
    try:
        results = [(p.returncode, err) for p in procs for _, err in [p.communicate(timeout=600)]]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    assert all(code == 0 for code, _ in results), results
    after = read_session(session)
    assert sorted(after.calibrations) == [f"{i:04d}" for i in range(3)]
    assert same_data(before, after)
    for i in range(3):
        assert (tmp_path / f"c{i}.json").exists()


@pytest.mark.skipif(
    not (hasattr(os, "sched_setaffinity") and os.path.exists("/proc/self/schedstat")),
    reason="needs Linux CPU affinity and schedstat",
)
def test_bench_times_a_read_by_what_it_does_not_by_a_busy_machine():
    """bench/reliability.py's hang verdict: a read that waits for a CPU held by another
    process is not blocked (a loaded machine is no hang); a read that sleeps is."""
    import sys

    from bench.reliability import _timed

    cpu = min(os.sched_getaffinity(0))
    before = os.sched_getaffinity(0)
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        os.sched_setaffinity(busy.pid, {cpu})
        os.sched_setaffinity(0, {cpu})  # this process shares that CPU with the busy one
        _, _, took = _timed(lambda: sum(range(25_000_000)))  # ~0.5 s of CPU: fixed costs small
    finally:
        os.sched_setaffinity(0, before)
        busy.kill()
        busy.wait()
    assert took.wall > 1.5 * took.cpu  # it did wait for the CPU ...
    assert took.blocked < 0.2 * took.wall  # ... and that wait is not counted as blocked
    _, _, slept = _timed(lambda: time.sleep(0.3))
    assert 0.25 < slept.blocked < 1.0 and slept.cpu < 0.05
