"""The gravity-magnitude accelerometer step: pose statistics -> Qureshi & Golnaraghi solver ->
the accel section of the calibration, with uncertainties, residuals and checks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal_cli.calibrate.accel.checks import pose_sigmas, quality, robust_fit
from imucal_cli.calibrate.accel.section import (
    PoseFit,
    axes_summary_with_std,
    check_fields,
    fit_fields,
    label_warnings,
    model_covariance,
    parameter_rows,
    triad_members,
    with_excluded,
)
from imucal_cli.calibrate.common import (
    StaticPoses,
    check_design,
    labels_determine,
    rms,
    session_name,
)
from imucal_cli.errors import DesignError
from imucal_cli.estimators.accel import gravity as gravity_solver
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.accel import AccelCalibration
from imucal_cli.model.codec import build

#: Exact refits for the held-out residuals up to this many poses; above it, the first-order
#: deletion of each pose (the same to well below the noise from ~20 poses on, and free).
LOO_EXACT_MAX_POSES = 20

GAUGE_9 = (
    "upper-triangular matrix: calibrated z is the z sensitivity axis, y lies in the plane of "
    "the y and z axes (Qureshi eq. 3); rotate it to your body frame if you need one"
)
GAUGE_12 = "full matrix, rotated onto the labelled up directions of the fixture"


def _matrix_of(variant: str):
    if variant == "9-parameter":
        return lambda p: gravity_solver.params_to_model(p)[1]
    return lambda p: p[3:].reshape(3, 3)


def _params_of(variant: str):
    if variant == "9-parameter":
        return gravity_solver.model_to_params
    return lambda B, M: np.r_[B, M.ravel()]


def fit_poses(poses: StaticPoses, g: float, cfg: Config) -> gravity_solver.GravityResult:
    """The gravity solver on a set of poses, with the config's options."""
    opts = cfg.accel.gravity
    up = poses.up if np.isfinite(poses.up).any() else None
    return gravity_solver.fit_gravity(
        poses.a_mean,
        g,
        cov_mean=poses.cov_mean if opts.weighting == "noise" else None,
        up=up,
        variant=opts.model,
        init=opts.init,
        max_iterations=opts.max_iterations,
    )


def held_out(
    poses: StaticPoses, g: float, res: gravity_solver.GravityResult, cfg: Config
) -> tuple[np.ndarray | None, str | None]:
    """Held-out residual of every pose and how it was computed (None when not asked)."""
    N = len(poses.a_mean)
    if not cfg.accel.gravity.leave_one_out or N <= 9:
        return None, None
    if N <= LOO_EXACT_MAX_POSES:
        cov = poses.cov_mean if cfg.accel.gravity.weighting == "noise" else None
        loo = gravity_solver.leave_one_out(poses.a_mean, g, res, cov_mean=cov)
        return loo, "refit without each pose"
    return res.residual_loo, "first-order deletion of each pose"


def design_check(nominal, cfg: Config, where: str):
    """Whether a reduced set of poses (outliers left out) still determines the model."""

    def design_ok(p: StaticPoses) -> bool:
        try:
            check_design(p, nominal, cfg.accel.min_separation_deg, where, cfg.accel.gravity.model)
        except DesignError:
            return False
        return True

    return design_ok


def solver_fields(res: gravity_solver.GravityResult, units: list[str]) -> dict:
    """The members of the section that describe the gravity solver's fit."""
    return {
        "variant": res.variant,
        "gauge": GAUGE_9 if res.variant == "9-parameter" else GAUGE_12,
        "parameters": parameter_rows(res.param_names, res.params, res.std, units),
        "covariance": model_covariance(_params_of(res.variant), res.bias, res.matrix, res.cov),
        **fit_fields(res),
        "rotation_std_deg": res.rotation_std_deg,
    }


