"""`imucal export`: a calibration as a C header, an imu_calib YAML file or compact JSON.

Three formats, each a function of a
:class:`~imucal_cli.formats.calibration.Calibration` returning text:

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
  for scripts.  It reads back with :func:`imucal_cli.formats.calibration.calibration_from_json`.
"""

from __future__ import annotations

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration
from imucal_cli.formats.exporters.c_header import export_c_header
from imucal_cli.formats.exporters.imu_calib import export_yaml
from imucal_cli.formats.exporters.imucal_json import export_json
from imucal_cli.formats.text import is_clean

__all__ = ["EXPORT_FORMATS", "export", "export_c_header", "export_json", "export_yaml"]

EXPORT_FORMATS = ("c-header", "yaml", "json")


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
        text = export_c_header(cal, prefix="IMUCAL" if prefix is None else prefix)
    elif fmt == "yaml":
        text = export_yaml(cal)
    else:
        text = export_json(cal)
    if any(not is_clean(line) for line in text.split("\n")):  # belt and braces (issue 11.5)
        raise InputError(f"the {fmt} export would hold control characters; refusing it")
    return text
