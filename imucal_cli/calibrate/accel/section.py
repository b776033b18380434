"""What every accelerometer section shares, whichever solver filled it: the |a| before
calibration, sensitivities and angles between axes with their std, the parameter list, the
per-pose table, coverage and the common fields of DEVELOPERS.md."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imucal_cli.calibrate.common import (
    Nominal,
    StaticPoses,
    accel_units,
    num,
    physical_checks,
    rms,
)
from imucal_cli.design.poses import count_distinct, coverage
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.accel import Coverage, PoseNoise, PoseRow
from imucal_cli.model.calibration import MODEL_EQUATION
from imucal_cli.model.parts import Covariance, Parameter

PAIRS = ((0, 1), (0, 2), (1, 2))


def magnitude_before(poses: StaticPoses, nominal: Nominal, g: float) -> np.ndarray:
    """|a| of each pose as an uncalibrated user would read it (nominal sensitivity and
    offset, or one scale fitted to the raw magnitudes), m/s^2."""
    raw = np.linalg.norm(poses.a_mean - nominal.bias, axis=1)
    if nominal.sensitivity is not None:
        return raw / nominal.sensitivity
    return raw * (g / np.median(raw))


def axes_summary(matrix: np.ndarray) -> np.ndarray:
    """(gain x, y, z in raw units per m/s^2; angle between axes xy, xz, yz minus 90 deg)."""
    S = np.linalg.inv(matrix)  # rows: each channel's sensitivity axis
    gains = np.linalg.norm(S, axis=1)
    s = S / gains[:, None]
    ang = [np.degrees(np.arccos(np.clip(s[i] @ s[j], -1, 1))) - 90.0 for i, j in PAIRS]
    return np.r_[gains, ang]


def axes_summary_with_std(
    matrix_of: Callable[[np.ndarray], np.ndarray], params: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`axes_summary` of ``matrix_of(params)`` and its std (delta method)."""
    f0 = axes_summary(matrix_of(params))
    J = np.empty((len(f0), len(params)))
    for i in range(len(params)):
        step = 1e-6 * max(abs(params[i]), 1e-12)
        dp = np.zeros_like(params)
        dp[i] = step
        J[:, i] = (axes_summary(matrix_of(params + dp)) - axes_summary(matrix_of(params - dp))) / (
            2 * step
        )
    return f0, np.sqrt(np.clip(np.diag(J @ cov @ J.T), 0, None))


#: What the ``covariance`` field of an accel section is the covariance of.
COVARIANCE_OF = "bias (3, raw units) then matrix row-major (9, m/s^2 per raw unit)"


def model_covariance(
    params_of: Callable[[np.ndarray, np.ndarray], np.ndarray],
    bias: np.ndarray,
    matrix: np.ndarray,
    cov: np.ndarray,
) -> Covariance:
    """The ``covariance`` field: the covariance of ``(bias, matrix row-major)`` from a solver's
    parameter covariance ``cov``, where ``params_of(bias, matrix)`` gives the solver's
    parameters (delta method through the pseudo-inverse of that map's Jacobian: a gauge the
    solver fixes, such as an upper-triangular matrix, has no variance). What uses the
    calibration's directions (the gyro's turns) propagates it (issue 10.2)."""
    Ji = model_map(params_of, bias, matrix)
    C = Ji @ cov @ Ji.T
    return Covariance(COVARIANCE_OF, (C + C.T) / 2)


def model_map(params_of: Callable[[np.ndarray, np.ndarray], np.ndarray], bias: np.ndarray,
              matrix: np.ndarray) -> np.ndarray:  # fmt: skip
    """``d (bias, matrix row-major) / d params`` (12, n): the pseudo-inverse of the Jacobian
    of ``params_of`` (:func:`model_covariance`)."""
    x0 = np.r_[bias, np.ravel(matrix)].astype(float)
    step = np.r_[np.full(3, 1e-6 * max(np.abs(bias).max(), 1.0)),
                 np.full(9, 1e-6 * np.abs(matrix).max())]  # fmt: skip

    def f(x):
        return np.asarray(params_of(x[:3], x[3:].reshape(3, 3)), float)

    J = np.empty((len(f(x0)), 12))
    for i in range(12):
        e = np.zeros(12)
        e[i] = step[i]
        J[:, i] = (f(x0 + e) - f(x0 - e)) / (2 * step[i])
    return np.linalg.pinv(J)


def parameter_rows(
    names: list[str],
    values: np.ndarray,
    std: np.ndarray,
    units: list[str],
    ci95: np.ndarray | None = None,
) -> list[Parameter]:
    """The ``parameters`` list: name, value, std, unit (and the 95 % half-width if given)."""
    return [Parameter(n, float(v), float(s), u, None if ci95 is None else float(ci95[k]))
            for k, (n, v, s, u) in enumerate(zip(names, values, std, units, strict=True))]


