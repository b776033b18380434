"""Exporters: a calibration written in another tool's format, one module per format.

Each exporter is a function of a :class:`~imucal_cli.formats.calibration.Calibration`
returning text; :mod:`imucal_cli.use.export` chooses one. This module holds what they share.
"""

from __future__ import annotations

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration, SensorCalibration
from imucal_cli.formats.text import clean_text

SENSORS = ("accel", "gyro")


def sections(cal: Calibration) -> list[tuple[str, SensorCalibration]]:
    return [(name, getattr(cal, name)) for name in SENSORS if getattr(cal, name) is not None]


def units_in(sec: SensorCalibration) -> str:
    unit = sec.extra.get("units_in")
    return unit if isinstance(unit, str) and unit != "unknown" else "raw units"


def one_line(text: object) -> str:
    """Free text (a sensor name, a solver) for a comment in an export: one printable line,
    control characters written as escapes (see :mod:`imucal_cli.formats.text`)."""
    return " ".join(clean_text(str(text)).split())


def check_finite(name: str, what: str, values: np.ndarray) -> np.ndarray:
    """Refuse NaN or infinite numbers (a matrix of 1e200 times a bias overflows to inf): an
    export must never carry a number the target would read as inf or nan."""
    values = np.asarray(values, dtype=np.float64)
    with np.errstate(all="ignore"):
        finite = np.isfinite(values).all()
    if not finite:
        raise InputError(
            f"the {name} {what} has a value that is not a finite number "
            f"({values.ravel()[~np.isfinite(values.ravel())][0]!r}); refusing to export it"
        )
    return values
