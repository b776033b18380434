"""History: how the parameters of each sensor drift across its calibrations.

:func:`build_history` groups calibrations by their ``sensor`` field and follows each tracked
figure over time; :func:`render_history` draws the result.

Like with like (issue 10.8): a figure is compared only between calibrations of the same
*basis*: the same solver, model variant, input units and, for an accelerometer, the same
gravity (a sensitivity fitted with g = 9.81 m/s^2 differs from one fitted with 9.80665 by 0.035 %
without the sensor changing).  A calibration of another basis starts its own comparison and is
never reported as drift against the others.  The same quantity has one name whatever the solver:
``b_<axis>`` (bias, raw units), ``sensitivity <axis>`` (raw units per SI unit; the
factorization solver's ``gain_<axis>``), ``misalignment <pair>`` (angle between two sensitivity
axes minus 90 degrees; the factorization solver's ``angles_deg``).  Other named parameters (the
model's matrix elements, ``k_xy``, ``m_xx``) keep their names; they only exist within one basis.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from rich import box
from rich.console import Console
from rich.rule import Rule
from rich.table import Table
from rich.text import Text

from imucal_cli.model.calibration import Calibration, SensorCalibration

from .fields import (
    as_list,
    as_number,
    member,
    read_misalignment,
    read_parameters,
    read_sensitivity,
)
from .fmt import MISSING, fmt_std
from .out import show_bullets, show_table, show_text

HISTORY_FORMAT = "imucal-history"

DRIFT_SIGMAS = 3.0
"""A change from the reference calibration (the first of the same basis that has the figure)
larger than this many combined standard deviations (``sqrt(std_ref^2 + std_now^2)``) is flagged
as drifted."""


# --------------------------------------------------------------------------------------------
# What is tracked, under one name per quantity


def _axis_names(sec: SensorCalibration) -> list[str]:
    n = np.asarray(sec.bias, dtype=float).size
    fz = member(sec, "factorization")
    names = list(fz.axis_names or []) if fz is not None else []
    if len(names) == n:
        return names
    return list("xyz") if n == 3 else [str(i + 1) for i in range(n)]


def tracked_rows(sec: SensorCalibration) -> list[dict[str, Any]]:
    """``name``, ``unit``, ``value``, ``std`` of each tracked figure of one section (see the
    module notes for the names); without named parameters, the bias and matrix elements."""
    rows = [
        {"name": p["name"], "unit": p["unit"], "value": p["value"], "std": p["std"]}
        for p in read_parameters(sec.parameters)
    ]
    if not rows:
        units_in = sec.units_in or "raw units"
        rows += [
            {"name": f"b_{a}", "unit": units_in, "value": as_number(v), "std": None}
            for a, v in zip(_axis_names(sec), np.asarray(sec.bias, float).ravel(), strict=True)
        ]
        matrix = np.asarray(sec.matrix, dtype=float)
        rows += [
            {"name": f"matrix[{i}][{j}]", "unit": f"{sec.units} per {units_in}",
             "value": as_number(matrix[i, j]), "std": None}
            for i in range(matrix.shape[0]) for j in range(matrix.shape[1])
        ]  # fmt: skip
    rows = _sensitivity_rows(sec, rows)
    return rows + _misalignment_rows(sec)


def _sensitivity_rows(sec: SensorCalibration, rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Append ``sensitivity <axis>``; a ``gain_<axis>`` parameter is the same quantity."""
    gains = {r["name"][len("gain_") :]: r for r in rows if r["name"].startswith("gain_")}
    rows = [r for r in rows if not r["name"].startswith("gain_")]
    sens = read_sensitivity(sec.sensitivity, sec.sensitivity_std, sec.sensitivity_unit)
    names = _axis_names(sec)
    if sens is None or len(sens["values"]) != len(names):
        return rows + [{**r, "name": f"sensitivity {a}"} for a, r in gains.items()]
    stds = sens["std"] or [None] * len(names)
    for a, v, s in zip(names, sens["values"], stds, strict=True):
        if s is None and a in gains:
            s = gains[a]["std"]
        rows.append({"name": f"sensitivity {a}", "unit": sens["unit"], "value": v, "std": s})
    return rows


