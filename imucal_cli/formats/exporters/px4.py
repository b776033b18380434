"""PX4 parameters (``CAL_ACC0_*``, ``CAL_GYRO0_*``) in QGroundControl's parameter file format.

PX4 corrects each sensor in its own frame, then rotates it to the body frame
(``src/lib/sensor_calibration``, ``Accelerometer::Correct`` and ``Gyroscope::Correct``)::

    accel = R_rot @ ((p - CAL_ACC0_[XYZ]OFF) * CAL_ACC0_[XYZ]SCALE)      m/s^2, per axis
    gyro  = R_rot @ (p - CAL_GYRO0_[XYZ]OFF)                            rad/s

``p`` is ``sensor_accel``/``sensor_gyro`` as the driver publishes it (m/s^2, rad/s) and
``R_rot`` the ``CAL_*_ROT`` mounting rotation (left as it is).  That is an offset and a
diagonal scale for the accelerometer and an offset only for the gyroscope: the misalignment
(and for the gyro the scale) of imucal's full calibration is lost.  The file says how much
(:func:`~imucal_cli.formats.exporters.diagonal_fit`).  PX4 applies a calibration only to the
device whose id is in ``CAL_ACC0_ID``/``CAL_GYRO0_ID``: pass ``--device-id`` (the
``device_id`` of ``sensor_accel`` in a ULog) or set it on the vehicle.

File format: ``#`` comments, then one tab-separated line per parameter, ``vehicle-id
component-id name value type`` (type 9 float, 6 int32), as QGroundControl saves and loads.
"""

from __future__ import annotations

from imucal_cli.formats.calibration import Calibration
from imucal_cli.formats.exporters import (
    ExportOptions,
    fmt,
    model_lines,
    offset_scale_fits,
    provenance,
)

__all__ = ["export_px4"]

_FLOAT, _INT32 = 9, 6


def export_px4(cal: Calibration, opts: ExportOptions) -> str:
    """PX4 ``CAL_ACC0_*``/``CAL_GYRO0_*`` parameters in QGroundControl's ``.params`` format."""
    target = "PX4"
    lost, fits = offset_scale_fits(cal, target, opts)
    comments = provenance(cal, "PX4 parameters (QGroundControl: Parameters > Tools > Load "
                          "from file)") + [  # fmt: skip
        "PX4 applies: accel = R_rot @ ((p - CAL_ACC0_xOFF) * CAL_ACC0_xSCALE) per axis, "
        "gyro = R_rot @ (p - CAL_GYRO0_xOFF);",
        "p as the driver publishes it (m/s^2, rad/s); offsets in those units, scales unitless.",
        *model_lines(),
        *lost,
    ]
    params: list[tuple[str, float | int, int]] = []
    for name, _, fit in fits:
        prefix = "CAL_ACC0" if name == "accel" else "CAL_GYRO0"
        if opts.device_id is not None:
            params.append((f"{prefix}_ID", int(opts.device_id), _INT32))
        for i, axis in enumerate("XYZ"):
            params.append((f"{prefix}_{axis}OFF", float(fit.offset[i]), _FLOAT))
        if name == "accel":
            for i, axis in enumerate("XYZ"):
                params.append((f"{prefix}_{axis}SCALE", float(fit.scale[i]), _FLOAT))
    if opts.device_id is None:
        comments.append("CAL_ACC0_ID / CAL_GYRO0_ID not written (no --device-id): PX4 uses "
                        "these values only for the device whose id they hold")  # fmt: skip
    lines = ["# " + c for c in comments]
    lines.append("# Vehicle-Id\tComponent-Id\tName\tValue\tType")
    for pname, value, ptype in params:
        text = str(value) if ptype == _INT32 else fmt(value)
        lines.append(f"1\t1\t{pname}\t{text}\t{ptype}")
    return "\n".join(lines) + "\n"
