"""IMU configs of visual-inertial estimators that read OpenCV ``FileStorage`` YAML
(``%YAML:1.0``) and model the IMU by its noise only: VINS-Mono / VINS-Fusion
(HKUST-Aerial-Robotics) and ORB-SLAM3 (UZ-SLAMLab).

Neither models scale, misalignment, a fixed bias or g-sensitivity: they estimate a slowly
varying bias online and take the driver's values as calibrated.  The calibration itself is
applied upstream (``imucal apply``, or a driver with the C header), and these files carry what
the estimators read about the IMU, from ``imucal noise --json`` (continuous-time densities):

- ``vins``: VINS's ``parameters.cpp`` reads ``imu`` (1: use the IMU; VINS-Fusion),
  ``imu_topic``, ``acc_n``, ``gyr_n`` (white noise, m/s^2/sqrt(Hz), rad/s/sqrt(Hz)), ``acc_w``,
  ``gyr_w`` (bias random walk, m/s^3/sqrt(Hz), rad/s^2/sqrt(Hz)) and ``g_norm`` (m/s^2), each
  with ``fsSettings["name"]``; merge the keys into the estimator's config (its camera keys stay).
- ``orbslam3``: ORB-SLAM3's ``Settings.cc`` (settings file ``File.version: "1.0"``) reads
  ``IMU.NoiseGyro``, ``IMU.NoiseAcc``, ``IMU.GyroWalk``, ``IMU.AccWalk`` (the same continuous
  densities: it multiplies them by sqrt(IMU.Frequency) itself) and ``IMU.Frequency`` (Hz);
  ``IMU.T_b_c1``, the camera-to-body transform, is the camera calibration's, not the IMU's:
  merge these keys into the settings file that holds it.

One value per sensor (the estimators use it for every axis): the worst axis, as Kalibr's file;
every axis in a comment.
"""

from __future__ import annotations

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration
from imucal_cli.formats.exporters import STANDARD_GRAVITY, ExportOptions, fmt, provenance
from imucal_cli.formats.noise import WALK_UNITS, WHITE_UNITS, NoiseFigures

__all__ = ["export_orbslam3", "export_vins"]


def _noise(opts: ExportOptions, target: str) -> NoiseFigures:
    """The noise figures, with both sensors (the estimators need both)."""
    noise = opts.noise
    if noise is None:
        raise InputError(f"{target}'s IMU config is its noise: pass --noise NOISE.json (from "
                         "imucal noise SESSION --json)")  # fmt: skip
    missing = [k for k in ("accel", "gyro") if noise.sensor(k) is None]
    if missing:
        raise InputError(f"{noise.source} has no {' or '.join(missing)} figures; {target} needs "
                         "both sensors")  # fmt: skip
    return noise


def _value(noise: NoiseFigures, kind: str, what: str) -> tuple[float, str]:
    """The worst axis's value and a comment with every axis."""
    s = noise.sensor(kind)
    value, axis, bound = s.worst(what)
    unit = WHITE_UNITS[kind] if what == "white" else WALK_UNITS[kind]
    per_axis = ", ".join(f"{a} {v:.4g}" for a, v in zip(s.axes, getattr(s, what), strict=True))
    return value, (f"{unit}, worst axis {axis}{'; an upper bound' if bound else ''}; per axis: "
                   f"{per_axis}")  # fmt: skip


def _header(cal: Calibration | None, noise: NoiseFigures, target: str) -> list[str]:
    lines = ["%YAML:1.0"]
    lines += ["# " + line for line in provenance(cal, f"{target} IMU config")]
    lines += [
        f"# noise from {noise.source}: continuous-time densities from the Allan deviation of "
        f"{noise.duration_s:.0f} s at {noise.rate_hz:.6g} Hz.",
        f"# {target} models no scale, misalignment, fixed bias or g-sensitivity: apply the "
        "calibration upstream",
        "# (imucal apply, or the driver with imucal export --format c-header); merge these keys "
        "into the estimator's config.",
        *(f"# note: {n}" for n in noise.notes),
    ]
    return lines


def _gravity(cal: Calibration | None) -> tuple[float, str]:
    g = None if cal is None or cal.accel is None else cal.accel.extra.get("gravity")
    if isinstance(g, int | float) and 9.0 < g < 10.5:
        return float(g), "the calibration's local gravity"
    return STANDARD_GRAVITY, "standard gravity (no calibration given)"


def export_vins(cal: Calibration | None, opts: ExportOptions) -> str:
    """VINS-Mono / VINS-Fusion IMU keys (see the module notes).

    Raises
    ------
    InputError
        No noise figures, or figures of one sensor only.
    """
    noise = _noise(opts, "VINS")
    lines = _header(cal, noise, "VINS-Mono / VINS-Fusion")
    g, said = _gravity(cal)
    lines += ["imu: 1", f'imu_topic: "{opts.topic}"']
    for key, kind, what in (("acc_n", "accel", "white"), ("gyr_n", "gyro", "white"),
                            ("acc_w", "accel", "random_walk"), ("gyr_w", "gyro", "random_walk")):
        value, comment = _value(noise, kind, what)
        lines.append(f"{key}: {fmt(value)}  # {comment}")
    lines.append(f"g_norm: {fmt(g)}  # m/s^2, {said}")
    return "\n".join(lines) + "\n"


def export_orbslam3(cal: Calibration | None, opts: ExportOptions) -> str:
    """ORB-SLAM3 settings IMU keys (see the module notes).

    Raises
    ------
    InputError
        No noise figures, or figures of one sensor only.
    """
    noise = _noise(opts, "ORB-SLAM3")
    rate = opts.rate_hz or noise.rate_hz
    lines = _header(cal, noise, "ORB-SLAM3")
    lines.append("# IMU.T_b_c1 (camera to body) is the camera calibration's: keep it in the "
                 "settings file.")
    for key, kind, what in (("IMU.NoiseGyro", "gyro", "white"), ("IMU.NoiseAcc", "accel", "white"),
                            ("IMU.GyroWalk", "gyro", "random_walk"),
                            ("IMU.AccWalk", "accel", "random_walk")):  # fmt: skip
        value, comment = _value(noise, kind, what)
        lines.append(f"{key}: {fmt(value)}  # {comment}")
    lines.append(f"IMU.Frequency: {fmt(rate)}  # Hz")
    return "\n".join(lines) + "\n"
