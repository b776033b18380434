"""Magnetometer calibration (issue 16, point 6).

Monte Carlo over seeds of the simulated ``qureshi18`` plan with a magnetometer (``imucal
simulate --mag``: an AK8963-like part, hard and soft iron, axes swapped relative to the
accelerometer, die misaligned; 48 uT at 60 degrees inclination, 0.4 uT noise, 4 s tumbles
between the 2 s holds):

* parameter errors of the ``[mag]`` solver (hard iron ``b``, the 9 entries of ``W`` in the
  accelerometer's calibrated frame, the dip ``s``) against the truth, beside the Cramér-Rao
  bound of each seed's design (:func:`imucal_cli.estimators.mag.crb.magnetometer_crb`:
  the readings the solver used, their true field directions, the poses' up directions with
  the accelerometer's noise), and how often the reported 95 % intervals hold the truth;
* side by side with a plain algebraic ellipsoid fit of the same readings (what MotionCal and
  the hobby sketches do: symmetric soft iron, unweighted, then the datasheet's axis mapping):
  hard and soft iron against the bound of the symmetric model, and the heading error over
  1000 random attitudes (tilt-compensated with the accelerometer, degrees RMS), uncalibrated
  for reference;
* solve time per session;
* the six faces (``six --mag``), whose accelerometer is known only from its six faces (the
  labelled solver): each term's error against its stated std and 95 % interval (Student t on
  the accelerometer placement's degrees of freedom), beside the same fit with the poses' up
  directions taken as exact (what it did before: hard iron several std off).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.spatial.transform import Rotation

from imucal_cli.calibrate.mag import mag_readings
from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.estimators.mag.crb import magnetometer_crb
from imucal_cli.estimators.mag.magnetometer import (
    PARAM_NAMES_ALIGNED,
    fit_magnetometer,
    fit_plain_ellipsoid,
    polar,
)
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.simulate.magnetometer import LAYOUTS, earth_field, simulate_mag

FIELD, INCLINATION = 48.0, 60.0
DESIGN = dict(hold_s=2.0, tumble_s=4.0, field_uT=FIELD, inclination_deg=INCLINATION)
HEADING_ATTITUDES = 1000
#: The accelerometer and the magnetometer (the gyro's turns are not what this bench measures).
CONFIG = config_from_dict({"gyro": {"solver": "none"}})


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _accel_frame(cal, truth) -> np.ndarray:
    """The rotation from the fixture frame (the truth's) into the frame the accelerometer of
    this run calibrates to (whichever solver ran): the nearest rotation to ``M_est A^-1``."""
    U, _, Vt = np.linalg.svd(cal.accel.matrix @ np.linalg.inv(truth.accel.matrix))
    return U @ Vt


def _crb(session, truth, cal, readings, W, aligned: bool) -> np.ndarray:
    """The bound of this seed's design at the truth ``W`` (output frame of the model)."""
    mag_t = truth.mag
    S = np.linalg.inv(mag_t.matrix)  # raw per uT, fixture frame
    noise = float(mag_t.noise)
    cov = noise**2 * S @ S.T + (np.eye(3) / 12.0 if session.mag_units == "counts" else 0.0)
    data = readings.data
    dirs = _unit((data.samples - mag_t.bias) @ W.T)
    pose_dirs = _unit((data.pose_mean - mag_t.bias) @ W.T)
    n = readings.pose_samples
    pose_cov = np.array([cov / k for k in n])
    if not aligned:
        return magnetometer_crb(W, FIELD, dirs, cov, pose_dirs=pose_dirs, pose_cov=pose_cov,
                                aligned=False)  # fmt: skip
    to_acc = _accel_frame(cal, truth)
    static = [s.name for s in session.static_segments()]
    true_up = np.array(truth.accel.true_up)
    ups = np.array([true_up[static.index(seg.name)] for seg in readings.segments]) @ to_acc.T
    sigma_a = float(truth.accel.noise) / float(truth.accel.gravity)
    up_cov = np.array([(np.eye(3) - np.outer(u, u)) * sigma_a**2 / k for u, k in zip(ups, n,
                                                                              strict=True)])
    return magnetometer_crb(W, FIELD, dirs, cov, pose_up=ups, pose_dirs=pose_dirs,
                            pose_cov=pose_cov, up_cov=up_cov)  # fmt: skip


def _heading_rms(W_est, b_est, truth, to_est_acc, rng) -> float:
    """Heading error (deg RMS) over random attitudes: the calibrated field projected on the
    horizontal plane (gravity from the accelerometer's frame) against the true one."""
    att = Rotation.random(HEADING_ATTITUDES, random_state=rng)
    h_fix = att.inv().apply(earth_field(FIELD, INCLINATION))
    up_fix = att.inv().apply([0.0, 0.0, 1.0])
    raw = h_fix @ np.linalg.inv(truth.mag.matrix).T + truth.mag.bias
    h_est = (raw - b_est) @ W_est.T
    h_true = h_fix @ to_est_acc.T
    u = up_fix @ to_est_acc.T

    def horizontal(v):
        return v - np.sum(v * u, axis=1, keepdims=True) * u

    a, b = horizontal(h_est), horizontal(h_true)
    ang = np.arctan2(np.sum(np.cross(b, a) * u, axis=1), np.sum(a * b, axis=1))
    return float(np.degrees(np.sqrt(np.mean(ang**2))))


def one_seed(seed: int) -> dict:
    session, truth = simulate_mag("qureshi18", seed, created="2026-01-01T00:00:00Z", **DESIGN)
    t0 = time.perf_counter()
    cal = calibrate_session(session, CONFIG)
    solve_s = time.perf_counter() - t0
    mag = cal.mag
    readings = mag_readings(session, Config().mag, cal.accel, "bench")
    to_acc = _accel_frame(cal, truth)
    W_true = to_acc @ truth.mag.matrix
    s_true = -np.sin(np.radians(INCLINATION))
    x_true = np.r_[truth.mag.bias, W_true.ravel(), s_true]
    names = [p.name for p in mag.parameters]
    std = {p.name: p.std for p in mag.parameters}
    s_std = np.radians(mag.inclination_std_deg) * np.cos(np.radians(INCLINATION))
    x_hat = np.r_[mag.bias, mag.matrix.ravel(), -np.sin(np.radians(mag.inclination_deg))]
    sd = np.r_[[std[n] for n in names], s_std]
    crb = np.diag(_crb(session, truth, cal, readings, W_true, aligned=True))
    # the rotation onto the accelerometer frame: angle error and its bound (delta method)
    R_est, _ = polar(mag.matrix)
    R_true, P_true = polar(W_true)
    rot_err = float(np.degrees(np.linalg.norm(Rotation.from_matrix(R_est @ R_true.T).as_rotvec())))

    # plain ellipsoid on the same readings, then the datasheet's axis mapping
    plain = fit_plain_ellipsoid(readings.data, FIELD)
    _, P_ml = polar(mag.matrix)
    crb_sym = np.diag(_crb(session, truth, cal, readings, P_true, aligned=False))
    sym = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]

    def soft(P):
        return np.array([P[i, j] for i, j in sym])

    to_est = to_acc
    rng = np.random.default_rng(10_000 + seed)
    layout = LAYOUTS["ak8963"]
    nominal = np.eye(3) / truth.mag.nominal_sensitivity
    heading = {
        "imucal": _heading_rms(mag.matrix, mag.bias, truth, to_est, rng),
        "ellipsoid": _heading_rms(layout.T @ plain.matrix, plain.bias, truth, to_est, rng),
        "uncalibrated": _heading_rms(layout.T @ nominal, np.zeros(3), truth, to_est, rng),
    }
    return dict(
        err=x_hat - x_true, std=sd, crb=crb, rot_err=rot_err,
        rot_std=mag.rotation_std_deg, solve_s=solve_s, heading=heading,
        b_err={"imucal": mag.bias - truth.mag.bias, "ellipsoid": plain.bias - truth.mag.bias},
        w_err={"imucal": soft(P_ml) - soft(P_true), "ellipsoid": soft(plain.matrix) - soft(P_true)},
        crb_sym=crb_sym, verdict=mag.quality.verdict,
        fit_error=mag.quality.checks[3].value_pct,
    )  # fmt: skip