def _misalignment_rows(sec: SensorCalibration) -> list[dict[str, Any]]:
    """``misalignment <pair>``, deg: stated angles, else the factorization's ``angles_deg``."""
    stated = read_misalignment(sec.misalignment_deg, sec.misalignment_std_deg)
    if stated:
        return [{"name": f"misalignment {m['axes']}", "unit": "deg", "value": m["angle"],
                 "std": m["std"]} for m in stated]  # fmt: skip
    fz = member(sec, "factorization")
    if fz is None:
        return []
    angles, stds = as_list(fz.angles_deg), as_list(fz.angles_std_deg)
    names = _axis_names(sec)
    rows = []
    for i in range(min(len(names), len(angles))):
        for j in range(i + 1, min(len(names), len(as_list(angles[i])))):
            value = as_number(as_list(angles[i])[j])
            std_row = as_list(stds[i]) if i < len(stds) else []
            std = as_number(std_row[j]) if j < len(std_row) else None
            rows.append({"name": f"misalignment {names[i]}{names[j]}", "unit": "deg",
                         "value": None if value is None else value - 90.0, "std": std})  # fmt: skip
    return rows


def section_basis(kind: str, sec: SensorCalibration) -> str:
    """What makes two calibrations of a section comparable: solver, model, units, gravity."""
    parts = [sec.solver]
    if sec.variant:
        parts.append(sec.variant)
    parts.append(f"from {sec.units_in or 'raw units'}")
    gravity = as_number(member(sec, "gravity"))
    if kind == "accel" and gravity is not None:
        parts.append(f"g = {gravity:.6g} m/s^2")
    frame = sec.frame
    if kind == "gyro" and frame:  # the gyro is calibrated in the accelerometer's frame
        parts.append(f"in {frame}")
    return ", ".join(parts)


# --------------------------------------------------------------------------------------------
# Building


def build_history(cals: list[Calibration]) -> dict[str, Any]:
    """How the parameters of each sensor drift between its calibrations.

    Calibrations are grouped by their ``sensor`` field and ordered by ``created``.  For each
    sensor with at least two, every tracked figure (see the module notes) of each section gets
    its values and standard deviations over time and, per calibration, the change from its
    reference (the first calibration of the same basis that has the figure), that change in
    combined standard deviations (``z``) and a ``drifted`` flag when ``|z| > DRIFT_SIGMAS``.

    Parameters
    ----------
    cals
        Calibrations as read (nothing is re-solved).

    Returns
    -------
    dict
        ``format`` (``imucal-history``), ``drift_sigmas``, ``sensors`` (one entry per sensor with
        >= 2 calibrations: ``sensor``, ``calibrations`` (``created``, ``session``), ``sections``
        (``{"accel": {"solvers": [...], "bases": [...], "not_compared": [...], "rows": [...]}}``;
        a set of several IMUs adds each other IMU's, ``"imu1 accel"``, ...),
        each row ``name``, ``unit``, ``values``, ``std``, ``reference`` (the first calibration
        that has the figure), ``compared_with`` (per calibration, the index of its reference, or
        None), ``change``, ``z``, ``drifted``), ``drifted`` (``"accel b_x"``...)), ``single``
        (sensors with one calibration) and ``without_sensor`` (calibrations that do not name
        their sensor).
    """
    groups: dict[str, list[Calibration]] = {}
    without = 0
    for cal in cals:
        sensor = cal.sensor
        if not sensor:
            without += 1
            continue
        groups.setdefault(sensor, []).append(cal)
    sensors = [_sensor_history(name, members) for name, members in groups.items()
               if len(members) >= 2]  # fmt: skip
    return {
        "format": HISTORY_FORMAT,
        "format_version": 2,
        "drift_sigmas": DRIFT_SIGMAS,
        "sensors": sensors,
        "single": [name for name, members in groups.items() if len(members) < 2],
        "without_sensor": without,
    }


