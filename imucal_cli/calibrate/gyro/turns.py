"""What the gyro solvers of a session work on and give back: the turns and still periods
(:class:`Turn`, :class:`Still`), the data every rotation solver starts from
(:class:`GyroData`) and a solver's result before it becomes the gyro section
(:class:`GyroFit`). :mod:`.gyro` builds them, :mod:`.gyro_axes` and :mod:`.gyro_full` fit
them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal_cli.errors import DesignError
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Segment, Session
from imucal_cli.model.calibration import MODEL_EQUATION_G, SensorCalibration
from imucal_cli.model.gyro import RotationRow
from imucal_cli.model.parts import Parameter

AXES = "xyz"


@dataclass
class Turn:
    """One rotation with the still periods around it (indices into the still list)."""

    segment: Segment
    before: int
    after: int


@dataclass
class Still:
    """One still period: its calibrated accelerometer mean and its raw gyro mean."""

    segment: Segment
    g: np.ndarray  # calibrated accel mean, m/s^2
    g_sigma: float  # direction noise of the mean, rad
    z_mean: np.ndarray  # raw gyro mean
    z_sigma: float  # noise of the raw gyro mean, per channel
    a_raw: np.ndarray  # raw accel mean (what the accelerometer calibration turned into g)


class ClippedTurns(DesignError):
    """Every turn reaches the gyro's range: what would calibrate it is turning more slowly
    (no other solver or label helps)."""


@dataclass
class GyroData:
    """What every rotation solver starts from: the usable turns, the still periods around
    them, the pooled gyro noise and bias, and the notes and warnings so far."""

    session: Session
    cfg: Config
    where: str
    accel_cal: SensorCalibration | None  # None: the known-angle solver on labelled axes only
    stills: list[Still]
    turns: list[Turn]
    noise: float  # per-sample gyro noise pooled over the still periods, raw units
    bias_still: np.ndarray  # mean of every still sample, raw units
    b_still_std: float
    units_in: str
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    said: list[str] = field(default_factory=list)  # warnings said, not refused (turns left out)
    left_out: list[str] = field(default_factory=list)  # turns left out, and what would add them
    #: covariance of the still means' rounding errors per channel, (3, P, P) raw units^2 (a
    #: quantised gyro too quiet to dither it: :func:`imucal_cli.calibrate.gyro.rotations.rounding`)
    round_cov: np.ndarray | None = None


@dataclass
class GyroFit:
    """A rotation solver's result, before it becomes the gyro section."""

    bias: np.ndarray
    matrix: np.ndarray
    parameters: list[Parameter]
    rotations: list[RotationRow]
    residual_rad: np.ndarray
    gains: np.ndarray  # raw units per rad/s of each axis, for the physical-sense checks
    members: dict  # more members of the section (for model.codec.build)


#: The model equation of a gyro section with g-sensitivity (spec: optional term).
MODEL_EQUATION_G = MODEL_EQUATION_G
