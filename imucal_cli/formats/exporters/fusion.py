"""x-io Technologies' Fusion AHRS library: the three arrays per sensor of its inertial sensor
model as C99 constants, for Fusion 1.3 (default) or 1.2 (``--fusion-version 1.2``).

Fusion's inertial model (1.3: ``FusionModelInertial`` in ``FusionModel.h``; 1.2:
``FusionCalibrationInertial`` in ``FusionCalibration.h``, the same arithmetic)::

    calibrated = misalignment @ ((uncalibrated - offset) * sensitivity)

``uncalibrated`` the raw sample as the device reports it (counts are fine), ``offset`` in raw
units, ``sensitivity`` per axis (output units per raw unit), ``misalignment`` a 3 x 3 matrix
(``FusionMatrix``, row-major: ``xx, xy, xz, yx, ...``).  Fusion's AHRS takes the gyroscope in
**degrees per second** and the accelerometer in **g** (standard gravity, 9.80665 m/s^2), so the
arrays give those units: imucal's ``matrix`` times 180/pi (gyro) or 1/9.80665 (accel) is split
into ``sensitivity`` = the norm of each column and ``misalignment`` = the columns divided by it
(unit vectors: each raw axis's direction in the calibrated frame).  Exact, no loss.  A gyro
g-sensitivity, which Fusion does not model, is refused (``use.export``), or dropped with
``--drop g-sensitivity``: the file then says how large it was.

The layout of ``FusionMatrix`` changed between the versions (Fusion's sources, tags v1.2.9 and
v1.3.2, ``FusionMath.h``): 1.2 is ``float array[3][3]``, written ``{{{xx, xy, xz}, {yx, ...},
{...}}}``; 1.3 is ``float array[9]``, written ``{{xx, xy, xz, yx, ...}}``.  The nested form
compiled against 1.3 fills the array wrongly (gcc only warns), so each file is for one
version and says which; compiled as C11 it also asserts the layout it was written for.

Constants: ``<prefix>GyroscopeMisalignment`` (``FusionMatrix``), ``...Sensitivity``,
``...Offset`` (``FusionVector``), the same for ``Accelerometer``; the default prefix is none,
giving Fusion's own example names (``gyroscopeMisalignment`` ...).

The magnetometer (1.3: ``FusionModelMagnetic``; 1.2: ``FusionCalibrationMagnetic``)::

    calibrated = softIronMatrix @ (uncalibrated - hardIronOffset)

is imucal's model exactly: ``softIronMatrix`` = ``matrix`` (a full matrix: soft iron and the
rotation onto the accelerometer's axes), ``hardIronOffset`` = ``bias`` (raw units), out in uT
(or units of the local field: Fusion's AHRS uses the field's direction only).  Constants
``softIronMatrix`` and ``hardIronOffset`` (Fusion's example names; with a prefix
``<prefix>SoftIronMatrix`` ...).
"""

from __future__ import annotations

import math

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.exporters import (
    STANDARD_GRAVITY,
    ExportOptions,
    provenance,
    require,
    sections,
    units_in,
)
from imucal_cli.formats.exporters.c_header import c_comment, c_float, check_prefix
from imucal_cli.model.calibration import Calibration

__all__ = ["FUSION_VERSIONS", "export_fusion", "fusion_arrays"]

#: Fusion versions whose ``FusionMatrix`` layout can be written, and each one's names of the
#: inertial and magnetic models (the default first).
FUSION_VERSIONS = {
    "1.3": ("FusionModelInertial", "FusionModelMagnetic", "FusionModel.h"),
    "1.2": ("FusionCalibrationInertial", "FusionCalibrationMagnetic", "FusionCalibration.h"),
}

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


def _matrix(values: np.ndarray, version: str, what: str) -> str:
    """A ``FusionMatrix`` initialiser in the layout of Fusion ``version`` (see the notes)."""
    rows = [[c_float(v, what) for v in row] for row in np.asarray(values)]
    if version == "1.2":
        return "{{" + ", ".join("{" + ", ".join(row) + "}" for row in rows) + "}}"
    return "{{" + ", ".join(v for row in rows for v in row) + "}}"


def _layout_check(version: str) -> list[str]:
    """A C11 static assertion that the ``Fusion.h`` compiled against has the layout written
    (``array[0]`` a float in 1.3, a row of three in 1.2); C99 and C++ compilers skip it."""
    same = "==" if version == "1.3" else "!="
    other = "1.2" if version == "1.3" else "1.3"
    return [
        "#if !defined(__cplusplus) && defined(__STDC_VERSION__) && __STDC_VERSION__ >= 201112L",
        f"_Static_assert(sizeof(((FusionMatrix *)0)->array[0]) {same} sizeof(float),",
        f'               "written for the FusionMatrix of Fusion {version}; this Fusion.h is '
        f'{other}: imucal export --fusion-version {other}");',
        "#endif",
        "",
    ]


