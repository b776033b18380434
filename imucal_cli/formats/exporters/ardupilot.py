"""ArduPilot parameters (``INS_ACCOFFS_*``, ``INS_ACCSCAL_*``, ``INS_GYROFFS_*``) as a ``.parm``
file (``NAME,VALUE`` lines, ``#`` comments; Mission Planner and MAVProxy ``param load``).

ArduPilot corrects the first IMU in the sensor frame, then rotates to the body frame
(``AP_InertialSensor_Backend::_rotate_and_correct_accel``/``_gyro``)::

    accel = R_board @ ((p - INS_ACCOFFS_[XYZ]) * INS_ACCSCAL_[XYZ])     m/s^2, per axis
    gyro  = R_board @ (p - INS_GYROFFS_[XYZ])                          rad/s

``p`` is the sample as the driver reports it (m/s^2, rad/s, after the driver's own axis
rotation).  Offset and diagonal scale only: the misalignment of imucal's full calibration (and
the gyro's scale) is lost, and the file says how much
(:func:`~imucal_cli.formats.exporters.diagonal_fit`).  ArduPilot's own accel calibration
refuses scales outside 0.8 .. 1.2 and offsets beyond 3.5 m/s^2; values outside are flagged.
``--device-id`` writes ``INS_ACC_ID``/``INS_GYR_ID`` (ArduPilot resets the calibration of a
device whose id changed).
"""

from __future__ import annotations

import numpy as np

from imucal_cli.formats.calibration import Calibration
from imucal_cli.formats.exporters import (
    ExportOptions,
    fmt,
    model_lines,
    offset_scale_fits,
    provenance,
)

__all__ = ["export_ardupilot"]

_SCALE_RANGE = (0.8, 1.2)
_MAX_OFFSET = 3.5  # m/s^2


def export_ardupilot(cal: Calibration, opts: ExportOptions) -> str:
    """ArduPilot ``INS_ACCOFFS_*``, ``INS_ACCSCAL_*``, ``INS_GYROFFS_*`` as ``NAME,VALUE``."""
    target = "ArduPilot"
    lost, fits = offset_scale_fits(cal, target, opts)
    comments = provenance(cal, "ArduPilot parameters (.parm: Mission Planner 'Load from "
                          "file', MAVProxy 'param load')") + [  # fmt: skip
        "ArduPilot applies: accel = R_board @ ((p - INS_ACCOFFS_x) * INS_ACCSCAL_x) per axis, "
        "gyro = R_board @ (p - INS_GYROFFS_x);",
        "p as the driver reports it (m/s^2, rad/s); offsets in those units, scales unitless.",
        *model_lines(),
        *lost,
    ]
    params: list[tuple[str, str]] = []
    for name, _, fit in fits:
        if name == "accel":
            if opts.device_id is not None:
                params.append(("INS_ACC_ID", str(int(opts.device_id))))
            params += [(f"INS_ACCOFFS_{a}", fmt(v)) for a, v in zip("XYZ", fit.offset,
                                                                     strict=True)]  # fmt: skip
            params += [(f"INS_ACCSCAL_{a}", fmt(v)) for a, v in zip("XYZ", fit.scale,
                                                                     strict=True)]  # fmt: skip
            lo, hi = _SCALE_RANGE
            if np.any(fit.scale < lo) or np.any(fit.scale > hi):
                comments.append(f"WARNING: a scale outside ArduPilot's accepted {lo} .. {hi}: "
                                "check the driver's units (--accel-scale)")  # fmt: skip
            if np.any(np.abs(fit.offset) > _MAX_OFFSET):
                comments.append(f"WARNING: an offset beyond ArduPilot's accepted {_MAX_OFFSET} "
                                "m/s^2: check the driver's units (--accel-scale)")  # fmt: skip
        else:
            if opts.device_id is not None:
                params.append(("INS_GYR_ID", str(int(opts.device_id))))
            params += [(f"INS_GYROFFS_{a}", fmt(v)) for a, v in zip("XYZ", fit.offset,
                                                                     strict=True)]  # fmt: skip
    lines = ["# " + c for c in comments]
    lines += [f"{n},{v}" for n, v in params]
    return "\n".join(lines) + "\n"