def fit_fields(res, weighting: str | None = None) -> dict:
    """The fit's statistics as a section's members: ``init``, ``weighting``, ``iterations``,
    ``function_evaluations``, ``converged``, ``message``, ``chi2``, ``dof``, ``noise_scale``
    (from a solver result with those attributes; ``nfev`` for the evaluations), for
    :func:`~imucal_cli.model.codec.build`."""
    return {
        "init": res.init,
        "weighting": res.weighting if weighting is None else weighting,
        "iterations": res.iterations,
        "function_evaluations": res.nfev,
        "converged": res.converged,
        "message": res.message,
        "chi2": res.chi2,
        "dof": res.dof,
        "noise_scale": res.noise_scale,
    }


@dataclass
class PoseFit:
    """What a solver says about each pose (arrays of length N)."""

    residuals: np.ndarray  # |h_k| - g, m/s^2
    directions: np.ndarray  # (N, 3) calibrated unit gravity direction
    up_angle_deg: np.ndarray | None = None
    residual_loo: np.ndarray | None = None
    excluded: np.ndarray | None = None  # bool: left out of the fit as an outlier

    @property
    def used(self) -> np.ndarray:
        n = len(self.residuals)
        return np.ones(n, bool) if self.excluded is None else ~self.excluded


def with_excluded(
    fit: PoseFit,
    used_index: np.ndarray,
    a_all: np.ndarray,
    up_all: np.ndarray,
    bias: np.ndarray,
    matrix: np.ndarray,
    g: float,
    frame: np.ndarray | None = None,
    output_aligned: bool = False,
) -> PoseFit:
    """Extend a fit over the poses it used to every pose of the session: a left-out pose gets
    its residual under the final calibration (which is also held out: the fit never saw it),
    its direction (``frame`` rotates ``matrix``'s output onto the labels) and its angle to its
    label."""
    N = len(a_all)
    if len(used_index) == N:
        return fit
    h = (a_all - bias) @ matrix.T
    mag = np.linalg.norm(h, axis=1)
    dirs = h / mag[:, None]
    aligned = dirs if frame is None else dirs @ frame.T
    lab = np.isfinite(up_all).all(axis=1)
    angle = np.full(N, np.nan)
    angle[lab] = np.degrees(np.arccos(np.clip(np.sum(aligned[lab] * up_all[lab], axis=1), -1, 1)))
    out_dirs = aligned if output_aligned else dirs
    out = PoseFit(mag - g, out_dirs, angle, (mag - g).copy(), excluded=np.ones(N, bool))
    out.residuals[used_index] = fit.residuals
    out.directions[used_index] = fit.directions
    if fit.up_angle_deg is not None:
        out.up_angle_deg[used_index] = fit.up_angle_deg
    if fit.residual_loo is not None:
        out.residual_loo[used_index] = fit.residual_loo
    out.excluded[used_index] = False
    return out


def pose_rows(poses: StaticPoses, fit: PoseFit, mag_before: np.ndarray, g: float
              ) -> list[PoseRow]:  # fmt: skip
    """The ``poses`` table of the section."""
    rows = []
    for k, s in enumerate(poses.segments):
        row = PoseRow(
            segment=s.name,
            label=s.label,
            up=None if s.up is None else [float(x) for x in s.up],
            samples=int(poses.samples[k]),
            magnitude_before=float(mag_before[k]),
            magnitude_after=float(fit.residuals[k] + g),
            residual=float(fit.residuals[k]),
            residual_loo=None if fit.residual_loo is None else num(fit.residual_loo[k]),
            angle_to_up_deg=None if fit.up_angle_deg is None else num(fit.up_angle_deg[k]),
            direction=[float(x) for x in fit.directions[k]],
        )
        if poses.spikes is not None and poses.spikes[k]:
            row.spikes_left_out = int(poses.spikes[k])
        if fit.excluded is not None and fit.excluded[k]:
            row.excluded = True
        rows.append(row)
    return rows


def label_warnings(fit: PoseFit, poses: StaticPoses, limit_deg: float = 20.0) -> list[str]:
    """Poses whose measured up is far from their label (more than ``limit_deg`` and five times
    the median placement): the label is wrong."""
    ang = fit.up_angle_deg
    if ang is None or not np.isfinite(ang).any():
        return []
    limit = max(limit_deg, 5 * float(np.nanmedian(ang)))
    out = []
    for k in np.flatnonzero(np.nan_to_num(ang, nan=0.0) > limit):
        s = poses.segments[k]
        name = f"segment {s.name}" + (f" ({s.label})" if s.label else "")
        out.append(
            f"{name}: the measured up is {ang[k]:.0f} deg from its label, the others are within "
            f"{float(np.nanmedian(ang)):.1f} deg: the label is wrong (relabel with `imucal label "
            "SESSION --faces`)"
        )
    return out


