"""Labelled-pose accelerometer calibration (issue 9.1).

Monte Carlo over seeds of two labelled designs, ``six`` (the six faces: 6 directions, too few
for the gravity-magnitude model) and ``qureshi18`` (six faces and twelve 45-degree edges),
100 Hz, 2 s holds, 0.01 m/s^2 noise, 2 degree RMS placement error:

* parameter errors against the simulator's truth in the solver's parameters (bias, the
  sensitivity of each axis, the angles between the axes, the rotation r onto the labels);
* the Cramér-Rao bound of the same design with the labels as a prior (each pose's direction a
  nuisance parameter, :func:`imucal_cli.solvers.crb.labelled_crb`) and the ratio RMS error /
  sqrt(bound) per parameter (target <= 1.2);
* how often the reported 95 % intervals (Student t on the placement's degrees of freedom)
  cover the truth (target 93-97 %), and the same for +-1.96 std;
* the placement estimate, and the solve time.

Then the six faces at 0.5 and 5 degrees of placement, to show the figures do not depend on
the default.
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.table import Table

from bench.gravity import quant_var
from imucal_cli.pipeline.common import static_poses
from imucal_cli.simulate.triad import simulate
from imucal_cli.solvers.crb import labelled_crb
from imucal_cli.solvers.labelled import PARAM_NAMES, fit_labelled, public_params

G0 = 9.80665
DESIGN = dict(rate_hz=100.0, hold_s=2.0, accel_noise=0.01)


def one_seed(plan: str, seed: int, jitter_deg: float) -> dict:
    session, truth = simulate(
        plan=plan, seed=seed, jitter_deg=jitter_deg, created="2026-01-01T00:00:00Z", **DESIGN
    )
    poses = static_poses(session)
    t0 = time.perf_counter()
    res = fit_labelled(poses.a_mean, poses.up, G0, poses.cov_mean, noise_dof=poses.noise.dof)
    solve_s = time.perf_counter() - t0
    S = np.linalg.inv(truth.accel.matrix)
    sigma = float(truth.accel.extra["noise"])
    cov_mean = np.array([(sigma**2 * S @ S.T + quant_var(session)) / n for n in poses.samples])
    u = np.array(truth.accel.extra["true_up"])
    crb = np.diag(labelled_crb(truth.accel.matrix, truth.accel.bias, u, G0, cov_mean, jitter_deg))
    return dict(
        err=res.params - public_params(truth.accel.bias, S),
        std=res.std,
        ci95=res.ci95,
        crb=crb,
        placement=res.placement_deg,
        solve_s=solve_s,
    )


def design_table(console: Console, plan: str, n_seeds: int, jitter_deg: float) -> dict:
    rows = [one_seed(plan, s, jitter_deg) for s in range(n_seeds)]
    err = np.array([r["err"] for r in rows])
    std = np.array([r["std"] for r in rows])
    ci95 = np.array([r["ci95"] for r in rows])
    bound = np.sqrt(np.mean([r["crb"] for r in rows], axis=0))
    ratio = np.sqrt(np.mean(err**2, axis=0)) / bound
    cover = np.mean(np.abs(err) <= ci95, axis=0)
    cover_196 = np.mean(np.abs(err) <= 1.96 * std, axis=0)
    t = Table(
        title=f"{plan}: {n_seeds} seeds, {jitter_deg:g} deg RMS placement, "
        "errors against truth and the bound with the labels as a prior"
    )
    for col in (
        "parameter",
        "unit",
        "RMS error",
        "sqrt(CRB)",
        "error/bound",
        "mean bias/bound",
        "mean std/bound",
        "95% interval coverage",
        "+-1.96 std coverage",
    ):
        t.add_column(col, justify="right")
    units = ["counts"] * 3 + ["counts per m/s^2"] * 3 + ["deg"] * 6
    for i, name in enumerate(PARAM_NAMES):
        t.add_row(
            name,
            units[i],
            f"{np.sqrt(np.mean(err[:, i] ** 2)):.4g}",
            f"{bound[i]:.4g}",
            f"{ratio[i]:.3f}",
            f"{np.mean(err[:, i]) / bound[i]:+.2f}",
            f"{np.sqrt(np.mean(std[:, i] ** 2)) / bound[i]:.2f}",
            f"{100 * cover[i]:.1f}%",
            f"{100 * cover_196[i]:.1f}%",
        )
    console.print(t)
    placement = np.array([r["placement"] for r in rows])
    solve = np.array([r["solve_s"] for r in rows])
    console.print(
        f"  placement estimated {np.mean(placement):.2f} deg (RMS over seeds "
        f"{np.sqrt(np.mean(placement**2)):.2f}; simulated {jitter_deg:g}); "
        f"coverage of all parameters {100 * cover.mean():.1f}%; "
        f"solve median {1000 * np.median(solve):.1f} ms"
    )
    return dict(ratio=ratio, cover=float(cover.mean()))


def run(console: Console, n_seeds: int = 200) -> bool:
    console.rule("[bold]Labelled-pose accelerometer calibration (issue 9.1)")
    console.print(f"design: {DESIGN}, simulated 16-bit part")
    ok = True
    verdicts = []
    for plan in ("six", "qureshi18"):
        out = design_table(console, plan, n_seeds, 2.0)
        ok_ratio = bool(np.all(out["ratio"] <= 1.2))
        ok_cover = 0.93 <= out["cover"] <= 0.97
        ok = ok and ok_ratio and ok_cover
        verdicts.append(
            f"{plan}: error/bound max {out['ratio'].max():.3f} (target <= 1.2) "
            f"{'[green]PASS' if ok_ratio else '[red]FAIL'}[/], 95% coverage "
            f"{100 * out['cover']:.1f}% (target 93-97%) "
            f"{'[green]PASS' if ok_cover else '[red]FAIL'}[/]"
        )
    for jitter in (0.5, 5.0):
        design_table(console, "six", max(50, n_seeds // 4), jitter)
    for v in verdicts:
        console.print(v)
    return ok
