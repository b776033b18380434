"""Speed of the full gyro model (issue 14.3): CPU time and memory of the solve.

The 37 rotations of the Xsens recording (``../shared/data/imu_tk_xsens``, raw counts, skipped
when absent), then simulated sessions of 37, 600 and 1,800 turns: CPU seconds of
``fit_full`` (median of several runs, so that a busy machine does not hide them; wall beside
it) and the peak memory the solve allocates (tracemalloc). Time and memory must grow linearly
with the number of turns.
"""

from __future__ import annotations

import time
import tracemalloc

import numpy as np
from rich.console import Console
from rich.table import Table

from bench.gyro import shared_data
from imucal_cli.formats.config import config_from_dict
from imucal_cli.pipeline.calibrate import calibrate_accel, with_segments
from imucal_cli.pipeline.gyro import full_problem
from imucal_cli.simulate.rotations import simulate_gyro_rotations
from imucal_cli.solvers.gyro_full import fit_full

DATA = shared_data()
CREATED = "2026-01-01T00:00:00Z"
#: Before the rewrite (issue 14): dense noise Jacobian, dense Cholesky and inverse.
BEFORE = {"Xsens": "2.8 s", 600: "17.7 s, 750 MB", 1800: "198 s, 5.1 GB"}
TARGET_XSENS_S, TARGET_1800_S, TARGET_1800_MIB = 0.1, 5.0, 300.0


def _problem(session):
    cfg = config_from_dict({"gyro": {"solver": "full"},
                            "accel": {"gravity": {"leave_one_out": False}}})  # fmt: skip
    session, _ = with_segments(session)
    accel = calibrate_accel(session, cfg)
    rot, still, noise = full_problem(session, cfg, accel)
    w = 1 / still.z_sigma**2
    b0 = (still.z_mean * w[:, None]).sum(axis=0) / w.sum()
    return rot, still, noise, b0


def _measure(args, runs: int) -> dict:
    cpu, wall = [], []
    for _ in range(runs):
        c0, w0 = time.process_time(), time.perf_counter()
        res = fit_full(*args)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    tracemalloc.start()
    fit_full(*args)
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return {"cpu": float(np.median(cpu)), "wall": float(np.median(wall)), "peak": peak,
            "nfev": res.iterations, "turns": len(args[0].t),
            "samples": sum(len(t) for t in args[0].t)}  # fmt: skip


def run(console: Console, runs: int = 5) -> bool:
    console.rule("[bold]Gyro full model: speed and memory (issue 14.3)")
    rows = []
    xsens = DATA / "imu_tk_xsens"
    if xsens.is_dir():
        from imucal_cli.formats.importers import import_files

        session = import_files([xsens / "xsens_acc.mat", xsens / "xsens_gyro.mat"], "imu_tk",
                               accel_units="counts", gyro_units="counts")  # fmt: skip
        rows.append(("Xsens (real)", _measure(_problem(session), runs)))
    else:
        console.print(f"[yellow]{xsens} not found: Xsens timing skipped")
    for n in (37, 600, 1800):
        if n <= 1000:
            session, _ = simulate_gyro_rotations(plan=f"free:{n}", seed=5, created=CREATED)
        else:
            session, _ = simulate_gyro_rotations(plan="qureshi-axes", rotations_per_axis=n // 3,
                                                 seed=5, created=CREATED)  # fmt: skip
        rows.append((f"simulated, {n} turns", _measure(_problem(session), 3 if n > 100 else runs)))
    t = Table(title="fit_full: CPU (median), wall, peak memory of the solve")
    for col in ("session", "turns", "samples in turns", "evaluations", "CPU, s", "wall, s",
                "CPU per turn, ms", "peak memory, MiB", "before"):  # fmt: skip
        t.add_column(col, justify="right")
    for name, m in rows:
        before = BEFORE.get("Xsens" if name.startswith("Xsens") else m["turns"], "-")
        t.add_row(name, str(m["turns"]), str(m["samples"]), str(m["nfev"]), f"{m['cpu']:.3f}",
                  f"{m['wall']:.3f}", f"{1000 * m['cpu'] / m['turns']:.2f}", f"{m['peak']:.0f}",
                  before)  # fmt: skip
    console.print(t)
    by_turns = {m["turns"]: m for name, m in rows if name.startswith("simulated")}
    big, mid = by_turns[1800], by_turns[600]
    growth = (big["cpu"] / big["samples"]) / (mid["cpu"] / mid["samples"])
    mem_growth = (big["peak"] / big["samples"]) / (mid["peak"] / mid["samples"])
    ok = big["cpu"] < TARGET_1800_S and big["peak"] < TARGET_1800_MIB and growth < 1.5
    msg = (f"1,800 turns: {big['cpu']:.2f} s CPU (target < {TARGET_1800_S:g}), "
           f"{big['peak']:.0f} MiB (target < {TARGET_1800_MIB:g}); per-sample CPU 1800 vs 600 "
           f"turns x{growth:.2f}, memory x{mem_growth:.2f} (linear: about 1)")  # fmt: skip
    if rows[0][0].startswith("Xsens"):
        x = rows[0][1]
        ok = ok and x["cpu"] < TARGET_XSENS_S
        msg = f"Xsens: {x['cpu']:.3f} s CPU (target < {TARGET_XSENS_S:g}); " + msg
    console.print(msg + (": [green]PASS[/]" if ok else ": [red]FAIL[/]"))
    return bool(ok)