def check_fields(quality, outliers, physical: list[str], more: list[str]) -> dict:
    """The warning members of a section: ``warnings`` (everything said out loud), ``blocking``
    (the subset that stops a save without --force), the outliers and the fit quality."""
    return {
        "warnings": physical
        + quality.blocking
        + [o.warning() for o in outliers]
        + more
        + quality.warnings,
        "blocking": physical + quality.blocking,
        "outliers": [o.row() for o in outliers],
        "spare_equations": int(quality.spare),
        "rms_expected": float(quality.expected_rms),
        "noise_excess": None if not np.isfinite(quality.excess) else float(quality.excess),
        "rms_after_below_noise": bool(quality.below_noise),
    }


def coverage_of(directions: np.ndarray, n_poses: int, min_separation_deg: float) -> Coverage:
    """How calibrated gravity ``directions`` (N, 3) cover the sphere."""
    cover = coverage(directions)
    return Coverage(
        fraction=cover.fraction,
        cap_deg=cover.cap_deg,
        largest_gap_deg=cover.largest_gap_deg,
        weakest_direction=[float(x) for x in cover.weakest_direction],
        n_poses=n_poses,
        n_distinct=count_distinct(directions, min_separation_deg),
    )


def common_members(
    *,
    units_in: str,
    g: float,
    summary: tuple[np.ndarray, np.ndarray],
    poses: StaticPoses,
    fit: PoseFit,
    nominal: Nominal,
    min_separation_deg: float,
) -> dict:
    """The members of DEVELOPERS.md every accelerometer solver fills the same way (for
    :func:`~imucal_cli.model.codec.build`)."""
    derived, derived_std = summary
    mag_before = magnitude_before(poses, nominal, g)
    used = fit.used
    loo = None if fit.residual_loo is None else fit.residual_loo[used]
    noise = poses.noise
    members = {
        "model": MODEL_EQUATION,
        "units_in": units_in,
        "gravity": g,
        "sensitivity": [float(x) for x in derived[:3]],
        "sensitivity_std": [float(x) for x in derived_std[:3]],
        "sensitivity_unit": f"{units_in} per m/s^2",
        "misalignment_deg": dict(zip(("xy", "xz", "yz"), map(float, derived[3:]), strict=True)),
        "misalignment_std_deg": dict(
            zip(("xy", "xz", "yz"), map(float, derived_std[3:]), strict=True)
        ),
        "rms_before": rms(mag_before[used] - g),
        "rms_after": rms(fit.residuals[used]),
        "rms_loo": rms(loo) if loo is not None and np.isfinite(loo).any() else None,
        "before_basis": nominal.basis,
        "coverage": coverage_of(fit.directions[used], int(used.sum()), min_separation_deg),
        "poses": pose_rows(poses, fit, mag_before, g),
        "notes": [
            f"{int(n)} spike sample(s) left out of the mean of segment {s.name}"
            + (f" ({s.label})" if s.label else "")
            for s, n in zip(
                poses.segments,
                poses.spikes if poses.spikes is not None else [0] * len(poses.segments),
                strict=True,
            )
            if n
        ],
    }
    if noise is not None:
        members["noise"] = PoseNoise(
            per_sample_std=[float(x) for x in np.sqrt(np.diag(noise.cov))],
            unit=units_in,
            dof=int(noise.dof),
            basis="pooled over every still hold (each pose mean weighted by noise / samples)",
        )
    return members


def triad_members(
    session: Session, cfg: Config, poses: StaticPoses, g: float, nominal: Nominal,
    summary: tuple[np.ndarray, np.ndarray], fit: PoseFit, bias: np.ndarray,
    residuals: np.ndarray,
) -> tuple[dict, str, str | None, list[str]]:  # fmt: skip
    """What a triad fit's section (gravity, labelled) starts from: the common fields
    (:func:`common_members`), the raw units and a note when they were inferred, and the
    physical-sense checks of ``bias``, the sensitivities and the fit's ``residuals``.
    Returns ``(members, units_in, units_note, physical)``."""
    units_in, units_note = accel_units(session, g)
    members = common_members(
        units_in=units_in, g=g, summary=summary, poses=poses, fit=fit, nominal=nominal,
        min_separation_deg=cfg.accel.min_separation_deg,
    )  # fmt: skip
    physical = physical_checks(bias, summary[0][:3], rms(residuals), nominal, cfg, units_in, g)
    return members, units_in, units_note, physical
