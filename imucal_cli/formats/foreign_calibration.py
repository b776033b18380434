"""Calibrations made by other tools, read as imucal calibrations so that ``apply``, ``report``,
``export`` and the history work with them (issue 15.3).

:func:`~imucal_cli.formats.calibration.calibration_from_json` (so ``read_calibration`` and
every reader of calibrations) calls :func:`foreign_calibration` first; both build the
model of :mod:`~imucal_cli.formats.calibration_model`.  Two formats:

**Kalibr results YAML** (``imu0:`` with ``model: scale-misalignment``; ``IccSensors.py``)::

    p_a = M_a @ a_i + b_a
    p_w = M_g @ C_gyro_i @ w_i + A @ C_gyro_i @ a_i + b_w

``p`` what the ROS driver published (m/s^2, rad/s).  In imucal's form, with the frame turned
back by ``T_i_b`` (``a_b = C_i_b^T a_i``; the identity for Kalibr's own imu0)::

    accel: matrix = C_i_b^T inv(M_a),            bias = b_a
    gyro:  matrix = C_i_b^T C_gyro_i^T inv(M_g),  bias = b_w,  g_sensitivity = A C_gyro_i C_i_b

(the rotations are inverted as written, so a file rounded to a few digits still applies its
own numbers exactly; one further than 1e-3 from a rotation is refused).

Kalibr estimates its biases as time-varying splines and writes none: the biases are those of
``accelerometer_bias``/``gyroscope_bias`` when present (imucal's Kalibr export writes them),
else zero, with a warning.  The ``size-effect`` lever arms (``rx_i`` ...) act only under
rotation and have no place in imucal's model: non-zero ones are dropped with a warning.

**MaD Lab's imucal JSON** (``mad-lab-fau/imucal``, ``FerrarisCalibrationInfo`` and
``TurntableCalibrationInfo``: ``K_a``, ``R_a``, ``b_a``, ``K_g``, ``R_g``, ``K_ga``, ``b_g``)::

    acc = inv(R_a) inv(K_a) (acc_raw - b_a)                       in acc_unit
    gyr = inv(R_g) inv(K_g) (gyr_raw - K_ga acc - b_g)            in gyr_unit

so ``matrix = inv(R) inv(K)`` times the factor from its output unit to SI (deg/s -> rad/s,
g -> m/s^2), ``bias = b``, and the gyro's ``g_sensitivity = K_ga`` (per m/s^2).  Raw units
``a.u.`` become ``counts``.

Neither format records when or on which part it was made: ``created`` is the file's
modification time (``created_basis`` says so), ``sensor`` is not set.
"""

from __future__ import annotations

import json
import math
import os
from datetime import UTC, datetime
from typing import Any

import numpy as np
import yaml

from imucal_cli.errors import CalibrationFileError
from imucal_cli.formats.calibration_model import MODEL_EQUATION, Calibration, SensorCalibration

__all__ = ["foreign_calibration", "from_kalibr", "from_mad_lab"]

_G0 = 9.80665
_TO_SI = {"m/s^2": 1.0, "g": _G0, "rad/s": 1.0, "deg/s": math.pi / 180.0}
_RAW_UNITS = {"a.u.": "counts", "au": "counts", "counts": "counts", "lsb": "counts",
              "m/s^2": "m/s^2", "g": "g", "deg/s": "deg/s", "rad/s": "rad/s"}  # fmt: skip


def _mtime_iso(path: str | os.PathLike | None) -> str:
    try:
        stamp = os.stat(path).st_mtime if path else None
    except OSError:
        stamp = None
    when = datetime.fromtimestamp(stamp, UTC) if stamp is not None else datetime.now(UTC)
    return when.strftime("%Y-%m-%dT%H:%M:%SZ")


def _matrix(
    d: dict, key: str, shape: tuple[int, ...], fail, default=None, where: str = ""
) -> np.ndarray:
    name = where + key
    if key not in d or d[key] is None:
        if default is not None:
            return default
        raise fail(f"{name!r} is missing")
    try:
        value = np.asarray(d[key], dtype=float)
    except (TypeError, ValueError):
        value = np.empty(0)
    if value.shape != shape or not np.isfinite(value).all():
        raise fail(f"{name!r} must be {' x '.join(map(str, shape))} finite numbers")
    return value


def _inverse(m: np.ndarray, key: str, fail) -> np.ndarray:
    if not np.isfinite(np.linalg.cond(m)) or np.linalg.cond(m) > 1e12:
        raise fail(f"{key!r} is singular")
    return np.linalg.inv(m)


