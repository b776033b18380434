"""Gyroscope calibration from hand rotations (issue 5, points 6-7).

Monte Carlo over seeds of the paper's procedure (``qureshi-axes``: 18 hand turns per axis
within +-180 degrees, up to 150 deg/s, 5 s still before and after, 2-degree placement and axis
errors): scale and bias errors of the static, dynamic and full solvers against the truth
(expressed in the calibrated accelerometer's frame, the frame every solver reports in), the
full model's misalignment error in degrees and its ratio to the Cramér-Rao bound, beside the
paper's comparison with its rate table. The bound is the gyro's own plus the accelerometer
calibration's covariance propagated through the turns (``pipeline.gyro.full_bound``): the error
is against the truth, and the accelerometer that measures every turn is calibrated from the
same session (its share is small here, 57 poses: up to 4 % of the variance). Then the real
recordings in ``../shared/data`` that hold rotations: imported, calibrated with the full model,
and their per-rotation residuals. The per-axis solvers (static, dynamic) have their own
coverage row (issue 24.6: their ``ci95`` against the truth, per term and pooled, with the
standardized errors' mean and RMS; :func:`per_axis_coverage`).

Each error/bound is an estimate from the seeds, with a sampling error of about
``1 / sqrt(2 N)`` (16 % at 20 seeds, 7 % at 100): the table states it (delta method on the
seeds' squared errors) with a 95 % interval, and each coverage with its binomial std. At 20
seeds an estimator exactly at the bound shows some parameter above 1.2 more often than not
(12 parameters; issue 10's "m_yz 1.31" was such a draw: 1.02 at 100 seeds), so the verdict is
taken on at least :data:`MIN_SEEDS` seeds.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.stats import chi2

from imucal_cli.calibrate.gyro.rotations import full_bound
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.errors import ImucalError
from imucal_cli.formats.config import config_from_dict
from imucal_cli.simulate.rotations import simulate_gyro_rotations

CREATED = "2026-01-01T00:00:00Z"
SOLVERS = ("static", "dynamic", "full")
PER_AXIS = ("static", "dynamic")
#: Qureshi & Golnaraghi Table III-B: mean deviation of the scale factors from the rate table.
PAPER_MEAN_DEVIATION_PCT = {"static": 0.1409, "dynamic": 0.4060}
#: The verdict (error/bound <= 1.2 for each of 12 parameters) needs this many seeds: an
#: estimator at the bound then passes 97 % of the time (at 20 seeds: 32 %).
MIN_SEEDS = 100
TARGET_RATIO, TARGET_COVERAGE = 1.2, (0.93, 0.97)


def shared_data() -> Path:
    """``shared/data`` beside the checkout (or beside the folder of a git worktree)."""
    here = Path(__file__).resolve().parent.parent
    for parent in here.parents:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return here.parent / "shared" / "data"


DATA = shared_data()


def error_over_bound(err: np.ndarray, crb: np.ndarray) -> dict:
    """RMS error over seeds / sqrt(mean CRB) per parameter, with its sampling uncertainty.

    ``err`` (N, p) the seeds' errors, ``crb`` (N, p) each seed's bound (variance). Returns
    ``ratio``, ``se`` (delta method on the seeds' squared errors: no Gaussian assumption),
    ``lo``/``hi`` (95 % interval, chi-square with N degrees of freedom: Gaussian errors) and
    ``p_any_above`` (the chance that an estimator exactly at the bound shows some parameter
    above :data:`TARGET_RATIO` with N seeds, parameters taken independent)."""
    n = len(err)
    q = err**2 / np.mean(crb, axis=0)
    ratio = np.sqrt(np.mean(q, axis=0))
    se = np.std(q, axis=0, ddof=1) / (2 * ratio * np.sqrt(n))
    lo = ratio * np.sqrt(n / chi2.ppf(0.975, n))
    hi = ratio * np.sqrt(n / chi2.ppf(0.025, n))
    p_one = chi2.sf(n * TARGET_RATIO**2, n)
    return {"ratio": ratio, "se": se, "lo": lo, "hi": hi, "n": n,
            "p_any_above": float(1 - (1 - p_one) ** err.shape[1])}  # fmt: skip


def coverage(hits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Share of intervals holding the truth (over axis 0) and its binomial std."""
    c = np.mean(hits, axis=0)
    return c, np.sqrt(c * (1 - c) / len(hits))


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
            "rot_rms": g.rotation_rms_deg,
        }
        if solver in PER_AXIS:  # b_x, b_y, b_z, k_x, k_y, k_z against the truth
            p = {q.name: q for q in g.parameters}
            names = [f"{t}_{a}" for t in "bk" for a in "xyz"]
            out[solver]["err"] = (np.array([p[n].value for n in names])
                                  - np.r_[truth.gyro.bias, np.diag(M_true)])  # fmt: skip
            out[solver]["std"] = np.array([p[n].std for n in names])
            out[solver]["ci95"] = np.array([p[n].ci95 for n in names])
        if solver == "full":
            x_hat = np.r_[g.bias, g.matrix.ravel()]
            x_true = np.r_[truth.gyro.bias, M_true.ravel()]
            out["full"]["err"] = x_hat - x_true
            out["full"]["std"] = np.array([p.std for p in g.parameters])[:12]
            out["full"]["axes_deg"] = _axes_angles_deg(g.matrix, M_true)
            crb, total = full_bound(session, cfg, cal.accel, x_true)
            out["full"]["crb_gyro"], out["full"]["crb"] = np.diag(crb), np.diag(total)
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
    accel_share = 1 - np.mean([r["full"]["crb_gyro"] for r in runs], axis=0) / np.mean(crb, axis=0)
    std = np.array([r["full"]["std"] for r in runs])
    stats = error_over_bound(err, crb)
    ratio = stats["ratio"]
    hits = np.abs(err) <= 1.96 * std
    cover, cover_se = coverage(hits)
    pooled, pooled_se = coverage(hits.ravel())  # seeds x parameters, taken independent
    axes = np.array([r["full"]["axes_deg"] for r in runs])
    names = ["b_x", "b_y", "b_z"] + [f"m_{a}{b}" for a in "xyz" for b in "xyz"]
    t2 = Table(title=f"Full 12-parameter model against its Cramér-Rao bound, {n_seeds} seeds "
                     "(± sampling std of the estimate over the seeds)")  # fmt: skip
    for col in ("parameter", "RMS error", "sqrt(CRB)", "accel's share of CRB", "error/bound",
                "95 % interval", "95% coverage"):  # fmt: skip
        t2.add_column(col, justify="right")
    for i, n in enumerate(names):
        rms_err, bound = np.sqrt(np.mean(err[:, i] ** 2)), np.sqrt(np.mean(crb[:, i]))
        t2.add_row(n, f"{rms_err:.4g}", f"{bound:.4g}", f"{100 * accel_share[i]:.1f} %",
                   f"{ratio[i]:.2f} ± {stats['se'][i]:.2f}",
                   f"{stats['lo'][i]:.2f}-{stats['hi'][i]:.2f}",
                   f"{100 * cover[i]:.0f} ± {100 * cover_se[i]:.0f} %")  # fmt: skip
    t2.add_row("all", "", "", "", f"{ratio.min():.2f}-{ratio.max():.2f}", "",
               f"{100 * pooled:.1f} ± {100 * pooled_se:.1f} %")  # fmt: skip
    console.print(t2)
    enough = n_seeds >= MIN_SEEDS
    per_axis_ok = per_axis_coverage(console, runs)
    ok = (enough and ratio.max() <= TARGET_RATIO and worst_scale < 0.1 and per_axis_ok
          and TARGET_COVERAGE[0] <= pooled <= TARGET_COVERAGE[1])  # fmt: skip
    console.print(
        f"full model: sensitivity-axis (misalignment) error RMS "
        f"{', '.join(f'{v:.4f}' for v in np.sqrt(np.mean(axes**2, axis=0)))} deg (x, y, z); "
        f"error/bound max {ratio.max():.2f} (target <= {TARGET_RATIO}; an estimator at the bound "
        f"exceeds it on some parameter with {n_seeds} seeds {100 * stats['p_any_above']:.0f} % "
        f"of the time); 95 % coverage {100 * pooled:.1f} % (target 93-97 %); worst scale error "
        f"RMS {worst_scale:.4f} % (target < 0.1 %): {'[green]PASS' if ok else '[red]FAIL'}[/]"
        + ("" if enough else f" (not decided: fewer than {MIN_SEEDS} seeds)")
    )
    return bool(ok)


