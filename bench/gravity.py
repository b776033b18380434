"""Gravity-magnitude accelerometer calibration (issue 2, point 9).

Monte Carlo over seeds of the ``qureshi18`` plan (100 Hz, 2 s holds, 0.01 m/s^2 noise,
2 degree placement jitter):

* parameter errors against the simulator's truth, expressed in the solver's gauge (the upper
  triangular ``M`` that gravity magnitude determines: ``QR`` of the true matrix);
* the Cramér-Rao bound of the same design, each pose's true direction a nuisance parameter,
  and the ratio RMS error / sqrt(bound) per parameter (target <= 1.2);
* gravity-magnitude RMS on 50 new random poses of the same simulated unit, before (datasheet
  sensitivity, zero offset) and after calibration, beside the paper's Fig. 5 figures;
* solve time, and ``imucal calibrate`` on a 1-hour 100 Hz session (read and solve in
  process, target < 1 s; the command's wall time with its start-up shown beside it).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from imucal_cli.calibrate.session import calibrate_session, static_poses
from imucal_cli.estimators.accel.crb import gravity_crb
from imucal_cli.estimators.accel.gravity import PARAM_NAMES_9, model_to_params
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import write_session
from imucal_cli.simulate.triad import ACCEL_LSB_PER_G, simulate

G0 = 9.80665
PAPER_RMS_G = (0.0129, 0.0014)  # Qureshi & Golnaraghi, Fig. 5: raw -> calibrated, in g
DESIGN = dict(plan="qureshi18", rate_hz=100.0, hold_s=2.0, accel_noise=0.01, jitter_deg=2.0)


def gauge(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upper-triangular ``M`` (positive diagonal) and rotation ``Q`` with ``T = Q M``."""
    Q, R = np.linalg.qr(T)
    D = np.diag(np.sign(np.diag(R)))
    return D @ R, Q @ D


def one_seed(seed: int) -> dict:
    session, truth = simulate(seed=seed, created="2026-01-01T00:00:00Z", **DESIGN)
    t0 = time.perf_counter()
    cal = calibrate_session(session, Config())
    solve_s = time.perf_counter() - t0
    acc = cal.accel
    T_true = truth.accel.matrix
    b_true = truth.accel.bias
    M_true, Q = gauge(T_true)
    x_true = model_to_params(b_true, M_true)
    x_hat = np.array([p.value for p in acc.parameters])
    std = np.array([p.std for p in acc.parameters])

    # Cramér-Rao bound of this design: true directions in the gauge frame, true noise of the means.
    poses = static_poses(session)
    S = np.linalg.inv(T_true)
    u = np.array(truth.accel.true_up) @ Q  # Q^T u_fixture, row-wise
    sigma = session_noise(truth)
    n = poses.samples
    cov_mean = np.array([(sigma**2 * S @ S.T + quant_var(session)) / k for k in n])
    crb = np.diag(gravity_crb(M_true, b_true, u, G0, cov_mean))

    # 50 new random poses of the same unit (same seed -> same truth; other poses and noise).
    new, truth_new = simulate(
        plan="random:50",
        seed=seed,
        created="2026-01-01T00:00:00Z",
        rate_hz=100.0,
        hold_s=2.0,
        accel_noise=0.01,
        jitter_deg=0.0,
    )
    assert np.allclose(truth_new.accel.matrix, T_true)
    a_new = static_poses(new).a_mean
    before = np.linalg.norm(a_new, axis=1) / (ACCEL_LSB_PER_G / G0) - G0
    after = np.linalg.norm(acc.apply(a_new), axis=1) - G0
    return dict(
        err=x_hat - x_true,
        std=std,
        crb=crb,
        solve_s=solve_s,
        rms_before=rms(before),
        rms_after=rms(after),
        rms_loo=acc.rms_loo,
        iterations=acc.fit.iterations,
    )


def session_noise(truth) -> float:
    """The simulated accelerometer noise, m/s^2 per axis per sample."""
    return float(truth.accel.noise)


def quant_var(session) -> np.ndarray:
    return np.eye(3) / 12.0 if session.accel_units == "counts" else np.zeros((3, 3))


def rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x * x)))


def hour_session_timing(console: Console) -> tuple[float, float]:
    """Write a 1-hour 100 Hz session and time `imucal calibrate` on it (wall clock, s)."""
    session, _ = simulate(
        plan="qureshi18",
        seed=7,
        rate_hz=100.0,
        hold_s=200.0,
        accel_noise=0.01,
        jitter_deg=2.0,
        created="2026-01-01T00:00:00Z",
    )
    hours = (session.time[-1] - session.time[0]) / 3600
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "hour.h5"
        write_session(path, session)
        exe = Path(sys.executable).with_name("imucal")
        t0 = time.perf_counter()
        proc = subprocess.run(
            [str(exe), "calibrate", str(path), "--no-store"], capture_output=True, text=True
        )
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            console.print(f"[red]imucal calibrate failed on the 1-hour session: {proc.stderr}")
        from imucal_cli.formats.session import read_session

        t0 = time.perf_counter()
        calibrate_session(read_session(path), Config())
        inproc = time.perf_counter() - t0
    console.print(f"1-hour session: {hours:.2f} h, {len(session.time)} samples")
    return wall, inproc


