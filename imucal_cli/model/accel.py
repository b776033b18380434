"""The accelerometer's section: the triad fits (gravity magnitude, labelled poses) and the
factorization of a unit, with their per-pose table, coverage, noise and checks (DEVELOPERS.md,
"Calibration JSON: the accel section")."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .codec import Record, item
from .parts import Factorization
from .section import SensorCalibration


@dataclass
class PoseRow(Record):
    """One static pose of the ``poses`` table.

    Attributes
    ----------
    segment, label : str
    up : list of float or None
        Its labelled up direction.
    samples : int
        Samples in its mean (spikes left out).
    magnitude_before, magnitude_after : float or None
        |a| before (nominal sensor) and after calibration, m/s^2.
    residual, residual_loo : float or None
        ``|a| - g`` after calibration, and held out (the fit without the pose), m/s^2.
    angle_to_up_deg : float or None
        Between the calibrated direction and the label.
    direction : list of float
        Calibrated unit gravity direction.
    spikes_left_out : int or None
    excluded : bool or None
        Left out of the fit as an outlier.
    """

    segment: str | None = None
    label: str | None = item(always=True)
    up: list[float] | None = item(always=True)
    samples: int | None = None
    magnitude_before: float | None = item(always=True)
    magnitude_after: float | None = None
    residual: float | None = None
    residual_loo: float | None = item(always=True)
    angle_to_up_deg: float | None = item(always=True)
    direction: list[float] | None = None
    spikes_left_out: int | None = None
    excluded: bool | None = None


@dataclass
class OutlierRow(Record):
    """A pose that disagrees with the rest, and what was done with it (issue 10)."""

    segment: str | None = None
    label: str | None = item(always=True)
    times_noise: float | None = item(always=True)
    p_value: float | None = None
    cause: str | None = None
    action: str | None = None


@dataclass
class Coverage(Record):
    """How the poses' calibrated gravity directions cover the sphere."""

    fraction: float | None = None
    cap_deg: float | None = None
    largest_gap_deg: float | None = None
    weakest_direction: list[float] | None = None
    n_poses: int | None = None
    n_distinct: int | None = None


@dataclass
class PoseNoise(Record):
    """The per-sample noise pooled over the still holds, behind the fit's weights."""

    per_sample_std: list[float] | None = None
    unit: str | None = None
    dof: int | None = None
    basis: str | None = None


@dataclass
class Placement(Record):
    """How far the poses sat from their labels (the labelled fit's prior)."""

    rms_deg: float | None = None
    source: str | None = None
    dof: float | None = None
    meaning: str | None = None
    face_deg: float | None = None  # a face's normal off its label, shared by its poses
    hold_deg: float | None = None  # each hold's own part
    parts: str | None = None


@dataclass
class Compensation:
    """The temperature compensation a gravity-magnitude fit's poses were moved with, and the
    error it leaves in them, kept in memory for the gyro solver that reads those poses (never
    written; ``docs/temperature.md``).

    Attributes
    ----------
    temperature_ref : float
        ``T_ref``, degrees C.
    columns : list of (int, int)
        ``(degree, channel)`` of each term: the fitted ones, then those the poses could not
        fit (held at zero, known by a prior).
    covariance : ndarray, shape (12 + T, 12 + T)
        Of the errors of ``(bias, matrix row-major, the terms)``, raw units: a pose at ``T``
        is off by ``-sum (T - T_ref)^j dc_(j, channel)`` in its channel.
    eigenvalue_range : tuple of float
        ``(smallest, largest)`` eigenvalue of the covariance as assembled, before its negative
        eigenvalues (rounding: the ``(bias, matrix)`` block is the solver's, the rest the
        fit's) were clipped to zero; a smallest one far below zero would be an inconsistent
        assembly, not rounding.
    """

    temperature_ref: float
    columns: list[tuple[int, int]]
    covariance: np.ndarray = field(repr=False)
    eigenvalue_range: tuple[float, float] = (0.0, 0.0)


