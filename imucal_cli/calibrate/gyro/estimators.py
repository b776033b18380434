"""The gyroscope's estimators and the design they read (issue 25.3), registered in
:data:`~imucal_cli.calibrate.registry.REGISTRY`; ``[gyro] solver = "auto"`` (the default)
takes the most accurate one the session's turns support (issue 10.7), by the tier of its
assessment:

0. a redundant gyro, or Hwangbo & Kanade's sweeps in mountings (whose turns about the
   vertical gravity cannot measure): the factorization;
1. turns of known angle: the known-angle solver (with the accelerometer, or on labelled axes
   spanning three dimensions without it);
2. turns about labelled axes and no accelerometer: the factorization;
3. other turns with the accelerometer: the full model.

The per-axis solvers of Qureshi & Golnaraghi (``static``, ``dynamic``) run when the config
names them; ``auto`` never takes them (the full model holds them).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from imucal_cli.calibrate.factorization import calibrate_gyro_factorization, independent_constraints
from imucal_cli.calibrate.gyro.known import calibrate_gyro_known
from imucal_cli.calibrate.gyro.rotations import calibrate_gyro_rotations, gyro_alternatives
from imucal_cli.calibrate.gyro.turns import ClippedTurns
from imucal_cli.calibrate.registry import Determined, Needs, Refusal, register
from imucal_cli.errors import ConfigError, DesignError
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Segment, Session
from imucal_cli.model.calibration import SensorCalibration


@dataclass
class GyroDesign:
    """What a session's turns determine, before any solver: their labels (axis, angle), the
    gyro's channels, and whether the accelerometer is calibrated (it measures the turns)."""

    session: Session
    cfg: Config
    accel: SensorCalibration | None

    @cached_property
    def turns(self) -> list[Segment]:
        return self.session.rotation_segments()

    @cached_property
    def channels(self) -> int:
        return self.session.gyro.shape[1]

    @cached_property
    def hwangbo_kanade(self) -> bool:
        """Hwangbo & Kanade IV-B: turns about labelled axes whose orthogonal pairs, per
        mounting, give the metric upgrade its 5 independent constraints, and one turn of known
        angle among them for the scale (eq. 31). Sweeps about the vertical there: gravity
        cannot see them."""
        if not any(s.angle_deg is not None and s.axis is not None for s in self.turns):
            return False
        return independent_constraints(self.turns) >= 5

    @cached_property
    def known_axes(self) -> bool:
        """Turns of known angle about labelled axes that span three dimensions (the Ferraris
        360-degree turns flat on each face): they determine the matrix without an
        accelerometer."""
        axes = [s.axis for s in self.turns if s.angle_deg is not None and s.axis is not None]
        return len(axes) >= 3 and np.linalg.matrix_rank(np.array(axes, float), tol=1e-3) == 3

    @cached_property
    def labelled_axes(self) -> bool:
        return any(s.axis is not None for s in self.turns)

    @cached_property
    def known_angles(self) -> bool:
        return any(s.angle_deg is not None for s in self.turns)

    def with_solver(self, solver: str) -> Config:
        """The config with ``[gyro] solver`` set to ``solver`` (what the solver steps read)."""
        return replace(self.cfg, gyro=replace(self.cfg.gyro, solver=solver))


def _with_alternatives(design: GyroDesign, solver: str, fit):
    """``fit()``, a refusal completed by what would work with what the session has (issue
    9.6)."""
    try:
        return fit()
    except ClippedTurns:
        raise  # turning more slowly is what would calibrate it
    except DesignError as exc:
        alternatives = gyro_alternatives(design.session, solver)
        if not alternatives:
            raise
        raise DesignError(f"{exc}; with what this session has: "
                          f"{'; or '.join(alternatives)}") from None  # fmt: skip


def _needs_accel(design: GyroDesign, solver: str) -> None:
    if design.accel is None:
        raise ConfigError(
            f"[gyro] solver = {solver!r} measures each rotation with the calibrated "
            "accelerometer: set an [accel] solver too"
        )


@dataclass(frozen=True)
class Factorization:
    """Hwangbo & Kanade's factorization of turns about labelled axes (IV-B)."""

    name: str = "factorization"
    sensor: str = "gyro"
    needs: Needs = Needs(channels=(3, None), labels=True, turns=True)

    def assess(self, design: GyroDesign) -> Determined | Refusal:
        if design.channels != 3:
            return Determined(f"a redundant gyro ({design.channels} channels)")
        if design.hwangbo_kanade:
            return Determined("turns about labelled axes in several mountings and one of known "
                              "angle (Hwangbo & Kanade IV-B): the factorization uses their "
                              "axes, which gravity cannot measure")  # fmt: skip
        if design.accel is None and design.labelled_axes:
            return Determined("turns about labelled axes and no accelerometer calibration",
                              tier=2)  # fmt: skip
        return Refusal("its turns are not about labelled axes in several mountings",
                       "sweeps about the faces of a right-angle iron (plan hk-gyro)")  # fmt: skip

    def fit(self, design: GyroDesign) -> SensorCalibration:
        return calibrate_gyro_factorization(design.session, design.with_solver(self.name))


@dataclass(frozen=True)
class Known:
    """Turns of known angle (issue 10.7), with the turns between still periods."""

    name: str = "known"
    sensor: str = "gyro"
    needs: Needs = Needs(labels=True, turns=True)

    def assess(self, design: GyroDesign) -> Determined | Refusal:
        if design.accel is None and design.known_axes:
            return Determined("turns of a known angle about labelled axes spanning three "
                              "dimensions: their axes are the labels, no accelerometer "
                              "needed", tier=1)  # fmt: skip
        if design.accel is not None and design.known_angles:
            return Determined("turns of a known angle (with any turns between still periods), "
                              "accelerometer calibrated", tier=1)  # fmt: skip
        return Refusal("no turns of a known angle" if design.accel is not None else
                       "no turns of a known angle about labelled axes spanning three "
                       "dimensions", "label turns of a known angle (imucal label SESSION "
                       "--segment NAME --angle DEG --axis X,Y,Z)")  # fmt: skip

    def fit(self, design: GyroDesign) -> SensorCalibration:
        cfg = design.with_solver(self.name)
        return _with_alternatives(
            design, self.name, lambda: calibrate_gyro_known(design.session, cfg, design.accel))


@dataclass(frozen=True)
class Rotations:
    """The model from integrated rotations between still periods: the full 12 (or 21 with
    g-sensitivity) parameters, or Qureshi & Golnaraghi's per-axis approaches (eqs. 18-21)."""

    name: str = "full"
    sensor: str = "gyro"
    needs: Needs = Needs(turns=True, accel=True)

    def assess(self, design: GyroDesign) -> Determined | Refusal:
        if design.accel is None:
            return Refusal("the full gyro model needs the accelerometer calibrated",
                           "an [accel] solver, or --accel CAL.json")  # fmt: skip
        if self.name != "full":
            return Refusal("a per-axis approximation of the full model; used when the config "
                           "names it")  # fmt: skip
        return Determined("turns between still periods, accelerometer calibrated", tier=3)

    def fit(self, design: GyroDesign) -> SensorCalibration:
        _needs_accel(design, self.name)
        cfg = design.with_solver(self.name)
        return _with_alternatives(
            design, self.name, lambda: calibrate_gyro_rotations(design.session, cfg,
                                                                design.accel))  # fmt: skip


for _estimator in (Factorization(), Known(), Rotations(), Rotations("static"),
                   Rotations("dynamic")):  # fmt: skip
    register(_estimator)
