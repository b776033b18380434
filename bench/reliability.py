"""Reliability (issue 11.6): hostile inputs and capture faults, and what became of each.

Rows:

* malformed sessions, configs and calibration JSONs (``tests/hostile.py``, read in-process);
* 10,000 fuzzed import files (fixed seed): a recording with one to three mutations each (a
  control character, ``_`` or a non-ASCII digit inside a number, ``nan``, non-UTF-8 bytes,
  CRLF, a BOM, a cut, a duplicated or swapped line, an extra or missing field, a long line),
  read in-process (one in ten imported whole, with segmentation); the first 10 also through
  ``imucal import`` for the real exit status;
* every other importer (issue 26): 400 damaged copies per format (60 with ``--quick``) of a
  file its own writer library made (ROS 1/2 bags, MCAP of ROS 1 and 2 with and without a
  summary, ULog raw and FIFO topics, telemetry logs, DataFlash IMU, ACC/GYR, ISBH/ISBD and text
  logs, MotionCal and i2cdevlib lines, WitMotion frames, imu_tk pairs, EuRoC CSV): bits
  flipped, bytes set, lengths set to 0x7fffffff, blocks zeroed or copied, cuts; each accepted
  file's rows checked against the values and times written (``tests/format_fuzz.py``): a row
  that is not the file's own is silently wrong, unless the format has no checksum over it and
  the damage hit that sample's bytes (counted as "read as damaged");
* capture faults through the virtual serial port (``imucal simulate --serve`` ->
  ``imucal capture``): clean, garbage, malformed lines, a stall, the device vanishing, Ctrl-C,
  SIGTERM, SIGHUP, ``kill -9``; a busy host (two CPU burners beside, and a start-up starved
  for seconds: the capture stopped from the device's first pose to its fourth);
* a full disk: a capture into a small tmpfs (root), else an injected ENOSPC in-process;
* concurrent calibrations of one session.

Columns: cases; handled (a one-line error with the right exit status, or a right result);
traceback; hang (a file's read running over 2 s, or blocked over 2 s, or a process that does
not end); wrong exit; silent wrong (a read that succeeds with values the file does not hold);
data lost (samples received or flushed that are not in the session, beyond what the tool
reported).  The last five must be 0.

A file's read is timed by what the reader does, not by the wall clock: its CPU time
(``time.process_time``) and the time it was blocked (sleeping or waiting for I/O: the wall
time less the CPU time and less the time it waited for a CPU, which Linux reports in
``/proc/self/schedstat``).  On a machine shared with other work a read waits for the CPU, which
says nothing about the reader (an earlier run counted a read of about 1 s CPU as a hang at
2.3 s wall); a read that spins or blocks (a FIFO, a lock never released, retries with sleeps)
is over the limit on either clock.  Where schedstat is missing the wall time stands in.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests/hostile.py: the cases the fast suite runs too

from tests.hostile import (  # noqa: E402
    BASE_SESSION,
    calibration_cases,
    config_cases,
    session_cases,
)

CLI = [sys.executable, "-m", "imucal_cli"]
HANG_S = 2.0
"""Seconds one file's read may run (CPU) or be blocked."""
COLUMNS = ("handled", "traceback", "hang", "wrong exit", "silent wrong", "data lost")


def _queued_s() -> float | None:
    """Seconds this process has waited for a CPU (Linux schedstat), or None."""
    try:
        with open("/proc/self/schedstat") as f:
            return int(f.read().split()[1]) * 1e-9
    except (OSError, ValueError, IndexError):
        return None


@dataclass(frozen=True)
class Took:
    """How long a call took: running (CPU), waiting for a CPU (None: unknown), wall; s."""

    cpu: float
    queued: float | None
    wall: float

    @property
    def blocked(self) -> float:
        """Wall time neither running nor waiting for a CPU (the wall time when unknown)."""
        if self.queued is None:
            return self.wall
        return max(self.wall - self.cpu - self.queued, 0.0)  # clock granularity: never < 0

    @property
    def hung(self) -> bool:
        return self.cpu > HANG_S or self.blocked > HANG_S

    def __str__(self) -> str:
        return f"{self.cpu:.2f} s CPU, {self.blocked:.2f} s blocked, {self.wall:.2f} s wall"


@dataclass
class Row:
    name: str
    counts: Counter = field(default_factory=Counter)
    examples: list[str] = field(default_factory=list)
    slowest: Took | None = None  # the file read that ran longest (CPU)
    most_blocked: Took | None = None

    def add(self, verdict: str, example: str = "", took: Took | None = None) -> None:
        self.counts["cases"] += 1
        self.counts[verdict] += 1
        if verdict != "handled" and len(self.examples) < 3:
            self.examples.append(f"{verdict}: {example}"[:160])
        if took is not None:
            if self.slowest is None or took.cpu > self.slowest.cpu:
                self.slowest = took
            if self.most_blocked is None or took.blocked > self.most_blocked.blocked:
                self.most_blocked = took