def run(console: Console, n_seeds: int = 40) -> bool:
    console.rule("[bold]Magnetometer calibration: hard and soft iron, aligned to the accelerometer")
    console.print(f"design: qureshi18 with a magnetometer, {DESIGN}, {n_seeds} seeds")
    rows = [one_seed(s) for s in range(n_seeds)]
    err = np.array([r["err"] for r in rows])
    std = np.array([r["std"] for r in rows])
    crb = np.array([r["crb"] for r in rows])
    rms_err = np.sqrt(np.mean(err**2, axis=0))
    bound = np.sqrt(np.mean(crb, axis=0))
    cover = np.mean(np.abs(err) <= 1.96 * std, axis=0)
    t = Table(title="imucal's magnetometer solver: errors against truth (accelerometer frame)")
    for col in ("parameter", "unit", "RMS error", "sqrt(CRB)", "error/bound",
                "mean reported std", "95% coverage"):  # fmt: skip
        t.add_column(col, justify="right")
    units = ["counts"] * 3 + ["uT per count"] * 9 + ["-"]
    for i, name in enumerate(PARAM_NAMES_ALIGNED):
        t.add_row(name, units[i], f"{rms_err[i]:.4g}", f"{bound[i]:.4g}",
                  f"{rms_err[i] / bound[i]:.3f}", f"{np.mean(std[:, i]):.4g}",
                  f"{100 * cover[i]:.1f}%")  # fmt: skip
    nees = np.mean([e @ (e / c) for e, c in zip(err, crb, strict=True)]) / err.shape[1]
    rot = np.array([r["rot_err"] for r in rows])
    rot_std = np.array([r["rot_std"] for r in rows])
    t.add_row("rotation", "deg", f"{np.sqrt(np.mean(rot**2)):.4g}", "", "",
              f"{np.sqrt(3) * np.mean(rot_std):.4g}", "")  # fmt: skip
    console.print(t)
    console.print(f"  mean error^2 / bound over all 13 parameters: {nees:.3f} (1 = at the bound); "
                  f"overall 95% coverage {100 * np.mean(cover):.1f}%")  # fmt: skip

    t2 = Table(title="imucal [mag] beside a plain ellipsoid fit (same readings), mean over seeds")
    for col in ("", "hard iron RMS, counts", "soft iron RMS, uT/count", "error/bound",
                "heading RMS, deg"):  # fmt: skip
        t2.add_column(col, justify="right")
    crb_sym = np.array([r["crb_sym"] for r in rows])
    bound_sym = np.sqrt(np.mean(crb_sym, axis=0))
    for name in ("imucal", "ellipsoid"):
        b = np.array([r["b_err"][name] for r in rows])
        w = np.array([r["w_err"][name] for r in rows])
        ratio = np.sqrt(np.mean(np.c_[b, w] ** 2, axis=0)) / bound_sym
        head = np.mean([r["heading"][name] for r in rows])
        label = "imucal (ML, aligned)" if name == "imucal" else "ellipsoid + datasheet axes"
        t2.add_row(label, f"{np.sqrt(np.mean(b**2)):.4g}", f"{np.sqrt(np.mean(w**2)):.4g}",
                   f"{np.mean(ratio):.3f}", f"{head:.3f}")  # fmt: skip
    head_raw = np.mean([r["heading"]["uncalibrated"] for r in rows])
    t2.add_row("uncalibrated (datasheet gain, axes)", "", "", "", f"{head_raw:.2f}")
    console.print(t2)
    console.print(
        "  bound: the 9-parameter symmetric model (hard iron + symmetric soft iron) of each "
        f"design; heading over {HEADING_ATTITUDES} random attitudes, the field {FIELD:g} uT at "
        f"{INCLINATION:g} deg, gravity from the accelerometer"
    )
    solve = np.array([r["solve_s"] for r in rows])
    passed = sum(r["verdict"] == "pass" for r in rows)
    fit = np.mean([r["fit_error"] for r in rows])
    console.print(f"  calibrate (accel + mag) per session: median {np.median(solve):.2f} s; "
                  f"quality pass {passed}/{n_seeds}; fit error {fit:.2f} %")  # fmt: skip
    ok = 0.85 < np.mean(cover) < 0.99 and nees < 1.5
    return bool(ok) & six_faces(console, max(40, n_seeds))