def _sensor_history(sensor: str, members: list[Calibration]) -> dict[str, Any]:
    members = sorted(members, key=lambda c: str(c.created))
    sections: dict[str, Any] = {}
    drifted: list[str] = []
    for key, kind, secs in _series(members):
        sections[key] = _section_history(kind, secs, [c.session for c in members])
        drifted += [f"{key} {r['name']}" for r in sections[key]["rows"] if any(r["drifted"])]
    return {
        "sensor": sensor,
        "calibrations": [{"created": c.created, "session": c.session} for c in members],
        "sections": sections,
        "drifted": drifted,
    }


def _series(members: list[Calibration]) -> list[tuple[str, str, list]]:
    """``(key, kind, sections)`` of each section kind the calibrations hold, one section (or
    None) per calibration: the reference IMU's ``accel`` and ``gyro``, then, in a set of
    several IMUs (``imus``), each other IMU's (``imu1 accel``, ...), the IMUs in the order the
    calibrations first name them."""
    names = list(dict.fromkeys(n for c in members for n in (c.imus or {})))
    out = []
    for imu in (None, *names):
        for kind in ("accel", "gyro"):
            holders = members if imu is None else [(c.imus or {}).get(imu) for c in members]
            secs = [None if h is None else getattr(h, kind) for h in holders]
            if any(s is not None for s in secs):
                out.append((kind if imu is None else f"{imu} {kind}", kind, secs))
    return out


def _section_history(
    kind: str, secs: list[SensorCalibration | None], sessions: list[str | None]
) -> dict[str, Any]:
    """``solvers``, ``bases``, ``not_compared`` and ``rows`` of one section kind across the
    calibrations of one sensor."""
    bases = [None if s is None else section_basis(kind, s) for s in secs]
    per_cal = [{} if s is None else {r["name"]: r for r in tracked_rows(s)} for s in secs]
    names: list[str] = []
    for table in per_cal:
        names += [n for n in table if n not in names]
    rows = []
    for name in names:
        found = [t.get(name) for t in per_cal]
        unit = next(r["unit"] for r in found if r is not None)
        values = [None if r is None else r["value"] for r in found]
        stds = [None if r is None else r["std"] for r in found]
        rows.append({"name": name, "unit": unit, "values": values, "std": stds,
                     **compare_with_reference(values, stds, bases)})  # fmt: skip
    return {
        "solvers": [None if s is None else s.solver for s in secs],
        "bases": bases,
        "not_compared": _not_compared(bases, sessions),
        "rows": rows,
    }


def compare_with_reference(
    values: list[float | None], stds: list[float | None], bases: list[str | None]
) -> dict[str, Any]:
    """Per calibration: its reference (``compared_with``: the first calibration of the same
    basis with this figure), the ``change`` from it, in combined std (``z``), ``drifted``."""
    present = [i for i, v in enumerate(values) if v is not None]
    compared, change, z, flags = [], [], [], []
    for i, (v, s) in enumerate(zip(values, stds, strict=True)):
        ref = next((j for j in present if j <= i and bases[j] == bases[i]), None)
        d = zz = None
        if v is not None and ref is not None:
            d = v - values[ref]
            both = s is not None and stds[ref] is not None
            combined = math.hypot(s, stds[ref]) if both else None
            zz = None if not combined else d / combined
        compared.append(None if d is None else ref)
        change.append(d)
        z.append(zz)
        flags.append(zz is not None and abs(zz) > DRIFT_SIGMAS)
    return {"reference": present[0], "compared_with": compared, "change": change, "z": z,
            "drifted": flags}  # fmt: skip


