"""Labelled-pose accelerometer calibration (issue 9.1).

Monte Carlo over seeds of two labelled designs, ``six`` (the six faces: 6 directions, too few
for the gravity-magnitude model) and ``qureshi18`` (six faces and twelve 45-degree edges),
100 Hz, 2 s holds, 0.01 m/s^2 noise, 2 degree RMS placement error:

* parameter errors against the simulator's truth in the solver's parameters (bias, the
  sensitivity of each axis, the angles between the axes, the rotation r onto the labels);
* the Cramér-Rao bound of the same design with the labels as a prior (each pose's direction a
  nuisance parameter, :func:`imucal_cli.estimators.accel.crb.labelled_crb`) and the ratio RMS
  error / sqrt(bound) per parameter (target <= 1.2);
* how often the reported 95 % intervals (Student t on the placement's degrees of freedom)
  cover the truth (target 93-97 %), and the same for +-1.96 std;
* the joint normalised estimation error squared (NEES) ``e^T C^-1 e`` over the 12
  parameters (truth and estimate in the same parameters, the labels' frame), which the
  per-parameter figures cannot see (issue 10: a stated covariance that covers each
  parameter but not their combinations):

  - with the placement given (the simulated RMS angle): the covariance alone, against
    chi^2(12): mean not above 12 + 3 sampling std (never understated), and at least 90 % of
    seeds below its 95 % quantile 21.03.  Not 93-97 %: on six faces the error left by the
    placement is second order in the placement angles (a quadratic form of Gaussian tilts, not
    Gaussian), and no Gaussian covariance puts more than about 92-94 % of such errors inside
    its 95 % ellipsoid (simulated); qureshi18, whose labels leave only the frame's rotation, is
    held to the same figures and sits at 95 %;
  - with the placement estimated (the default): the stated covariance rests on a placement
    estimated from few equations (six faces: 6), as the per-parameter t intervals do, so
    the reference is the NEES's distribution with that estimate's scatter (first-order
    placement part ~ sigma_p^2, second-order part ~ sigma_p^4, :func:`nees_reference`):
    at least 90 % of seeds below that distribution's 95 % quantile, for the same reason as
    above (six faces measured 92.0 % at 200 seeds, 93.8 % at 400; its mean, with so few
    degrees of freedom unbounded, is not a target); the fraction below 21.03 is beside it;
* the placement estimate, and the solve time.

Then the six faces at 0.5 and 5 degrees of placement, to show the figures do not depend on
the default.
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.stats import chi2

from bench.gravity import quant_var
from imucal_cli.calibrate.common import static_poses
from imucal_cli.estimators.accel.crb import labelled_crb
from imucal_cli.estimators.accel.labelled import PARAM_NAMES, fit_labelled, public_params
from imucal_cli.simulate.triad import simulate

G0 = 9.80665
DESIGN = dict(rate_hz=100.0, hold_s=2.0, accel_noise=0.01)
P = len(PARAM_NAMES)
#: chi^2(12) 95 % quantile.
CHI2_95 = float(chi2.ppf(0.95, P))


def nees(err: np.ndarray, cov: np.ndarray) -> float:
    """``e^T C^-1 e`` (scaled to unit diagonal first: the parameters are decades apart)."""
    d = np.sqrt(np.diag(cov))
    z = err / d
    return float(z @ np.linalg.solve(cov / np.outer(d, d), z))


def nees_reference(parts: dict, dof: float, seed: int, draws: int = 4000) -> np.ndarray:
    """Draws of the NEES of a fit whose placement was estimated on ``dof`` degrees of freedom.

    The stated covariance is ``C = C_m + C_p + C_q`` (``parts``: measurement, placement to
    first order, placement beyond it) at the estimate ``s_hat`` of the placement variance.
    With ``s_hat / s ~ chi^2(dof) / dof`` the error's covariance is ``C_m + C_p / k + C_q /
    k^2`` (``k = s_hat / s``; ``C_q`` goes with the square), and the NEES a weighted sum of
    chi^2(1) draws, the weights the eigenvalues of ``C^-1/2 (that covariance) C^-1/2``.
    ``dof = inf`` (the placement given) gives chi^2(12)."""
    Cm, Cp, Cq = (parts[k] for k in ("measurement", "placement", "placement_second_order"))
    C = Cm + Cp + Cq
    d = np.sqrt(np.diag(C))
    W = np.linalg.cholesky(np.linalg.inv(C / np.outer(d, d)))
    A = [W.T @ (X / np.outer(d, d)) @ W for X in (Cm, Cp, Cq)]
    rng = np.random.default_rng(seed)
    k = rng.chisquare(dof, draws) / dof if np.isfinite(dof) else np.ones(draws)
    T = A[0] + A[1] / k[:, None, None] + A[2] / k[:, None, None] ** 2
    weights = np.clip(np.linalg.eigvalsh(T), 0, None)
    return np.sum(weights * rng.standard_normal((draws, P)) ** 2, axis=1)


def one_seed(plan: str, seed: int, jitter_deg: float) -> dict:
    session, truth = simulate(
        plan=plan, seed=seed, jitter_deg=jitter_deg, created="2026-01-01T00:00:00Z", **DESIGN
    )
    poses = static_poses(session)
    t0 = time.perf_counter()
    res = fit_labelled(poses.a_mean, poses.up, G0, poses.cov_mean, noise_dof=poses.noise.dof)
    solve_s = time.perf_counter() - t0
    S = np.linalg.inv(truth.accel.matrix)
    sigma = float(truth.accel.noise)
    cov_mean = np.array([(sigma**2 * S @ S.T + quant_var(session)) / n for n in poses.samples])
    u = np.array(truth.accel.true_up)
    crb = np.diag(labelled_crb(truth.accel.matrix, truth.accel.bias, u, G0, cov_mean, jitter_deg))
    x_true = public_params(truth.accel.bias, S)
    err = res.params - x_true
    dof = res.placement_dof if res.placement_source == "estimated" else np.inf
    reference = nees_reference(res.cov_parts, dof, seed)
    given = fit_labelled(
        poses.a_mean, poses.up, G0, poses.cov_mean, noise_dof=poses.noise.dof,
        placement_deg=jitter_deg,
    )  # fmt: skip
    return dict(
        err=err,
        std=res.std,
        ci95=res.ci95,
        crb=crb,
        placement=res.placement_deg,
        solve_s=solve_s,
        nees=nees(err, res.cov),
        nees_q95=float(np.quantile(reference, 0.95)),
        nees_given=nees(given.params - x_true, given.cov),
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
    joint = joint_table(console, plan, rows)
    return dict(ratio=ratio, cover=float(cover.mean()), **joint)


def joint_table(console: Console, plan: str, rows: list[dict]) -> dict:
    """The joint NEES rows of one design (module docstring) and their verdicts."""
    n = len(rows)
    given = np.array([r["nees_given"] for r in rows])
    est = np.array([r["nees"] for r in rows])
    q95 = np.array([r["nees_q95"] for r in rows])
    se = np.sqrt(2 * P / n)  # sampling std of the mean of n chi^2(12) draws
    out = dict(
        given_mean=float(given.mean()),
        given_mean_ok=bool(given.mean() <= P + 3 * se),
        given_frac=float(np.mean(given <= CHI2_95)),
        est_frac=float(np.mean(est <= q95)),
    )
    t = Table(title=f"{plan}: joint NEES over the {P} parameters, {n} seeds")
    for col in ("placement", "reference", "its 95 % quantile (median)", "mean NEES",
                "median NEES", "target mean", "below the reference's 95 % quantile",
                "below 21.03 (chi^2(12))"):  # fmt: skip
        t.add_column(col, justify="right")
    t.add_row(
        "given", "chi^2(12)", f"{CHI2_95:.2f}", f"{given.mean():.2f}", f"{np.median(given):.2f}",
        f"<= {P + 3 * se:.2f}", f"{100 * out['given_frac']:.1f}%",
        f"{100 * out['given_frac']:.1f}%",
    )  # fmt: skip
    t.add_row(
        "estimated", "with the placement's dof", f"{np.median(q95):.2f}", f"{est.mean():.2f}",
        f"{np.median(est):.2f}", "-", f"{100 * out['est_frac']:.1f}%",
        f"{100 * np.mean(est <= CHI2_95):.1f}%",
    )  # fmt: skip
    console.print(t)
    return out


def run(console: Console, n_seeds: int = 200) -> bool:
    console.rule("[bold]Labelled-pose accelerometer calibration (issue 9.1)")
    console.print(f"design: {DESIGN}, simulated 16-bit part")
    ok = True
    verdicts = []
    for plan in ("six", "qureshi18"):
        out = design_table(console, plan, n_seeds, 2.0)
        ok_ratio = bool(np.all(out["ratio"] <= 1.2))
        ok_cover = 0.93 <= out["cover"] <= 0.97
        ok_joint = [
            out["given_mean_ok"],
            out["given_frac"] >= 0.90,
            out["est_frac"] >= 0.90,  # the same non-Gaussian ceiling as the given row
        ]
        ok = ok and ok_ratio and ok_cover and all(ok_joint)
        mark = lambda good: "[green]PASS" if good else "[red]FAIL"  # noqa: E731
        verdicts.append(
            f"{plan}: error/bound max {out['ratio'].max():.3f} (target <= 1.2) "
            f"{mark(ok_ratio)}[/], 95% coverage {100 * out['cover']:.1f}% (target 93-97%) "
            f"{mark(ok_cover)}[/]; joint NEES, placement given: mean {out['given_mean']:.2f} "
            f"(target <= {P} + 3 sampling std) {mark(ok_joint[0])}[/], "
            f"{100 * out['given_frac']:.1f}% below 21.03 (target >= 90%) "
            f"{mark(ok_joint[1])}[/]; placement estimated: {100 * out['est_frac']:.1f}% below "
            f"the reference's 95% quantile (target >= 90%) {mark(ok_joint[2])}[/]"
        )
    for jitter in (0.5, 5.0):
        design_table(console, "six", max(50, n_seeds // 4), jitter)
    for v in verdicts:
        console.print(v)
    return ok
