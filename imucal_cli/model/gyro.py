"""The gyroscope's section: the model from integrated rotations (full, or Qureshi &
Golnaraghi's per axis), the known-angle turns and the factorization, with the turns' table,
the rate's uncertainty and the checks (DEVELOPERS.md, "Calibration JSON: the gyro section")."""

from __future__ import annotations

from dataclasses import dataclass

from .codec import Record, item
from .parts import Factorization, SampleClock
from .section import SensorCalibration


@dataclass
class RotationRow(Record):
    """One turn of the ``rotations`` table.

    Attributes
    ----------
    segment, label : str
    axis : str or None
        The axis a per-axis solver gave it.
    known_angle_deg : float or None
        Its labelled angle (None: a turn between still periods, measured by gravity).
    measured_angle_deg, angle_error_deg : float
    axis_error_deg : float or None
        Between its measured and labelled axis.
    noise_deg, axis_noise_deg : float or None
        What the noise allows of the angle and of the axis.
    measured_by : str or None
        ``"gravity"``: a turn between still periods beside the known ones.
    used : bool or None
        Whether the fit used it.
    """

    segment: str | None = None
    label: str | None = item(always=True)
    axis: str | None = None
    known_angle_deg: float | None = item(always=True)
    measured_angle_deg: float | None = None
    angle_error_deg: float | None = None
    axis_error_deg: float | None = None
    noise_deg: float | None = None
    axis_noise_deg: float | None = None
    measured_by: str | None = None
    used: bool | None = None


@dataclass
class StdRatio(Record):
    """The sigma points' std over the first order's: of the parameters, gains and rate."""

    parameters: float | None = None
    gains: float | None = None
    rate: float | None = None


@dataclass
class AccelPropagation(Record):
    """How the accelerometer calibration's uncertainty was carried into the gyro's (issue
    10.2): first order, or by refitting at sigma points."""

    method: str | None = None
    meaning: str | None = None
    reason: str | None = None
    effect: float | None = item(always=True)
    nonlinearity: float | None = item(always=True)
    refits: int | None = None
    failed: int | None = None
    directions: int | None = None
    std_ratio_to_first_order: list[float] | None = None
    first_order_total: float | None = None
    std_ratio: StdRatio | None = None
    warning: str | None = None


@dataclass
class RateStd(Record):
    """Relative std of a calibrated rate in its worst direction: in total, from the noise and
    from the accelerometer calibration that measures the turns."""

    total: float | None = None
    noise: float | None = None
    accel_calibration: float | None = item(always=True)
    meaning: str | None = None
    accel_propagation: AccelPropagation | None = None


@dataclass
class GSensitivityTest(Record):
    """Whether the g-sensitivity belongs in the model: observable, and significant (F-test of
    the chi^2 drop)."""

    included: bool | None = None
    observable: bool | None = None
    reason: str | None = None
    F: float | None = None
    dof: list[int] | None = None
    p_value: float | None = None
    chi2_without: float | None = None
    chi2_with: float | None = None
    criterion: str | None = None


@dataclass
class KnownTurnCheck(Record):
    """The turns of known angle against the rest of the fit (issue 24.5)."""

    turns_between_still_periods: str | None = None
    their_level: float | None = None
    their_excess_deg: float | None = None
    their_rms_under_known_deg: float | None = None
    why_left_out: str | None = None
    known_chi2: float | None = None
    known_redundancy: float | None = None
    known_p_value: float | None = None
    explained_by: str | None = None


@dataclass
class IgnoredMisalignment(Record):
    """What a per-axis solver ignores: the full model's axes on the same turns, the shift of
    each per-axis gain against the full model's (fraction) and that shift in the gain's std
    without the misalignment's share (``gain_shift_std``; the gain's stated std carries it)."""

    measured: bool | None = None
    axis_to_accel_frame_deg: dict[str, float] | None = None
    gain_shift: list[float] | None = None
    gain_shift_std: list[float] | None = None


@dataclass
class GyroCalibration(SensorCalibration):
    """A gyroscope's section (module notes; the common members in
    :class:`~.section.SensorCalibration`).

    Attributes
    ----------
    approach : str or None
    model_paper : str or None
        A per-axis solver's equation in the paper.
    ignored_misalignment : IgnoredMisalignment or None
    axis_to_accel_frame_deg : dict or None
        Each sensitivity axis's angle from the accelerometer's axis of the same name.
    rate_std : RateStd or None
    g_sensitivity_test : GSensitivityTest or None
    rotations : list of RotationRow or None
    rotation_rms_deg : float or None
        RMS of the turns' angle residuals.
    gyro_noise_raw : float or None
        Per-sample noise, raw units; ``noise_basis`` says from what.
    noise_basis : str or None
    turn_excess_deg : float or None
        Scatter of the turns beyond their noise.
    known_turn_check : KnownTurnCheck or None
    undetermined : str or None
        Why the std are not to be trusted (``auto`` leaves such a gyro out).
    sample_clock : SampleClock or None
        The clock estimate applied to this section's time (with ``sample_clock_scale``).
    factorization : Factorization or None
    """

    approach: str | None = None
    model_paper: str | None = None
    ignored_misalignment: IgnoredMisalignment | None = None
    axis_to_accel_frame_deg: dict[str, float] | None = None
    rate_std: RateStd | None = None
    g_sensitivity_test: GSensitivityTest | None = None
    rotations: list[RotationRow] | None = None
    rotation_rms_deg: float | None = None
    gyro_noise_raw: float | None = None
    noise_basis: str | None = None
    turn_excess_deg: float | None = None
    known_turn_check: KnownTurnCheck | None = None
    undetermined: str | None = None
    sample_clock: SampleClock | None = None
    factorization: Factorization | None = item(flat=True)