def _imported(cal: Calibration, fmt: str, source: str, path, warnings: list[str]) -> Calibration:
    cal.extra.update({
        "imported_from": {"format": fmt, "file": source},
        "created_basis": "the imported file's modification time (the format records no date)",
    })  # fmt: skip
    for name in ("accel", "gyro"):
        sec = getattr(cal, name)
        if sec is not None:
            sec.extra.setdefault("model", MODEL_EQUATION)
            sec.extra.setdefault("warnings", []).extend(warnings)
    return cal


# --------------------------------------------------------------------------------------------
# Kalibr
# --------------------------------------------------------------------------------------------


def from_kalibr(doc: Any, source: str, path=None) -> Calibration:
    """An imucal :class:`Calibration` from Kalibr's ``scale-misalignment`` IMU YAML (parsed).

    Raises
    ------
    CalibrationFileError
        Another model, no intrinsics, or malformed matrices; one line naming ``source``.
    """

    def fail(problem: str) -> CalibrationFileError:
        return CalibrationFileError(f"{source}: Kalibr IMU file: {problem}")

    imus = sorted(k for k in doc if isinstance(k, str) and k.startswith("imu"))
    warnings: list[str] = []
    if imus:
        imu = doc[imus[0]]
        if len(imus) > 1:
            warnings.append(f"the file holds {', '.join(imus)}; {imus[0]} was read")
    else:
        imu = doc
    if not isinstance(imu, dict):
        raise fail(f"{imus[0] if imus else 'the document'} must be a mapping")
    if "Tw" in imu or "Ta" in imu:
        raise fail("an OpenVINS chain file (Tw, Ta): import the Kalibr results it came from")
    model = imu.get("model", "calibrated")
    if not isinstance(model, str) or not model.startswith("scale-misalignment"):
        raise fail(f"model {model!r} holds no intrinsics (only scale-misalignment does); "
                   "this is a noise file, not a calibration")  # fmt: skip
    acc, gyr = imu.get("accelerometers"), imu.get("gyroscopes")
    if not isinstance(acc, dict) or not isinstance(gyr, dict):
        raise fail("'accelerometers' and 'gyroscopes' with their matrices are missing")
    M_a = _matrix(acc, "M", (3, 3), fail, where="accelerometers.")
    M_g = _matrix(gyr, "M", (3, 3), fail, where="gyroscopes.")
    A = _matrix(gyr, "A", (3, 3), fail, default=np.zeros((3, 3)), where="gyroscopes.")
    C = _matrix(gyr, "C_gyro_i", (3, 3), fail, default=np.eye(3), where="gyroscopes.")
    if not np.allclose(C @ C.T, np.eye(3), atol=1e-3) or np.linalg.det(C) < 0:
        raise fail("'gyroscopes.C_gyro_i' is not a rotation matrix")
    T = _matrix(imu, "T_i_b", (4, 4), fail, default=np.eye(4))
    C_i_b = T[:3, :3]
    if not np.allclose(C_i_b @ C_i_b.T, np.eye(3), atol=1e-3) or np.linalg.det(C_i_b) < 0:
        raise fail("the rotation of 'T_i_b' is not a rotation matrix")
    biases = {}
    for key in ("accelerometer_bias", "gyroscope_bias"):
        if key in imu:
            biases[key] = _matrix(imu, key, (3,), fail)
    if len(biases) < 2:
        warnings.append("Kalibr writes no fixed bias (it estimates time-varying biases): a "
                        "missing bias is zero; remove the bias at start-up")  # fmt: skip
    if any(np.any(np.asarray(acc.get(k, [0, 0, 0]), float)) for k in ("rx_i", "ry_i", "rz_i")):
        warnings.append("the size-effect lever arms (rx_i, ry_i, rz_i) are dropped: imucal's "
                        "model has no term for them")  # fmt: skip
    accel = SensorCalibration(
        "kalibr", "m/s^2", biases.get("accelerometer_bias", np.zeros(3)),
        np.linalg.inv(C_i_b) @ _inverse(M_a, "accelerometers.M", fail), None,
        {"units_in": "m/s^2"},
    )  # fmt: skip
    gyro = SensorCalibration(
        "kalibr", "rad/s", biases.get("gyroscope_bias", np.zeros(3)),
        np.linalg.inv(C_i_b) @ np.linalg.inv(C) @ _inverse(M_g, "gyroscopes.M", fail), None,
        {"units_in": "rad/s"},
    )  # fmt: skip
    G = A @ C @ C_i_b
    if G.any():
        gyro.extra["g_sensitivity"] = G.tolist()
    cal = Calibration(accel=accel, gyro=gyro, session=None, created=_mtime_iso(path))
    return _imported(cal, f"kalibr {model}", source, path, warnings)


