"""PX4 parameters (``CAL_ACC0_*``, ``CAL_GYRO0_*``, ``CAL_MAG0_*``) in QGroundControl's
parameter file format.

PX4 corrects each sensor in its own frame, then rotates it to the body frame
(``src/lib/sensor_calibration``, ``Accelerometer::Correct`` and ``Gyroscope::Correct``)::

    accel = R_rot @ ((p - CAL_ACC0_[XYZ]OFF) * CAL_ACC0_[XYZ]SCALE)      m/s^2, per axis
    gyro  = R_rot @ (p - CAL_GYRO0_[XYZ]OFF)                            rad/s

``p`` is ``sensor_accel``/``sensor_gyro`` as the driver publishes it (m/s^2, rad/s) and
``R_rot`` the ``CAL_*_ROT`` mounting rotation (left as it is).  The magnetometer
(``src/lib/sensor_calibration/Magnetometer.cpp``)::

    mag = R_rot @ (S @ (p - CAL_MAG0_[XYZ]OFF))          gauss,
    S = [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG], [YODIAG, ZODIAG, ZSCALE]]

a symmetric matrix: imucal's rotation of the magnetometer onto the accelerometer is not part of
it (:mod:`~imucal_cli.formats.exporters.magnetic` says how far it was).  That is an offset and a
diagonal scale for the accelerometer and an offset only for the gyroscope: the misalignment
(and for the gyro the scale) of imucal's full calibration is lost.  The file says how much
(:func:`~imucal_cli.formats.exporters.diagonal_fit`).  PX4 applies a calibration only to the
device whose id is in ``CAL_ACC0_ID``/``CAL_GYRO0_ID``: pass ``--device-id`` (the
``device_id`` of ``sensor_accel`` in a ULog) or set it on the vehicle.  A set of IMUs goes to
``CAL_ACC0..3``/``CAL_GYRO0..3``, each with its own id (:mod:`imucal_cli.use.export_set`).

A temperature-dependent bias (``bias_tempco``, issue 17.1) goes into PX4's thermal
compensation (``src/lib/temperature_compensation``), which subtracts before the offset above::

    p' = p - (X0 + X1 dT + X2 dT^2 + X3 dT^3),   dT = clamp(T, TMIN, TMAX) - TREF

as ``TC_A_ENABLE``/``TC_G_ENABLE`` = 1, ``TC_A0_TREF`` = ``temperature_ref``, ``TC_A0_X0_i`` = 0
(the offset at ``TREF`` stays in ``CAL_ACC0_xOFF``), ``TC_A0_Xk_i`` the coefficients in m/s^2
per C^k, ``TC_A0_TMIN``/``TMAX`` the fitted range (the same for ``TC_G0_*``, rad/s).  PX4
matches the set to a sensor by ``TC_A0_ID``/``TC_G0_ID``: written with ``--device-id``.

File format: ``#`` comments, then one tab-separated line per parameter, ``vehicle-id
component-id name value type`` (type 9 float, 6 int32), as QGroundControl saves and loads.
"""

from __future__ import annotations

from imucal_cli.errors import InputError
from imucal_cli.formats.exporters import (
    ExportOptions,
    Published,
    clock_lines,
    fmt,
    model_lines,
    offset_scale_fits,
    provenance,
)
from imucal_cli.formats.exporters.magnetic import mag_for_target
from imucal_cli.model.calibration import Calibration

__all__ = ["export_px4", "px4_int32"]

_FLOAT, _INT32 = 9, 6


def px4_int32(device_id: int) -> int:
    """A device id as PX4's ``CAL_*_ID`` parameter holds it: an int32 that PX4 compares as
    ``(uint32_t)`` with the sensor's ``device_id`` (PX4-Autopilot
    ``src/lib/sensor_calibration/Utilities.cpp``, ``FindCurrentCalibrationIndex``), so an id of
    2^31 or more (as a ULog shows it, unsigned) is written as its two's complement."""
    value = int(device_id)
    return value - (1 << 32) if value >= 1 << 31 else value


