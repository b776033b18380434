"""Factorization solver (issue 4, point 9): Hwangbo & Kanade's Table I by Monte Carlo, and the
factorization and gravity solvers side by side on the same triad sessions.

Table I's design: the redundant unit of two dual-axis accelerometers (n = 4, the second at 45
degrees), 20 random orientations x 10 samples, gravity-magnitude constraints only, noise of
1.5 and 0.7 counts. For each of the paper's linear method, the subspace-first linear method
and the nonlinear refinement: the RMS error over seeds of every bias (V), gain (V/g) and angle
between sensitivity axes (deg), beside the paper's figures (which are the errors of one run)
and the Cramér-Rao bound of the design.
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.table import Table

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.estimators import factorization as fz
from imucal_cli.estimators.accel.crb import (
    factorization_crb,
    gravity_crb,
    invariant_summary,
    propagate,
)
from imucal_cli.formats.config import config_from_dict
from imucal_cli.simulate.redundant import simulate_redundant_accel
from imucal_cli.simulate.triad import simulate

CREATED = "2026-01-01T00:00:00Z"
ROWS = ["b1", "b2", "b3", "b4", "|s1|", "|s2|", "|s3|", "|s4|",
        "s1s2", "s1s3", "s1s4", "s2s3", "s2s4", "s3s4"]  # fmt: skip
UNITS = ["V"] * 4 + ["V/g"] * 4 + ["deg"] * 6
#: Table I of the paper: errors of one run (linear at sigma 1.5, linear at 0.7, nonlinear at 0.7).
PAPER = {
    "linear 1.5": [0.00139, 0.00122, 0.00113, 0.00177, 0.00236, 0.00150, 0.00187, 0.00325,
                   -0.16495, -0.35232, -0.08894, -0.18666, -0.37098, -0.07601],
    "linear 0.7": [0.00063, 0.00079, 0.00104, 0.00095, 0.00173, 0.00123, 0.00141, 0.00198,
                   -0.05283, -0.22175, -0.04328, -0.16611, -0.27205, -0.00955],
    "nonlinear 0.7": [0.00019, 0.00035, 0.00000, -0.00014, 0.00021, 0.00029, 0.00012,
                      -0.00034, -0.02079, -0.02585, 0.00030, -0.02502, 0.02135, -0.02103],
}  # fmt: skip


def _table1_run(seed: int, sigma: float) -> dict:
    session, truth = simulate_redundant_accel(seed=seed, sigma_counts=sigma, created=CREATED)
    cpv = truth.accel.counts_per_volt
    rows = [session.accel[s.start : s.stop] for s in session.static_segments()]
    Z = np.vstack(rows)
    owner = np.repeat(np.arange(len(rows)), [len(r) for r in rows])
    c = fz.Constraints(np.arange(len(Z)), np.arange(len(Z)), np.ones(len(Z)))
    S_true = np.array(truth.accel.S_counts_per_g)
    b_true = truth.accel.bias
    truth_v = invariant_summary(S_true, b_true)
    scale = np.r_[np.full(8, 1 / cpv), np.ones(6)]  # counts -> V for biases and gains
    noise = float(truth.accel.noise_total_counts)  # noise and quantisation

    out = {}
    t0 = time.perf_counter()
    paper = fz.factorize(Z, c, linear="paper")
    out["time_linear"] = time.perf_counter() - t0
    sub = fz.factorize(Z, c, linear="subspace")
    t0 = time.perf_counter()
    ref = fz.refine(Z, c, paper, sigma=noise, row_owner=owner)
    out["time_refine"] = time.perf_counter() - t0
    for name, r in (("paper", paper), ("subspace", sub), ("refined", ref)):
        out[name] = (invariant_summary(r.S, r.b) - truth_v) * scale
    if ref.cov is not None:
        n = 4

        def summary(x):
            return invariant_summary(np.linalg.pinv(x[n:].reshape(3, n)).T, x[:n])

        cov = propagate(summary, np.r_[ref.b, ref.T.ravel()], ref.cov)
        out["std"] = np.sqrt(np.diag(cov)) * scale
    u = np.array(truth.accel.true_up)
    crb = factorization_crb(S_true, b_true, u, noise, 10)
    cov = propagate(
        lambda x: invariant_summary(x[4:].reshape(3, 4), x[:4]), np.r_[b_true, S_true.ravel()], crb
    )
    out["crb"] = np.diag(cov) * scale**2
    return out


def table1(console: Console, n_seeds: int) -> bool:
    ok = True
    for sigma in (1.5, 0.7):
        runs = [_table1_run(seed, sigma) for seed in range(n_seeds)]
        rms = {k: np.sqrt(np.mean([r[k] ** 2 for r in runs], axis=0))
               for k in ("paper", "subspace", "refined")}  # fmt: skip
        bound = np.sqrt(np.mean([r["crb"] for r in runs], axis=0))
        std = np.mean([r["std"] for r in runs], axis=0)
        t = Table(title=f"Table I by Monte Carlo: sigma = {sigma} counts, {n_seeds} seeds "
                        "(RMS error; the paper's columns are one run)")  # fmt: skip
        cols = ["", "unit", "paper: linear", "imucal linear (paper's method)",
                "imucal linear (subspace)", "imucal refined", "reported std", "sqrt(CRB)",
                "subspace/CRB", "refined/CRB"]  # fmt: skip
        if sigma == 0.7:
            cols.insert(3, "paper: nonlinear")
        for col in cols:
            t.add_column(col, justify="right")
        for i, name in enumerate(ROWS):
            row = [name, UNITS[i], f"{abs(PAPER[f'linear {sigma}'][i]):.5f}"]
            if sigma == 0.7:
                row.append(f"{abs(PAPER['nonlinear 0.7'][i]):.5f}")
            row += [
                f"{rms['paper'][i]:.5f}",
                f"{rms['subspace'][i]:.5f}",
                f"{rms['refined'][i]:.5f}",
                f"{std[i]:.5f}",
                f"{bound[i]:.5f}",
                f"{rms['subspace'][i] / bound[i]:.2f}",
                f"{rms['refined'][i] / bound[i]:.2f}",
            ]
            t.add_row(*row)
        console.print(t)
        lin_ratio = (rms["subspace"] / bound).max()
        ref_ratio = (rms["refined"] / bound).max()
        below_paper = np.mean(rms["subspace"] <= np.abs(PAPER[f"linear {sigma}"]))
        ok &= lin_ratio <= 1.2 and ref_ratio <= 1.2
        verdict = "[green]PASS" if max(lin_ratio, ref_ratio) <= 1.2 else "[red]FAIL"
        console.print(
            f"sigma {sigma}: max error/bound linear (subspace) {lin_ratio:.2f}, refined "
            f"{ref_ratio:.2f} (target <= 1.2: {verdict}[/]); "
            f"linear (subspace) at or below the paper's linear column on "
            f"{100 * below_paper:.0f}% of the rows; paper's own linear method here: "
            f"{(rms['paper'] / bound).min():.1f}-{(rms['paper'] / bound).max():.1f} x the bound"
        )
        if sigma == 0.7:
            paper_nl = np.abs(PAPER["nonlinear 0.7"])
            at_or_below = np.mean(rms["refined"] <= paper_nl)
            below_bound = np.mean(paper_nl < bound)
            console.print(
                f"  refined at or below the paper's nonlinear column on {100 * at_or_below:.0f}% "
                f"of the rows; that column is the error of one run, and on "
                f"{100 * below_bound:.0f}% of the rows it lies below sqrt(CRB), which no "
                "estimator's RMS error can reach: the comparison that holds is the bound"
            )
        console.print(
            f"  time per run: linear {1000 * np.mean([r['time_linear'] for r in runs]):.1f} ms, "
            f"refinement {1000 * np.mean([r['time_refine'] for r in runs]):.0f} ms"
        )
    return ok


def side_by_side(console: Console, n_seeds: int) -> None:
    """Both solvers on the same triad sessions (qureshi18, 2-degree hand placement)."""
    cfgs = {
        "gravity (9-parameter)": config_from_dict({"accel": {"gravity": {"leave_one_out": False}}}),
        "factorization (triad)": config_from_dict({"accel": {"solver": "factorization"}}),
        "factorization, fixture trusted (tolerance 0)": config_from_dict(
            {"accel": {"solver": "factorization", "factorization": {"fixture_tolerance_deg": 0.0}}}
        ),
    }
    err = {k: [] for k in cfgs}
    cover = {k: [] for k in cfgs}
    bound = []
    for seed in range(n_seeds):
        session, truth = simulate(plan="qureshi18", seed=seed, created=CREATED)
        gains = np.linalg.norm(np.linalg.inv(truth.accel.matrix), axis=1)
        expected = np.r_[truth.accel.bias, gains]
        for name, cfg in cfgs.items():
            acc = calibrate_session(session, cfg).accel
            got = np.r_[acc.bias, acc.sensitivity]
            std = np.r_[[p.std for p in acc.parameters[:3]],
                        acc.sensitivity_std]  # fmt: skip
            err[name].append(got - expected)
            cover[name].append(np.abs(got - expected) <= 1.96 * std)
        # The bound on biases and gains (rows of S) from the gravity design's CRB.
        M_true = np.linalg.qr(truth.accel.matrix)[1]
        M_true = np.diag(np.sign(np.diag(M_true))) @ M_true
        Q = truth.accel.matrix @ np.linalg.inv(M_true)
        u = np.array(truth.accel.true_up) @ Q
        noise = truth.accel.noise * gains.mean()
        cov_mean = np.repeat(((noise**2 + 1 / 12) / 200 * np.eye(3))[None], len(u), axis=0)
        crb = gravity_crb(M_true, truth.accel.bias, u, 9.80665, cov_mean)

        def bias_gain(x):
            from imucal_cli.estimators.accel.gravity import params_to_model

            B, M = params_to_model(x)
            return np.r_[B, np.linalg.norm(np.linalg.inv(M), axis=1)]

        from imucal_cli.estimators.accel.gravity import model_to_params

        bound.append(np.diag(propagate(bias_gain, model_to_params(truth.accel.bias, M_true), crb)))
    b = np.sqrt(np.mean(bound, axis=0))
    t = Table(title=f"Gravity and factorization solvers on the same {n_seeds} qureshi18 sessions "
                    "(RMS error; counts, counts per m/s^2)")  # fmt: skip
    for col in (
        "solver",
        "b_x",
        "b_y",
        "b_z",
        "gain x",
        "gain y",
        "gain z",
        "max error/bound",
        "95% coverage",
    ):
        t.add_column(col, justify="right")
    for name in cfgs:
        e = np.sqrt(np.mean(np.square(err[name]), axis=0))
        t.add_row(
            name,
            *[f"{v:.3f}" for v in e],
            f"{(e / b).max():.2f}",
            f"{100 * np.mean(cover[name]):.1f}%",
        )
    t.add_row("sqrt(CRB)", *[f"{v:.3f}" for v in b], "", "")
    console.print(t)


def run(console: Console, n_seeds: int = 200) -> bool:
    console.rule("[bold]Factorization (Hwangbo & Kanade): Table I and the triad comparison")
    ok = table1(console, n_seeds)
    side_by_side(console, max(20, n_seeds // 2))
    return ok
