"""The labelled-pose accelerometer step (issue 9.1): static poses with `up` labels -> bias and
full 3x3 matrix in the fixture frame, each pose's true direction a nuisance parameter with a
prior around its label (:mod:`imucal_cli.estimators.accel.labelled`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from imucal_cli.calibrate.accel.checks import (
    Outlier,
    drop_wrong_labels,
    pose_sigmas,
    quality,
    robust_fit,
)
from imucal_cli.calibrate.accel.section import (
    PoseFit,
    check_fields,
    fit_fields,
    model_covariance,
    model_map,
    parameter_rows,
    triad_members,
    with_excluded,
)
from imucal_cli.calibrate.common import (
    StaticPoses,
    check_design,
    labels_determine,
    rms,
)
from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.accel import gravity as gravity_solver
from imucal_cli.estimators.accel import labelled as labelled_solver
from imucal_cli.estimators.accel.labelled_checks import placement_outliers
from imucal_cli.estimators.accel.labelled_model import public_params
from imucal_cli.estimators.accel.labelled_response import pose_response
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.accel import AccelCalibration, GivenPlacement, Placement
from imucal_cli.model.codec import build

GAUGE = (
    "full matrix in the fixture frame of the labels: matrix = R(r) K, K upper triangular "
    "(Qureshi eq. 3, set by the sensitivities s_* and angles a_*) and r the rotation vector "
    "(deg) onto the labelled up directions"
)


def design_ok(p: StaticPoses) -> bool:
    """Whether a reduced set of poses (outliers left out) still determines the model."""
    return labels_determine(p.up) and len(p.segments) >= 5


def used_up(poses: StaticPoses, used: StaticPoses, used_index: np.ndarray) -> np.ndarray:
    """The labels as the final fit used them (a wrong label dropped), for every pose."""
    up = poses.up.copy()
    up[used_index] = used.up
    return up


def screen_by_magnitude(
    poses: StaticPoses, g: float, cfg: Config, nominal, design_ok
) -> tuple[StaticPoses, list]:
    """Poses whose gravity magnitude disagrees with the rest (a bump along gravity), found by
    the gravity-magnitude fit where the poses determine it (>= 9 distinct directions).

    The labelled fit rescales its measurement noise to a bad pose's misfit, which then hides
    among the others; the magnitude fit keeps the measured noise as its weights, so a pose
    that disagrees stands out (issue 10.6). Returns the poses to fit and the outliers found.
    """
    try:
        check_design(poses, nominal, cfg.accel.min_separation_deg, "", "9")
    except DesignError:
        return poses, []

    def fit(p: StaticPoses):
        return gravity_solver.fit_gravity(
            p.a_mean, g, cov_mean=p.cov_mean, variant="9", init="ellipsoid",
            max_iterations=cfg.accel.gravity.max_iterations,
        )  # fmt: skip

    try:
        _, used, found = robust_fit(fit, poses, cfg.accel.outliers, design_ok)
    except (DesignError, SolverError):
        return poses, []
    return used, [o for o in found if o.action != "kept"]


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
) -> AccelCalibration:
    """Fit the labelled solver to ``poses`` (outliers handled) and build the accel section."""

    relabelled, wrong = drop_wrong_labels(poses, g)
    screened, screen = screen_by_magnitude(relabelled, g, cfg, nominal, design_ok)
    res, used, outliers = robust_fit(
        lambda p: fit_poses(p, g, cfg), screened, cfg.accel.outliers, design_ok, labelled=True
    )
    res, used, misplaced, tied = misplaced_labels(res, used, g, cfg)
    misplaced = [replace(o, index=poses.segments.index(used.segments[o.index]))
                 for o in misplaced]  # fmt: skip
    outliers = wrong + screen + outliers + misplaced
    used_index = np.array([poses.segments.index(s) for s in used.segments])
    summary = (res.params[3:9], res.std[3:9])  # sensitivities and angles are parameters
    fit = with_excluded(
        PoseFit(res.residuals, res.directions, res.up_angle_deg, res.residual_loo),
        used_index,
        poses.a_mean,
        used_up(poses, used, used_index),
        res.bias,
        res.matrix,
        g,
    )
    members, units_in, units_note, physical = triad_members(
        session, cfg, poses, g, nominal, summary, fit, res.bias, res.residuals
    )
    units = [units_in] * 3 + [f"{units_in} per m/s^2"] * 3 + ["deg"] * 6
    q = quality(
        used,
        res.residuals,
        pose_sigmas(used, res.matrix, res.bias),
        res.dof,
        12,
        rms(res.residual_loo),
        g,
        members["coverage"],
        excess=float(np.sqrt(res.noise_scale)),
    )
    members.update(
        {
            **solver_fields(res, units),
            "given_placement": given_placement(res, used),
            **check_fields(q, outliers, physical, [units_note] if units_note else []),
        }
    )
    if tied:  # issue 24.6: named, and not saved without --force (the design cannot say which)
        members["warnings"].insert(0, tied)
        members["blocking"].insert(0, tied)
    return build(AccelCalibration, solver="labelled", units="m/s^2", bias=res.bias,
                 matrix=res.matrix, residual_rms=rms(res.residuals), **members)


#: At most this many labels are ignored for their placement.
MAX_MISPLACED = 3


def misplaced_labels(res, poses: StaticPoses, g: float, cfg: Config):
    """Labels whose pose sat off them by more than the others' placement spread allows
    (:func:`imucal_cli.estimators.accel.labelled_checks.placement_outliers`; issue 24.6: a
    label 5-20 degrees wrong used to inflate the placement estimate, and every std with it,
    instead of being named). A pose the design can single out loses its label (its magnitude
    still counts; the holds of one placement, fitted as one, lose theirs together) and the fit
    is redone; a group it cannot tell apart (opposite faces of six, whose
    disagreement the fit shares) is named in a warning that stops the save.

    Returns the result, the poses used, the outliers (action ``"label ignored"``) and the
    warning for a group (None when there is none)."""

    if cfg.accel.outliers == "keep":
        return res, poses, [], None
    found = []
    for _ in range(MAX_MISPLACED):
        groups = placement_outliers(res)
        if not groups:
            return res, poses, found, None
        idx, p = groups[0]
        names = [_pose_name(poses, k) for k in idx]
        angles = [float(res.up_angle_deg[k]) for k in idx]
        others = np.delete(res.up_angle_deg, idx)
        spread = float(np.sqrt(np.nanmean(others**2))) if np.isfinite(others).any() else 0.0
        if len(idx) > 1 and not _one_placement(res, idx):
            return res, poses, found, (
                f"{' and '.join(names)} disagree with each other: their placements come to "
                f"{', '.join(f'{a:.1f}' for a in angles)} deg off their labels where the other "
                f"poses sit within {spread:.1f} deg RMS (p = {p:.2g}): one of their labels is "
                "wrong, or the unit did not sit flat on one of them, and these poses cannot tell "
                "which; check them and re-capture (the 12 edges of plan qureshi18 tell each "
                "pose apart)"
            )  # fmt: skip
        up = poses.up.copy()
        up[idx] = np.nan  # one pose, or the holds of one placement (a turn on the table)
        trial = replace(poses, up=up)
        if not design_ok(trial):
            return res, poses, found, None
        try:
            new = fit_poses(trial, g, cfg)
        except (DesignError, SolverError):
            return res, poses, found, None
        cause = (f"it sat {angles[0]:.1f} deg off its label where the other poses sit within "
                 f"{spread:.1f} deg RMS (p = {p:.2g}): its label is wrong, or it rested on "
                 "something")  # fmt: skip
        for k in idx:
            seg = poses.segments[k]
            found.append(Outlier(k, seg.name, seg.label, float("nan"), p, cause,
                                 "label ignored"))  # fmt: skip
        res, poses = new, trial
    return res, poses, found, None


def _one_placement(res: labelled_solver.LabelledResult, idx: list[int]) -> bool:
    """Whether the poses ``idx`` are the holds of one placement, fitted as one
    (:mod:`imucal_cli.estimators.accel.labelled_holds`): their labels go together."""
    runs = None if res.fit is None else res.fit.runs
    return runs is not None and len({int(runs.index[k]) for k in idx}) == 1


def _pose_name(poses: StaticPoses, k: int) -> str:
    seg = poses.segments[k]
    return f"segment {seg.name}" + (f" ({seg.label})" if seg.label else "")


def _params_of(B: np.ndarray, M: np.ndarray) -> np.ndarray:
    return public_params(B, np.linalg.inv(M))


def given_placement(res: labelled_solver.LabelledResult, used: StaticPoses) -> GivenPlacement:
    """The fit's errors given the poses' placement, in ``(bias, matrix row-major)``: its
    response to each used pose's mean (eq. L7, :func:`.labelled_response.pose_response`) and
    the covariance that gives at the measured noise, as the pose pairs of a set's rotations
    take it (``docs/imu-set.md``, eq. R3). Computed when first asked for (only a set of IMUs
    asks): a calibration of one IMU never computes it."""

    def compute() -> tuple[np.ndarray, np.ndarray]:
        L = np.einsum("ij,jnk->ink", model_map(_params_of, res.bias, res.matrix),
                      pose_response(res))  # fmt: skip
        C = np.einsum("inj,njk,lnk->il", L, used.cov_mean[:, :3, :3], L)
        return (C + C.T) / 2, L

    return GivenPlacement(segments=[seg.name for seg in used.segments], compute=compute)


def solver_fields(res: labelled_solver.LabelledResult, units: list[str]) -> dict:
    """The fields of the section that describe the labelled solver's fit."""
    r_std = res.std[9:12]
    return {
        "variant": "12-parameter (labelled poses)",
        "gauge": GAUGE,
        "parameters": parameter_rows(res.param_names, res.params, res.std, units, res.ci95),
        "covariance": model_covariance(_params_of, res.bias, res.matrix, res.cov),
        "placement": Placement(
            rms_deg=res.placement_deg,
            source=res.placement_source,
            dof=res.placement_dof,
            meaning="RMS angle between each pose's true up and its label",
            **({} if res.placement_face_deg is None else {
                "face_deg": res.placement_face_deg, "hold_deg": res.placement_hold_deg,
                "parts": "face_deg: each face's normal off its label, shared by every pose on "
                         "it; hold_deg: each hold's own (the table's tilt, how it sat)"}),
        ),
        **fit_fields(res, "noise"),
        "rotation_std_deg": float(np.sqrt(np.mean(r_std**2))),
        "loo_method": "first-order deletion of each pose",
    }
