"""What the gyro solvers of a session work on and give back: the turns and still periods
(:class:`Turn`, :class:`Still`), the data every rotation solver starts from
(:class:`GyroData`) and a solver's result before it becomes the gyro section
(:class:`GyroFit`). :mod:`.gyro` builds them, :mod:`.gyro_axes` and :mod:`.gyro_full` fit
them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal_cli.formats.calibration import SensorCalibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Segment, Session

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


@dataclass
class GyroFit:
    """A rotation solver's result, before it becomes the gyro section."""

    bias: np.ndarray
    matrix: np.ndarray
    parameters: list[dict]
    rotations: list[dict]
    residual_rad: np.ndarray
    gains: np.ndarray  # raw units per rad/s of each axis, for the physical-sense checks
    extra: dict


#: The model equation of a gyro section with g-sensitivity (spec: optional term).
MODEL_EQUATION_G = "calibrated = matrix @ (raw - bias - g_sensitivity @ a)"