def _timed(call):
    """(kind, value, :class:`Took`): kind "error" (ImucalError), "ok" or "crash"."""
    from imucal_cli.errors import ImucalError

    cpu, queued, wall = time.process_time(), _queued_s(), time.monotonic()

    def took() -> Took:
        now_queued = _queued_s()
        waited = None if queued is None or now_queued is None else now_queued - queued
        return Took(time.process_time() - cpu, waited, time.monotonic() - wall)

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            value = call()
    except ImucalError as exc:
        return "error", exc, took()
    except Exception as exc:  # noqa: BLE001 - counted as a traceback
        return "crash", exc, took()
    return "ok", value, took()


def _verdict(kind, value, took: Took, expect: str, check_ok=None) -> str:
    if kind == "crash":
        return "traceback"
    if took.hung:
        return "hang"
    if kind == "error":
        if "\n" in str(value):
            return "wrong exit"  # not one line
        return "handled" if expect != "ok" else "wrong exit"
    if expect == "error":
        return "silent wrong"
    if check_ok is not None and not check_ok(value):
        return "silent wrong"
    return "handled"


# --------------------------------------------------------------------------------------------
# Hostile files (the cases of the fast suite, with their timings)
# --------------------------------------------------------------------------------------------


def _same_data(a, b) -> bool:
    def eq(x, y):
        return (x is None and y is None) or (
            x is not None and y is not None and x.shape == y.shape and np.array_equal(x, y)
        )

    return all(eq(getattr(a, k), getattr(b, k)) for k in ("time", "accel", "gyro", "temperature"))


def hostile_rows(folder: Path) -> list[Row]:
    from imucal_cli.formats.calibration import calibration_to_json, read_calibration
    from imucal_cli.formats.config import Config, load_config
    from imucal_cli.formats.session import read_session
    from imucal_cli.pipeline.calibrate import calibrate_session

    sessions = Row("malformed sessions")
    original = None
    for name, make, expect in session_cases():
        path = make(folder)
        if original is None:
            original = read_session(folder / "base.h5")
        kind, value, took = _timed(lambda p=path: read_session(p))
        check = (lambda s, o=original: _same_data(s, o)) if expect == "either" else None
        sessions.add(_verdict(kind, value, took, expect, check), f"{name} ({took}): {value}",
                     took)  # fmt: skip

    configs = Row("malformed configs")
    for name, content, expect in config_cases():
        path = folder / "c.toml"
        path.write_bytes(content)
        kind, value, took = _timed(lambda p=path: load_config(p))
        configs.add(_verdict(kind, value, took, expect), f"{name} ({took}): {value}", took)

    cal = calibrate_session(read_session(BASE_SESSION.with_name("qureshi18-seed1.h5")), Config())
    jsons = Row("malformed calibration JSONs")
    for name, content, expect in calibration_cases(calibration_to_json(cal)):
        path = folder / "c.json"
        path.write_bytes(content)
        kind, value, took = _timed(lambda p=path: read_calibration(p))
        jsons.add(_verdict(kind, value, took, expect), f"{name} ({took}): {value}", took)
    return [sessions, configs, jsons]


# --------------------------------------------------------------------------------------------
# Import fuzzer
# --------------------------------------------------------------------------------------------

_REJECT_KINDS = ("control", "underscore", "digit", "special", "garbage")
_STRUCT_KINDS = ("crlf", "bom", "blanks", "comment", "duplicate", "swap", "extra_field",
                 "missing_field", "long_line", "cut", "empty", "no_header")  # fmt: skip
_CONTROLS = ["\v", "\f", "\x1c", "\x1d", "\x1e", "\x85", "\u2028", "\u2029", "\x00", "\x1b",
             "\x7f", "\r"]  # fmt: skip
_DIGITS = ["\u0660", "\uff10", "\u0966", "\u06f0"]  # Arabic-Indic, fullwidth, Devanagari, ...


def base_recording(folder: Path) -> tuple[Path, list[str]]:
    """A short recording (six poses, 25 Hz) as CSV: a header, then one line per sample."""
    from imucal_cli.simulate.device import stream_arrays

    t, a, g = stream_arrays("six", rate_hz=25.0, hold_s=1.6, move_s=0.6)
    lines = ["t,ax,ay,az,gx,gy,gz"] + [
        f"{ti:.3f}," + ",".join(f"{v:.6g}" for v in (*ai, *gi))
        for ti, ai, gi in zip(t, a, g, strict=True)
    ]
    path = folder / "base.csv"
    path.write_text("\n".join(lines) + "\n")
    return path, lines


