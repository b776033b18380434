"""``sensor_msgs/Imu`` covariances from the noise figures, for a ROS driver's parameters.

A ``sensor_msgs/Imu`` message carries, per sample, ``angular_velocity_covariance`` and
``linear_acceleration_covariance`` (3 x 3, row-major, (rad/s)^2 and (m/s^2)^2) and
``orientation_covariance`` (``[-1, 0, ...]`` when the message has no orientation, per the
message's documentation).  White noise of continuous-time density ``N`` sampled at ``rate``
Hz has a per-sample variance ``N^2 * rate`` (Kalibr wiki, "IMU Noise Model": ``sigma_d = N /
sqrt(dt)``), so the file holds ``diag(N_x^2, N_y^2, N_z^2) * rate`` at the rate the driver
publishes (default: the noise recording's rate).  A driver that averages down to a lower rate
gets ``N^2 * new_rate``: pass ``--rate``.  The bias random walk is not a per-sample covariance
and is left out.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.exporters import ExportOptions, fmt, provenance
from imucal_cli.formats.exporters.kalibr import yaml_vector
from imucal_cli.model.calibration import Calibration

__all__ = ["export_ros_imu", "imu_covariances"]


def imu_covariances(opts: ExportOptions) -> dict[str, np.ndarray | None]:
    """Per-sample covariances (3 x 3) of ``angular_velocity`` and ``linear_acceleration``.

    Raises
    ------
    InputError
        No noise figures, or a sensor with other than 3 axes.
    """
    noise = opts.noise
    if noise is None:
        raise InputError("ros-imu needs the noise figures: pass --noise NOISE.json "
                         "(from imucal noise SESSION --json)")  # fmt: skip
    rate = opts.rate_hz or noise.rate_hz
    out: dict[str, np.ndarray | None] = {}
    for kind, key in (("gyro", "angular_velocity"), ("accel", "linear_acceleration")):
        s = noise.sensor(kind)
        if s is not None and len(s.axes) != 3:
            raise InputError(f"{noise.source}: {kind} has {len(s.axes)} axes; sensor_msgs/Imu "
                             "holds 3")  # fmt: skip
        out[key] = None if s is None else np.diag(s.white**2 * rate)
    return out


def export_ros_imu(cal: Calibration | None, opts: ExportOptions) -> str:
    """YAML with the three ``sensor_msgs/Imu`` covariance arrays (9 numbers, row-major)."""
    cov = imu_covariances(opts)
    noise = opts.noise
    rate = opts.rate_hz or noise.rate_hz
    lines = ["# " + c for c in provenance(cal, "sensor_msgs/Imu covariances")]
    lines += [
        f"# per-sample variance = (white-noise density)^2 x rate, at {rate:.6g} Hz; densities "
        f"from {noise.source}",
        f"# (Allan deviation of {noise.duration_s:.0f} s at {noise.rate_hz:.6g} Hz). 3 x 3 "
        "row-major, in the calibrated axes.",
        *(f"# note: {n}" for n in noise.notes),
        "orientation_covariance: [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # no "
        "orientation in the message",
    ]
    units = {"angular_velocity": "(rad/s)^2", "linear_acceleration": "(m/s^2)^2"}
    for key, matrix in cov.items():
        if matrix is None:
            lines.append(f"# {key}_covariance: not written (no figures for it in the noise file)")
            continue
        std = ", ".join(f"{v:.4g}" for v in np.sqrt(np.diag(matrix)))
        lines.append(f"{key}_covariance: {yaml_vector(matrix)}  # {units[key]}; std per "
                     f"sample {std}")  # fmt: skip
    lines.append(f"rate_hz: {fmt(rate)}  # the rate these covariances are for")
    return "\n".join(lines) + "\n"