def export_fusion(cal: Calibration, opts: ExportOptions) -> str:
    """C99 constants for Fusion's inertial (and magnetic) model, per sensor present, in the
    ``FusionMatrix`` layout of ``opts.fusion_version`` (1.3 unless "1.2").

    Raises
    ------
    InputError
        No section Fusion holds, an unknown version, a bad prefix, a redundant unit, or a
        value that does not fit a float.
    """
    require(cal, ("accel", "gyro", "mag"), "Fusion")
    version = opts.fusion_version or "1.3"
    if version not in FUSION_VERSIONS:
        raise InputError(f"--fusion-version {version!r}: use {' or '.join(FUSION_VERSIONS)}")
    prefix = opts.prefix or ""
    if prefix:
        check_prefix(prefix)
    lines = _comment(cal, version)
    lines += [" */", '#include "Fusion.h"', "", *_layout_check(version)]
    lines += _constants(cal, version, prefix)
    return "\n".join(lines)


def _comment(cal: Calibration, version: str) -> list[str]:
    """The opening comment's lines up to its close: provenance, the model Fusion ``version``
    applies against imucal's, and each section's units and solver.

    Raises
    ------
    InputError
        A magnetometer calibration that is not 3-axis.
    """
    inertial, magnetic, header = FUSION_VERSIONS[version]
    dims, other = ("3][3", "1.3") if version == "1.2" else ("9", "1.2")
    lines = ["/*"] + [" * " + c_comment(line) for line in provenance(
        cal, f"Fusion {version} AHRS calibration")]  # fmt: skip
    lines += [
        " *",
        f" * For Fusion {version} (FusionMatrix as float array[{dims}]); Fusion {other}: imucal "
        f"export --fusion-version {other}.",
        f" * Fusion applies ({inertial}, {header}):",
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
        gs = sec.g_term if name == "gyro" else None
        if gs is not None:  # only with --drop g-sensitivity (use.export refuses it otherwise)
            worst = float(np.linalg.norm(sec.matrix @ gs, 2) * STANDARD_GRAVITY)
            lines.append(f" * gyro g-sensitivity dropped (Fusion has none; --drop "
                         f"g-sensitivity): up to {worst:.4g} rad/s ({math.degrees(worst):.4g} "
                         "deg/s) at 1 g")  # fmt: skip
    mag = cal.mag
    if mag is not None:
        if mag.bias.shape[0] != 3:
            raise InputError(f"the mag calibration has {mag.bias.shape[0]} channels; Fusion "
                             "holds a 3-axis magnetometer")  # fmt: skip
        lines += [
            f" * magnetometer ({magnetic}):",
            " *   calibrated = softIronMatrix * (uncalibrated - hardIronOffset)",
            f" * mag: raw {c_comment(units_in(mag))} -> {c_comment(mag.units)}, solver "
            f"{c_comment(mag.solver)}; {c_comment(mag.frame or '')}",
        ]
    return lines


def _constants(cal: Calibration, version: str, prefix: str) -> list[str]:
    """The ``FusionMatrix`` and ``FusionVector`` constants of each section present
    (misalignment, sensitivity, offset; soft and hard iron), named with ``prefix``.

    Raises
    ------
    InputError
        A value that does not fit a float.
    """
    lines: list[str] = []
    mag = cal.mag
    for name, sec in sections(cal):
        _, factor = _UNITS[name]
        misalignment, sensitivity = fusion_arrays(sec.matrix, factor)
        base = _NAMES[name]
        ident = (prefix + base[0].upper() + base[1:]) if prefix else base
        m = _matrix(misalignment, version, f"{name} misalignment")
        s = ", ".join(c_float(v, f"{name} sensitivity") for v in sensitivity)
        o = ", ".join(c_float(v, f"{name} offset") for v in sec.bias)
        lines += [
            f"static const FusionMatrix {ident}Misalignment = {m};",
            f"static const FusionVector {ident}Sensitivity = {{{{{s}}}}};",
            f"static const FusionVector {ident}Offset = {{{{{o}}}}};",
            "",
        ]
    if mag is not None:
        m = _matrix(mag.matrix, version, "mag soft iron")
        o = ", ".join(c_float(v, "mag hard iron") for v in mag.bias)
        soft = prefix + "SoftIronMatrix" if prefix else "softIronMatrix"
        hard = prefix + "HardIronOffset" if prefix else "hardIronOffset"
        lines += [
            f"static const FusionMatrix {soft} = {m};",
            f"static const FusionVector {hard} = {{{{{o}}}}};",
            "",
        ]
    return lines
