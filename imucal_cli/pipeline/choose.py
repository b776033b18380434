"""``[accel] solver = "auto"`` (the default): the most accurate accelerometer solver the session
supports, and why (issue 9.1, point 2 of the accel work package).

* a redundant unit (4 or more channels): the factorization, which finds its biases without
  labels (Hwangbo & Kanade);
* a triad with 9 or more distinct poses: the gravity-magnitude solver (Qureshi & Golnaraghi
  III-A), which needs no labels; unless the poses carry labels placed so well that using them
  makes the fit measurably more precise (predicted from the Cramér-Rao bounds of both designs
  at the gravity solution, with the placement the labels showed), then the labelled solver.
  Where only some poses are labelled (Hwangbo & Kanade's iron: the second mounting has no
  `up`) the labelled solver fits the unlabelled ones by their magnitude (a free direction), so
  its bound is the gravity bound with the labelled poses' priors added: on 9 distinct
  directions (no spare equation for the gravity fit) the labels decide the axes;
* a triad with fewer distinct poses whose labels determine the model (six faces): the
  labelled-pose solver;
* otherwise a refusal that names what would work with what the user already has.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import DesignError
from imucal_cli.formats.calibration import SensorCalibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.solvers.crb import gravity_crb, labelled_crb
from imucal_cli.solvers.gravity import params_to_model
from imucal_cli.solvers.labelled_model import jacobian, public_from_theta
from imucal_cli.solvers.poses import count_distinct, unit

from .common import (
    StaticPoses,
    check_design,
    labels_determine,
    nominal_sensor,
    session_name,
    static_poses,
)
from .factorization import calibrate_accel_factorization
from .gravity import gravity_section
from .labelled import labelled_section

#: The labelled solver replaces the gravity solver only when its predicted variance of the
#: gauge-free parameters (bias and K) is below this fraction of the gravity solver's.
LABELS_WORTH = 0.8


def auto_accel(session: Session, cfg: Config) -> SensorCalibration | None:
    """Choose, run and annotate the accelerometer solver (None: nothing to calibrate)."""
    if session.accel is None or not session.static_segments():
        return None
    na = session.accel.shape[1]
    if na >= 4:
        sec = calibrate_accel_factorization(session, cfg)
        reason = (
            f"a redundant unit of {na} channels: the factorization finds its biases without "
            "labels (Hwangbo & Kanade)"
        )
        return _annotate(sec, "factorization", reason)
    g = cfg.gravity or session.gravity
    poses = static_poses(session)
    nominal = nominal_sensor(session, cfg, g)
    where = session_name(session)
    try:
        check_design(poses, nominal, cfg.accel.min_separation_deg, where)
        gravity_ok = None
    except DesignError as exc:
        gravity_ok = exc
    n_lab = int(np.isfinite(poses.up).all(axis=1).sum())
    if gravity_ok is None:
        sec = gravity_section(session, cfg, poses, g, nominal)
        better = _labels_worth_it(sec, poses, g) if labels_determine(poses.up) else None
        if better is None:
            return _annotate(sec, "gravity", _gravity_reason(sec, n_lab))
        ratios, placement = better

        lab = labelled_section(session, cfg, poses, g, nominal)
        some = "" if n_lab == len(poses.segments) else (
            f" ({n_lab} of {len(poses.segments)} poses labelled; the others enter by their "
            "magnitude, as in the gravity fit)")  # fmt: skip
        reason = (
            f"the labels are placed within {placement:.2g} deg RMS{some}: using them makes the "
            f"bias {1 / np.sqrt(np.mean(ratios[:3])):.1f}x and the gains and axes "
            f"{1 / np.sqrt(np.mean(ratios[3:])):.1f}x more precise than gravity magnitude alone "
            "(Cramer-Rao bounds of both designs)"
        )
        return _annotate(lab, "labelled", reason)
    if labels_determine(poses.up):
        sec = labelled_section(session, cfg, poses, g, nominal)
        distinct = sec.extra["coverage"]["n_distinct"]
        reason = (
            f"{distinct} distinct directions are too few for the gravity-magnitude model (9 "
            f"parameters), but the {n_lab} labelled poses determine bias and the full matrix, "
            "each pose's placement a nuisance parameter"
        )
        return _annotate(sec, "labelled", reason)
    raise DesignError(_refusal(session, poses, nominal, gravity_ok, where))


def _annotate(sec: SensorCalibration, solver: str, reason: str) -> SensorCalibration:
    sec.extra["choice"] = {"solver": solver, "by": "auto", "reason": reason}
    return sec


def _gravity_reason(sec: SensorCalibration, n_lab: int) -> str:
    x = sec.extra
    text = (
        f"{x['coverage']['n_distinct']} distinct poses determine the 9-parameter "
        "gravity-magnitude model, which needs no labels"
    )
    if n_lab:
        angles = [p["angle_to_up_deg"] for p in x["poses"] if p["angle_to_up_deg"] is not None]
        if angles:
            text += (
                f"; the labels (poses within {np.sqrt(np.mean(np.square(angles))):.2g} deg RMS "
                "of them) would not make it measurably more precise"
            )
    return text


def _labels_worth_it(sec: SensorCalibration, poses: StaticPoses, g: float):
    """``(variance ratios (9,), placement deg)`` when the labelled solver is predicted to be
    measurably more precise than the gravity solver on bias and K (the mean of the ratios of
    bias, gain and axis-angle variances below :data:`LABELS_WORTH`), else None.

    Where only some poses are labelled (the second mounting of Hwangbo & Kanade's iron has
    no `up`), the labelled solver is the maximum-likelihood fit of all of them: a labelled
    pose gives its vector equation with the placement error as a prior (L2, L3), an
    unlabelled one its magnitude equation with a free direction, exactly as in the gravity
    solver. Its bound (L5) then has the prior on the labelled poses only and is never above
    the gravity-magnitude bound; using the labelled poses alone would throw the others'
    magnitude equations away. The placement is the RMS angle between the labelled poses'
    gravity-fit directions and their labels: where the gravity fit is poorly determined its
    frame error inflates that angle, which only understates what the labels are worth."""
    x = sec.extra
    lab = np.isfinite(poses.up).all(axis=1)
    if lab.sum() < 4:
        return None
    angles = np.array([np.nan if p["angle_to_up_deg"] is None else p["angle_to_up_deg"]
                       for p in x["poses"]], float)  # fmt: skip
    if len(angles) != len(lab) or not np.isfinite(angles[lab]).any():
        return None
    placement = float(np.sqrt(np.nanmean(angles[lab] ** 2)))
    # Both bounds at the gravity solution, directions in its (triangular) frame.

    if x["variant"] != "9-parameter":
        return None
    theta = np.array([p["value"] for p in x["parameters"]])
    B, M = params_to_model(theta)
    u = unit((poses.a_mean - B) @ M.T)
    # both bounds on (bias, sensitivities, angles between the axes)
    T = jacobian(public_from_theta, np.r_[theta, np.zeros(3)])[:9, :9]
    grav = np.diag(T @ gravity_crb(M, B, u, g, poses.cov_mean) @ T.T)
    # The labels' frame differs from the triangular one by a rotation, which changes neither
    # bound on bias and K: both are evaluated in the triangular frame.
    per_pose = np.where(lab, max(placement, 1e-3), np.inf)  # unlabelled: a free direction
    lab_crb = np.diag(labelled_crb(M, B, u, g, poses.cov_mean, per_pose))[:9]
    ratios = lab_crb / grav
    return (ratios, placement) if float(np.mean(ratios)) < LABELS_WORTH else None


def _faces(directions: np.ndarray, up: np.ndarray) -> list[str]:
    """The faces (``+Z``, ...) the poses lie on: each pose's label, else its raw direction
    within 15 deg of an axis (raw axes named as the body's)."""
    faces = set()
    for d, u in zip(directions, up, strict=True):
        v = u if np.isfinite(u).all() else d
        i = int(np.argmax(np.abs(v)))
        if abs(v[i]) > np.cos(np.radians(15.0)):
            faces.add(("+" if v[i] > 0 else "-") + "XYZ"[i])
    return sorted(faces, key=lambda f: ("XYZ".index(f[1]), f[0]))


def _refusal(session: Session, poses: StaticPoses, nominal, exc: DesignError, where: str) -> str:
    """What would work with what the user already has, before a new capture (issue 9.6)."""
    centre = nominal.bias
    if nominal.sensitivity is None and nominal.range is None:
        centre = (poses.a_mean.min(axis=0) + poses.a_mean.max(axis=0)) / 2
    directions = unit(poses.a_mean - centre)
    N = len(directions)
    distinct = count_distinct(directions, 10.0)
    faces = _faces(directions, poses.up)
    n_lab = int(np.isfinite(poses.up).all(axis=1).sum())
    labels = f"{n_lab} of them labelled" if n_lab else "no `up` labels"
    text = str(exc).removeprefix(f"{where}: ")
    if distinct >= 9:
        return f"{where}: {text}"
    head = (f"{where}: {N} static poses give only {distinct} distinct gravity directions, too "
            f"few for the gravity-magnitude model (9 parameters), {labels}")  # fmt: skip
    face_up = np.array([np.eye(3)["XYZ".index(f[1])] * (1 if f[0] == "+" else -1)
                        for f in faces]).reshape(-1, 3)  # fmt: skip
    if labels_determine(face_up):  # labels on these faces would determine the labelled model
        return (f"{head}; they lie on {len(faces)} faces ({', '.join(faces)}): label them "
                "(`imucal label SESSION --faces`) and the labelled-pose solver calibrates them, "
                "or capture the 45-degree edges too (plan qureshi18)")  # fmt: skip
    if len(faces) < 4 and _on_faces(directions, poses.up) < N / 2:  # not faces (issue 24.7)
        return (f"{head}{_near_poses(poses, directions, 10.0)}; capture {9 - distinct} or more "
                "poses in new directions, each more than 10 deg from the others (12 or more "
                "in all let the fit check itself against the noise: plan random:12), or the "
                "6 faces and 12 edges of plan qureshi18")  # fmt: skip
    on = f" ({', '.join(faces)})" if faces else ""
    return (f"{head}; they lie on {len(faces)} faces{on}, and the labelled-pose solver needs "
            "4 faces (not only the 4 around one axis): capture the other faces too (plan "
            "six), or the 45-degree edges (plan qureshi18)")  # fmt: skip


def _on_faces(directions: np.ndarray, up: np.ndarray) -> int:
    """How many poses lie on a face (their label, else their direction, within 15 deg of an
    axis), as :func:`_faces` sees them."""
    v = np.where(np.isfinite(up).all(axis=1, keepdims=True), up, directions)
    return int(np.sum(np.max(np.abs(v), axis=1) > np.cos(np.radians(15.0))))


def _near_poses(poses: StaticPoses, directions: np.ndarray, min_deg: float) -> str:
    """Which poses count as one direction (within ``min_deg`` of one counted before them, as
    :func:`count_distinct` counts), at most three pairs: ``"; pose 7 is 4 deg from pose 2"``."""
    cos = np.clip(directions @ directions.T, -1.0, 1.0)
    near = cos >= np.cos(np.radians(min_deg))
    kept, pairs = [], []
    for i in range(len(directions)):
        j = next((j for j in kept if near[i, j]), None)
        if j is None:
            kept.append(i)
        else:
            pairs.append((i, j))
    if not pairs:
        return ""

    def name(k: int) -> str:
        seg = poses.segments[k]
        return seg.label or f"segment {seg.name}"

    said = [f"{name(i)} is {np.degrees(np.arccos(cos[i, j])):.0f} deg from {name(j)}"
            for i, j in pairs[:3]]  # fmt: skip
    return "; " + ", ".join(said) + (f" (and {len(pairs) - 3} more)" if len(pairs) > 3 else "")
