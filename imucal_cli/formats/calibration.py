"""Calibration JSON files (``shared/spec/session-format.md``, version 1): text to the model
(:mod:`.calibration_model`: :class:`Calibration`, :class:`SensorCalibration`, given here too)
and back.

:func:`calibration_from_json` (and :func:`read_calibration`) read imucal's JSON and the
calibrations of other tools (:mod:`.foreign_calibration`: Kalibr YAML, MaD Lab imucal JSON);
:func:`calibration_to_json` and :func:`write_calibration` write imucal's JSON.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from imucal_cli.errors import CalibrationFileError
from imucal_cli.formats.calibration_model import (
    FORMAT,
    FORMAT_VERSION,
    LOCAL_FIELD,
    MODEL_EQUATION,
    SENSOR_UNITS,
    SENSORS,
    Calibration,
    SensorCalibration,
)
from imucal_cli.formats.foreign_calibration import foreign_calibration
from imucal_cli.formats.inputs import read_text_input
from imucal_cli.formats.output import write_output
from imucal_cli.formats.text import clean_tree

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "LOCAL_FIELD",
    "MODEL_EQUATION",
    "SENSORS",
    "SENSOR_UNITS",
    "Calibration",
    "SensorCalibration",
    "calibration_from_json",
    "calibration_to_json",
    "read_calibration",
    "write_calibration",
]

def _jsonable(value: Any) -> Any:
    """Convert numpy arrays/scalars and tuples to JSON types; NaN and inf become None."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def calibration_to_json(cal: Calibration) -> str:
    """Return the calibration as pretty JSON text (indent 2, NaN and inf written as null)."""
    return json.dumps(_jsonable(cal.to_dict()), indent=2, allow_nan=False)


#: Nesting deeper than this is no calibration (and would exhaust Python's recursion).
MAX_DEPTH = 64


def _parse_int(text: str) -> int | float:
    """JSON integers: exact while a float can hold them, else a float (inf past 1e308), so
    that a 400-digit integer is refused as not finite instead of overflowing later."""
    return int(text) if len(text.lstrip("-")) <= 15 else float(text)


def _depth(value: Any) -> int:
    depth, level = 0, [value]
    while level:
        depth += 1
        if depth > MAX_DEPTH:
            return depth
        level = [
            child
            for item in level
            if isinstance(item, dict | list)
            for child in (item.values() if isinstance(item, dict) else item)
            if isinstance(child, dict | list)
        ]
    return depth


def calibration_from_json(text: str, source: str = "<string>") -> Calibration:
    """Parse and validate calibration JSON text.

    Strings are cleaned of control characters (:func:`~imucal_cli.formats.text.clean_text`);
    ``Infinity``, numbers past the float range and nesting deeper than :data:`MAX_DEPTH` are
    refused.  A calibration another tool wrote (Kalibr YAML, MaD Lab imucal JSON) is read too,
    as :mod:`imucal_cli.formats.foreign_calibration` describes.

    Raises
    ------
    CalibrationFileError
        Invalid JSON (the message gives the line) or a document that breaks the format.
    """
    try:
        foreign = foreign_calibration(text, source)  # issue 15.3
    except (RecursionError, ValueError):  # hostile JSON: the strict parse below says what
        foreign = None
    if foreign is not None:
        return _cleaned(foreign)
    try:
        d = json.loads(text, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise CalibrationFileError(
            f"{source}: invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except RecursionError:
        raise CalibrationFileError(f"{source}: JSON nested too deeply") from None
    except ValueError as exc:
        raise CalibrationFileError(f"{source}: invalid JSON ({exc})") from None
    if _depth(d) > MAX_DEPTH:
        raise CalibrationFileError(f"{source}: JSON nested deeper than {MAX_DEPTH} levels")
    cal = Calibration.from_dict(clean_tree(d), source=source)
    where = _first_infinite(d)
    if where is not None:
        raise CalibrationFileError(f"{source}: {where} is not a finite number")
    return cal


def _cleaned(cal: Calibration) -> Calibration:
    """Every free string of a calibration read from another tool's file made printable."""
    cal.session = None if cal.session is None else clean_tree(cal.session)
    cal.created = clean_tree(cal.created)
    cal.extra = clean_tree(cal.extra)
    for section in (cal.accel, cal.gyro):
        if section is not None:
            section.solver = clean_tree(section.solver)
            section.extra = clean_tree(section.extra)
    return cal


def _first_infinite(value: Any, path: str = "") -> str | None:
    """JSON path of the first infinite number (``Infinity``, or a number past the float
    range such as a 400-digit integer), or None.  NaN stays: it marks an undetermined value
    (a standard deviation the solver could not compute), and the standard fields refuse it."""
    if isinstance(value, float) and math.isinf(value):
        return path or "the document"
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(
        value, list) else ()  # fmt: skip
    for key, child in items:
        child_path = f"{path}[{key}]" if isinstance(key, int) else f"{path}.{key}".lstrip(".")
        found = _first_infinite(child, child_path)
        if found is not None:
            return found
    return None


def read_calibration(path: str | os.PathLike) -> Calibration:
    """Read and validate a calibration JSON file (or Kalibr YAML, MaD Lab imucal JSON: see
    :func:`calibration_from_json`).

    Raises
    ------
    CalibrationFileError
        Missing or unreadable file, not a regular file, too large, not UTF-8, invalid JSON, or
        not a valid calibration.
    """
    text = read_text_input(path, what="calibration file", error=CalibrationFileError)
    return calibration_from_json(text, source=str(path))


def write_calibration(
    path: str | os.PathLike,
    cal: Calibration,
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike | None] = (),
) -> Path:
    """Write a calibration JSON file through :func:`~imucal_cli.formats.output.write_output`
    (a fresh temporary file renamed into place; an existing file only with ``force``, never
    one of ``inputs``).

    Raises
    ------
    CalibrationFileError
        The calibration would not read back as valid (e.g. NaN in ``bias``).
    OutputError
        The file exists (without ``force``), is an input, or cannot be written.
    """
    src = str(path)
    text = calibration_to_json(cal)
    calibration_from_json(text, source=src)  # never write what cannot be read back
    return write_output(path, text + "\n", force=force, inputs=inputs)
