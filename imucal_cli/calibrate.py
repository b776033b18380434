"""The calibrate step: a session and a config in, a :class:`Calibration` with its diagnostics out.

This module turns session data into solver inputs (per-pose means and their covariance),
refuses designs that cannot determine the model, runs the chosen solver, and packs the result,
its uncertainties, per-pose residuals, held-out residuals and physical-sense checks into the
calibration JSON's accel section (layout in DEVELOPERS.md). It does no printing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imucal_cli import __version__
from imucal_cli.calibration import MODEL_EQUATION, Calibration, SensorCalibration
from imucal_cli.config import Config
from imucal_cli.errors import DesignError, SolverError
from imucal_cli.session import Segment, Session, utc_now_iso
from imucal_cli.solvers import gravity as gravity_solver
from imucal_cli.solvers.poses import count_distinct, coverage, describe_direction, spread_deg, unit

#: Exact refits for the held-out residuals up to this many poses; above it, the leverage
#: (PRESS) formula, which is the same to first order and keeps large sessions fast.
LOO_EXACT_MAX_POSES = 200
#: Every pose within this angle of one direction cannot separate bias from scale.
MIN_SPREAD_DEG = 20.0
#: Sensor range assumed for SI-unit data when the config gives none: +-16 g.
SI_RANGE_G = 16.0


@dataclass
class StaticPoses:
    """Per-pose statistics of the static segments of a session.

    Attributes
    ----------
    segments : list of Segment
    a_mean : ndarray, shape (N, na)
        Mean raw accelerometer reading per pose, raw units.
    cov_mean : ndarray, shape (N, na, na)
        Covariance of each mean (sample covariance / samples), raw units^2.
    up : ndarray, shape (N, 3)
        Labelled up directions, NaN rows where unlabelled.
    samples : ndarray of int, shape (N,)
    """

    segments: list[Segment]
    a_mean: np.ndarray
    cov_mean: np.ndarray
    up: np.ndarray
    samples: np.ndarray


def static_poses(session: Session) -> StaticPoses:
    """Mean and covariance of the accelerometer over each static segment."""
    segs = session.static_segments()
    if not segs or session.accel is None:
        raise DesignError(
            f"{_name(session)}: no static segments with accelerometer data; "
            "capture poses held still (e.g. `imucal capture --plan qureshi18`)"
        )
    na = session.accel.shape[1]
    a_mean = np.empty((len(segs), na))
    cov_mean = np.zeros((len(segs), na, na))
    up = np.full((len(segs), 3), np.nan)
    samples = np.empty(len(segs), dtype=int)
    for k, s in enumerate(segs):
        block = session.accel[s.start : s.stop]
        n = len(block)
        samples[k] = n
        a_mean[k] = block.mean(axis=0)
        if n > 1:
            cov_mean[k] = np.cov(block, rowvar=False) / n
        if s.up is not None:
            up[k] = s.up
    return StaticPoses(segs, a_mean, cov_mean, up, samples)


# --------------------------------------------------------------------------- nominal sensor


@dataclass
class Nominal:
    """What an uncalibrated user would assume: datasheet sensitivity and zero-g offset."""

    sensitivity: float | None  # raw units per m/s^2; None when unknown
    bias: np.ndarray  # raw units (3,)
    range: tuple[float, float] | None  # raw output range
    basis: str  # words for the report
    notes: list[str] = field(default_factory=list)


def _adc_range(data_min: float, data_max: float) -> tuple[float, float] | None:
    """The smallest standard ADC word (signed or unsigned) that holds the data."""
    for bits in (8, 10, 12, 14, 16, 18, 20, 24, 32):
        if data_min >= 0 and data_max <= 2**bits - 1:
            return 0.0, float(2**bits - 1)
        if -(2 ** (bits - 1)) <= data_min and data_max <= 2 ** (bits - 1) - 1:
            return float(-(2 ** (bits - 1))), float(2 ** (bits - 1) - 1)
    return None


def nominal_sensor(session: Session, cfg: Config, g: float) -> Nominal:
    """Nominal sensitivity, bias and range from the config, else from the units and data."""
    a = cfg.accel
    units = session.accel_units or "unknown units"
    accel = session.accel
    sens = a.nominal_sensitivity
    rng = tuple(a.range) if a.range else None
    if sens is None:
        sens = {"m/s^2": 1.0, "g": 1.0 / g}.get(units)
    if rng is None:
        if units in ("m/s^2", "g"):
            full = SI_RANGE_G * (g if units == "m/s^2" else 1.0)
            rng = (-full, full)
        elif units == "counts":
            finite = accel[np.isfinite(accel).all(axis=1)]
            rng = _adc_range(float(finite.min()), float(finite.max())) if len(finite) else None
    if a.nominal_bias is not None:
        bias = np.broadcast_to(np.asarray(a.nominal_bias, float), (3,)).copy()
    elif rng is not None and rng[0] == 0.0 and units == "counts":
        bias = np.full(3, (rng[1] + 1) / 2)  # unsigned ADC: zero-g at mid-scale
    else:
        bias = np.zeros(3)
    if sens is not None:
        basis = (
            f"nominal sensitivity {sens:.6g} {units} per m/s^2, offset {_fmt_bias(bias)} {units}"
        )
    else:
        basis = f"one scale fitted to the raw magnitudes, offset {_fmt_bias(bias)} {units}"
    return Nominal(sens, bias, rng, basis)


def _fmt_bias(b: np.ndarray) -> str:
    return "0" if not np.any(b) else "[" + ", ".join(f"{v:.6g}" for v in b) + "]"


# --------------------------------------------------------------------------- design checks


def check_design(
    poses: StaticPoses, nominal: Nominal, min_separation_deg: float, where: str
) -> None:
    """Refuse poses that cannot determine a triad's 9 parameters, with advice."""
    N = len(poses.a_mean)
    centre = nominal.bias
    if nominal.sensitivity is None and nominal.range is None:
        # No idea of the offset: the middle of what was seen on each axis.
        centre = (poses.a_mean.min(axis=0) + poses.a_mean.max(axis=0)) / 2
    directions = unit(poses.a_mean - centre)
    distinct = count_distinct(directions, min_separation_deg)
    if distinct < 9:
        raise DesignError(
            f"{where}: {N} static poses give only {distinct} distinct gravity directions "
            f"(>{min_separation_deg:g} deg apart); the 9-parameter model needs at least 9: "
            "capture the 6 faces and the 45-degree edges (plan qureshi18)"
        )
    spread = spread_deg(directions)
    if spread <= MIN_SPREAD_DEG:
        mean_dir = describe_direction(directions.sum(axis=0))
        raise DesignError(
            f"{where}: every pose is within {spread:.0f} deg of {mean_dir} up, which cannot "
            "separate bias from scale; turn the unit over: capture each face up, then the edges"
        )


