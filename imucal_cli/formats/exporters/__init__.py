"""Exporters: a calibration written in another tool's format, one module per format.

Each exporter is a function of a :class:`~imucal_cli.formats.calibration.Calibration`
returning text; :mod:`imucal_cli.use.export` chooses one. This module holds what they share.
"""

from __future__ import annotations

from imucal_cli.formats.calibration import Calibration, SensorCalibration

SENSORS = ("accel", "gyro")


def sections(cal: Calibration) -> list[tuple[str, SensorCalibration]]:
    return [(name, getattr(cal, name)) for name in SENSORS if getattr(cal, name) is not None]


def units_in(sec: SensorCalibration) -> str:
    unit = sec.extra.get("units_in")
    return unit if isinstance(unit, str) and unit != "unknown" else "raw units"


def one_line(text: object) -> str:
    return " ".join(str(text).split())
