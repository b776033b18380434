"""The labelled-pose accelerometer step (issue 9.1): static poses with `up` labels -> bias and
full 3x3 matrix in the fixture frame, each pose's true direction a nuisance parameter with a
prior around its label (:mod:`imucal_cli.solvers.labelled`)."""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import DesignError
from imucal_cli.formats.calibration import SensorCalibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.solvers import labelled as labelled_solver

from .accel import PoseFit, common_extra, parameter_rows
from .common import (
    StaticPoses,
    labels_determine,
    nominal_sensor,
    physical_checks,
    rms,
    session_name,
    static_poses,
)

GAUGE = (
    "full matrix in the fixture frame of the labels: matrix = R(r) K, K upper triangular "
    "(Qureshi eq. 3, set by the sensitivities s_* and angles a_*) and r the rotation vector "
    "(deg) onto the labelled up directions"
)


def fit_poses(poses: StaticPoses, g: float, cfg: Config) -> labelled_solver.LabelledResult:
    """The labelled solver on a set of poses, with the config's options."""
    opts = cfg.accel.labelled
    noise_dof = poses.noise.dof if poses.noise is not None else np.inf
    return labelled_solver.fit_labelled(
        poses.a_mean,
        poses.up,
        g,
        poses.cov_mean,
        placement_deg=opts.placement_deg,
        noise_dof=noise_dof,
        max_iterations=opts.max_iterations,
    )


def labelled_section(
    session: Session, cfg: Config, poses: StaticPoses, g: float, nominal
) -> SensorCalibration:
    """Fit the labelled solver to ``poses`` and build the accel section."""
    res = fit_poses(poses, g, cfg)
    units_in = session.accel_units or "unknown"
    summary = (res.params[3:9], res.std[3:9])  # sensitivities and angles are parameters
    fit = PoseFit(res.residuals, res.directions, res.up_angle_deg, res.residual_loo)
    extra = common_extra(
        units_in=units_in,
        g=g,
        summary=summary,
        poses=poses,
        fit=fit,
        nominal=nominal,
        min_separation_deg=cfg.accel.min_separation_deg,
    )
    units = [units_in] * 3 + [f"{units_in} per m/s^2"] * 3 + ["deg"] * 6
    r_std = res.std[9:12]
    extra.update(
        {
            "variant": "12-parameter (labelled poses)",
            "gauge": GAUGE,
            "parameters": parameter_rows(res.param_names, res.params, res.std, units, res.ci95),
            "placement": {
                "rms_deg": res.placement_deg,
                "source": res.placement_source,
                "dof": res.placement_dof,
                "meaning": "RMS angle between each pose's true up and its label",
            },
            "init": res.init,
            "weighting": "noise",
            "iterations": res.iterations,
            "function_evaluations": res.nfev,
            "converged": res.converged,
            "message": res.message,
            "chi2": res.chi2,
            "dof": res.dof,
            "noise_scale": res.noise_scale,
            "rotation_std_deg": float(np.sqrt(np.mean(r_std**2))),
            "loo_method": "first-order deletion of each pose",
            "warnings": physical_checks(
                res.bias,
                summary[0][:3],
                rms(res.residuals),
                nominal,
                cfg,
                session.accel_units or "raw units",
                g,
            ),
        }
    )
    return SensorCalibration(
        solver="labelled",
        units="m/s^2",
        bias=res.bias,
        matrix=res.matrix,
        residual_rms=rms(res.residuals),
        extra=extra,
    )


def calibrate_accel_labelled(session: Session, cfg: Config) -> SensorCalibration:
    """Run the labelled-pose solver on a session's static poses.

    Raises
    ------
    DesignError
        Not a triad, or labels that cannot separate bias from sensitivity (says what would).
    SolverError
        No convergence.
    """
    where = session_name(session)
    g = cfg.gravity or session.gravity
    poses = static_poses(session)
    na = poses.a_mean.shape[1]
    if na != 3:
        raise DesignError(
            f"{where}: the labelled-pose solver calibrates a triad (3 accelerometer channels); "
            f'this session has {na}: [accel] solver = "factorization" (or the default "auto") '
            "calibrates a redundant unit"
        )
    if not labels_determine(poses.up):
        n_lab = int(np.isfinite(poses.up).all(axis=1).sum())
        raise DesignError(
            f"{where}: the labelled-pose solver needs at least 4 poses whose `up` labels are not "
            f"in one plane (this session has {n_lab} labelled of {len(poses.segments)}): label "
            "the faces with `imucal label SESSION --faces`, or use the gravity solver (9 or more "
            "distinct poses need no labels)"
        )
    nominal = nominal_sensor(session, cfg, g)
    return labelled_section(session, cfg, poses, g, nominal)