#: What a gravity fit with too few spare equations could use instead when its poses carry
#: labels that determine the labelled-pose fit (issue 9.6).
LABELS_INSTEAD = ('its `up` labels determine the labelled-pose fit, which checks itself: '
                  '[accel] solver = "labelled" (or the default "auto")')  # fmt: skip


@dataclass
class GravityFit:
    """The gravity solver's fit of a session's poses, before it becomes a section: what the
    ``auto`` choice reads of it (:mod:`imucal_cli.calibrate.accel.estimators`: the bound at
    its solution, the labels' placement) and what the section is built from.

    Attributes
    ----------
    res : GravityResult
        The fit of the poses used.
    used : StaticPoses
        The poses used (outliers left out).
    outliers : list of Outlier
    loo : ndarray or None
        Held-out residual of each pose used, m/s^2; ``loo_method`` says how.
    loo_method : str or None
    summary : (ndarray (6,), ndarray (6,))
        Gains and angles between the axes, with their std.
    fit : PoseFit
        Residual, direction and angle to the label of every pose (left-out ones too).
    """

    res: gravity_solver.GravityResult
    used: StaticPoses
    outliers: list
    loo: np.ndarray | None
    loo_method: str | None
    summary: tuple[np.ndarray, np.ndarray]
    fit: PoseFit


def gravity_fit(session: Session, cfg: Config, poses: StaticPoses, g: float, nominal
                ) -> GravityFit:  # fmt: skip
    """Fit the gravity solver to ``poses``, outliers handled (:func:`robust_fit`)."""
    res, used, outliers = robust_fit(
        lambda p: fit_poses(p, g, cfg),
        poses,
        cfg.accel.outliers,
        design_check(nominal, cfg, session_name(session)),
    )
    first = {}  # each segment's first index among the poses, as list.index finds it
    for k, s in enumerate(poses.segments):
        first.setdefault(s, k)
    used_index = np.array([first[s] for s in used.segments])
    loo, loo_method = held_out(used, g, res, cfg)
    summary = axes_summary_with_std(_matrix_of(res.variant), res.params, res.cov)
    fit = with_excluded(
        PoseFit(res.residuals, res.directions, res.up_angle_deg, loo),
        used_index,
        poses.a_mean,
        poses.up,
        res.bias,
        res.M,
        g,
        frame=res.rotation,
        output_aligned=res.variant == "12-parameter",
    )
    return GravityFit(res, used, outliers, loo, loo_method, summary, fit)


def gravity_section(
    session: Session, cfg: Config, poses: StaticPoses, g: float, nominal, gf: GravityFit
) -> AccelCalibration:
    """The accel section of a gravity fit (:func:`gravity_fit`) of ``poses``."""
    res, used, outliers, loo, loo_method, fit = (
        gf.res, gf.used, gf.outliers, gf.loo, gf.loo_method, gf.fit)  # fmt: skip
    members, units_in, units_note, physical = triad_members(
        session, cfg, poses, g, nominal, gf.summary, fit, res.bias, res.residuals
    )
    units = [units_in] * 3 + [f"m/s^2 per {units_in}"] * (len(res.params) - 3)
    q = quality(
        used,
        res.residuals,
        pose_sigmas(used, res.M, res.bias),
        res.dof,
        9,
        rms(loo) if loo is not None else None,
        g,
        members["coverage"],
        excess=float(np.sqrt(res.chi2 / res.dof)) if res.dof > 0 else None,
        distinct=members["coverage"].n_distinct,  # a repeated direction checks no model term
        instead=LABELS_INSTEAD if labels_determine(used.up) else None,
    )
    members.update(
        {
            **solver_fields(res, units),
            "loo_method": loo_method,
            **check_fields(
                q,
                outliers,
                physical,
                label_warnings(fit, poses) + ([units_note] if units_note else []),
            ),
        }
    )
    if loo_method is None:
        members["rms_loo"] = None
    return build(AccelCalibration, solver="gravity", units="m/s^2", bias=res.bias,
                 matrix=res.matrix, residual_rms=rms(res.cost_residuals), **members)