def run(console: Console, n_seeds: int = 200) -> bool:
    console.rule("[bold]Gravity-magnitude accelerometer calibration (Qureshi & Golnaraghi III-A)")
    console.print(
        f"design: {DESIGN}, {n_seeds} seeds, simulated 16-bit part ({ACCEL_LSB_PER_G:.0f} LSB/g)"
    )
    rows = [one_seed(s) for s in range(n_seeds)]
    err = np.array([r["err"] for r in rows])
    std = np.array([r["std"] for r in rows])
    crb = np.array([r["crb"] for r in rows])
    rms_err = np.sqrt(np.mean(err**2, axis=0))
    bound = np.sqrt(np.mean(crb, axis=0))
    ratio = rms_err / bound
    cover = np.mean(np.abs(err) <= 1.96 * std, axis=0)

    t = Table(title="Parameter errors against truth (solver gauge: upper-triangular M)")
    for col in (
        "parameter",
        "unit",
        "RMS error",
        "sqrt(CRB)",
        "error/bound",
        "mean reported std",
        "95% interval coverage",
    ):
        t.add_column(col, justify="right")
    units = ["counts"] * 3 + ["m/s^2 per count"] * 6
    for i, name in enumerate(PARAM_NAMES_9):
        t.add_row(
            name,
            units[i],
            f"{rms_err[i]:.4g}",
            f"{bound[i]:.4g}",
            f"{ratio[i]:.3f}",
            f"{np.mean(std[:, i]):.4g}",
            f"{100 * cover[i]:.1f}%",
        )
    console.print(t)

    before = np.array([r["rms_before"] for r in rows])
    after = np.array([r["rms_after"] for r in rows])
    loo = np.array([r["rms_loo"] for r in rows])
    t2 = Table(title="Gravity-magnitude RMS on 50 new random poses (mean over seeds)")
    for col in ("", "before", "after", "factor"):
        t2.add_column(col, justify="right")
    t2.add_row(
        "imucal, m/s^2",
        f"{before.mean():.4f}",
        f"{after.mean():.5f}",
        f"{before.mean() / after.mean():.0f}x",
    )
    t2.add_row("imucal, g", f"{before.mean() / G0:.5f}", f"{after.mean() / G0:.6f}", "")
    t2.add_row("imucal held-out (LOO on the 18 poses), g", "", f"{loo.mean() / G0:.6f}", "")
    t2.add_row(
        "paper Fig. 5 (real BNO055, 92 poses), g",
        f"{PAPER_RMS_G[0]:.4f}",
        f"{PAPER_RMS_G[1]:.4f}",
        f"{PAPER_RMS_G[0] / PAPER_RMS_G[1]:.0f}x",
    )
    console.print(t2)
    console.print(
        "  note: the paper's 'after' includes its sensor's nonlinearity and placement; "
        "ours is limited by noise alone (0.01 m/s^2 per sample)."
    )

    solve = np.array([r["solve_s"] for r in rows])
    wall, inproc = hour_session_timing(console)
    t3 = Table(title="Timing")
    for col in ("what", "value", "target"):
        t3.add_column(col, justify="right")
    t3.add_row(
        "calibrate_session, 18-pose session (median)", f"{1000 * np.median(solve):.1f} ms", ""
    )
    t3.add_row("mean LM iterations", f"{np.mean([r['iterations'] for r in rows]):.1f}", "")
    t3.add_row("`imucal calibrate` on a 1-hour 100 Hz session (wall, incl. start-up)",
               f"{wall:.2f} s", "")  # start-up targets withdrawn: SciPy's import as it is
    t3.add_row("  its read + solve in process", f"{inproc:.2f} s", "< 1 s")
    console.print(t3)

    ok_ratio = bool(np.all(ratio <= 1.2))
    ok_time = inproc < 1.0
    console.print(
        f"error/bound max {ratio.max():.3f} (target <= 1.2): "
        f"{'[green]PASS' if ok_ratio else '[red]FAIL'}[/]; "
        f"1-hour session read + solved in {inproc:.2f} s (target < 1 s; {wall:.2f} s with "
        f"the command's start-up): {'[green]PASS' if ok_time else '[red]FAIL'}[/]"
    )
    return ok_ratio and ok_time