def _not_compared(bases: list[str | None], sessions: list[str | None]) -> list[str]:
    """One line per calibration whose basis differs from the first one's: why it is not compared
    with the calibrations before it."""
    first = next((b for b in bases if b is not None), None)
    out = []
    for i, b in enumerate(bases):
        if b is not None and b != first:
            who = sessions[i] or f"calibration {i + 1}"
            out.append(f"{who} ({b}) is compared only with calibrations of the same basis, "
                       f"not with {first}")  # fmt: skip
    return out


# --------------------------------------------------------------------------------------------
# Rendering


def render_history(history: dict[str, Any], console: Console) -> None:
    """Draw a history dict (from :func:`build_history`): per sensor and section, a row per
    figure, the first value ± std, then each later calibration's change and ``z``."""
    sigmas = history["drift_sigmas"]
    for entry in history["sensors"]:
        cals = entry["calibrations"]
        console.print(
            Rule(Text(f"history of {entry['sensor']}: {len(cals)} calibrations"), style="bold")
        )
        for kind, section in entry["sections"].items():
            show_table(console, _section_table(kind, section, cals, sigmas))
            if section.get("not_compared"):
                show_bullets(console, section["not_compared"], f"{kind}: different basis", "dim")
        if entry["drifted"]:
            show_bullets(console, entry["drifted"], "Drifted beyond the uncertainty", "bold red")
        else:
            show_text(console, f"no parameter changed by more than {sigmas:g} combined std")
    if history["single"]:
        single = ", ".join(history["single"])
        show_text(console, Text(f"one calibration only (no history): {single}", style="dim"))
    if history["without_sensor"]:
        text = (
            f"{history['without_sensor']} calibration(s) name no sensor and are left out "
            "(capture or simulate with --sensor)"
        )
        show_text(console, Text(text, style="dim"))
    if not history["sensors"]:
        text = "no sensor has two or more calibrations: nothing to compare"
        show_text(console, Text(text, style="yellow"))


def _section_table(kind: str, section: dict[str, Any], cals: list[dict], sigmas: float) -> Table:
    title = (
        f"{kind}: change from the reference calibration (z: in combined std; drifted when "
        f"|z| > {sigmas:g}; compared only within one solver, model, units and gravity)"
    )
    table = Table(title=Text(title), box=box.SIMPLE, title_justify="left", pad_edge=False)
    table.add_column("parameter", no_wrap=True)
    table.add_column("unit", max_width=18, overflow="fold")
    for i, cal in enumerate(cals):
        when = str(cal["created"] or "?")[:16].replace("T", " ")
        head = f"{when}\n{cal['session'] or ''}"
        table.add_column(head if i == 0 else f"{head}\nchange (z)", justify="right", no_wrap=True)
    for row in section["rows"]:
        cells = [Text(row["name"]), Text(row["unit"] or "")]
        compared = row.get("compared_with") or [row.get("reference", 0)] * len(cals)
        for i in range(len(cals)):
            cells.append(_cell(row, i, compared[i]))
        table.add_row(*cells)
    solvers = {s for s in section["solvers"] if s}
    if len(solvers) > 1:
        table.caption = Text(f"different solvers: {', '.join(sorted(solvers))}")
        table.caption_justify = "left"
    return table


def _cell(row: dict[str, Any], i: int, ref: int | None) -> Text:
    value, std = row["values"][i], row["std"][i]
    if value is None or ref is None:
        return Text(MISSING)
    if ref == i:  # a reference: its value
        return Text(fmt_std(value, std) + ("" if i == row["reference"] else " (ref)"))
    d, z = row["change"][i], row["z"][i]
    text = f"{d:+.3g}" + ("" if z is None else f" ({z:+.1f})")
    if row["drifted"][i]:
        return Text(text + " drifted", style="bold red")
    return Text(text)
