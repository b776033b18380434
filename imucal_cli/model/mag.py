"""The magnetometer's section: hard and soft iron, the rotation onto the accelerometer, the
field, MotionCal's quality figures and the map's directions (DEVELOPERS.md, "Calibration
JSON: the mag section")."""

from __future__ import annotations

from dataclasses import dataclass

from .codec import Record, item
from .section import SensorCalibration


@dataclass
class MagPoseRow(Record):
    """One static pose of the magnetometer's ``poses`` table."""

    segment: str | None = None
    label: str | None = item(always=True)
    samples: int | None = None
    magnitude_after: float | None = None
    residual: float | None = None
    dip_residual_deg: float | None = item(always=True)


@dataclass
class QualityCheck(Record):
    """One of MotionCal's figures against its limit."""

    name: str | None = None
    value_pct: float | None = item(always=True)
    limit_pct: float | None = None
    meaning: str | None = None
    ok: bool | None = None
    #: gaps over its limit: the largest 2-std error of |B| the fit states where it missed the
    #: sphere, percent of the field (the check passes when it is within the fit error)
    held_pct: float | None = None


@dataclass
class Quality(Record):
    """The verdict of the quality checks (``pass`` or ``recapture``) and the checks."""

    verdict: str | None = None
    failed: list[str] | None = None
    checks: list[QualityCheck] | None = None


@dataclass
class RowsLeftOut(Record):
    """Rows of the magnetometer left out, by cause."""

    nonfinite: int | None = None
    before_first: int | None = None
    clipped: int | None = None
    repeated: int | None = None


@dataclass
class Readings(Record):
    """How many readings the fit used: motion rows and pose means, and what was left out."""

    motion: int | None = None
    poses: int | None = None
    left_out: RowsLeftOut | None = None


@dataclass
class MagCoverage(Record):
    """How the calibrated field directions cover the sphere (MotionCal's regions)."""

    fraction: float | None = None
    gaps_pct: float | None = None
    regions: int | None = None
    n_readings: int | None = None
    n_poses: int | None = None


@dataclass
class MagCalibration(SensorCalibration):
    """A magnetometer's section (module notes; the common members in
    :class:`~.section.SensorCalibration`).

    Attributes
    ----------
    field_uT : float or None
        The field magnitude of the output (None: unknown, output in local fields).
    field_source, field_estimate_uT, field_estimate_basis
        Where the magnitude came from; an estimate when unknown.
    aligned : bool or None
        Rotated onto the accelerometer's frame.
    inclination_deg, inclination_std_deg : float or None
    inclination_ci95_deg : float or None
        Half-width of its 95 % interval (Student t: the accelerometer's part of its variance
        rests on the accelerometer's placement where six faces estimated it).
    rotation : list of list of float or None
        Onto the accelerometer's frame (3 x 3); ``rotation_std_deg`` its std.
    rotation_std_deg : float or None
    axes : list of str or None
        Each magnetometer axis in the accelerometer's frame, in words.
    hard_iron_out, hard_iron_out_magnitude : list of float, float
        The hard iron in output units.
    soft_iron_axis_ratio_pct, variance_before_pct : float
    rms_after, rms_held_out : float or None
        |B| residual RMS, and held out.
    dip_rms_deg : float or None
    readings : Readings or None
    poses : list of MagPoseRow or None
    quality : Quality or None
    coverage : MagCoverage or None
    directions : list of list of float or None
        At most 400 calibrated unit directions, for the map.
    range : list of float or None
        The raw range a reading was clipped at.
    """

    field_uT: float | None = None
    field_source: str | None = None
    field_estimate_uT: float | None = None
    field_estimate_basis: str | None = None
    aligned: bool | None = None
    inclination_deg: float | None = None
    inclination_std_deg: float | None = None
    inclination_ci95_deg: float | None = None
    rotation: list[list[float]] | None = None
    rotation_std_deg: float | None = None
    axes: list[str] | None = None
    hard_iron_out: list[float] | None = None
    hard_iron_out_magnitude: float | None = None
    soft_iron_axis_ratio_pct: float | None = None
    variance_before_pct: float | None = None
    rms_after: float | None = None
    dip_rms_deg: float | None = None
    readings: Readings | None = None
    poses: list[MagPoseRow] | None = None
    quality: Quality | None = None
    coverage: MagCoverage | None = None
    directions: list[list[float]] | None = None
    rms_held_out: float | None = None
    range: list[float] | None = None
