"""Gyroscope calibration from hand rotations (issue 5, points 6-7).

Monte Carlo over seeds of the paper's procedure (``qureshi-axes``: 18 hand turns per axis
within +-180 degrees, up to 150 deg/s, 5 s still before and after, 2-degree placement and axis
errors): scale and bias errors of the static, dynamic and full solvers against the truth
(expressed in the calibrated accelerometer's frame, the frame every solver reports in), the
full model's misalignment error in degrees and its ratio to the Cramér-Rao bound, beside the
paper's comparison with its rate table. Then the real recordings in ``../shared/data`` that
hold rotations: imported, calibrated with the full model, and their per-rotation residuals.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from imucal_cli.errors import ImucalError
from imucal_cli.formats.config import config_from_dict
from imucal_cli.pipeline.calibrate import calibrate_session
from imucal_cli.pipeline.gyro import full_problem
from imucal_cli.simulate.rotations import simulate_gyro_rotations
from imucal_cli.solvers.gyro_full import full_information

CREATED = "2026-01-01T00:00:00Z"
SOLVERS = ("static", "dynamic", "full")
#: Qureshi & Golnaraghi Table III-B: mean deviation of the scale factors from the rate table.
PAPER_MEAN_DEVIATION_PCT = {"static": 0.1409, "dynamic": 0.4060}
DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def _truth_in_accel_frame(cal, truth) -> np.ndarray:
    R = cal.accel.matrix @ np.linalg.inv(truth.accel.matrix)
    U, _, Vt = np.linalg.svd(R)
    return (U @ Vt) @ truth.gyro.matrix


def _axes_angles_deg(M_est: np.ndarray, M_true: np.ndarray) -> np.ndarray:
    """Angle between estimated and true sensitivity axes (rows of M^-1), degrees."""
    a, b = np.linalg.inv(M_est), np.linalg.inv(M_true)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1, 1)))


def one_seed(seed: int) -> dict:
    session, truth = simulate_gyro_rotations(plan="qureshi-axes", seed=seed, created=CREATED)
    out = {}
    for solver in SOLVERS:
        cfg = config_from_dict({"accel": {"gravity": {"leave_one_out": False}},
                                "gyro": {"solver": solver}})  # fmt: skip
        t0 = time.perf_counter()
        cal = calibrate_session(session, cfg)
        elapsed = time.perf_counter() - t0
        M_true = _truth_in_accel_frame(cal, truth)
        g = cal.gyro
        out[solver] = {
            "scale_pct": 100 * (np.diag(g.matrix) / np.diag(M_true) - 1),
            "bias": g.bias - truth.gyro.bias,
            "time": elapsed,
            "rot_rms": g.extra["rotation_rms_deg"],
        }
        if solver == "full":
            x_hat = np.r_[g.bias, g.matrix.ravel()]
            x_true = np.r_[truth.gyro.bias, M_true.ravel()]
            out["full"]["err"] = x_hat - x_true
            out["full"]["std"] = np.array([p["std"] for p in g.extra["parameters"]])
            out["full"]["axes_deg"] = _axes_angles_deg(g.matrix, M_true)
            rot, still, noise = full_problem(session, cfg, cal.accel)
            out["full"]["crb"] = np.diag(np.linalg.inv(full_information(x_true, rot, still, noise)))
    return out


def simulated(console: Console, n_seeds: int) -> bool:
    runs = [one_seed(s) for s in range(n_seeds)]
    t = Table(title=f"Gyro from hand rotations, qureshi-axes plan, {n_seeds} seeds "
                    "(errors against truth in the accelerometer's frame)")  # fmt: skip
    for col in ("solver", "scale error RMS, % (x, y, z)", "mean |scale error|, %",
                "paper vs rate table, %", "bias error RMS, counts", "rotation residual RMS, deg",
                "time per calibrate"):  # fmt: skip
        t.add_column(col, justify="right")
    worst_scale = 0.0
    for solver in SOLVERS:
        sc = np.array([r[solver]["scale_pct"] for r in runs])
        bi = np.array([r[solver]["bias"] for r in runs])
        rms_sc = np.sqrt(np.mean(sc**2, axis=0))
        worst_scale = max(worst_scale, rms_sc.max())
        paper = PAPER_MEAN_DEVIATION_PCT.get(solver)
        t.add_row(
            solver,
            ", ".join(f"{v:.4f}" for v in rms_sc),
            f"{np.mean(np.abs(sc)):.4f}",
            f"{paper:.2f}" if paper else "-",
            ", ".join(f"{v:.3f}" for v in np.sqrt(np.mean(bi**2, axis=0))),
            f"{np.mean([r[solver]['rot_rms'] for r in runs]):.3f}",
            f"{1000 * np.mean([r[solver]['time'] for r in runs]):.0f} ms",
        )
    console.print(t)
    err = np.array([r["full"]["err"] for r in runs])
    crb = np.array([r["full"]["crb"] for r in runs])
    std = np.array([r["full"]["std"] for r in runs])
    ratio = np.sqrt(np.mean(err**2, axis=0) / np.mean(crb, axis=0))
    cover = np.mean(np.abs(err) <= 1.96 * std, axis=0)
    axes = np.array([r["full"]["axes_deg"] for r in runs])
    names = ["b_x", "b_y", "b_z"] + [f"m_{a}{b}" for a in "xyz" for b in "xyz"]
    t2 = Table(title="Full 12-parameter model against its Cramér-Rao bound")
    for col in ("parameter", "RMS error", "sqrt(CRB)", "error/bound", "95% coverage"):
        t2.add_column(col, justify="right")
    for i, n in enumerate(names):
        rms_err, bound = np.sqrt(np.mean(err[:, i] ** 2)), np.sqrt(np.mean(crb[:, i]))
        t2.add_row(n, f"{rms_err:.4g}", f"{bound:.4g}",
                   f"{ratio[i]:.2f}", f"{100 * cover[i]:.0f}%")  # fmt: skip
    console.print(t2)
    ok = ratio.max() <= 1.2 and worst_scale < 0.1
    console.print(
        f"full model: sensitivity-axis (misalignment) error RMS "
        f"{', '.join(f'{v:.4f}' for v in np.sqrt(np.mean(axes**2, axis=0)))} deg (x, y, z); "
        f"error/bound max {ratio.max():.2f} (target <= 1.2); worst scale error RMS "
        f"{worst_scale:.4f} % (target < 0.1 %): {'[green]PASS' if ok else '[red]FAIL'}[/]"
    )
    return bool(ok)


REAL = [
    ("imu_tk xsens (counts)", "imu_tk",
     ["imu_tk_xsens/xsens_acc.mat", "imu_tk_xsens/xsens_gyro.mat"],
     dict(accel_units="counts", gyro_units="counts")),
    *[(f"mikoff MPU-9150 imu{i}", "csv", [f"mikoff_mpu9150/imu{i}.log"],
       dict(columns="ax,ay,az,gx,gy,gz", rate_hz=100.0, accel_units="m/s^2", gyro_units="rad/s"))
      for i in range(5)],
    ("tomisuarez2 MPU-6050 (counts)", "csv", ["tomisuarez2_mpu6050/example_data_calibration.csv"],
     dict(columns="ax,ay,az,gx,gy,gz", rate_hz=100.0, accel_units="counts", gyro_units="counts")),
]  # fmt: skip


def real_data(console: Console) -> None:
    if not DATA.is_dir():
        console.print(f"[yellow]{DATA} not found: real recordings skipped")
        return
    from imucal_cli.formats.importers import import_files

    t = Table(title="Real recordings with rotations: accel (gravity) + gyro (full) calibration")
    for col in ("recording", "stills", "rotations used", "accel |a|-g RMS after, m/s^2",
                "rotation residual RMS, deg", "gyro gains, raw per rad/s", "notes"):  # fmt: skip
        t.add_column(col)
    cfg = config_from_dict({"gyro": {"solver": "full"}})
    for name, fmt, files, opts in REAL:
        try:
            session = import_files([DATA / f for f in files], fmt, **opts)
            cal = calibrate_session(session, cfg)
            g = cal.gyro
            t.add_row(name, str(len(session.static_segments())), str(len(g.extra["rotations"])),
                      f"{cal.accel.extra['rms_after']:.4f}", f"{g.extra['rotation_rms_deg']:.3f}",
                      ", ".join(f"{v:.4g}" for v in g.extra["sensitivity"]),
                      "; ".join(g.extra.get("warnings", []))[:60])  # fmt: skip
        except ImucalError as exc:
            t.add_row(name, "", "", "", "", "", f"refused: {str(exc)[:80]}")
    console.print(t)
    _known_turn(console)


def _known_turn(console: Console) -> None:
    """tomisuarez2's +90 degree turn about x, measured with the gyro calibrated from its own
    calibration recording: a check of the scale on data the calibration never saw."""
    from imucal_cli.formats.importers import import_files

    base = DATA / "tomisuarez2_mpu6050"
    opts = dict(columns="ax,ay,az,gx,gy,gz", rate_hz=100.0, accel_units="counts",
                gyro_units="counts")  # fmt: skip
    try:
        source = import_files([base / "example_data_calibration.csv"], "csv", **opts)
        cal = calibrate_session(source, config_from_dict({"gyro": {"solver": "full"}}))
        turn = import_files([base / "imu_90_x_rot.csv"], "csv", **opts)
    except ImucalError as exc:
        console.print(f"tomisuarez2 known turn: refused ({exc})")
        return
    still = turn.static_segments()
    start, stop = still[0].stop, still[-1].start
    w = cal.gyro.apply(turn.gyro[start:stop])
    from imucal_cli.solvers.gyro_axes import rotation_angle_about_axis
    from imucal_cli.solvers.gyro_full import integrate_rotations

    R = integrate_rotations([turn.time[start:stop]], [w])[0]
    rotvec = (
        __import__("scipy.spatial.transform", fromlist=["Rotation"])
        .Rotation.from_matrix(R)
        .as_rotvec()
    )
    g0 = cal.accel.apply(turn.accel[still[0].start : still[0].stop]).mean(axis=0)
    g1 = cal.accel.apply(turn.accel[still[-1].start : still[-1].stop]).mean(axis=0)
    axis = rotvec / np.linalg.norm(rotvec)
    seen, _ = rotation_angle_about_axis(g0, g1, axis)
    console.print(
        f"tomisuarez2 imu_90_x_rot (README: +90 deg about x): the calibrated gyro integrates a "
        f"turn of {np.degrees(np.linalg.norm(rotvec)):.2f} deg about "
        f"[{axis[0]:+.3f}, {axis[1]:+.3f}, {axis[2]:+.3f}]; the calibrated accelerometer sees "
        f"{np.degrees(seen):+.2f} deg about that axis"
    )


def run(console: Console, n_seeds: int = 100) -> bool:
    console.rule("[bold]Gyroscope from hand rotations (Qureshi III-B and the full model)")
    ok = simulated(console, n_seeds)
    real_data(console)
    return ok
