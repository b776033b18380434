"""Tolerant readers of a calibration's optional fields: a malformed field reads as missing.

Calibrations come from this toolkit and from other tools; the report and the history read
their optional solver fields through these functions, so a field of the wrong type or a NaN
("not determined" in solver output) becomes ``None`` instead of an exception.
"""

from __future__ import annotations

import math
from typing import Any


def member(sec: Any, name: str) -> Any:
    """A typed member of a section that only some classes hold (a magnetometer's
    ``field_uT``, an accelerometer fit's ``coverage``), None where its class has none (a
    truth section, another tool's calibration)."""
    return getattr(sec, name, None)


def read_fields(raw: dict, **readers) -> dict[str, Any]:
    """``{key: reader(raw.get(key))}`` for each ``key=reader`` given, in that order."""
    return {key: read(raw.get(key)) for key, read in readers.items()}


def as_number(value: Any) -> float | None:
    """A finite number, else ``None`` (NaN marks "not determined" in solver output)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def as_int(value: Any) -> int | None:
    number = as_number(value)
    return None if number is None else int(number)


def as_text(value: Any) -> str | None:
    return None if value is None else str(value)


def as_list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else []


def as_vector(value: Any) -> list[float] | None:
    numbers = [as_number(v) for v in as_list(value)]
    if len(numbers) != 3 or any(n is None for n in numbers):
        return None
    return numbers


def scaled(value: float | None, factor: float | None) -> float | None:
    return None if value is None or factor is None else value * factor


def ratio(num: float | None, den: float | None) -> float | None:
    if num is None or den is None or den == 0:
        return None
    return num / den


# --------------------------------------------------------------------------------------------
# Rendering


def read_parameters(parameters: list | None) -> list[dict[str, Any]]:
    """A section's named parameters (finite numbers, else None); ``status`` ("measured" or
    "assumed", issue 27.3) where the section states it."""
    rows = []
    for p in parameters or []:
        if p.name is None:
            continue
        row = {"name": p.name, "value": as_number(p.value), "std": as_number(p.std),
               "unit": p.unit}  # fmt: skip
        if getattr(p, "status", None) is not None:
            row["status"] = p.status
        rows.append(row)
    return rows


def read_misalignment(angles: Any, stds: Any) -> list[dict[str, Any]]:
    if not isinstance(angles, dict):
        return []
    stds = stds if isinstance(stds, dict) else {}
    return [
        {"axes": str(axes), "angle": as_number(angle), "std": as_number(stds.get(axes))}
        for axes, angle in angles.items()
    ]


def read_sensitivity(values: Any, stds: Any, unit: Any) -> dict[str, Any] | None:
    numbers = [as_number(v) for v in as_list(values)]
    if not numbers:
        return None
    std = [as_number(v) for v in as_list(stds)]
    return {
        "values": numbers,
        "std": std if len(std) == len(numbers) else None,
        "unit": as_text(unit),
    }