def six_seed(seed: int) -> dict:
    """One ``six --mag`` session: each term's error (hard iron, ``W`` in the accelerometer's
    frame, inclination in degrees), std and 95 % half-width; and the same fit with the up
    directions taken as exact (no :attr:`MagData.up_shared`)."""
    session, truth = simulate_mag("six", seed, created="2026-01-01T00:00:00Z", **DESIGN)
    cal = calibrate_session(session, CONFIG)
    mag = cal.mag
    true = np.r_[truth.mag.bias, (_accel_frame(cal, truth) @ truth.mag.matrix).ravel(),
                 INCLINATION]  # fmt: skip
    err = np.r_[[p.value for p in mag.parameters], mag.inclination_deg] - true
    std = np.r_[[p.std for p in mag.parameters], mag.inclination_std_deg]
    ci95 = np.r_[[p.ci95 for p in mag.parameters], mag.inclination_ci95_deg]
    data = mag_readings(session, Config().mag, cal.accel, "bench").data
    exact = fit_magnetometer(dataclasses.replace(data, up_shared=None), FIELD)
    err_x = np.r_[exact.params[:12], exact.inclination_deg] - true
    std_x = np.r_[exact.std[:12], exact.inclination_std_deg]
    return dict(err=err, std=std, ci95=ci95, err_x=err_x, std_x=std_x,
                verdict=mag.quality.verdict)  # fmt: skip


