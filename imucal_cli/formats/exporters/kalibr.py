"""Kalibr (ethz-asl/kalibr): the IMU noise file ``imu.yaml`` and the scale-misalignment
intrinsics.

``kalibr-imu``: the ``imu.yaml`` that ``kalibr_calibrate_imu_camera --imu`` reads (Kalibr wiki,
"YAML formats" and "IMU Noise Model"): ``rostopic``, ``update_rate`` (Hz), and the continuous-time
``accelerometer_noise_density`` (m/s^2/sqrt(Hz)), ``accelerometer_random_walk``
(m/s^3/sqrt(Hz)), ``gyroscope_noise_density`` (rad/s/sqrt(Hz)), ``gyroscope_random_walk``
(rad/s^2/sqrt(Hz)).  Kalibr takes one number per figure, the same for the three axes: the file
holds the worst axis, with every axis in a comment.

``kalibr``: the layout Kalibr writes for the ``scale-misalignment`` IMU model (``imu0:`` with
``model``, ``accelerometers: {M}``, ``gyroscopes: {M, A, C_gyro_i}``; ``IccSensors.py``,
``IccScaledMisalignedImu``), whose measurement model is::

    p_a = M_accel @ a_i + b_a
    p_w = M_gyro @ C_gyro_i @ w_i + A @ C_gyro_i @ a_i + b_w

``p`` is what the ROS driver publishes (m/s^2, rad/s), ``a_i``/``w_i`` the true specific force
and rate in Kalibr's IMU frame, ``M`` lower triangular, ``A`` in (rad/s)/(m/s^2).  Kalibr
estimates the biases as time-varying splines and writes none; this file adds the fixed biases
of imucal's calibration as ``accelerometer_bias`` and ``gyroscope_bias`` (same units as ``p``).
``T_i_b`` holds the rotation from imucal's calibrated frame ``b`` to Kalibr's frame ``i``
(:class:`~imucal_cli.formats.exporters.KalibrFrame`).
"""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.exporters import (
    ExportOptions,
    KalibrFrame,
    fmt,
    kalibr_frame,
    model_lines,
    provenance,
    published,
    require,
    rotation_angle_deg,
)
from imucal_cli.formats.noise import WALK_UNITS, WHITE_UNITS, NoiseFigures
from imucal_cli.model.calibration import Calibration

__all__ = [
    "export_kalibr",
    "export_kalibr_imu",
    "kalibr_block",
    "kalibr_header",
    "frame_comments",
    "frame_for",
    "noise_lines",
    "yaml_matrix",
    "yaml_vector",
]

_NOISE_KEYS = {
    "accel": ("accelerometer_noise_density", "accelerometer_random_walk"),
    "gyro": ("gyroscope_noise_density", "gyroscope_random_walk"),
}


def yaml_vector(values) -> str:
    return "[" + ", ".join(fmt(v) for v in np.ravel(values)) + "]"


def yaml_matrix(matrix: np.ndarray, indent: str) -> list[str]:
    """Block list of rows, ``- [a, b, c]`` each (how Kalibr and OpenVINS lay matrices out)."""
    return [f"{indent}- {yaml_vector(row)}" for row in np.asarray(matrix)]


def noise_lines(noise: NoiseFigures, indent: str, rate_hz: float | None) -> list[str]:
    """The four Kalibr noise keys (worst axis), per-axis values and the rate in comments.

    Raises
    ------
    InputError
        The noise file lacks the accelerometer or the gyroscope (Kalibr needs both).
    """
    missing = [k for k in ("accel", "gyro") if noise.sensor(k) is None]
    if missing:
        raise InputError(
            f"{noise.source} has no {' or '.join(missing)} figures; Kalibr's noise keys need "
            "both sensors: run imucal noise on a recording that has both"
        )
    out = [
        f"{indent}# noise from {noise.source}: continuous-time densities from the Allan "
        f"deviation of {noise.duration_s:.0f} s recorded at {noise.rate_hz:.6g} Hz;",
        f"{indent}# one value per sensor (Kalibr uses it for every axis): the worst axis.",
    ]
    for kind, (white_key, walk_key) in _NOISE_KEYS.items():
        s = noise.sensor(kind)
        for key, what, unit in ((white_key, "white", WHITE_UNITS[kind]),
                                (walk_key, "random_walk", WALK_UNITS[kind])):  # fmt: skip
            value, axis, bound = s.worst(what)
            per_axis = ", ".join(f"{a} {v:.4g}" for a, v in zip(s.axes, getattr(s, what),
                                                                 strict=True))  # fmt: skip
            note = "; an upper bound (no slope on the curve)" if bound else ""
            out.append(f"{indent}{key}: {fmt(value)}  # {unit}, worst axis {axis}{note}; "
                       f"per axis: {per_axis}")  # fmt: skip
    if rate_hz is not None:
        out.append(f"{indent}update_rate: {fmt(rate_hz)}  # Hz")
    return out


