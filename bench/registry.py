"""The registry (issue 29.5): ``python -m bench --only registry``.

10,000 units recorded by 4 writer processes at once (2,500 each, one transaction per unit, the
whole calibration kept), into a SQLite file and, when a server can start here
(:mod:`bench.pg_server`), into PostgreSQL; then

- nothing lost: the registry holds exactly the 10,000 calibrations the writers said they
  recorded, each document's SHA-256 the one its writer computed, each with its sections and
  figures (count and content check);
- ``imucal registry lot LOT`` over all 10,000 units, in a fresh process, under
  :data:`LOT_TARGET_S` of CPU (the command's own, start-up included, plus on PostgreSQL the
  server's) (PASS/FAIL), with its breakdown beside it: the command's start-up (``imucal
  registry lot --help`` measured the same way: the interpreter, typer and the registry
  command's modules and libraries, nothing read; ``imucal`` imports a command's module only
  when a command line names it), the CPU beyond it, the statistics' own CPU in this process,
  and the wall time (on a shared machine mostly the wait for a CPU); and that
  it finds the units planted to stand apart and to drift (a check of the statistics, not only
  of their speed).

The units are variants of one real calibration (``sessions/qureshi18-seed1.h5`` calibrated once):
every bias, gain and angle drawn anew per unit around it, with the std it states
(:func:`variant`), some units far off (:data:`APART`) and some re-calibrated, some of those
drifted (:data:`DRIFTED`).

``python -m bench.registry writer URL TEMPLATE.json FIRST COUNT LOT [--hang-after K]`` is one
writer (the tests start it too): it records units FIRST..FIRST+COUNT-1 and prints ``recorded
UID SHA256 SERIAL`` for each after its commit; with ``--hang-after K`` the unit after K stops in
the middle of its transaction (the calibration written, not its figures), prints ``mid-write``
and waits, to be killed there.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table
from sqlalchemy import func, select

from bench import pg_server
from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.model.calibration import Calibration
from imucal_cli.registry import record as record_module
from imucal_cli.registry.lot import lot_statistics
from imucal_cli.registry.record import UnitInfo, record_calibration
from imucal_cli.registry.schema import calibrations, documents, figures, sections, units
from imucal_cli.registry.store import open_registry
from imucal_cli.use.limits import judge_calibration, limits_from_dict

ROOT = Path(__file__).resolve().parents[1]
UNITS = 10_000
WRITERS = 4
LOT = "LOT-A"
LOT_TARGET_S = 2.0
"""``imucal registry lot`` over the 10,000 units: CPU seconds, client and server, start-up
included (the issue's "in under 2 s": on a shared machine the wall time is mostly the wait for
a CPU; it is shown beside)."""
LOT_RUNS = 3
APART = 10
"""Units whose accel bias x is drawn 40 of the lot's std away (they must stand apart)."""
RECALIBRATED = 200
"""Units calibrated a second time; every tenth of them has drifted (:data:`DRIFTED`)."""
DRIFTED = RECALIBRATED // 10
PRODUCT_LIMITS = {
    "product": {"name": "SIM-16"},
    "limits": {
        "accel": {"units": "m/s^2", "bias_max": 0.8, "nominal_sensitivity": 835.0,
                  "gain_error_max_pct": 4.0, "misalignment_max_deg": 1.0, "noise_max": 0.03,
                  "residual_rms_max": 0.005, "held_out_rms_max": 0.01},
        "gyro": {"bias_max": 0.1, "nominal_sensitivity": 939.7, "gain_error_max_pct": 5.0,
                 "misalignment_max_deg": 1.0},
    },
}  # fmt: skip


def make_template(folder: Path) -> Path:
    """Calibrate a copy of the shipped qureshi18 session; the calibration JSON's path."""
    session = folder / "template.h5"
    shutil.copy(ROOT / "sessions" / "qureshi18-seed1.h5", session)
    out = folder / "template.cal.json"
    imucal = str(Path(sys.executable).with_name("imucal"))
    subprocess.run([imucal, "calibrate", str(session), "-o", str(out), "--force"], check=True,
                   stdout=subprocess.DEVNULL)  # fmt: skip
    return out