def six_faces(console: Console, n_seeds: int) -> bool:
    """The six-face table (module docstring); ok when every term's 95 % interval holds the
    truth within 3 binomial sigma of 95 % and all of them together within 3 sigma."""
    rows = [six_seed(1000 + s) for s in range(n_seeds)]
    err, std, ci95 = (np.array([r[k] for r in rows]) for k in ("err", "std", "ci95"))
    err_x, std_x = (np.array([r[k] for r in rows]) for k in ("err_x", "std_x"))
    cover = np.mean(np.abs(err) <= ci95, axis=0)
    t = Table(title=f"six --mag ({n_seeds} seeds): accelerometer from six faces (labelled)")
    for col in ("term", "unit", "RMS error", "RMS z", "95% coverage", "up exact: RMS error",
                "up exact: RMS z", "up exact: coverage"):  # fmt: skip
        t.add_column(col, justify="right")
    names = PARAM_NAMES_ALIGNED[:12] + ["inclination"]
    units = ["counts"] * 3 + ["uT per count"] * 9 + ["deg"]

    def rms(a):
        return np.sqrt(np.mean(a**2, axis=0))

    z, z_x = rms(err / std), rms(err_x / std_x)
    cover_x = np.mean(np.abs(err_x) <= 1.96 * std_x, axis=0)
    e, e_x = rms(err), rms(err_x)
    for i, name in enumerate(names):
        t.add_row(name, units[i], f"{e[i]:.4g}", f"{z[i]:.2f}", f"{100 * cover[i]:.1f}%",
                  f"{e_x[i]:.4g}", f"{z_x[i]:.2f}", f"{100 * cover_x[i]:.1f}%")  # fmt: skip
    console.print(t)
    sd = np.sqrt(0.95 * 0.05 / n_seeds)
    passed = sum(r["verdict"] == "pass" for r in rows)
    console.print(f"  95% intervals (Student t on the accelerometer placement's dof) hold the "
                  f"truth {100 * np.mean(cover):.1f}% over all terms (target 95 +- "
                  f"{300 * sd:.1f}, 3 binomial sigma); up directions exact (the fit before): "
                  f"{100 * np.mean(cover_x):.1f}%; quality pass {passed}/{n_seeds}")  # fmt: skip
    return bool(np.all(cover >= 0.95 - 3 * sd) and abs(np.mean(cover) - 0.95) < 3 * sd)