def per_axis_coverage(console: Console, runs: list[dict]) -> bool:
    """Issue 24.6 for the per-axis solvers: the share of their 95 % intervals (``ci95``) that
    hold the truth, per term and pooled (gains and biases, seeds x 6, with its binomial std),
    and the standardized errors ``z = err / std`` (mean, RMS). Before the misalignment's term
    (d936e88): 90.1 % static, 87.0 % dynamic over 200 seeds, gains' RMS z 1.45-1.54. Each
    solver passes when its pooled coverage is in 93-97 % over at least :data:`MIN_SEEDS`
    seeds; prints one verdict line."""
    n = len(runs)
    t = Table(title=f"Per-axis solvers' 95 % intervals (ci95) against the truth, {n} seeds "
                    "(± binomial std)")  # fmt: skip
    for col in ("solver", "coverage b_x, b_y, b_z", "coverage k_x, k_y, k_z",
                "pooled (target 93-97 %)", "mean z (b, k)", "RMS z (b, k)"):  # fmt: skip
        t.add_column(col, justify="right")
    pooled = {}
    for solver in PER_AXIS:
        err = np.array([r[solver]["err"] for r in runs])
        z = err / np.array([r[solver]["std"] for r in runs])
        hits = np.abs(err) <= np.array([r[solver]["ci95"] for r in runs])
        c, _ = coverage(hits)
        pooled[solver] = coverage(hits.ravel())
        rz = np.sqrt(np.mean(z**2, axis=0))
        t.add_row(solver, ", ".join(f"{100 * v:.1f}" for v in c[:3]),
                  ", ".join(f"{100 * v:.1f}" for v in c[3:]),
                  f"{100 * pooled[solver][0]:.1f} ± {100 * pooled[solver][1]:.1f} %",
                  f"{np.mean(z[:, :3]):+.2f}, {np.mean(z[:, 3:]):+.2f}",
                  f"{np.sqrt(np.mean(rz[:3] ** 2)):.2f}, {np.sqrt(np.mean(rz[3:] ** 2)):.2f}")
    console.print(t)
    ok = n >= MIN_SEEDS and all(TARGET_COVERAGE[0] <= c <= TARGET_COVERAGE[1]
                                for c, _ in pooled.values())  # fmt: skip
    console.print(
        "per-axis solvers (issue 24.6): 95 % coverage "
        + "; ".join(f"{s} {100 * c:.1f} ± {100 * se:.1f} %" for s, (c, se) in pooled.items())
        + f" over {n} seeds (target 93-97 %): {'[green]PASS' if ok else '[red]FAIL'}[/]"
        + ("" if n >= MIN_SEEDS else f" (not decided: fewer than {MIN_SEEDS} seeds)")
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
            t.add_row(name, str(len(session.static_segments())), str(len(g.rotations)),
                      f"{cal.accel.rms_after:.4f}", f"{g.rotation_rms_deg:.3f}",
                      ", ".join(f"{v:.4g}" for v in g.sensitivity),
                      "; ".join(g.warnings or [])[:60])  # fmt: skip
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
    from imucal_cli.estimators.gyro.axes import rotation_angle_about_axis
    from imucal_cli.estimators.gyro.full import integrate_rotations

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


def run(console: Console, n_seeds: int = MIN_SEEDS) -> bool:
    """The tables; at least :data:`MIN_SEEDS` seeds (0.5 s each), fewer cannot decide."""
    console.rule("[bold]Gyroscope from hand rotations (Qureshi III-B and the full model)")
    ok = simulated(console, max(n_seeds, MIN_SEEDS))
    real_data(console)
    return ok