def export_px4(cal: Calibration, opts: ExportOptions) -> str:
    """PX4 ``CAL_ACC0_*``/``CAL_GYRO0_*``/``CAL_MAG0_*`` parameters in QGroundControl's
    ``.params`` format."""
    target = "PX4"
    lost, fits = offset_scale_fits(cal, target, opts, also=("mag",))
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
            params.append((f"{prefix}_ID", px4_int32(opts.device_id), _INT32))
        for i, axis in enumerate("XYZ"):
            params.append((f"{prefix}_{axis}OFF", float(fit.offset[i]), _FLOAT))
        if name == "accel":
            for i, axis in enumerate("XYZ"):
                params.append((f"{prefix}_{axis}SCALE", float(fit.scale[i]), _FLOAT))
    for name, pub, _ in fits:
        params += _thermal(name, pub, opts, comments)
    mag = mag_for_target(cal, target, "gauss", opts.scale.get("mag"))
    if mag is not None:
        comments.append("PX4 applies: mag = R_rot @ (S @ (p - CAL_MAG0_xOFF)), S symmetric from "
                        "CAL_MAG0_xSCALE (diagonal), CAL_MAG0_[XYZ]ODIAG (xy, xz, yz); gauss")
        comments += mag.lines
        comments.append("CAL_MAG0_ID not written: PX4 uses these values for the magnetometer "
                        "whose device id is in CAL_MAG0_ID (set it on the vehicle)")  # fmt: skip
        P = mag.symmetric
        for i, axis in enumerate("XYZ"):
            params.append((f"CAL_MAG0_{axis}OFF", float(mag.offset[i]), _FLOAT))
        for i, axis in enumerate("XYZ"):
            params.append((f"CAL_MAG0_{axis}SCALE", float(P[i, i]), _FLOAT))
        for axis, (i, j) in zip("XYZ", ((0, 1), (0, 2), (1, 2)), strict=True):
            params.append((f"CAL_MAG0_{axis}ODIAG", float(P[i, j]), _FLOAT))
    comments += clock_lines(cal)
    if opts.device_id is None and (cal.accel is not None or cal.gyro is not None):
        comments.append("CAL_ACC0_ID / CAL_GYRO0_ID (and TC_A0_ID / TC_G0_ID) not written (no "
                        "--device-id): PX4 uses these values only for the device whose id they "
                        "hold")  # fmt: skip
    lines = ["# " + c for c in comments]
    lines.append("# Vehicle-Id\tComponent-Id\tName\tValue\tType")
    for pname, value, ptype in params:
        text = str(value) if ptype == _INT32 else fmt(value)
        lines.append(f"1\t1\t{pname}\t{text}\t{ptype}")
    return "\n".join(lines) + "\n"


def _thermal(name: str, pub: Published, opts: ExportOptions, comments: list[str]) -> list:
    """``TC_A*``/``TC_G*`` parameters of a temperature-dependent bias (none without one)."""
    tt = pub.temperature
    if tt is None:
        return []
    if tt.tempco.shape[0] > 3:
        raise InputError(f"the {name} bias polynomial has degree {tt.tempco.shape[0]}: PX4 "
                         "holds at most 3")  # fmt: skip
    tc = "TC_A" if name == "accel" else "TC_G"
    unit = pub.unit
    comments.append(f"{name}: temperature-dependent bias in {tc}0_* ({tt.range_text()}): "
                    f"{tc}0_Xk_i in {unit} per C^k about {tc}0_TREF")  # fmt: skip
    lo = tt.t_ref - 50.0 if tt.t_min is None else tt.t_min
    hi = tt.t_ref + 50.0 if tt.t_max is None else tt.t_max
    out: list[tuple[str, float | int, int]] = [(f"{tc}_ENABLE", 1, _INT32)]
    if opts.device_id is not None:
        out.append((f"{tc}0_ID", px4_int32(opts.device_id), _INT32))
    out += [(f"{tc}0_TREF", tt.t_ref, _FLOAT), (f"{tc}0_TMIN", lo, _FLOAT),
            (f"{tc}0_TMAX", hi, _FLOAT)]  # fmt: skip
    for k in range(3, -1, -1):
        for i in range(3):
            value = 0.0 if k == 0 or k > tt.tempco.shape[0] else float(tt.tempco[k - 1, i])
            out.append((f"{tc}0_X{k}_{i}", value, _FLOAT))
    return out