# --------------------------------------------------------------------------- the accel solve


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


def calibrate_accel(session: Session, cfg: Config) -> SensorCalibration:
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
    where = _name(session)
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
    warnings = _physical_checks(res, gains, nominal, cfg, session.accel_units or "raw units", g)

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
                "residual_loo": _num(loo[k]),
                "angle_to_up_deg": _num(res.up_angle_deg[k])
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
        "rms_before": _rms(mag_before - g),
        "rms_after": _rms(res.residuals),
        "rms_loo": _rms(loo) if loo_method else None,
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
        residual_rms=_rms(res.cost_residuals),
        extra=extra,
    )


def _physical_checks(res, gains, nominal: Nominal, cfg: Config, units: str, g: float) -> list[str]:
    warnings = []
    limit = cfg.accel.max_scale_error
    if nominal.sensitivity is not None:
        ref, what = np.full(3, nominal.sensitivity), "nominal"
    else:
        ref, what = np.full(3, np.median(gains)), "the median of the three axes"
    for axis, gain, r in zip("xyz", gains, ref, strict=True):
        if abs(gain / r - 1) > limit:
            warnings.append(
                f"{axis} sensitivity {gain:.6g} {units} per m/s^2 is {100 * (gain / r - 1):+.0f}% "
                f"from {what} ({r:.6g}); more than {100 * limit:.0f}% is not a working part or "
                "the units are wrong"
            )
    if nominal.range is not None:
        lo, hi = nominal.range
        for axis, b in zip("xyz", res.bias, strict=True):
            if not lo <= b <= hi:
                warnings.append(
                    f"{axis} bias {b:.6g} {units} lies outside the sensor's range "
                    f"[{lo:.6g}, {hi:.6g}]"
                )
    rms = _rms(res.residuals)
    if rms > 0.05 * g:
        warnings.append(
            f"the poses do not agree on one gravity magnitude even after calibration (RMS "
            f"{rms:.3g} m/s^2): was the unit moving during the holds?"
        )
    return warnings


def calibrate_session(
    session: Session, cfg: Config, *, session_name: str | None = None
) -> Calibration:
    """Calibrate every sensor the config asks for; returns the calibration (not yet saved)."""
    accel = calibrate_accel(session, cfg)
    extra = {"toolkit_version": __version__, "config": cfg.to_dict()}
    if session.sensor:
        extra["sensor"] = session.sensor
    return Calibration(
        accel=accel, session=session_name or _name(session), created=utc_now_iso(), extra=extra
    )


def suspect_error(cal: Calibration) -> SolverError | None:
    """A :class:`SolverError` describing the physical-sense warnings, or None when clean."""
    warnings = [w for sec in (cal.accel, cal.gyro) if sec for w in sec.extra.get("warnings", [])]
    if not warnings:
        return None
    more = f" (and {len(warnings) - 1} more)" if len(warnings) > 1 else ""
    return SolverError(
        f"result outside physical sense, not saved: {warnings[0]}{more}; "
        "check the units and the capture, or pass --force to save it with these warnings"
    )


def default_output(session_path: Path) -> Path:
    """``run3.h5`` -> ``run3.cal.json`` beside it."""
    return session_path.with_suffix(".cal.json")


def _rms(x) -> float:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if len(x) else float("nan")


def _num(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _name(session: Session) -> str:
    return str(session.path) if session.path is not None else "session"