def export_kalibr_imu(cal: Calibration | None, opts: ExportOptions) -> str:
    """Kalibr's ``imu.yaml``: topic, rate and the four noise figures (worst axis).

    Raises
    ------
    InputError
        No noise figures (``--noise``), or figures of one sensor only.
    """
    noise = opts.noise
    if noise is None:
        raise InputError("kalibr-imu needs the noise figures: pass --noise NOISE.json "
                         "(from imucal noise SESSION --json)")  # fmt: skip
    rate = opts.rate_hz or noise.rate_hz
    lines = ["# " + line for line in provenance(cal, "Kalibr IMU noise file (imu.yaml)")]
    lines += [
        "# Kalibr's noise model per axis: measured = true + bias + white noise (density below),",
        "# d(bias)/dt = white noise (random walk below). Kalibr's wiki advises inflating these",
        "# bench figures for vibration on a moving platform.",
        *(f"# note: {n}" for n in noise.notes),
        f"rostopic: {opts.topic}",
    ]
    lines += noise_lines(noise, "", rate)
    return "\n".join(lines) + "\n"


def frame_for(cal: Calibration, opts: ExportOptions, target: str) -> KalibrFrame:
    """The calibration in Kalibr's layout, with the driver's SI units (see ``published``)."""
    require(cal, ("accel", "gyro"), target)
    return kalibr_frame(published(cal, "accel", target, opts.scale),
                        published(cal, "gyro", target, opts.scale))  # fmt: skip


def frame_comments(frame: KalibrFrame, cal: Calibration, opts: ExportOptions,
                    target: str) -> list[str]:  # fmt: skip
    lines = [*model_lines()]
    for name in ("accel", "gyro"):
        pub = published(cal, name, target, opts.scale)
        lines.append(f"{name}: " + (f"p = {pub.basis}" if pub else "not calibrated: identity, "
                                    "zero bias"))  # fmt: skip
    angle = rotation_angle_deg(frame.C_i_b)
    rows = ", ".join(yaml_vector(row) for row in frame.C_i_b)
    lines += [
        f"frames: {target}'s IMU frame i = C_i_b @ imucal's calibrated frame b (a {angle:.4f} deg "
        "turn, because",
        f"  {target}'s accel matrix is lower triangular): C_i_b = [{rows}]",
    ]
    if frame.has_gyro and not frame.A.any():
        lines.append("gyro g-sensitivity: none in the calibration, A = 0")
    return lines


def export_kalibr(cal: Calibration, opts: ExportOptions) -> str:
    """Kalibr's scale-misalignment intrinsics (``M``, ``A``, ``C_gyro_i``) plus bias fields.

    With ``opts.noise`` the noise keys, topic and rate are included, so the file is a complete
    ``imu0`` entry; without them it holds the intrinsics only.
    """
    target = "Kalibr"
    frame = frame_for(cal, opts, target)
    lines = kalibr_header(cal) + ["# " + line for line in frame_comments(frame, cal, opts,
                                                                          target)]  # fmt: skip
    lines += kalibr_block(frame, opts)
    return "\n".join(lines) + "\n"


def kalibr_header(cal: Calibration) -> list[str]:
    """The comment lines of a Kalibr intrinsics file: provenance and the model."""
    lines = ["# " + line for line in provenance(cal, "Kalibr IMU intrinsics, model "
                                                "scale-misalignment")]  # fmt: skip
    return lines + [
        "# Kalibr's model (IccScaledMisalignedImu), p what the driver publishes (m/s^2, rad/s):",
        "#   p_a = M_accel @ a_i + accelerometer_bias",
        "#   p_w = M_gyro @ C_gyro_i @ w_i + A @ C_gyro_i @ a_i + gyroscope_bias",
        "# so, to calibrate: a_i = inv(M_accel) @ (p_a - accelerometer_bias),",
        "#   w_i = C_gyro_i^T @ inv(M_gyro) @ (p_w - gyroscope_bias - A @ C_gyro_i @ a_i).",
        "# a_i in m/s^2, w_i in rad/s, A in (rad/s)/(m/s^2). The bias keys are imucal's fixed",
        "# biases (Kalibr itself estimates time-varying biases and does not read them).",
    ]


def kalibr_block(frame: KalibrFrame, opts: ExportOptions, name: str = "imu0",
                 T_i_b: np.ndarray | None = None, time_offset: float = 0.0,
                 topic: str | None = None) -> list[str]:  # fmt: skip
    """One IMU's entry: ``T_i_b`` (4 x 4; default the rotation into Kalibr's frame),
    ``time_offset`` (s, Kalibr's: the time added to this IMU's stamps), the noise keys when
    given, and the intrinsics."""
    if T_i_b is None:
        T_i_b = np.block([[frame.C_i_b, np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]])
    lines = [
        f"{name}:",
        "  T_i_b:",
        *yaml_matrix(T_i_b, "    "),
        "  model: scale-misalignment",
        f"  rostopic: {topic or opts.topic}",
        f"  time_offset: {fmt(time_offset) if time_offset else '0.0'}",
    ]
    if opts.noise is not None:
        lines += noise_lines(opts.noise, "  ", opts.rate_hz or opts.noise.rate_hz)
    elif opts.rate_hz is not None:
        lines.append(f"  update_rate: {fmt(opts.rate_hz)}  # Hz")
    lines += [
        "  accelerometers:",
        "    M:",
        *yaml_matrix(frame.M_accel, "    "),
        "  gyroscopes:",
        "    M:",
        *yaml_matrix(frame.M_gyro, "    "),
        "    A:  # (rad/s)/(m/s^2)",
        *yaml_matrix(frame.A, "    "),
        "    C_gyro_i:",
        *yaml_matrix(frame.C_gyro_i, "    "),
        f"  accelerometer_bias: {yaml_vector(frame.b_accel)}  # m/s^2",
        f"  gyroscope_bias: {yaml_vector(frame.b_gyro)}  # rad/s",
    ]
    return lines
