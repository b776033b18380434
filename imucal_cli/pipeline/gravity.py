"""The gravity-magnitude accelerometer step: pose statistics -> Qureshi & Golnaraghi solver ->
the accel section of the calibration, with uncertainties, residuals and checks."""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import DesignError
from imucal_cli.formats.calibration import MODEL_EQUATION, SensorCalibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.solvers import gravity as gravity_solver
from imucal_cli.solvers.poses import count_distinct, coverage

from .common import (
    check_design,
    nominal_sensor,
    num,
    physical_checks,
    rms,
    session_name,
    static_poses,
)

#: Exact refits for the held-out residuals up to this many poses; above it, the leverage
#: (PRESS) formula, which is the same to first order and keeps large sessions fast.
LOO_EXACT_MAX_POSES = 200


def _sensitivity_axes(matrix: np.ndarray) -> np.ndarray:
    """Rows of ``S = matrix^-1``: each channel's sensitivity axis, raw units per m/s^2."""
    return np.linalg.inv(matrix)


def _derived(params: np.ndarray, variant: str) -> np.ndarray:
    """(sensitivity x, y, z; non-orthogonality xy, xz, yz in deg) from the parameters."""
    if variant == "9-parameter":
        _, M = gravity_solver.params_to_model(params)
    else:
        M = params[3:].reshape(3, 3)
    S = _sensitivity_axes(M)
    gains = np.linalg.norm(S, axis=1)
    s = S / gains[:, None]
    pairs = [(0, 1), (0, 2), (1, 2)]
    ang = [np.degrees(np.arccos(np.clip(s[i] @ s[j], -1, 1))) - 90.0 for i, j in pairs]
    return np.r_[gains, ang]


def _derived_with_std(
    params: np.ndarray, cov: np.ndarray, variant: str
) -> tuple[np.ndarray, np.ndarray]:
    f0 = _derived(params, variant)
    J = np.empty((len(f0), len(params)))
    for i in range(len(params)):
        step = 1e-6 * max(abs(params[i]), 1e-12)
        dp = np.zeros_like(params)
        dp[i] = step
        J[:, i] = (_derived(params + dp, variant) - _derived(params - dp, variant)) / (2 * step)
    return f0, np.sqrt(np.clip(np.diag(J @ cov @ J.T), 0, None))