def _time_of(line: str) -> float | None:
    try:
        return round(float(line.split(",")[0]), 3)
    except ValueError:
        return None


def _mutate(lines: list[str], rng: np.random.Generator) -> tuple[str, set[float], list[str]]:
    """(text, times of the sample lines mutated, kinds applied)."""
    lines = list(lines)
    touched: set[float] = set()
    kinds = []
    for _ in range(int(rng.integers(1, 4))):
        kind = str(rng.choice(_REJECT_KINDS + _STRUCT_KINDS))
        kinds.append(kind)
        i = int(rng.integers(1, len(lines)))
        t = _time_of(lines[i])
        if t is not None and kind not in ("blanks", "comment", "long_line"):
            touched.add(t)
        fields = lines[i].split(",")
        j = int(rng.integers(0, len(fields)))
        f = fields[j]
        digits = [k for k, c in enumerate(f) if c.isdigit()]
        if kind in _REJECT_KINDS:
            k = int(rng.choice(digits)) if digits else 0
            if kind == "control":
                fields[j] = f[:k] + str(rng.choice(_CONTROLS)) + f[k:]
            elif kind == "underscore":
                fields[j] = f[: max(k, 1)] + "_" + f[max(k, 1) :]
            elif kind == "digit" and digits:
                fields[j] = f[:k] + _DIGITS[int(rng.integers(0, 4))] + f[k + 1 :]
            elif kind == "special":
                fields[j] = str(rng.choice(["nan", "inf", "-inf", "1e999", "0x10", "NaN", ""]))
            else:
                fields[j] = f + "\udcff\udcfe"  # non-UTF-8 bytes (written with surrogateescape)
            lines[i] = ",".join(fields)
        elif kind == "duplicate":
            lines.insert(i, lines[i])
        elif kind == "swap" and i + 1 < len(lines):
            touched.add(_time_of(lines[i + 1]))
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
        elif kind == "extra_field":
            lines[i] += ",1.5"
        elif kind == "missing_field":
            lines[i] = ",".join(fields[:-1])
        elif kind == "long_line":
            lines.insert(i, "9" * 200_000)
        elif kind == "blanks":
            lines[i] = "  " + lines[i] + " \t"
        elif kind == "comment":
            lines.insert(i, "# " + lines[i])
        elif kind == "no_header":
            lines[0] = "1,2,3"
    text = "\n".join(lines) + "\n"
    if "crlf" in kinds:
        text = text.replace("\n", "\r\n")
    if "bom" in kinds:
        text = "\ufeff" + text
    if "cut" in kinds:
        text = text[: int(rng.integers(0, len(text)))]
    if "empty" in kinds:
        text = ""
    return text, touched, kinds


def fuzz_imports(folder: Path, n_files: int, seed: int = 20261123) -> Row:
    """Each file is read by the import's reader (every file) and segmented into a session
    (one file in ten, the full ``import_files``); the first 10 also through ``imucal import``."""
    from imucal_cli.formats.importers import import_files, read_recording

    base, lines = base_recording(folder)
    truth = {}
    for line in lines[1:]:
        values = [float(v) for v in line.split(",")]
        truth[values[0]] = values[1:]
    row = Row(f"fuzzed import files (seed {seed})")
    rng = np.random.default_rng(seed)
    cli_left = 10
    for n in range(n_files):
        text, touched, kinds = _mutate(lines, rng)
        path = folder / f"f{n % 4}.csv"
        path.write_bytes(text.encode("utf-8", "surrogateescape"))
        columns = None if n % 2 else "t,ax,ay,az,gx,gy,gz"
        read = import_files if n % 10 == 0 else read_recording
        kind, value, took = _timed(lambda p=path, c=columns, r=read: r([p], "csv", c))
        where = f"file {n} ({'+'.join(kinds)}, {took}): {str(value)[:80]}"
        if kind == "ok":
            verdict = _check_import(value, truth, touched, kinds)
            if verdict != "handled":
                row.add(verdict, where, took)
                continue
        if kind == "error" and getattr(value, "exit_code", 2) != 2:
            row.add("wrong exit", where, took)
            continue
        verdict = _verdict(kind, value, took, "either")
        if verdict == "handled" and cli_left > 0:
            cli_left -= 1
            verdict = _cli_import(path, columns, kind if read is import_files else "unknown")
        row.add(verdict, where, took)
    return row


