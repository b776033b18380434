"""The accelerometer's estimators and the design they read (issue 25.3): the factorization
(Hwangbo & Kanade), the gravity-magnitude fit (Qureshi & Golnaraghi III-A) and the
labelled-pose fit, registered in :data:`~imucal_cli.calibrate.registry.REGISTRY`, and what
``[accel] solver = "auto"`` (the default) chooses among them (issue 9.1) from their
assessments of the design:

* a redundant unit (4 or more channels): the factorization, which finds its biases without
  labels;
* a triad with 9 or more distinct poses: the gravity-magnitude solver, which needs no labels;
  unless the poses carry labels placed so well that using them makes the fit measurably more
  precise (predicted from the Cramer-Rao bounds of both designs at the gravity solution, with
  the placement the labels showed), then the labelled solver. Where only some poses are
  labelled (Hwangbo & Kanade's iron: the second mounting has no `up`) the labelled solver fits
  the unlabelled ones by their magnitude (a free direction), so its bound is the gravity bound
  with the labelled poses' priors added: on 9 distinct directions (no spare equation for the
  gravity fit) the labels decide the axes;
* a triad with fewer distinct poses whose labels determine the model (six faces): the
  labelled-pose solver;
* otherwise a refusal that names what would work with what the user already has
  (:meth:`AccelDesign.refusal`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from imucal_cli.calibrate.accel.gravity import GravityFit, gravity_fit, gravity_section
from imucal_cli.calibrate.accel.labelled import labelled_section
from imucal_cli.calibrate.accel.partial import nominal_gain, nominal_prior, partial_section
from imucal_cli.calibrate.common import (
    Nominal,
    StaticPoses,
    check_design,
    labels_determine,
    nominal_sensor,
    session_name,
    static_poses,
    stored_accel_hint,
)
from imucal_cli.calibrate.factorization import calibrate_accel_factorization
from imucal_cli.calibrate.registry import Bound, Determined, Needs, Refusal, register
from imucal_cli.design.poses import count_distinct, unit
from imucal_cli.errors import DesignError, SolverError
from imucal_cli.estimators.accel.crb import gravity_crb, labelled_crb
from imucal_cli.estimators.accel.gravity import params_to_model
from imucal_cli.estimators.accel.labelled_model import jacobian, public_from_theta
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import SensorCalibration

#: What the bounds of the triad solvers compare: the gauge-free parameters.
TRIAD_KEY = "bias (3), sensitivities (3) and angles between the axes (3)"
TRIAD_GROUPS = (("the bias", slice(0, 3)), ("the gains and axes", slice(3, 9)))


@dataclass
class AccelDesign:
    """What a session's accelerometer data determine, before any solver's section: the
    static poses, the nominal sensor, the gravity-magnitude design check and (computed once,
    when an assessment needs it) the gravity solver's fit, whose solution the bounds are
    evaluated at."""

    session: Session
    cfg: Config
    prior: object | None = None  # an earlier calibration's Prior (--prior), else nominal

    @cached_property
    def where(self) -> str:
        return session_name(self.session)

    @cached_property
    def channels(self) -> int:
        return self.session.accel.shape[1]

    @cached_property
    def g(self) -> float:
        return self.cfg.gravity or self.session.gravity

    @cached_property
    def poses(self) -> StaticPoses:
        return static_poses(self.session)

    @cached_property
    def nominal(self) -> Nominal:
        return nominal_sensor(self.session, self.cfg, self.g)

    @cached_property
    def n_labelled(self) -> int:
        return int(np.isfinite(self.poses.up).all(axis=1).sum())

    @cached_property
    def gravity_refusal(self) -> DesignError | None:
        """Why the poses cannot determine the gravity-magnitude model (None: they can)."""
        try:
            check_design(self.poses, self.nominal, self.cfg.accel.min_separation_deg,
                         self.where)  # fmt: skip
        except DesignError as exc:
            return exc
        return None

    @cached_property
    def distinct(self) -> int:
        """Distinct gravity directions of the poses (as the design check counts them)."""
        return count_distinct(_raw_directions(self.poses, self.nominal),
                              self.cfg.accel.min_separation_deg)  # fmt: skip

    @cached_property
    def gravity(self) -> GravityFit:
        """The gravity solver's fit (outliers handled), shared by the assessments and the
        section."""
        return gravity_fit(self.session, self.cfg, self.poses, self.g, self.nominal)

    @cached_property
    def gravity_failure(self) -> SolverError | None:
        """Why the gravity solver's fit failed where its poses leave it no spare equation
        (9 distinct directions for 9 parameters: an exactly determined fit can fail to
        converge on the noise alone) and the labels determine the labelled-pose model, None
        when it did not.  Assessing it then refuses the gravity solver instead of ending the
        calibration, and the labels decide.  With spare equations a fit that does not
        converge says the data are wrong, and without labels nothing else can calibrate the
        poses: both are raised."""
        try:
            _ = self.gravity  # computed once, kept for the assessments
        except SolverError as exc:
            if self.distinct > 9 or not labels_determine(self.poses.up):
                raise  # the data are wrong, or nothing else can calibrate these poses
            return exc
        return None

    def triad(self, solver: str) -> StaticPoses:
        """The poses, for a triad ``solver`` (its name as the refusal says it); a redundant
        unit is refused naming the factorization."""
        poses = self.poses
        if self.channels != 3:
            raise DesignError(
                f"{self.where}: the {solver} calibrates a triad (3 accelerometer channels); "
                f'this session has {self.channels}: [accel] solver = "factorization" (or the '
                'default "auto") calibrates a redundant unit'
            )
        return poses

    def refusal(self) -> str:
        """What would work with what the user already has, when no estimator can calibrate
        the poses (issue 9.6)."""
        return _refusal(self.session, self.poses, self.nominal, self.gravity_refusal,
                        self.where)  # fmt: skip


def _raw_directions(poses: StaticPoses, nominal: Nominal) -> np.ndarray:
    """The poses' gravity directions before calibration, about the nominal offset (or the
    middle of what each axis saw when nothing is known of it)."""
    centre = nominal.bias
    if nominal.sensitivity is None and nominal.range is None:
        centre = (poses.a_mean.min(axis=0) + poses.a_mean.max(axis=0)) / 2
    return unit(poses.a_mean - centre)


@dataclass(frozen=True)
class Factorization:
    """Hwangbo & Kanade's factorization of a unit's static poses (IV-A, IV-C)."""

    name: str = "factorization"
    sensor: str = "accel"
    needs: Needs = Needs(channels=(3, None))

    def assess(self, design: AccelDesign) -> Determined | Refusal:
        na = design.channels
        if na < 4:
            return Refusal("a triad: the gravity-magnitude and labelled-pose fits model its "
                           "axes and their errors")  # fmt: skip
        return Determined(f"a redundant unit of {na} channels: the factorization finds its "
                          "biases without labels (Hwangbo & Kanade)")  # fmt: skip

    def fit(self, design: AccelDesign) -> SensorCalibration:
        return calibrate_accel_factorization(design.session, design.cfg)


@dataclass(frozen=True)
class Gravity:
    """The gravity-magnitude fit of a triad (Qureshi & Golnaraghi III-A, eqs. 3-8)."""

    name: str = "gravity"
    sensor: str = "accel"
    needs: Needs = Needs()

    def assess(self, design: AccelDesign) -> Determined | Refusal:
        if design.channels != 3:
            return Refusal(f"a redundant unit of {design.channels} channels")
        if design.gravity_refusal is not None:
            return Refusal(_reason(design.gravity_refusal, design.where))
        if design.gravity_failure is not None:
            return Refusal(_reason(design.gravity_failure, design.where))
        gf = design.gravity
        return Determined(_gravity_reason(gf, design), _gravity_bound(gf, design),
                          compared_with="gravity magnitude alone")  # fmt: skip

    def fit(self, design: AccelDesign) -> SensorCalibration:
        poses, cfg = design.triad("gravity solver"), design.cfg
        check_design(poses, design.nominal, cfg.accel.min_separation_deg, design.where,
                     cfg.accel.gravity.model)  # fmt: skip
        return gravity_section(design.session, cfg, poses, design.g, design.nominal,
                               design.gravity)  # fmt: skip


@dataclass(frozen=True)
class Labelled:
    """The labelled-pose fit of a triad (issue 9.1): bias and the full matrix, each pose's
    placement about its label a nuisance parameter."""

    name: str = "labelled"
    sensor: str = "accel"
    needs: Needs = Needs(labels=True)

    def assess(self, design: AccelDesign) -> Determined | Refusal:
        if design.channels != 3:
            return Refusal(f"a redundant unit of {design.channels} channels")
        poses, n_lab = design.poses, design.n_labelled
        if not labels_determine(poses.up):
            return Refusal(f"{n_lab} labelled poses do not separate bias from sensitivity (4 "
                           "labels not in one plane)", "label the faces (imucal label "
                           "SESSION --faces)")  # fmt: skip
        if design.gravity_refusal is not None:
            return Determined(
                f"{design.distinct} distinct directions are too few for the gravity-magnitude "
                f"model (9 parameters), but the {n_lab} labelled poses determine bias and the "
                "full matrix, each pose's placement a nuisance parameter", tier=1)  # fmt: skip
        if design.gravity_failure is not None:  # no fit to linearise the bound about
            return Determined("the gravity-magnitude fit of these 9 directions (no spare "
                              "equation) did not converge; the labels determine the "
                              "labelled-pose model", tier=1)  # fmt: skip
        found = _labelled_bound(design.gravity, design)
        if found is None:
            return Determined("the labels determine the labelled-pose model", tier=1)
        bound, placement = found
        some = "" if n_lab == len(poses.segments) else (
            f" ({n_lab} of {len(poses.segments)} poses labelled; the others enter by their "
            "magnitude, as in the gravity fit)")  # fmt: skip
        return Determined(f"the labels are placed within {placement:.2g} deg RMS{some}",
                          bound, tier=1)  # fmt: skip

    def fit(self, design: AccelDesign) -> SensorCalibration:
        poses = design.triad("labelled-pose solver")
        if not labels_determine(poses.up):
            n_lab = design.n_labelled
            raise DesignError(
                f"{design.where}: the labelled-pose solver needs at least 4 poses whose `up` "
                f"labels are not in one plane (this session has {n_lab} labelled of "
                f"{len(poses.segments)}): label the faces with `imucal label SESSION --faces`, "
                "or use the gravity solver (9 or more distinct poses need no labels)"
            )
        return labelled_section(design.session, design.cfg, poses, design.g, design.nominal)


@dataclass(frozen=True)
class PartialFit:
    """A triad whose poses cannot determine the whole model (issue 27.3): the
    gravity-magnitude equations with a prior on every parameter
    (:mod:`imucal_cli.calibrate.accel.partial`); the last resort of ``auto``."""

    name: str = "partial"
    sensor: str = "accel"
    needs: Needs = Needs()

    def assess(self, design: AccelDesign) -> Determined | Refusal:
        if design.channels != 3:
            return Refusal(f"a redundant unit of {design.channels} channels")
        if design.gravity_refusal is None or labels_determine(design.poses.up):
            return Refusal("the poses determine the whole model (gravity or labelled fit)")
        if design.prior is None and nominal_gain(design.nominal, design.poses.a_mean,
                                                 design.g) is None:  # fmt: skip
            return Refusal("the nominal sensitivity is unknown, so no parameter can be held "
                           "at a prior", "set [accel] nominal_sensitivity, or pass --prior "
                           "CAL.json")  # fmt: skip
        return Determined(
            f"{design.distinct} distinct directions cannot determine the 9 parameters: the "
            "poses measure what they determine, the rest is held at "
            f"{'the earlier calibration' if design.prior is not None else 'nominal values'} "
            "with its std", tier=2)  # fmt: skip

    def fit(self, design: AccelDesign) -> SensorCalibration:
        poses = design.triad("partial fit")
        prior = design.prior
        if prior is None:
            try:
                prior = nominal_prior(design.nominal, poses.a_mean, design.g)
            except DesignError as exc:
                raise DesignError(f"{design.where}: {exc}") from None
        sec = partial_section(poses, design.session, design.cfg, design.g, design.nominal,
                              prior)  # fmt: skip
        why = _reason(DesignError(design.refusal()), design.where)
        stored = stored_accel_hint(design.session)
        if stored:
            stored += " (--prior SESSION.h5 holds the assumed terms at it)"
        sec.notes = [sec.notes[0], f"why not the whole model: {why}{stored}", *sec.notes[1:]]
        return sec


for _estimator in (Factorization(), Gravity(), Labelled(), PartialFit()):
    register(_estimator)


def _reason(exc: Exception, where: str) -> str:
    """A refusal's message without the session's name in front."""
    return str(exc).removeprefix(f"{where}: ")


def _gravity_reason(gf: GravityFit, design: AccelDesign) -> str:
    used = gf.fit.used
    distinct = count_distinct(gf.fit.directions[used], design.cfg.accel.min_separation_deg)
    text = (f"{distinct} distinct poses determine the 9-parameter gravity-magnitude model, "
            "which needs no labels")  # fmt: skip
    angles = gf.fit.up_angle_deg
    if design.n_labelled and angles is not None and np.isfinite(angles).any():
        text += (
            f"; the labels (poses within {np.sqrt(np.nanmean(np.square(angles))):.2g} deg RMS "
            "of them) would not make it measurably more precise"
        )
    return text


def _at_solution(gf: GravityFit, poses: StaticPoses):
    """``(M, B, u, T)`` of the 9-parameter gravity solution: matrix, bias, each pose's
    calibrated direction (the triangular frame) and the Jacobian of (bias, sensitivities,
    angles between the axes) by the solver's parameters."""
    theta = np.asarray(gf.res.params, float)
    B, M = params_to_model(theta)
    u = unit((poses.a_mean - B) @ M.T)
    T = jacobian(public_from_theta, np.r_[theta, np.zeros(3)])[:9, :9]
    return M, B, u, T


