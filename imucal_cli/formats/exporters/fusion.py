"""x-io Technologies' Fusion AHRS library: the three arrays per sensor of
``FusionCalibrationInertial`` as C99 constants.

Fusion's inertial calibration model (``FusionCalibration.h``)::

    calibrated = misalignment @ ((uncalibrated - offset) * sensitivity)

``uncalibrated`` the raw sample as the device reports it (counts are fine), ``offset`` in raw
units, ``sensitivity`` per axis (output units per raw unit), ``misalignment`` a 3 x 3 matrix
(``FusionMatrix``, row-major: ``xx, xy, xz, yx, ...``).  Fusion's AHRS takes the gyroscope in
**degrees per second** and the accelerometer in **g** (standard gravity, 9.80665 m/s^2), so the
arrays give those units: imucal's ``matrix`` times 180/pi (gyro) or 1/9.80665 (accel) is split
into ``sensitivity`` = the norm of each column and ``misalignment`` = the columns divided by it
(unit vectors: each raw axis's direction in the calibrated frame).  Exact, no loss, except a
gyro g-sensitivity, which Fusion does not model: the file says how large it was.

Constants: ``<prefix>GyroscopeMisalignment`` (``FusionMatrix``), ``...Sensitivity``,
``...Offset`` (``FusionVector``), the same for ``Accelerometer``; the default prefix is none,
giving Fusion's own example names (``gyroscopeMisalignment`` ...).
"""

from __future__ import annotations

import math

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration
from imucal_cli.formats.exporters import (
    STANDARD_GRAVITY,
    ExportOptions,
    provenance,
    require,
    sections,
    units_in,
)
from imucal_cli.formats.exporters.c_header import c_comment, c_float, check_prefix

__all__ = ["export_fusion", "fusion_arrays"]

_UNITS = {"accel": ("g", 1.0 / STANDARD_GRAVITY), "gyro": ("deg/s", 180.0 / math.pi)}
_NAMES = {"accel": "accelerometer", "gyro": "gyroscope"}


def fusion_arrays(matrix: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """Split ``factor * matrix`` into Fusion's ``misalignment`` (unit columns) and
    ``sensitivity`` (column norms): ``misalignment @ diag(sensitivity) = factor * matrix``."""
    scaled = factor * np.asarray(matrix, float)
    sensitivity = np.linalg.norm(scaled, axis=0)
    if np.any(sensitivity == 0):
        raise InputError("a raw axis has an all-zero column in the matrix: Fusion's "
                         "sensitivity would be zero")  # fmt: skip
    return scaled / sensitivity, sensitivity


def export_fusion(cal: Calibration, opts: ExportOptions) -> str:
    """C99 constants for Fusion's ``FusionCalibrationInertial``, per sensor present."""
    require(cal, ("accel", "gyro"), "Fusion")
    prefix = opts.prefix or ""
    if prefix:
        check_prefix(prefix)
    lines = ["/*"] + [" * " + c_comment(line) for line in provenance(cal, "Fusion AHRS "
                                                                    "calibration")]  # fmt: skip
    lines += [
        " *",
        " * Fusion applies (FusionCalibrationInertial):",
        " *   calibrated = misalignment * ((uncalibrated - offset) .* sensitivity)",
        " * uncalibrated: raw sample as the device reports it; offset in raw units;",
        " * out: gyroscope in deg/s, accelerometer in g (9.80665 m/s^2), what FusionAhrs takes.",
        " * imucal's model: calibrated = matrix @ (raw - bias) in m/s^2, rad/s; here",
        " * misalignment * diag(sensitivity) = matrix * (180/pi for the gyro, 1/9.80665 accel).",
    ]
    for name, sec in sections(cal):
        unit, _ = _UNITS[name]
        lines.append(f" * {name}: raw {c_comment(units_in(sec))} -> {unit}, solver "
                     f"{c_comment(sec.solver)}")  # fmt: skip
        gs = sec.g_sensitivity if name == "gyro" else None
        if gs is not None:
            worst = float(np.linalg.norm(sec.matrix @ gs, 2) * STANDARD_GRAVITY)
            lines.append(f" * gyro g-sensitivity dropped (Fusion has none): up to {worst:.4g} "
                         f"rad/s ({math.degrees(worst):.4g} deg/s) at 1 g")  # fmt: skip
    lines += [" */", '#include "Fusion.h"', ""]
    for name, sec in sections(cal):
        _, factor = _UNITS[name]
        misalignment, sensitivity = fusion_arrays(sec.matrix, factor)
        base = _NAMES[name]
        ident = (prefix + base[0].upper() + base[1:]) if prefix else base
        m = ", ".join("{" + ", ".join(c_float(v, f"{name} misalignment") for v in row) + "}"
                      for row in misalignment)  # fmt: skip
        s = ", ".join(c_float(v, f"{name} sensitivity") for v in sensitivity)
        o = ", ".join(c_float(v, f"{name} offset") for v in sec.bias)
        lines += [
            f"static const FusionMatrix {ident}Misalignment = {{{{{m}}}}};",
            f"static const FusionVector {ident}Sensitivity = {{{{{s}}}}};",
            f"static const FusionVector {ident}Offset = {{{{{o}}}}};",
            "",
        ]
    return "\n".join(lines)