def variant(template: dict, serial: str, index: int, *, apart: bool = False,
            drift: float = 0.0, created: str | None = None):  # fmt: skip
    """A calibration like ``template`` for another unit: biases, sensitivities and angles of
    accel and gyro drawn around the template's by the spread of a lot (per parameter: 50
    times its stated std), deterministically from ``index``; ``apart``: accel bias x 40 lot
    std off; ``drift``: accel bias x moved by this many of its stated std (a re-calibration).

    Returns
    -------
    Calibration
    """
    rng = np.random.default_rng(index)
    again = np.random.default_rng(index + 1_000_000) if created else None  # a re-calibration
    doc = copy.deepcopy(template)
    doc["sensor"] = serial
    doc["created"] = created or f"2026-01-01T00:00:{index % 60:02d}Z"
    for kind in ("accel", "gyro"):
        sec = doc.get(kind)
        if not sec:
            continue
        params = {p["name"]: p for p in sec.get("parameters", [])}
        bias = np.array(sec["bias"], dtype=float)
        std_b = np.array([params.get(f"b_{a}", {}).get("std") or 1.0 for a in "xyz"])
        bias += rng.normal(0.0, 50.0 * std_b)
        if kind == "accel" and apart:
            bias[0] += 40 * 50.0 * std_b[0]
        if again is not None:  # measured anew: its own noise, the stated std
            bias += again.normal(0.0, std_b)
        if kind == "accel" and drift:
            bias[0] += drift * std_b[0]
        gain = 1.0 + rng.normal(0.0, 0.004, 3)
        sec["bias"] = bias.tolist()
        sec["matrix"] = (np.array(sec["matrix"]) / gain[:, None]).tolist()
        for a, b in zip("xyz", bias, strict=True):
            if f"b_{a}" in params:
                params[f"b_{a}"]["value"] = float(b)
        if sec.get("sensitivity"):
            sec["sensitivity"] = (np.array(sec["sensitivity"]) * gain).tolist()
        if isinstance(sec.get("misalignment_deg"), dict):
            sec["misalignment_deg"] = {k: v + float(rng.normal(0.0, 0.05))
                                       for k, v in sec["misalignment_deg"].items()}  # fmt: skip
    return Calibration.from_dict(doc, source=serial)