def _gravity_bound(gf: GravityFit, design: AccelDesign) -> Bound | None:
    """The Cramer-Rao bound of the gravity fit's bias, sensitivities and angles between the
    axes at its solution (9-parameter variant; None for the 12-parameter one)."""
    if gf.res.variant != "9-parameter":
        return None
    M, B, u, T = _at_solution(gf, design.poses)
    crb = T @ gravity_crb(M, B, u, design.g, design.poses.cov_mean) @ T.T
    return Bound(np.diag(crb), TRIAD_KEY, TRIAD_GROUPS)


def _labelled_bound(gf: GravityFit, design: AccelDesign) -> tuple[Bound, float] | None:
    """The labelled fit's bound at the gravity solution, and the labels' placement (deg RMS),
    or None where it cannot be said (fewer than 4 labels, no angle to a label, the
    12-parameter gravity variant).

    Where only some poses are labelled (the second mounting of Hwangbo & Kanade's iron has
    no `up`), the labelled solver is the maximum-likelihood fit of all of them: a labelled
    pose gives its vector equation with the placement error as a prior (L2, L3), an
    unlabelled one its magnitude equation with a free direction, exactly as in the gravity
    solver. Its bound (L5) then has the prior on the labelled poses only and is never above
    the gravity-magnitude bound; using the labelled poses alone would throw the others'
    magnitude equations away. The placement is the RMS angle between the labelled poses'
    gravity-fit directions and their labels: where the gravity fit is poorly determined its
    frame error inflates that angle, which only understates what the labels are worth. The
    labels' frame differs from the triangular one by a rotation, which changes neither bound
    on bias and K: both are evaluated in the triangular frame."""
    poses = design.poses
    lab = np.isfinite(poses.up).all(axis=1)
    angles = gf.fit.up_angle_deg
    if lab.sum() < 4 or angles is None or len(angles) != len(lab):
        return None
    if not np.isfinite(angles[lab]).any() or gf.res.variant != "9-parameter":
        return None
    placement = float(np.sqrt(np.nanmean(angles[lab] ** 2)))
    M, B, u, _ = _at_solution(gf, poses)
    per_pose = np.where(lab, max(placement, 1e-3), np.inf)  # unlabelled: a free direction
    lab_crb = np.diag(labelled_crb(M, B, u, design.g, poses.cov_mean, per_pose))[:9]
    return Bound(lab_crb, TRIAD_KEY, TRIAD_GROUPS), placement


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
    directions = _raw_directions(poses, nominal)
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