def _check_import(rec, truth, touched, kinds) -> str:
    """Every sample read must be one of the file's intact lines, unchanged; none lost."""
    cut_last = "cut" in kinds
    kept_times = rec.time
    for k, t in enumerate(kept_times):
        expected = truth.get(round(float(t), 3))
        got = [*rec.accel[k], *rec.gyro[k]]
        if expected is None or got != expected:
            if cut_last and k == len(kept_times) - 1:
                continue  # the last line of a cut file may be cut inside a number
            return "silent wrong"
    if cut_last or "empty" in kinds:
        return "handled"
    kept = {round(float(t), 3) for t in kept_times}
    missing = set(truth) - kept - touched
    return "data lost" if missing else "handled"


def _cli_import(path: Path, columns: str | None, kind: str) -> str:
    args = [*CLI, "import", str(path), "-o", str(path.with_suffix(".h5")), "--force"]
    if columns:
        args += ["--columns", columns]
    try:
        proc = subprocess.run(args, capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        return "hang"
    if "Traceback" in proc.stderr:
        return "traceback"
    want = {"ok": (0,), "error": (2,)}.get(kind, (0, 2))
    if proc.returncode not in want:
        return "wrong exit"
    if proc.returncode == 2 and len(proc.stderr.strip().splitlines()) != 1:
        return "wrong exit"
    return "handled"


# --------------------------------------------------------------------------------------------
# Every other importer: damaged files of each format (tests/format_fuzz.py), judged by the oracle
# --------------------------------------------------------------------------------------------


def fuzz_formats(folder: Path, n_files: int, seed: int = 26) -> list[Row]:
    """Per format (:data:`tests.format_fuzz.MAKERS`), ``n_files`` damaged copies of a file its
    writer library made, each read by ``imucal import``'s reader in-process (the first two
    also through ``imucal import`` for the real exit status) and judged: a one-line error with
    exit 2, or values that are the file's own (:func:`tests.format_fuzz.judge`; rows read from
    bytes the damage hit, in a format without a checksum, are counted as read as damaged)."""
    from imucal_cli.formats.importers import read_recording
    from tests.format_fuzz import MAKERS, judge, mutate, place

    rows = []
    for name, make in MAKERS.items():
        work = folder / f"fmt-{name}"
        (work / "base").mkdir(parents=True)
        base = make(work / "base")
        row = Row(f"damaged {base.name}")
        kind, value, took = _timed(lambda b=base: read_recording(b.paths, b.fmt, **b.options))
        if kind != "ok" or judge(base, value, []).verdict != "handled":
            row.add("silent wrong" if kind == "ok" else "traceback", f"the undamaged file: {value}")
        original = base.target.read_bytes()
        rng = np.random.default_rng(seed)
        damaged_rows = wrong_rows = 0
        for n in range(n_files):
            data, ranges, what = mutate(original, rng)
            paths = place(base, data, work)
            kind, value, took = _timed(
                lambda p=paths, b=base: read_recording(p, b.fmt, **b.options))
            where = f"file {n} ({what}, {took}): {str(value)[:100]}"
            if kind == "ok":
                verdict = judge(base, value, ranges)
                damaged_rows += verdict.damaged
                wrong_rows += verdict.wrong
                if verdict.verdict != "handled":
                    row.add(verdict.verdict, f"{where}: {verdict.detail}", took)
                    continue
            if kind == "error" and getattr(value, "exit_code", 2) != 2:
                row.add("wrong exit", where, took)
                continue
            verdict = _verdict(kind, value, took, "either")
            if verdict == "handled" and n < 2:
                verdict = _cli_format(paths, base, kind)
            row.add(verdict, where, took)
        row.name += f" ({damaged_rows} rows read as damaged, {wrong_rows} silently wrong)"
        rows.append(row)
    return rows


def _cli_format(paths: list[Path], base, kind: str) -> str:
    """``imucal import`` of a damaged file: exit 0 when the reader accepted it (or 2 when the
    segmentation finds no still period in what is left), else exit 2 with one line."""
    args = [*CLI, "import", *map(str, paths), "-o", str(paths[0].with_suffix(".h5")), "--force",
            "--format", base.fmt]  # fmt: skip
    if "rate_hz" in base.options:
        args += ["--rate", str(base.options["rate_hz"])]
    if "topic" in base.options:
        args += ["--topic", base.options["topic"]]
    try:
        proc = subprocess.run(args, capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        return "hang"
    if "Traceback" in proc.stderr:
        return "traceback"
    if proc.returncode not in ((0, 2) if kind == "ok" else (2,)):
        return "wrong exit"
    if proc.returncode == 2 and len(proc.stderr.strip().splitlines()) != 1:
        return "wrong exit"
    return "handled"


# --------------------------------------------------------------------------------------------
# Capture faults through the virtual serial port
# --------------------------------------------------------------------------------------------


def _server(*args: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([*CLI, "simulate", "--serve", "--rate", "200", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    return proc, proc.stdout.readline().strip()


def _sent(server: subprocess.Popen) -> dict | None:
    try:
        out, _ = server.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        server.kill()
        out, _ = server.communicate()
    m = re.search(r"# sent (\d+) lines, (\d+) malformed", out)
    return None if m is None else {"lines": int(m[1]), "malformed": int(m[2])}


def _capture_case(folder: Path, name: str, server_args, signum=None, after_s=2.5) -> tuple:
    """Run one capture; return (verdict, detail)."""
    import h5py

    from imucal_cli.formats.session import read_session

    out = folder / f"{name}.h5"
    server, port = _server(*server_args)
    cap = subprocess.Popen([*CLI, "capture", "--port", port, "--output", str(out), "--no-prompt",
                            "--duration", "30", "--read-timeout", "1.5"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    if signum is not None:
        end = time.monotonic() + 20
        while not out.exists() and time.monotonic() < end and cap.poll() is None:
            time.sleep(0.05)
        time.sleep(after_s)
        cap.send_signal(signum)
    try:
        stdout, stderr = cap.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        cap.kill()
        server.kill()
        return "hang", f"{name}: capture did not end"
    if signum is not None:
        server.kill()
        server.communicate()
        sent = None
    else:
        sent = _sent(server)
    if "Traceback" in stderr:
        return "traceback", f"{name}: {stderr.strip()[-120:]}"
    if sent is not None and sent["lines"] == 0:
        return _nothing_sent(name, cap.returncode, stderr, out)
    killed = signum == signal.SIGKILL
    want = {None: (0, 3), signal.SIGKILL: (-9,)}.get(signum, (3,))
    if cap.returncode not in want:
        return "wrong exit", f"{name}: exit {cap.returncode}: {stderr.strip()[-120:]}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            n_file = read_session(out).time.size
        except Exception as exc:  # noqa: BLE001
            return "data lost", f"{name}: unreadable after the capture: {exc}"
    if not killed:
        with h5py.File(out, "r"):
            pass  # closed cleanly: plain HDF5 opens it
        m = re.search(r"saved (\d+) samples", stdout)
        if m is None or int(m[1]) != n_file:
            return "data lost", f"{name}: summary {m and m[1]} vs file {n_file}"
    if sent is not None and n_file != sent["lines"] - sent["malformed"]:
        return "data lost", f"{name}: sent {sent}, file {n_file}"
    return "handled", f"{name}: {n_file} samples"


def _nothing_sent(name: str, code: int, stderr: str, out: Path) -> tuple[str, str]:
    """A device that sent no line (garbage: a wrong baud rate) has no sample to lose: the
    capture must write no file, say in one line what came and exit 2 (nothing saved), whether
    the wait ran out or the device went first."""
    last = stderr.strip().splitlines()[-1] if stderr.strip() else ""
    if out.exists():
        return "silent wrong", f"{name}: no line sent, yet {out.name} was written"
    if code != 2 or not last.startswith("imucal: ") or "wrong baud rate?" not in last:
        return "wrong exit", f"{name}: exit {code}: {last[-120:]}"
    return "handled", f"{name}: no line sent, no file, exit {code}"


def capture_rows(folder: Path) -> list[Row]:
    row = Row("capture faults (virtual port)")
    cases = [
        ("clean", ["--plan", "six", "--hold", "1", "--vanish-after", "4"], None),
        ("garbage", ["--plan", "six", "--garbage", "--vanish-after", "4"], None),
        ("malformed", ["--plan", "six", "--malformed-every", "7", "--vanish-after", "4"], None),
        ("stall", ["--plan", "six", "--stall-after", "3"], None),
        ("ctrl-c", ["--plan", "six", "--loop"], signal.SIGINT),
        ("sigterm", ["--plan", "six", "--loop"], signal.SIGTERM),
        ("sighup", ["--plan", "six", "--loop"], signal.SIGHUP),
        ("kill -9", ["--plan", "six", "--loop"], signal.SIGKILL),
    ]
    for name, args, signum in cases:
        verdict, detail = _capture_case(folder, name.replace(" ", ""), args, signum)
        row.add(verdict, detail)
    busy = Row("busy host (two CPU burners; virtual port)")
    for k, stall in enumerate((None, None, ("pose 1/6", "pose 4/6"), ("pose 1/6", "pose 4/6"))):
        busy.add(*_busy_case(folder, f"busy{k}", stall))
    return [row, busy]


def _busy_case(folder: Path, name: str, stall) -> tuple[str, str]:
    """Plan six captured unattended beside two CPU burners; with ``stall`` the capture gets no
    CPU from the device's first status line to its second (a start-up at load 40: seconds of
    samples wait).  Handled: complete (exit 0), every line sent in the session, the summary's
    rate the device's (issue 24.3: 'advanced 9.17 s in 3 s of host time', exit 2, before)."""
    import json

    out = folder / f"{name}.h5"
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        server, port = _server("--plan", "six", "--hold", "2", "--move", "1")
        args = ["--port", port, "--output", str(out), "--no-prompt", "--plan", "six", "--json"]
        cap = subprocess.Popen([*CLI, "capture", *args], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)  # fmt: skip
        said = _stall(server, cap, stall)
        try:
            stdout, stderr = cap.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            cap.kill()
            server.kill()
            return "hang", f"{name}: capture did not end"
        said.join(timeout=60)
        out_text, _ = server.communicate(timeout=60)
    finally:
        for b in burners:
            b.kill()
    m = re.search(r"# sent (\d+) lines, (\d+) malformed", out_text)
    if "Traceback" in stderr:
        return "traceback", f"{name}: {stderr.strip()[-120:]}"
    if cap.returncode != 0:
        return "wrong exit", f"{name}: exit {cap.returncode}: {stderr.strip()[-120:]}"
    summary = json.loads(stdout)
    n = len(_held(out).time)
    if m is None or n != int(m[1]) - int(m[2]) or summary["samples"] != n:
        return "data lost", f"{name}: sent {m and m[1]}, file {n}, said {summary['samples']}"
    if abs(summary["rate_hz"] - 200.0) > 0.2:
        return "silent wrong", f"{name}: {summary['rate_hz']:.1f} Hz said for a 200 Hz stream"
    return "handled", f"{name}: {n} samples, {summary['rate_hz']:.1f} Hz"


def _stall(server: subprocess.Popen, cap: subprocess.Popen, stall):
    """Read the server's status lines in a thread; SIGSTOP the capture at ``stall[0]`` and
    SIGCONT it at ``stall[1]`` (None: no stall).  Returns the thread."""
    import threading

    def follow():
        stopped = False
        for line in server.stderr:
            if stall and not stopped and stall[0] in line:
                cap.send_signal(signal.SIGSTOP)
                stopped = True
            elif stall and stopped and stall[1] in line:
                cap.send_signal(signal.SIGCONT)
                stopped = False
        if stopped:
            cap.send_signal(signal.SIGCONT)

    thread = threading.Thread(target=follow, daemon=True)
    thread.start()
    return thread


# --------------------------------------------------------------------------------------------
# A full disk
# --------------------------------------------------------------------------------------------


def _mount_tmpfs(path: Path, size: str) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    path.mkdir(exist_ok=True)
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True)  # fmt: skip
    return proc.returncode == 0


def disk_full_rows(folder: Path) -> list[Row]:
    """Captures into a tmpfs too small for them (or with ENOSPC injected when it cannot be
    mounted).  A capture that fills the disk must stop in time (issue 24.3): exit 3 with
    ``ended: disk-full``, the file closed cleanly (plain HDF5 opens it) holding every sample
    it received and every segment it reported, and ``capture --resume`` must continue it once
    there is space (the tmpfs grown).  Injected write failures (another program filling the
    disk) must lose nothing when freeing the reserve is enough, and otherwise keep every
    sample written before and say how many were lost."""
    mount = folder / "small"
    row = Row("disk full")
    for k, (size, rate) in enumerate((("96k", 200), ("256k", 500), ("2m", 1000))):
        real = _mount_tmpfs(mount, size)
        if not real:
            break
        row.name = "disk full (tmpfs 96 KiB .. 2 MiB, resumed; injected ENOSPC)"
        try:
            row.add(*_tmpfs_disk_full(mount, k, size, rate))
        finally:
            subprocess.run(["umount", str(mount)], check=False)
    if row.counts["cases"] == 0:
        row.name = "disk full (injected ENOSPC; tmpfs needs root)"
    for k, mode in enumerate(("transient", "permanent", "permanent")):
        row.add(*_injected_disk_full(folder, k, mode))
    return [row]


def _tmpfs_disk_full(mount: Path, k: int, size: str, rate: int) -> tuple[str, str]:
    """One capture of a ``rate`` Hz stream into a ``size`` tmpfs, then resumed (run 0).  The
    rate lets a start-up backlog of a few seconds fit the disk (samples that reached the host
    and could never fit are counted as lost, which this row counts as data lost)."""
    out = mount / f"full{k}.h5"
    cap = _serve_and_capture(out, "--duration", "120", rate=rate)
    detail = f"{size}: exit {cap.returncode}: {cap.stdout.strip()[-160:]}"
    if "Traceback" in cap.stderr:
        return "traceback", cap.stderr[-160:]
    if cap.returncode != 3 or "disk-full" not in cap.stdout:
        return "wrong exit", detail
    found = _session_as_said(out, cap.stdout)
    if found is not None:
        _keep_for_study(out, mount.parent)
        return "data lost", f"{size}: {found}; {detail}"
    if k == 0:  # space freed: the capture goes on in the same file
        before = _held(out).time.size
        subprocess.run(["mount", "-o", "remount,size=8m", str(mount)], check=False)
        more = _serve_and_capture(out, "--duration", "3", resume=True)
        if more.returncode not in (0, 3) or "Traceback" in more.stderr:
            return "wrong exit", f"{size}: resumed: exit {more.returncode}: {more.stderr[-160:]}"
        after = _held(out).time.size
        if after <= before:
            return "data lost", f"{size}: resumed: {before} -> {after} samples"
        detail += f"; resumed: {before} -> {after} samples"
    return "handled", detail


def _serve_and_capture(out: Path, *args: str, resume: bool = False, rate: int = 1000):
    server, port = _server("--plan", "six", "--loop", "--rate", str(rate), "--baud", "921600")
    target = ["--resume", str(out)] if resume else ["--output", str(out)]
    try:
        return subprocess.run([*CLI, "capture", "--port", port, "--baud", "921600", *target,
                               "--no-prompt", *args, "--columns", "t,ax,ay,az,gx,gy,gz,temp"],
                              capture_output=True, text=True, timeout=180)  # fmt: skip
    finally:
        server.kill()
        server.communicate()


def _held(path: Path):
    from imucal_cli.formats.session import read_session

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_session(path)


def _session_as_said(out: Path, stdout: str) -> str | None:
    """What is wrong with a session against the capture's summary (None: nothing): closed
    cleanly, every sample received in it, no NaN row, the segments it reported."""
    import h5py

    try:
        held = _held(out)
        with h5py.File(out, "r"):
            pass  # closed cleanly: plain HDF5 opens it
    except Exception as exc:  # noqa: BLE001 - a session that cannot be read is lost
        return f"unreadable after the capture: {exc}"
    n = held.time.size
    saved = re.search(r"saved (\d+) samples", stdout)
    lines = re.search(r"lines (\d+), comments (\d+), malformed (\d+)", stdout)
    segments = re.search(r"(\d+) static and (\d+) rotation segments", stdout)
    received = int(lines[1]) - int(lines[2]) - int(lines[3])
    holes = int((~np.isfinite(held.accel)).any(axis=1).sum())  # NaN: fill, not data
    said_segments = int(segments[1]) + int(segments[2])
    if not saved or int(saved[1]) != n or received != n or holes:
        return f"received {received}, said {saved and saved[1]}, file {n}, {holes} NaN rows"
    if len(held.segments) != said_segments or "could not be written" in stdout:
        return f"{said_segments} segments said, {len(held.segments)} in the file"
    return None


def _keep_for_study(path: Path, folder: Path) -> None:
    """A session the bench found damaged is copied out of the temporary folders (the path is
    printed), so that it can be looked at after the run."""
    keep = Path(tempfile.gettempdir()) / f"imucal-bench-{folder.name}-{path.name}"
    shutil.copy(path, keep)
    print(f"  kept {keep}", file=sys.stderr)


def _injected_disk_full(folder: Path, k: int, mode: str) -> tuple[str, str]:
    """ENOSPC from the ``/raw`` writes after 40 reads: ``transient`` fails once (freeing the
    reserve makes room: nothing may be lost), ``permanent`` always (what was written before
    stays, the rest is counted as lost, a segment over it is left out, none raises)."""
    import h5py

    from imucal_cli.capture.recorder import Recorder
    from imucal_cli.capture.stream import LineProtocol
    from imucal_cli.formats.columns import ColumnSpec

    state = {"reads": 0, "failures": 0}
    original = h5py.Dataset.__setitem__

    def setitem(ds, key, value):
        failing = mode == "permanent" or state["failures"] == 0
        if state["reads"] > 40 + 10 * k and ds.name.startswith("/raw") and failing:
            state["failures"] += 1
            raise OSError(28, "No space left on device")
        return original(ds, key, value)

    class Source:
        uri = "bench"

        def read(self):
            state["reads"] += 1
            time.sleep(0.02)  # 50 lines at 1 kHz every 20 ms or more: flushed as it goes
            n0 = state["reads"] * 50
            return b"".join(f"{(n0 + i) * 0.001:.3f},0,0,9.8,0,0,0\n".encode() for i in range(50))

        def close(self):
            pass

        def describe(self):
            return "bench source"

    out = folder / f"injected{k}.h5"
    h5py.Dataset.__setitem__ = setitem
    try:
        rec = Recorder(out, Source(), LineProtocol(ColumnSpec.parse("t,ax,ay,az,gx,gy,gz")))
        for _ in rec.blocks():
            if state["reads"] > 80:
                rec.stop()
        rec.add_segment("static", 0, 50, label="before")
        rec.add_segment("static", rec.n_samples - 50 + rec.samples_lost, rec.n_samples
                        + rec.samples_lost, label="after")  # fmt: skip
        rec.close()
    except Exception as exc:  # noqa: BLE001 - counted as a traceback
        return "traceback", f"injected {k} ({mode}): {type(exc).__name__}: {exc}"[:160]
    finally:
        h5py.Dataset.__setitem__ = original
    received = rec.protocol.stats["samples"]
    held = _held(out)
    n = held.time.size
    detail = f"injected {k} ({mode}): {n} of {received}, {len(held.segments)} segments"
    if rec.end_kind != "disk-full":
        return "wrong exit", f"{detail}: ended {rec.end_kind}"
    lost_ok = rec.samples_lost == 0 if mode == "transient" else n > 0
    ok = n == received - rec.samples_lost and lost_ok and len(held.segments) >= 1
    return ("handled" if ok else "data lost"), detail


# --------------------------------------------------------------------------------------------
# Concurrent calibrations
# --------------------------------------------------------------------------------------------


def concurrent_rows(folder: Path, n: int = 8) -> list[Row]:
    from imucal_cli.formats.session import read_session

    session = Path(shutil.copy(BASE_SESSION.with_name("qureshi18-seed1.h5"), folder / "q.h5"))
    before = read_session(session)
    procs = [subprocess.Popen([*CLI, "calibrate", str(session), "-o", str(folder / f"c{i}.json")],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for i in range(n)]  # fmt: skip
    row = Row(f"concurrent calibrations ({n} of one session)")
    results = []
    for p in procs:
        try:
            out, err = p.communicate(timeout=300)
            results.append((p.returncode, err))
        except subprocess.TimeoutExpired:
            p.kill()
            results.append((None, "timeout"))
    after = read_session(session)
    stored = len(after.calibrations)
    for code, err in results:
        if code is None:
            row.add("hang", err)
        elif "Traceback" in err:
            row.add("traceback", err[-160:])
        elif code != 0:
            row.add("wrong exit", f"exit {code}: {err.strip()}")
        else:
            row.add("handled")
    if stored != n or not _same_data(before, after):
        row.counts["data lost"] += 1
        row.examples.append(f"data lost: {stored} of {n} stored")
    return [row]


# --------------------------------------------------------------------------------------------


def run(console: Console, quick: bool = False) -> bool:
    """Run every part, print the table; return whether the last five columns are all 0."""
    n_files = 1000 if quick else 10_000
    rows: list[Row] = []
    timings = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name, part in [
            ("hostile files", lambda: hostile_rows(folder)),
            ("import fuzzer", lambda: [fuzz_imports(folder, n_files)]),
            ("format fuzzer", lambda: fuzz_formats(folder, 60 if quick else 400)),
            ("capture faults", lambda: capture_rows(folder)),
            ("disk full", lambda: disk_full_rows(folder)),
            ("concurrent", lambda: concurrent_rows(folder)),
        ]:
            start = time.monotonic()
            rows += part()
            timings[name] = time.monotonic() - start
    table = Table(title="Reliability (issue 11.6): what became of each hostile input or fault")
    table.add_column("suite")
    table.add_column("cases", justify="right")
    for column in COLUMNS:
        table.add_column(column, justify="right")
    for row in rows:
        table.add_row(row.name, str(row.counts["cases"]),
                      *(str(row.counts[c]) for c in COLUMNS))  # fmt: skip
    console.print(table)
    console.print(
        "time: " + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()),
        highlight=False,
    )
    for row in rows:
        if row.slowest is not None:
            console.print(f"  {row.name}: slowest read {row.slowest}; most blocked "
                          f"{row.most_blocked} (a hang: over {HANG_S:g} s of either)",
                          highlight=False, markup=False)  # fmt: skip
    bad = [(row, ex) for row in rows for ex in row.examples]
    for row, example in bad:
        console.print(f"  {row.name}: {example}", highlight=False, markup=False)
    return all(row.counts[c] == 0 for row in rows for c in COLUMNS[1:])


if __name__ == "__main__":
    raise SystemExit(0 if run(Console(width=160), quick="--quick" in sys.argv) else 1)