def plan(index: int) -> dict:
    """What unit ``index`` (0-based) is: ``apart``, ``recalibrated``, ``drift``."""
    recal = index % (UNITS // RECALIBRATED) == 1 if UNITS >= RECALIBRATED else False
    return {"apart": index % (UNITS // APART) == 3, "recalibrated": recal,
            "drift": 12.0 if recal and (index // (UNITS // RECALIBRATED)) % 10 == 0 else 0.0}


def serial_of(index: int) -> str:
    return f"SN{index:06d}"


def writer_main(argv: list[str]) -> int:
    """One writer process (see the module notes)."""
    url, template_path, first, count, lot = argv[:5]
    hang_after = int(argv[argv.index("--hang-after") + 1]) if "--hang-after" in argv else None
    template = json.loads(Path(template_path).read_text())
    limits = limits_from_dict(PRODUCT_LIMITS, "bench")
    registry = open_registry(url)
    print("ready", flush=True)
    for n, index in enumerate(range(int(first), int(first) + int(count))):
        if hang_after is not None and n == hang_after:
            _hang_in_the_middle(record_module)
        todo = plan(index)
        cal = variant(template, serial_of(index), index, apart=todo["apart"])
        _record(registry, cal, lot, limits)
        if todo["recalibrated"]:
            again = variant(template, serial_of(index), index, apart=todo["apart"],
                            drift=todo["drift"], created="2026-06-01T00:00:00Z")  # fmt: skip
            _record(registry, again, lot, limits)
    registry.close()
    return 0


def _record(registry, cal, lot, limits) -> None:
    acceptance = judge_calibration(cal, limits)
    done = record_calibration(registry, cal,
                              UnitInfo(cal.sensor, "SIM-16", lot, "bench", "w"),
                              session_sha256="0" * 64, acceptance=acceptance,
                              limits=limits)  # fmt: skip
    sha = hashlib.sha256(calibration_to_json(cal).encode()).hexdigest()
    print(f"recorded {done.uid} {sha} {done.serial}", flush=True)


def _hang_in_the_middle(record_module) -> None:
    """From now on a record stops after writing half its figures, inside its transaction."""
    original = record_module._figures

    def half_then_wait(conn, cal_id, figs):
        first = dict(list(figs.items())[:1])
        original(conn, cal_id, first)
        print("mid-write", flush=True)
        sys.stdin.readline()  # killed here
        original(conn, cal_id, dict(list(figs.items())[1:]))

    record_module._figures = half_then_wait


def start_writers(url: str, template: Path, units: int, writers: int, lot: str,
                  env: dict | None = None) -> list[subprocess.Popen]:  # fmt: skip
    """``writers`` writer processes sharing ``units`` units."""
    per = units // writers
    return [subprocess.Popen([sys.executable, "-m", "bench.registry", "writer", url,
                              str(template), str(i * per), str(per), lot],
                             cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, env=env)
            for i in range(writers)]  # fmt: skip


def collect(procs: list[subprocess.Popen]) -> tuple[dict[str, tuple[str, str]], list[str]]:
    """Wait for the writers: ``{uid: (sha256, serial)}`` they recorded, and their errors."""
    recorded: dict[str, tuple[str, str]] = {}
    errors = []
    for proc in procs:
        out, err = proc.communicate()
        for line in out.splitlines():
            if line.startswith("recorded "):
                _, uid, sha, serial = line.split(" ", 3)
                recorded[uid] = (sha, serial)
        if proc.returncode:
            last = err.strip().splitlines()[-1] if err.strip() else f"exit {proc.returncode}"
            errors.append(last)
    return recorded, errors


def verify(url: str, recorded: dict[str, tuple[str, str]]) -> tuple[bool, str]:
    """Whether the registry holds exactly ``recorded``: same uids, each document's SHA-256 as
    its writer computed it (recomputed from the stored text), each with its sections and
    figures."""
    with open_registry(url, create=False) as reg, reg.read() as conn:
        rows = conn.execute(select(calibrations.c.uid, documents.c.document,
                                   calibrations.c.document_sha256, units.c.serial)
                            .join(units, units.c.id == calibrations.c.unit_id)
                            .join(documents, documents.c.calibration_id == calibrations.c.id)
                            ).all()  # fmt: skip
        empty = conn.execute(
            select(func.count()).select_from(calibrations)
            .where(~select(sections.c.id).where(sections.c.calibration_id == calibrations.c.id)
                   .exists())
        ).scalar_one()  # fmt: skip
        bare = conn.execute(
            select(func.count()).select_from(sections)
            .where(~select(figures.c.id).where(figures.c.section_id == sections.c.id).exists())
        ).scalar_one()  # fmt: skip
    stored = {r.uid: r for r in rows}
    missing = set(recorded) - set(stored)
    extra = set(stored) - set(recorded)
    wrong = [uid for uid, (sha, serial) in recorded.items() if uid in stored and (
        hashlib.sha256(stored[uid].document.encode()).hexdigest() != sha
        or stored[uid].document_sha256 != sha or stored[uid].serial != serial)]  # fmt: skip
    ok = not (missing or extra or wrong or empty or bare)
    return ok, (f"{len(stored)} stored, {len(missing)} missing, {len(extra)} unexpected, "
                f"{len(wrong)} differ, {empty} without sections, {bare} sections without "
                "figures")  # fmt: skip


def _timed(args: list[str], folder: Path) -> tuple[float, float, str]:
    """Run ``args`` once: its CPU seconds (user + system, from its own rusage: start-up
    included, a loaded machine's wait for the CPU not), wall seconds, and its stdout."""
    out_path, err_path = folder / "lot.out", folder / "lot.err"
    with open(out_path, "w") as out, open(err_path, "w") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(args, stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise RuntimeError(err_path.read_text().strip())
    return usage.ru_utime + usage.ru_stime, wall, out_path.read_text()


def _lot_timing(url: str, folder: Path, server=None) -> tuple[float, float, float, dict]:
    """``imucal registry lot`` over the whole lot in a fresh process, :data:`LOT_RUNS` times
    after a warm-up run (the operating system's file cache, the bytecode): median CPU seconds
    (the command's own and, on PostgreSQL, the server's for it), the server's part, median wall
    seconds, and its statistics."""
    imucal = str(Path(sys.executable).with_name("imucal"))
    args = [imucal, "registry", "lot", LOT, "--registry", url, "--json"]
    _timed(args, folder)
    cpus, server_cpus, walls = [], [], []
    for _ in range(LOT_RUNS):
        before = server.cpu_s() if server is not None else None
        cpu, wall, out = _timed(args, folder)
        after = server.cpu_s() if server is not None else None
        part = after - before if before is not None and after is not None else 0.0
        cpus.append(cpu + part)
        server_cpus.append(part)
        walls.append(wall)
    return (float(np.median(cpus)), float(np.median(server_cpus)), float(np.median(walls)),
            json.loads(out))  # fmt: skip


def _statistics_cpu(url: str, server=None) -> float:
    """CPU seconds of the lot's statistics alone (``lot_statistics`` in this process, the
    registry open; on PostgreSQL with the server's part): what ``registry lot`` costs beyond
    the start-up every command has. Median of :data:`LOT_RUNS`."""
    cpus = []
    with open_registry(url, create=False) as reg:
        for _ in range(LOT_RUNS):
            before = server.cpu_s() if server is not None else None
            c0 = time.process_time()
            lot_statistics(reg, LOT)
            cpu = time.process_time() - c0
            after = server.cpu_s() if server is not None else None
            cpus.append(cpu + (after - before if before is not None and after is not None
                               else 0.0))  # fmt: skip
    return float(np.median(cpus))


def _expected() -> tuple[set[str], set[str]]:
    apart = {serial_of(i) for i in range(UNITS) if plan(i)["apart"]}
    drifted = {serial_of(i) for i in range(UNITS) if plan(i)["drift"]}
    return apart, drifted


def _one(console: Console, table: Table, name: str, url: str, template: Path,
         server=None) -> bool:  # fmt: skip
    t0 = time.perf_counter()
    procs = start_writers(url, template, UNITS, WRITERS, LOT)
    recorded, errors = collect(procs)
    wall = time.perf_counter() - t0
    ok, what = verify(url, recorded)
    expected_records = UNITS + RECALIBRATED
    ok = ok and not errors and len(recorded) == expected_records
    lot_s, server_s, lot_wall, stats = _lot_timing(url, template.parent, server)
    work_s = _statistics_cpu(url, server)
    start_s = float(np.median([_timed([str(Path(sys.executable).with_name("imucal")),
                                       "registry", "lot", "--help"], template.parent)[0]
                               for _ in range(LOT_RUNS)]))  # fmt: skip
    apart, drifted = _expected()
    found_apart = {u["serial"] for u in stats["units_apart"]
                   if any(p.startswith("accel bias x") for p in u["parameters"])}  # fmt: skip
    found_drift = {a["serial"] for a in stats["drift"]["alarms"]}
    right = apart <= found_apart and found_drift == drifted
    own_s = lot_s - start_s  # the lot's work, beyond the command's start-up
    table.add_row(
        name, f"{UNITS:,} + {RECALIBRATED} re-cal", f"{wall:.1f} s",
        f"{expected_records / wall:.0f}/s",
        ("PASS " if ok else "FAIL ") + what + (f"; errors: {errors[:2]}" if errors else ""),
        f"{lot_s:.2f} s CPU" + (f" ({server_s:.2f} server)" if server is not None else "")
        + f" = start-up (imucal registry lot --help) {start_s:.2f} s + {own_s:.2f} s; "
        f"{lot_wall:.2f} s "
        f"wall; the statistics alone {work_s:.2f} s CPU "
        + ("PASS" if lot_s < LOT_TARGET_S else "FAIL"),
        f"apart {len(found_apart & apart)}/{len(apart)}, drift {len(found_drift & drifted)}/"
        f"{len(drifted)} (+{len(found_drift - drifted)} false) " + ("PASS" if right else "FAIL"),
    )  # fmt: skip
    return ok and lot_s < LOT_TARGET_S and right


def run(console: Console) -> bool:
    """Both databases (PostgreSQL when a server starts here); True when every row passes."""
    title = (f"registry: {UNITS:,} units by {WRITERS} concurrent writer processes, then "
             f"imucal registry lot in a fresh process (median of {LOT_RUNS}; target < "
             f"{LOT_TARGET_S:g} s CPU, start-up included, client and server)")  # fmt: skip
    table = Table(title=title)
    for col in ("database", "records", "write wall", "throughput", "nothing lost",
                "registry lot", "lot finds"):  # fmt: skip
        table.add_column(col)
    ok = True
    with tempfile.TemporaryDirectory(prefix="imucal-bench-registry-") as tmp:
        folder = Path(tmp)
        template = make_template(folder)
        ok = _one(console, table, "SQLite (WAL, synchronous=FULL)", str(folder / "reg.db"),
                  template) and ok  # fmt: skip
        why = pg_server.unavailable()
        if why is None:
            try:
                server = pg_server.start("bench", fsync=True)
            except RuntimeError as exc:
                why = str(exc)
            else:
                try:
                    ok = _one(console, table, "PostgreSQL (fsync on)", server.url, template,
                              server) and ok  # fmt: skip
                finally:
                    server.stop()
        if why is not None:
            table.add_row("PostgreSQL", "skipped", "", "", why, "", "")
    console.print(table)
    return ok


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "writer":
        os.environ.setdefault("PYTHONUNBUFFERED", "1")
        raise SystemExit(writer_main(sys.argv[2:]))
    raise SystemExit(0 if run(Console(width=200)) else 1)