# --------------------------------------------------------------------------------------------
# MaD Lab imucal
# --------------------------------------------------------------------------------------------


def from_mad_lab(doc: dict, source: str, path=None) -> Calibration:
    """An imucal :class:`Calibration` from MaD Lab's ``imucal`` calibration JSON (parsed).

    Raises
    ------
    CalibrationFileError
        Missing or malformed fields, or units it cannot convert; one line naming ``source``.
    """

    def fail(problem: str) -> CalibrationFileError:
        return CalibrationFileError(f"{source}: MaD Lab imucal calibration: {problem}")

    warnings: list[str] = []
    units = {}
    for key, default in (("acc_unit", "m/s^2"), ("gyr_unit", "deg/s")):
        unit = doc.get(key)
        if unit is None:
            warnings.append(f"{key} not stated: {default} assumed (imucal's default)")
            unit = default
        if unit not in _TO_SI:
            raise fail(f"{key} {unit!r} cannot be converted to SI (m/s^2, g, rad/s, deg/s)")
        units[key] = unit
    raw = {}
    for key in ("from_acc_unit", "from_gyr_unit"):
        unit = doc.get(key)
        raw[key] = _RAW_UNITS.get(str(unit).lower(), "unknown") if unit is not None else "unknown"
    a_factor, g_factor = _TO_SI[units["acc_unit"]], _TO_SI[units["gyr_unit"]]
    K_a, R_a = _matrix(doc, "K_a", (3, 3), fail), _matrix(doc, "R_a", (3, 3), fail)
    K_g, R_g = _matrix(doc, "K_g", (3, 3), fail), _matrix(doc, "R_g", (3, 3), fail)
    b_a, b_g = _matrix(doc, "b_a", (3,), fail), _matrix(doc, "b_g", (3,), fail)
    K_ga = _matrix(doc, "K_ga", (3, 3), fail, default=np.zeros((3, 3)))
    cal_type = str(doc.get("cal_type", "imucal"))
    accel = SensorCalibration(
        f"mad-lab-{cal_type.lower()}", "m/s^2", b_a,
        a_factor * _inverse(R_a, "R_a", fail) @ _inverse(K_a, "K_a", fail), None,
        {"units_in": raw["from_acc_unit"]},
    )  # fmt: skip
    gyro = SensorCalibration(
        f"mad-lab-{cal_type.lower()}", "rad/s", b_g,
        g_factor * _inverse(R_g, "R_g", fail) @ _inverse(K_g, "K_g", fail), None,
        {"units_in": raw["from_gyr_unit"]},
    )  # fmt: skip
    if K_ga.any():
        gyro.extra["g_sensitivity"] = (K_ga / a_factor).tolist()  # K_ga acts on acc in acc_unit
    extra = {}
    if isinstance(doc.get("comment"), str) and doc["comment"].strip():
        extra["comment"] = doc["comment"]
    cal = Calibration(accel=accel, gyro=gyro, session=None, created=_mtime_iso(path), extra=extra)
    return _imported(cal, f"mad-lab imucal {cal_type}", source, path, warnings)


def _is_mad_lab(doc: Any) -> bool:
    return isinstance(doc, dict) and "K_a" in doc and "R_a" in doc and "b_a" in doc


def _is_kalibr(doc: Any) -> bool:
    if not isinstance(doc, dict):
        return False
    imu = next((doc[k] for k in sorted(doc) if isinstance(k, str) and k.startswith("imu")), doc)
    return isinstance(imu, dict) and ("accelerometers" in imu or "model" in imu
                                      or "accelerometer_noise_density" in imu)  # fmt: skip


def foreign_calibration(text: str, source: str, path=None) -> Calibration | None:
    """The calibration in ``text`` if it is one of the foreign formats, else None.

    Raises
    ------
    CalibrationFileError
        The text is one of them but cannot be read as a calibration.
    """
    path = source if path is None else path
    try:
        doc = json.loads(text)
    except json.JSONDecodeError:
        doc = None
        stripped = text.lstrip()
        if stripped.startswith("%YAML:1.0"):  # OpenCV's header (OpenVINS's copy of the file)
            stripped = stripped.split("\n", 1)[1] if "\n" in stripped else ""
        try:
            doc = yaml.safe_load(stripped)
        except Exception:  # noqa: BLE001 - not YAML either: not ours to read
            return None
        if _is_kalibr(doc):
            return from_kalibr(doc, source, path)
        return None
    if _is_mad_lab(doc):
        return from_mad_lab(doc, source, path)
    return None


