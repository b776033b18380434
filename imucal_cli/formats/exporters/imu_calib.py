"""ROS ``imu_calib`` YAML: the layout of ROS ``imu_calib`` (``do_calib`` writes it,
``apply_calib`` reads it): ``SM``, the 3 x 3 scale-misalignment matrix row-major as a flat
list of 9 numbers, and ``bias``, 3 numbers.  imu_calib's ``AccelCalib::applyCalib``
computes ``corrected = SM * raw - bias``: its bias is **in output units (m/s^2)**, subtracted
after the matrix, and ``raw`` is the ``linear_acceleration`` of the ``sensor_msgs/Imu`` the
driver publishes (m/s^2).  The file therefore holds the calibration rewritten for the
published values (:func:`~imucal_cli.formats.exporters.published`: raw in m/s^2 or g converts
exactly, counts or V need the driver's ``--accel-scale``), ``SM = matrix`` and ``bias = matrix
@ bias`` of it, so that ``SM @ p - bias`` equals imucal's ``matrix @ (raw - bias_raw)``
exactly (up to rounding).  A comment in the file states the equation and the scale.
imu_calib calibrates accelerometers only: the accelerometer is the top-level ``SM``/``bias``;
a gyroscope calibration, when present, goes under a separate ``gyro:`` key (same convention,
rad/s, ``--gyro-scale``) that imu_calib ignores.  imu_calib has no g-sensitivity: a gyro
calibration holding one is refused unless ``--drop g-sensitivity`` (``use.export``).
imu_calib needs 3 x 3: a redundant unit (N != 3) is refused.
"""

from __future__ import annotations

import numpy as np

from imucal_cli import __version__
from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import (
    MODEL_EQUATION,
    Calibration,
    SensorCalibration,
)
from imucal_cli.formats.exporters import (
    ExportOptions,
    Published,
    check_finite,
    one_line,
    published,
)

__all__ = ["export_yaml"]


def _yaml_float(value: float) -> str:
    """Shortest round-trip repr that YAML 1.1 (PyYAML) and yaml-cpp both read as a float."""
    text = repr(float(value))
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:
        text = f"{mantissa}.0e{exponent}"
    return text


def _yaml_list(values) -> str:
    return "[" + ", ".join(_yaml_float(v) for v in values) + "]"


def _imu_calib_arrays(name: str, sec: SensorCalibration, scale: dict[str, float] | None
                      ) -> tuple[np.ndarray, np.ndarray, Published]:  # fmt: skip
    """``SM`` and ``bias`` of a section for the values the driver publishes."""
    n = sec.bias.shape[0]
    if n != 3:
        raise InputError(
            f"the {name} calibration has {n} raw channels (a redundant unit); imu_calib's "
            "YAML holds a 3 x 3 SM matrix only: export it with --format c-header or json"
        )
    pub = published(Calibration(**{name: sec}), name, "imu_calib", scale)
    with np.errstate(all="ignore"):
        bias = pub.matrix @ pub.bias
    return (check_finite(name, "matrix", pub.matrix), check_finite(name, "matrix @ bias", bias),
            pub)  # fmt: skip


def export_yaml(cal: Calibration, opts: ExportOptions | None = None) -> str:
    """Return the calibration in ROS imu_calib's YAML layout (``SM``: 9 numbers, ``bias``: 3).

    ``SM`` is the calibration matrix for the driver's published values, row-major, and
    ``bias`` is ``matrix @ bias`` in m/s^2, because imu_calib computes ``corrected = SM * raw
    - bias`` (see the module docstring).  A gyroscope calibration goes under ``gyro:`` with
    the same convention, in rad/s.

    Raises
    ------
    InputError
        No accelerometer calibration (imu_calib's file is one), a sensor with N != 3 raw
        channels (the layout holds a 3 x 3 matrix), or raw units in counts or V without the
        driver's scale (``--accel-scale``, ``--gyro-scale``).
    """
    if cal.accel is None:
        raise InputError(
            "the calibration has no accelerometer section; imu_calib's YAML is an "
            "accelerometer calibration: export the gyro with --format c-header or json"
        )
    scale = None if opts is None else opts.scale
    arrays = {name: _imu_calib_arrays(name, sec, scale) for name, sec in
              (("accel", cal.accel), ("gyro", cal.gyro)) if sec is not None}  # fmt: skip
    sensor = cal.extra.get("sensor")
    out = [
        "# IMU calibration for ROS imu_calib (apply_calib calib_file), written by imucal "
        + __version__,
        "# imu_calib applies:  calibrated = SM @ raw - bias",
        "#   raw: the driver's sensor_msgs/Imu linear_acceleration (m/s^2);",
        "#   SM: 3 x 3 scale-misalignment matrix, row-major; bias in calibrated units.",
        f"# This equals imucal's model {MODEL_EQUATION} with SM = matrix and",
        "# bias = matrix @ (imucal's raw-unit bias), both rewritten for raw = p below.",
        "# Check the convention of any other reader.",
        f"# sensor: {one_line(sensor) if sensor else 'not stated'}; session: "
        f"{one_line(cal.session) if cal.session else 'not stated'}; created: "
        f"{one_line(cal.created)}",
    ]
    sm, bias, pub = arrays["accel"]
    out += [
        f"# accelerometer: solver {one_line(cal.accel.solver)}, p = {one_line(pub.basis)} -> "
        "m/s^2",
        f"SM: {_yaml_list(sm.ravel())}",
        f"bias: {_yaml_list(bias)}",
    ]
    if "gyro" in arrays:
        sm, bias, pub = arrays["gyro"]
        out += [
            "# gyroscope (not read by imu_calib, which estimates gyro bias at start-up): same "
            "equation,",
            f"# solver {one_line(cal.gyro.solver)}, p = {one_line(pub.basis)} -> rad/s",
        ]
        if pub.g_sensitivity is not None:  # only with --drop g-sensitivity
            worst = float(np.linalg.norm(pub.matrix @ pub.g_sensitivity, 2) * 9.80665)
            out.append(f"# gyro g-sensitivity dropped (imu_calib has none; --drop "
                       f"g-sensitivity): up to {worst:.4g} rad/s at 1 g")  # fmt: skip
        out += [
            "gyro:",
            f"  SM: {_yaml_list(sm.ravel())}",
            f"  bias: {_yaml_list(bias)}",
        ]
    return "\n".join(out) + "\n"
