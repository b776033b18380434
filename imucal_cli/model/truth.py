"""The simulator's truth (``imucal simulate`` writes it beside the session, ``"solver":
"truth"``): each sensor's true calibration and what the simulated part and procedure were,
for tests and benchmarks to compare a calibration with."""

from __future__ import annotations

from dataclasses import dataclass

from .codec import Record
from .section import SensorCalibration


@dataclass
class TruthCalibration(SensorCalibration):
    """A sensor's truth: its true calibration and the simulated part.

    Attributes
    ----------
    quantised : bool
        Raw readings rounded to whole counts.
    noise : float or list of float
        White noise per axis per sample, input-referred (``noise_unit``).
    nominal_sensitivity : float
        The datasheet's gain, raw units per SI unit.
    scale_error : list of float
        Each axis's gain error from nominal.
    S : list of list of float
        The part's sensitivity matrix (raw = S x + b), raw units per SI unit.
    design : str
        The procedure simulated (paper and section).
    bias_mg, bias_dps : list of float
        Datasheet biases.
    """

    quantised: bool | None = None
    noise_factor: float | None = None  # a set's IMU: its noise over the part's (issue 28)
    sample_rate_hz: float | None = None  # a set's IMU: its own rate
    noise: float | list[float] | None = None
    noise_unit: str | None = None
    nominal_sensitivity: float | None = None
    scale_error: list[float] | None = None
    S: list[list[float]] | None = None
    design: str | None = None
    bias_mg: list[float] | None = None
    bias_dps: list[float] | None = None


@dataclass
class AccelTruth(TruthCalibration):
    """The accelerometer's truth: the part, each static pose's true and labelled up, and for
    Hwangbo & Kanade's redundant unit (section V) its datasheet.

    Attributes
    ----------
    gravity : float
    mount_rotvec_deg : list of float
        The part's mounting in the body, rotation vector.
    jitter_deg : float
        Placement error, RMS.
    segments, labels : list of str
        The static segments, in order.
    true_up, labelled_up : list
        Each pose's true up (body frame) and its label (None: unlabelled).
    tilt_deg : list of float
        Each pose's tilt from its label.
    """

    gravity: float | None = None
    mount_rotvec_deg: list[float] | None = None
    jitter_deg: float | None = None
    segments: list[str] | None = None
    labels: list[str] | None = None
    true_up: list[list[float]] | None = None
    labelled_up: list[list[float]] | None = None
    tilt_deg: list[float] | None = None
    g_unit: str | None = None
    S_counts_per_g: list[list[float]] | None = None
    S_layout: str | None = None
    gains_V_per_g: list[float] | None = None
    bias_V: list[float] | None = None
    angles_deg: dict[str, float] | None = None
    counts_per_volt: float | None = None
    adc_range_counts: list[int] | None = None
    adc_range_V: list[float] | None = None
    noise_counts: float | None = None
    quantisation_counts: float | None = None
    noise_total_counts: float | None = None
    perturbed: bool | None = None


@dataclass
class Ruler(Record):
    """Hwangbo & Kanade's ruler-guided turn of known angle (section IV-B)."""

    segment: str | None = None
    axis_iron: list[float] | None = None
    axis_sensor: list[float] | None = None
    angle_deg: float | None = None


@dataclass
class GyroTruth(TruthCalibration):
    """The gyroscope's truth: the part, and each turn's true rotation.

    Attributes
    ----------
    segments : list of str
        The moves between poses.
    true_rotvec : list of list of float
        Each turn's rotation vector (``true_rotvec_unit``).
    turn_segments, turn_labels, turn_axis_names : list
        The hand turns (Qureshi & Golnaraghi Fig. 2, or any axes).
    true_angle_deg, true_axis, nominal_axis, axis_error_deg : list
        Each turn's angle, axis, the axis it was meant about and how far off.
    peak_rate_dps, duration_s : list of float
    axis_jitter_deg : float
    mounting_rotvec_deg : list of list of float
        Each mounting's rotation (Hwangbo & Kanade's iron); ``mounting_rotvec_note``.
    segment_mounting : dict
        Each segment's mounting.
    sweep_axes_sensor : dict
        Each sweep's axis in the sensor frame.
    peak_rate, sweep_period_s : float
    ruler : Ruler
    g_sensitivity_physical : list of list of float
        The g-sensitivity in physical units (rad/s per m/s^2).
    """

    segments: list[str] | None = None
    true_rotvec: list[list[float]] | None = None
    true_rotvec_unit: str | None = None
    turn_segments: list[str] | None = None
    turn_labels: list[str] | None = None
    turn_axis_names: list[str] | None = None
    true_angle_deg: list[float] | None = None
    true_axis: list[list[float]] | None = None
    nominal_axis: list[list[float]] | None = None
    axis_error_deg: list[float] | None = None
    peak_rate_dps: list[float] | None = None
    duration_s: list[float] | None = None
    axis_jitter_deg: float | None = None
    mounting_rotvec_deg: list[list[float]] | None = None
    mounting_rotvec_note: str | None = None
    segment_mounting: dict[str, int] | None = None
    sweep_axes_sensor: dict[str, list[float]] | None = None
    peak_rate: float | None = None
    sweep_period_s: float | None = None
    ruler: Ruler | None = None
    g_sensitivity_physical: list[list[float]] | None = None


@dataclass
class MagTruth(TruthCalibration):
    """The magnetometer's truth: the part (hard iron in uT), the field and the layout."""

    hard_iron_uT: list[float] | None = None
    field_uT: float | None = None
    inclination_deg: float | None = None
    layout: str | None = None
    tumble_s: float | None = None