def calibrate_accel_gravity(session: Session, cfg: Config) -> SensorCalibration:
    """Run the configured accelerometer solver on a session's static poses.

    Returns
    -------
    SensorCalibration
        With the fields of DEVELOPERS.md; ``extra["warnings"]`` lists results outside
        physical sense (empty when none).

    Raises
    ------
    DesignError
        Poses that cannot determine the model (says what to capture).
    SolverError
        No convergence.
    """
    where = session_name(session)
    g = cfg.gravity or session.gravity
    poses = static_poses(session)
    na = poses.a_mean.shape[1]
    if na != 3:
        raise DesignError(
            f"{where}: the gravity solver calibrates a triad (3 accelerometer channels); this "
            f"session has {na}: use a solver for redundant units"
        )
    nominal = nominal_sensor(session, cfg, g)
    check_design(poses, nominal, cfg.accel.min_separation_deg, where)

    opts = cfg.accel.gravity
    weighted = opts.weighting == "noise"
    cov_mean = poses.cov_mean if weighted else None
    up = poses.up if np.isfinite(poses.up).any() else None
    res = gravity_solver.fit_gravity(
        poses.a_mean,
        g,
        cov_mean=cov_mean,
        up=up,
        variant=opts.model,
        init=opts.init,
        max_iterations=opts.max_iterations,
    )

    # ---- residuals before / after / held out
    if nominal.sensitivity is not None:
        mag_before = np.linalg.norm(poses.a_mean - nominal.bias, axis=1) / nominal.sensitivity
    else:
        raw_mag = np.linalg.norm(poses.a_mean - nominal.bias, axis=1)
        mag_before = raw_mag * (g / np.median(raw_mag))
    mag_after = res.residuals + g
    loo = np.full(len(poses.a_mean), np.nan)
    loo_method = None
    if opts.leave_one_out and len(poses.a_mean) > 9:
        if len(poses.a_mean) <= LOO_EXACT_MAX_POSES:
            loo = gravity_solver.leave_one_out(poses.a_mean, g, res, cov_mean=cov_mean)
            loo_method = "refit without each pose"
        else:
            loo = gravity_solver.leave_one_out_press(poses.a_mean, g, res, cov_mean=cov_mean)
            loo_method = "leverage (PRESS) approximation"

    derived, derived_std = _derived_with_std(res.params, res.cov, res.variant)
    gains, gains_std = derived[:3], derived_std[:3]
    cover = coverage(res.directions)

    # ---- physical sense
    warnings = physical_checks(
        res.bias, gains, rms(res.residuals), nominal, cfg, session.accel_units or "raw units", g
    )

    units_in = session.accel_units or "unknown"
    param_units = [units_in] * 3 + [f"m/s^2 per {units_in}"] * (len(res.params) - 3)
    parameters = [
        {"name": n, "value": float(v), "std": float(s), "unit": u}
        for n, v, s, u in zip(res.param_names, res.params, res.std, param_units, strict=True)
    ]
    pose_rows = []
    for k, s in enumerate(poses.segments):
        pose_rows.append(
            {
                "segment": s.name,
                "label": s.label,
                "up": None if s.up is None else [float(x) for x in s.up],
                "samples": int(poses.samples[k]),
                "magnitude_before": float(mag_before[k]),
                "magnitude_after": float(mag_after[k]),
                "residual": float(res.residuals[k]),
                "residual_loo": num(loo[k]),
                "angle_to_up_deg": num(res.up_angle_deg[k])
                if res.up_angle_deg is not None
                else None,
                "direction": [float(x) for x in res.directions[k]],
            }
        )

    gauge = (
        "upper-triangular matrix: calibrated z is the z sensitivity axis, y lies in the plane of "
        "the y and z axes (Qureshi eq. 3); rotate it to your body frame if you need one"
        if res.variant == "9-parameter"
        else "full matrix, rotated onto the labelled up directions of the fixture"
    )
    extra = {
        "model": MODEL_EQUATION,
        "units_in": units_in,
        "variant": res.variant,
        "gauge": gauge,
        "gravity": g,
        "parameters": parameters,
        "sensitivity": [float(x) for x in gains],
        "sensitivity_std": [float(x) for x in gains_std],
        "sensitivity_unit": f"{units_in} per m/s^2",
        "misalignment_deg": dict(zip(("xy", "xz", "yz"), map(float, derived[3:]), strict=True)),
        "misalignment_std_deg": dict(
            zip(("xy", "xz", "yz"), map(float, derived_std[3:]), strict=True)
        ),
        "init": res.init,
        "weighting": res.weighting,
        "iterations": res.iterations,
        "function_evaluations": res.nfev,
        "converged": res.converged,
        "message": res.message,
        "chi2": res.chi2,
        "dof": res.dof,
        "noise_scale": res.noise_scale,
        "rotation_std_deg": res.rotation_std_deg,
        "rms_before": rms(mag_before - g),
        "rms_after": rms(res.residuals),
        "rms_loo": rms(loo) if loo_method else None,
        "loo_method": loo_method,
        "before_basis": nominal.basis,
        "coverage": {
            "fraction": cover.fraction,
            "cap_deg": cover.cap_deg,
            "largest_gap_deg": cover.largest_gap_deg,
            "weakest_direction": [float(x) for x in cover.weakest_direction],
            "n_poses": len(poses.segments),
            "n_distinct": count_distinct(res.directions, cfg.accel.min_separation_deg),
        },
        "poses": pose_rows,
        "warnings": warnings,
    }
    return SensorCalibration(
        solver="gravity",
        units="m/s^2",
        bias=res.bias,
        matrix=res.matrix,
        residual_rms=rms(res.cost_residuals),
        extra=extra,
    )
