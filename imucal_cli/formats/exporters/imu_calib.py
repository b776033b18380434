"""ROS ``imu_calib`` YAML: the layout of ROS ``imu_calib`` (``do_calib`` writes it,
``apply_calib`` reads it): ``SM``, the 3 x 3 scale-misalignment matrix row-major as a flat
list of 9 numbers, and ``bias``, 3 numbers.  imu_calib's ``AccelCalib::applyCalib``
computes ``corrected = SM * raw - bias``: its bias is **in output units (m/s^2)**, subtracted
after the matrix.  The file therefore holds ``SM = matrix`` and ``bias = matrix @ bias_raw``
(imucal's raw-unit bias mapped through the matrix), so that ``SM @ raw - bias`` equals
imucal's ``matrix @ (raw - bias_raw)`` exactly (up to rounding).  A comment in the file
states the equation; check the convention of whatever else reads the file.  imu_calib
calibrates accelerometers only: the accelerometer is the top-level ``SM``/``bias``; a
gyroscope calibration, when present, goes under a separate ``gyro:`` key (same convention)
that imu_calib ignores.  imu_calib needs 3 x 3: a redundant unit (N != 3) is refused.
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
from imucal_cli.formats.exporters import check_finite, one_line, sections, units_in

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


def _imu_calib_arrays(name: str, sec: SensorCalibration) -> tuple[np.ndarray, np.ndarray]:
    n = sec.bias.shape[0]
    if n != 3:
        raise InputError(
            f"the {name} calibration has {n} raw channels (a redundant unit); imu_calib's "
            "YAML holds a 3 x 3 SM matrix only: export it with --format c-header or json"
        )
    with np.errstate(all="ignore"):
        bias = sec.matrix @ sec.bias
    return check_finite(name, "matrix", sec.matrix), check_finite(name, "matrix @ bias", bias)


def export_yaml(cal: Calibration) -> str:
    """Return the calibration in ROS imu_calib's YAML layout (``SM``: 9 numbers, ``bias``: 3).

    ``SM`` is the calibration matrix row-major and ``bias`` is ``matrix @ bias`` in m/s^2,
    because imu_calib computes ``corrected = SM * raw - bias`` (see the module docstring).
    A gyroscope calibration goes under ``gyro:`` with the same convention, in rad/s.

    Raises
    ------
    InputError
        No accelerometer calibration (imu_calib's file is one), or a sensor with N != 3 raw
        channels (the layout holds a 3 x 3 matrix).
    """
    if cal.accel is None:
        raise InputError(
            "the calibration has no accelerometer section; imu_calib's YAML is an "
            "accelerometer calibration: export the gyro with --format c-header or json"
        )
    arrays = {name: _imu_calib_arrays(name, sec) for name, sec in sections(cal)}
    sensor = cal.extra.get("sensor")
    out = [
        "# IMU calibration for ROS imu_calib (apply_calib calib_file), written by imucal "
        + __version__,
        "# imu_calib applies:  calibrated = SM @ raw - bias",
        "#   SM: 3 x 3 scale-misalignment matrix, row-major; bias in calibrated units.",
        f"# This equals imucal's model {MODEL_EQUATION} with SM = matrix and",
        "# bias = matrix @ (imucal's raw-unit bias). Check the convention of any other reader.",
        f"# sensor: {one_line(sensor) if sensor else 'not stated'}; session: "
        f"{one_line(cal.session) if cal.session else 'not stated'}; created: "
        f"{one_line(cal.created)}",
    ]
    sm, bias = arrays["accel"]
    out += [
        f"# accelerometer: solver {one_line(cal.accel.solver)}, raw in "
        f"{one_line(units_in(cal.accel))} -> m/s^2",
        f"SM: {_yaml_list(sm.ravel())}",
        f"bias: {_yaml_list(bias)}",
    ]
    if "gyro" in arrays:
        sm, bias = arrays["gyro"]
        out += [
            "# gyroscope (not read by imu_calib, which estimates gyro bias at start-up): same "
            "equation,",
            f"# solver {one_line(cal.gyro.solver)}, raw in {one_line(units_in(cal.gyro))} -> rad/s",
            "gyro:",
            f"  SM: {_yaml_list(sm.ravel())}",
            f"  bias: {_yaml_list(bias)}",
        ]
    return "\n".join(out) + "\n"