@dataclass
class GivenPlacement:
    """A labelled fit's errors given its poses' true placement (the measurement noise's part:
    eq. L4 without the labels' rows), kept in memory for a set's rotations, never written;
    computed when first asked for (a calibration of one IMU never asks).

    Attributes
    ----------
    segments : list of str
        The poses the fit used, in ``response``'s order.
    compute : callable
        ``() -> (covariance, response)``, called once, on the first access to either.
    covariance : ndarray, shape (12, 12)
        Of ``(bias, matrix row-major)`` given the placement.
    response : ndarray, shape (12, P, 3)
        ``d (bias, matrix row-major) / d`` each pose's mean raw reading, first order.
    """

    segments: list[str]
    compute: Callable[[], tuple[np.ndarray, np.ndarray]] = field(repr=False, compare=False)
    _value: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False, repr=False,
                                                          compare=False)  # fmt: skip

    def _computed(self) -> tuple[np.ndarray, np.ndarray]:
        if self._value is None:
            self._value = self.compute()
        return self._value

    @property
    def covariance(self) -> np.ndarray:
        return self._computed()[0]

    @property
    def response(self) -> np.ndarray:
        return self._computed()[1]


@dataclass
class OwnFit(Record):
    """An IMU's own accelerometer fit, kept beside the set's joint one."""

    bias: list[float] | None = None
    matrix: list[list[float]] | None = None
    residual_rms: float | None = item(always=True)


@dataclass
class SetFit(Record):
    """A set of IMUs' joint accelerometer fit (issue 28; docs/imu-set.md, eq. S1) that gave
    this section's bias and matrix: its own fit's, its method and statistics."""

    own_fit: OwnFit | None = None
    method: str | None = None
    imus: int | None = None
    poses: int | None = None
    chi2: float | None = None
    dof: int | None = None
    noise_scale: float | None = None
    converged: bool | None = None


@dataclass
class AccelCalibration(SensorCalibration):
    """An accelerometer's section (module notes; the common members in
    :class:`~.section.SensorCalibration`).

    Attributes
    ----------
    gravity : float or None
        The local gravity the fit used, m/s^2.
    rms_before, rms_after, rms_loo : float or None
        ``|a| - g`` RMS before calibration (nominal sensor, ``before_basis``), after, and held
        out (``loo_method``), m/s^2.
    coverage : Coverage or None
    poses : list of PoseRow or None
    noise : PoseNoise or None
    placement : Placement or None
        The labelled fit's.
    rotation_std_deg : float or None
        Std of the frame's rotation.
    outliers : list of OutlierRow or None
    spare_equations : int or None
        Equations beyond the parameters.
    rms_expected : float or None
        The fit RMS the noise predicts, m/s^2.
    noise_excess : float or None
        ``sqrt(chi^2 / dof)`` against the measured noise.
    rms_after_below_noise : bool or None
        The fit RMS is below what the noise allows (an exact fit: no improvement factor).
    set_fit : SetFit or None
        An IMU of a set whose bias and matrix are the set's joint fit (its own fit kept).
    factorization : Factorization or None
        Hwangbo & Kanade's fields (members of the section).
    given_placement : GivenPlacement or None
        The labelled fit's errors given the poses' true placement. Not written (transient):
        what a set of IMUs on one body needs for their rotations (``docs/imu-set.md``, eq. R3).
    compensation : Compensation or None
        The temperature compensation its poses were moved with and its error. Not written
        (transient): what the gyro solver that reads those poses needs.
    """

    gravity: float | None = None
    rms_before: float | None = None
    rms_after: float | None = None
    rms_loo: float | None = None
    before_basis: str | None = None
    coverage: Coverage | None = None
    poses: list[PoseRow] | None = None
    noise: PoseNoise | None = None
    placement: Placement | None = None
    rotation_std_deg: float | None = None
    loo_method: str | None = None
    outliers: list[OutlierRow] | None = None
    spare_equations: int | None = None
    rms_expected: float | None = None
    noise_excess: float | None = None
    rms_after_below_noise: bool | None = None
    set_fit: SetFit | None = None
    factorization: Factorization | None = item(flat=True)
    given_placement: GivenPlacement | None = item(transient=True)
    compensation: Compensation | None = item(transient=True)
