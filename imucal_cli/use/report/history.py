"""History: how the parameters of each sensor drift across its calibrations.

:func:`build_history` groups calibrations by their ``sensor`` field and compares each tracked
figure with the first calibration that has it; :func:`render_history` draws the result.
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

from imucal_cli.formats.calibration import Calibration, SensorCalibration

from .fields import as_number, as_text, read_misalignment, read_parameters, read_sensitivity
from .fmt import MISSING, fmt_std
from .render import bullet_panel

HISTORY_FORMAT = "imucal-history"

DRIFT_SIGMAS = 3.0
"""A change from the first calibration larger than this many combined standard deviations
(``sqrt(std_first^2 + std_now^2)``) is flagged as drifted."""


def _history_rows(sec: SensorCalibration) -> list[dict[str, Any]]:
    """``name``, ``unit``, ``value``, ``std`` of each tracked figure of one section: the named
    parameters, sensitivities and misalignment angles; without named parameters, the bias and
    matrix elements (no std)."""
    extra = sec.extra or {}
    rows = [
        {"name": p["name"], "unit": p["unit"], "value": p["value"], "std": p["std"]}
        for p in read_parameters(extra.get("parameters"))
    ]
    if not rows:
        bias = np.asarray(sec.bias, dtype=float).ravel()
        units_in = as_text(extra.get("units_in")) or "raw units"
        rows += [
            {"name": f"bias[{i}]", "unit": units_in, "value": as_number(v), "std": None}
            for i, v in enumerate(bias)
        ]
        matrix = np.asarray(sec.matrix, dtype=float)
        rows += [
            {"name": f"matrix[{i}][{j}]", "unit": f"{sec.units} per {units_in}",
             "value": as_number(matrix[i, j]), "std": None}
            for i in range(matrix.shape[0]) for j in range(matrix.shape[1])
        ]  # fmt: skip
    sens = read_sensitivity(extra.get("sensitivity"), extra.get("sensitivity_std"),
                        extra.get("sensitivity_unit"))  # fmt: skip
    if sens:
        names = "xyz" if len(sens["values"]) == 3 else [str(i) for i in range(len(sens["values"]))]
        stds = sens["std"] or [None] * len(sens["values"])
        rows += [
            {"name": f"sensitivity {a}", "unit": sens["unit"], "value": v, "std": s}
            for a, v, s in zip(names, sens["values"], stds, strict=True)
        ]
    for m in read_misalignment(extra.get("misalignment_deg"), extra.get("misalignment_std_deg")):
        rows.append(
            {"name": f"misalignment {m['axes']}", "unit": "deg", "value": m["angle"],
             "std": m["std"]}
        )  # fmt: skip
    return rows


def build_history(cals: list[Calibration]) -> dict[str, Any]:
    """How the parameters of each sensor drift between its calibrations.

    Calibrations are grouped by their ``sensor`` field and ordered by ``created``.  For each
    sensor with at least two, every tracked figure (see :func:`_history_rows`) of each section
    gets its values and standard deviations over time, the change from the first calibration,
    that change in combined standard deviations (``z``) and a ``drifted`` flag when
    ``|z| > DRIFT_SIGMAS``.

    Parameters
    ----------
    cals
        Calibrations as read (nothing is re-solved).

    Returns
    -------
    dict
        ``format`` (``imucal-history``), ``drift_sigmas``, ``sensors`` (one entry per sensor with
        >= 2 calibrations: ``sensor``, ``calibrations`` (``created``, ``session``), ``sections``
        (``{"accel": {"solvers": [...], "rows": [...]}}``, each row ``name``, ``unit``,
        ``values``, ``std``, ``change``, ``z``, ``drifted``), ``drifted`` (``"accel b_x"``...)),
        ``single`` (sensors with one calibration) and ``without_sensor`` (calibrations that do
        not name their sensor).
    """
    groups: dict[str, list[Calibration]] = {}
    without = 0
    for cal in cals:
        sensor = as_text((cal.extra or {}).get("sensor"))
        if not sensor:
            without += 1
            continue
        groups.setdefault(sensor, []).append(cal)
    sensors, single = [], []
    for sensor, members in groups.items():
        if len(members) < 2:
            single.append(sensor)
            continue
        members = sorted(members, key=lambda c: str(c.created))
        sections: dict[str, Any] = {}
        drifted: list[str] = []
        for kind in ("accel", "gyro"):
            secs = [getattr(c, kind) for c in members]
            if all(s is None for s in secs):
                continue
            sections[kind] = _section_history(secs)
            drifted += [f"{kind} {r['name']}" for r in sections[kind]["rows"] if any(r["drifted"])]
        sensors.append(
            {
                "sensor": sensor,
                "calibrations": [{"created": c.created, "session": c.session} for c in members],
                "sections": sections,
                "drifted": drifted,
            }
        )
    return {
        "format": HISTORY_FORMAT,
        "format_version": 1,
        "drift_sigmas": DRIFT_SIGMAS,
        "sensors": sensors,
        "single": single,
        "without_sensor": without,
    }


def _section_history(secs: list[SensorCalibration | None]) -> dict[str, Any]:
    """``solvers`` and ``rows`` of one section kind across the calibrations of one sensor."""
    per_cal = [{} if s is None else {r["name"]: r for r in _history_rows(s)} for s in secs]
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
                     **_compare(values, stds)})  # fmt: skip
    return {"solvers": [None if s is None else s.solver for s in secs], "rows": rows}


def _compare(values: list[float | None], stds: list[float | None]) -> dict[str, Any]:
    """``reference`` (index of the first calibration that has the figure: an earlier one may
    lack the section, e.g. an accelerometer-only run), then per calibration its ``change``
    from the reference, that change in combined std (``z``) and the ``drifted`` flag."""
    ref = next(i for i, v in enumerate(values) if v is not None)
    change, z, flags = [], [], []
    for i, (v, s) in enumerate(zip(values, stds, strict=True)):
        d = None if v is None or i < ref else v - values[ref]
        combined = math.hypot(s, stds[ref]) if s is not None and stds[ref] is not None else None
        zz = None if d is None or not combined else d / combined
        change.append(d)
        z.append(zz)
        flags.append(zz is not None and abs(zz) > DRIFT_SIGMAS)
    return {"reference": ref, "change": change, "z": z, "drifted": flags}


def render_history(history: dict[str, Any], console: Console) -> None:
    """Draw a history dict (from :func:`build_history`): per sensor and section, a row per
    parameter, the first value ± std, then each later calibration's change and ``z``."""
    for entry in history["sensors"]:
        cals = entry["calibrations"]
        console.print(
            Rule(Text(f"history of {entry['sensor']}: {len(cals)} calibrations"), style="bold")
        )
        for kind, section in entry["sections"].items():
            title = (
                f"{kind}: change from the first calibration (z: in combined std; "
                f"drifted when |z| > {history['drift_sigmas']:g})"
            )
            table = Table(title=Text(title), box=box.SIMPLE, title_justify="left", pad_edge=False)
            table.add_column("parameter", no_wrap=True)
            table.add_column("unit", max_width=18, overflow="fold")
            for i, cal in enumerate(cals):
                when = str(cal["created"] or "?")[:16].replace("T", " ")
                head = f"{when}\n{cal['session'] or ''}"
                table.add_column(
                    head if i == 0 else f"{head}\nchange (z)", justify="right", no_wrap=True
                )
            for row in section["rows"]:
                cells = [Text(row["name"]), Text(row["unit"] or "")]
                ref = row.get("reference", 0)
                cells.append(Text(fmt_std(row["values"][0], row["std"][0])))
                for i in range(1, len(cals)):
                    d, z, flag = row["change"][i], row["z"][i], row["drifted"][i]
                    if i == ref:  # first calibration with this figure: its value
                        cells.append(Text(fmt_std(row["values"][i], row["std"][i]) + " (ref)"))
                        continue
                    if d is None:
                        cells.append(Text(MISSING))
                        continue
                    text = f"{d:+.3g}" + ("" if z is None else f" ({z:+.1f})")
                    if flag:
                        cells.append(Text(text + " drifted", style="bold red"))
                    else:
                        cells.append(Text(text))
                table.add_row(*cells)
            solvers = {s for s in section["solvers"] if s}
            if len(solvers) > 1:
                table.caption = Text(f"different solvers: {', '.join(sorted(solvers))}")
                table.caption_justify = "left"
            console.print(table)
        if entry["drifted"]:
            console.print(
                bullet_panel(entry["drifted"], "Drifted beyond the uncertainty", "bold red")
            )
        else:
            console.print(
                Text(f"no parameter changed by more than {history['drift_sigmas']:g} combined std")
            )
    if history["single"]:
        console.print(
            Text("one calibration only (no history): " + ", ".join(history["single"]), style="dim")
        )
    if history["without_sensor"]:
        console.print(
            Text(
                f"{history['without_sensor']} calibration(s) name no sensor and are left out "
                "(capture or simulate with --sensor)",
                style="dim",
            )
        )
    if not history["sensors"]:
        console.print(
            Text("no sensor has two or more calibrations: nothing to compare", style="yellow")
        )
