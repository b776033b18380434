"""`imucal export`: a calibration as a C header, an imu_calib YAML file or compact JSON.

Three formats, each a function of a :class:`~imucal_cli.calibration.Calibration` returning text:

- :func:`export_c_header`: C99 for microcontroller firmware.  For each sensor present,
  ``static const float <P>_ACCEL_MATRIX[3][N]``, ``<P>_ACCEL_BIAS[N]`` (float32 values written
  with 9 significant digits, which round-trip float32 exactly), ``#define <P>_ACCEL_CHANNELS N``
  and ``static inline void <p>_accel_apply(const float raw[N], float out[3])`` computing
  ``out = M (raw - b)`` in float; the same for ``GYRO``.  No dynamic memory, no libm, no other
  header.  The arithmetic is plain float: subtract the bias, then for each output axis sum
  ``M[i][j] * d[j]`` for j = 0..N-1 in order, so a compiler that does not contract to FMA
  gives exactly what numpy does in float32 in the same order.
- :func:`export_yaml`: the layout of ROS ``imu_calib`` (``do_calib`` writes it,
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
- :func:`export_json`: the standard fields of the calibration format only (``format``,
  ``format_version``, ``session``, ``created``; per sensor ``solver``, ``units``, ``bias``,
  ``matrix``, ``residual_rms``) plus ``model`` per sensor, on one line with a fixed key order,
  for scripts.  It reads back with :func:`imucal_cli.calibration.calibration_from_json`.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np

from imucal_cli import __version__
from imucal_cli.calibration import (
    FORMAT,
    FORMAT_VERSION,
    MODEL_EQUATION,
    Calibration,
    SensorCalibration,
)
from imucal_cli.errors import InputError

__all__ = ["EXPORT_FORMATS", "export", "export_c_header", "export_json", "export_yaml"]

EXPORT_FORMATS = ("c-header", "yaml", "json")
SENSORS = ("accel", "gyro")
_PREFIX_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")
_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if "
    "inline int long register restrict return short signed sizeof static struct switch typedef "
    "union unsigned void volatile while".split()
)


def _sections(cal: Calibration) -> list[tuple[str, SensorCalibration]]:
    return [(name, getattr(cal, name)) for name in SENSORS if getattr(cal, name) is not None]


def _units_in(sec: SensorCalibration) -> str:
    unit = sec.extra.get("units_in")
    return unit if isinstance(unit, str) and unit != "unknown" else "raw units"


def one_line(text: object) -> str:
    return " ".join(str(text).split())


# --------------------------------------------------------------------------------------------
# C header
# --------------------------------------------------------------------------------------------


def check_prefix(prefix: str) -> str:
    """Return ``prefix`` if it makes valid, unreserved C identifiers, else raise InputError.

    It must start with a letter and hold only letters, digits and ``_`` (a leading ``_`` is
    reserved to the C implementation), and not be a C keyword in lower case.
    """
    if not isinstance(prefix, str) or not _PREFIX_RE.match(prefix):
        raise InputError(
            f"--prefix {prefix!r}: must be a C identifier starting with a letter "
            "(letters, digits and _), e.g. IMUCAL or IMU0"
        )
    if prefix.lower() in _C_KEYWORDS:
        raise InputError(f"--prefix {prefix!r}: is a C keyword in lower case; choose another")
    return prefix


def _c_float(value: float, where: str) -> str:
    """A C float literal for the float32 nearest ``value``, 9 significant digits."""
    with np.errstate(over="ignore"):
        f32 = np.float32(value)
    if not np.isfinite(f32):
        raise InputError(f"{where} = {value!r} does not fit in a float (float32)")
    text = f"{float(f32):.9g}"
    if "." not in text and "e" not in text:
        text += ".0"
    return text + "f"


def _c_comment(text: object) -> str:
    """Free text made safe inside a ``/* */`` comment: one line, no ``*/``, printable ASCII."""
    line = one_line(text).replace("*/", "* /").replace("/*", "/ *")
    return "".join(c if 32 <= ord(c) < 127 else "?" for c in line)


def export_c_header(cal: Calibration, *, prefix: str = "IMUCAL") -> str:
    """Return a C99 header holding the calibration as constants and inline apply functions.

    Parameters
    ----------
    cal : Calibration
        Every sensor section present is exported.
    prefix : str
        Name prefix: constants and macros are ``<PREFIX upper>_ACCEL_MATRIX`` ...,
        functions ``<prefix lower>_accel_apply``, the include guard ``<PREFIX>_CALIBRATION_H``.

    Returns
    -------
    str
        The header text, ending with a newline.

    Raises
    ------
    InputError
        ``prefix`` is not a valid C identifier, or a value does not fit in a float32.
    """
    check_prefix(prefix)
    upper, lower = prefix.upper(), prefix.lower()
    guard = f"{upper}_CALIBRATION_H"
    made_with = cal.extra.get("toolkit_version")
    lines = [
        "/*",
        " * IMU calibration generated by imucal "
        + __version__
        + " (imucal export --format c-header). Do not edit.",
        " *",
        " * Model, per sensor:  out = M (raw - b)",
        " *   raw: the N raw channels as the device reports them, b: bias (N, raw units),",
        " *   M: 3 x N matrix, out: calibrated 3-vector (accel m/s^2, gyro rad/s).",
    ]
    for name, sec in _sections(cal):
        n = sec.bias.shape[0]
        rms = "n/a" if sec.residual_rms is None else f"{sec.residual_rms:.6g} {sec.units}"
        lines.append(
            f" * {name}: solver {_c_comment(sec.solver)}, N = {n} channels in "
            f"{_c_comment(_units_in(sec))} -> {sec.units}, residual RMS {rms}"
        )
    sensor = cal.extra.get("sensor")
    lines += [
        f" * Sensor:   {_c_comment(sensor) if sensor else 'not stated'}",
        f" * Session:  {_c_comment(cal.session) if cal.session else 'not stated'}",
        f" * Created:  {_c_comment(cal.created)}",
        f" * Toolkit:  imucal {__version__}"
        + (f" (calibration made with imucal {_c_comment(made_with)})" if made_with else ""),
        " *",
        " * C99, no dynamic memory, no libm. Floats carry 9 significant digits (exact float32).",
        " */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
    ]
    for name, sec in _sections(cal):
        n = sec.bias.shape[0]
        const = f"{upper}_{name.upper()}"
        channels = f"{const}_CHANNELS"
        matrix_rows = [
            "    { "
            + ", ".join(_c_float(v, f"{name}.matrix[{i}][{j}]") for j, v in enumerate(row))
            + " }"
            for i, row in enumerate(sec.matrix.tolist())
        ]
        bias = ", ".join(_c_float(v, f"{name}.bias[{j}]") for j, v in enumerate(sec.bias))
        lines += [
            f"/* {name}: {n} raw channels ({_c_comment(_units_in(sec))}) -> {sec.units} */",
            f"#define {channels} {n}",
            "",
            f"static const float {const}_MATRIX[3][{channels}] = {{",
            ",\n".join(matrix_rows),
            "};",
            "",
            f"static const float {const}_BIAS[{channels}] = {{ {bias} }};",
            "",
            f"/* out = {const}_MATRIX (raw - {const}_BIAS), in {sec.units}. */",
            f"static inline void {lower}_{name}_apply(const float raw[{channels}], float out[3])",
            "{",
            f"    float d[{channels}];",
            "    int i;",
            "    int j;",
            f"    for (j = 0; j < {channels}; ++j) {{",
            f"        d[j] = raw[j] - {const}_BIAS[j];",
            "    }",
            "    for (i = 0; i < 3; ++i) {",
            "        float sum = 0.0f;",
            f"        for (j = 0; j < {channels}; ++j) {{",
            f"            sum += {const}_MATRIX[i][j] * d[j];",
            "        }",
            "        out[i] = sum;",
            "    }",
            "}",
            "",
        ]
    lines += [f"#endif /* {guard} */", ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# imu_calib YAML
# --------------------------------------------------------------------------------------------


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
    return sec.matrix, sec.matrix @ sec.bias


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
    arrays = {name: _imu_calib_arrays(name, sec) for name, sec in _sections(cal)}
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
        f"{one_line(_units_in(cal.accel))} -> m/s^2",
        f"SM: {_yaml_list(sm.ravel())}",
        f"bias: {_yaml_list(bias)}",
    ]
    if "gyro" in arrays:
        sm, bias = arrays["gyro"]
        out += [
            "# gyroscope (not read by imu_calib, which estimates gyro bias at start-up): same "
            "equation,",
            f"# solver {one_line(cal.gyro.solver)}, raw in {one_line(_units_in(cal.gyro))} "
            "-> rad/s",
            "gyro:",
            f"  SM: {_yaml_list(sm.ravel())}",
            f"  bias: {_yaml_list(bias)}",
        ]
    return "\n".join(out) + "\n"


# --------------------------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------------------------


def _finite_or_none(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def export_json(cal: Calibration) -> str:
    """Return the standard fields of the calibration as compact JSON on one line (plus ``\\n``).

    Keys in a fixed order: ``format``, ``format_version``, ``session`` (when known),
    ``created``, then ``accel``/``gyro`` each with ``solver``, ``units``, ``model``, ``bias``,
    ``matrix``, ``residual_rms``.  Numbers are written so that they read back bit for bit.
    """
    doc: dict = {"format": FORMAT, "format_version": FORMAT_VERSION}
    if cal.session is not None:
        doc["session"] = cal.session
    doc["created"] = cal.created
    for name, sec in _sections(cal):
        doc[name] = {
            "solver": sec.solver,
            "units": sec.units,
            "model": MODEL_EQUATION,
            "bias": [float(v) for v in sec.bias],
            "matrix": [[float(v) for v in row] for row in sec.matrix],
            "residual_rms": _finite_or_none(sec.residual_rms),
        }
    return json.dumps(doc, separators=(",", ":"), allow_nan=False) + "\n"


def export(cal: Calibration, fmt: str, *, prefix: str | None = None) -> str:
    """Dispatch to the exporter for ``fmt`` (one of :data:`EXPORT_FORMATS`).

    Raises
    ------
    InputError
        An unknown format, ``prefix`` with a format other than ``c-header``, or what the
        exporter refuses.
    """
    if fmt not in EXPORT_FORMATS:
        raise InputError(f"--format {fmt!r}: use {', '.join(EXPORT_FORMATS)}")
    if prefix is not None and fmt != "c-header":
        raise InputError(f"--prefix applies to --format c-header only, not {fmt}")
    if fmt == "c-header":
        return export_c_header(cal, prefix="IMUCAL" if prefix is None else prefix)
    if fmt == "yaml":
        return export_yaml(cal)
    return export_json(cal)
