"""Calibration report: what a stored calibration says, as a JSON-ready dict and as rich tables.

A report only *reads* results.  It takes a
:class:`~imucal_cli.formats.calibration.Calibration` (from a
calibration JSON, or the last one stored under ``/calibrations`` of a session) and lays out what
the solver wrote: the model and its parameters with standard deviations, misalignment angles,
the gravity-magnitude RMS before / after / leave-one-pose-out, the per-pose residuals and how
well the measured gravity directions cover the sphere.  Nothing is re-solved or recomputed from
raw data; fields a calibration does not carry (one written by another tool has only the
standard ``solver``/``units``/``bias``/``matrix``/``residual_rms``) are listed as unavailable.

Sections written by the factorization solver (Hwangbo & Kanade; accelerometer triads and
redundant units, gyroscopes) are shown the same way, plus the frame the matrix is expressed in
(the rotation the constraints leave free, resolved by the solver), the constraint case, a
linear-versus-refined table in the layout of the paper's Table I (per element bias and gain,
per pair of sensitivity axes the angle between them, and the constraint RMS ``C_err``) and,
for gyroscopes, each known-angle turn with its measured angle.

:func:`build_report` gives the dict (the ``imucal report --json`` output), :func:`render_report`
draws that dict on a :class:`rich.console.Console`.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from rich import box
from rich.console import Console
from rich.panel import Panel
from rich.rule import Rule
from rich.table import Table
from rich.text import Text

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration, SensorCalibration, calibration_from_json
from imucal_cli.formats.inputs import is_hdf5_file, read_input
from imucal_cli.formats.session import read_session

STANDARD_GRAVITY = 9.80665
"""m/s^2; used for milli-g figures when a calibration does not state its local gravity."""

REPORT_FORMAT = "imucal-report"
REPORT_FORMAT_VERSION = 1

PAPER_REFERENCE: dict[str, Any] = {
    "source": (
        "Qureshi & Golnaraghi, 'An Algorithm for the In-Field Calibration of a MEMS IMU', "
        "Fig. 5 / Table II"
    ),
    "description": "their real unit, 92 orientations, gravity-magnitude RMS error",
    "rms_before_g": 0.0129,
    "rms_after_g": 0.0014,
    "rms_before_mg": 12.9,
    "rms_after_mg": 1.4,
    "improvement": round(0.0129 / 0.0014, 1),
}
"""The paper's published result, shown next to ours for context (it is not a pass mark)."""

_MISSING = "—"

# (report key, what the user is told is not in the file, sensors it applies to)
_OPTIONAL_ITEMS = (
    ("variant", "model variant", ("accel", "gyro")),
    ("units_in", "raw input units", ("accel", "gyro")),
    ("parameters", "named parameters with standard deviations", ("accel", "gyro")),
    ("misalignment_deg", "misalignment angles", ("accel", "gyro")),
    ("sensitivity", "sensitivities", ("accel", "gyro")),
    ("fit", "solver iterations / convergence", ("accel", "gyro")),
    ("rms.before", "RMS before calibration", ("accel",)),
    ("rms.after", "RMS after calibration", ("accel",)),
    ("rms.held_out", "leave-one-pose-out (held-out) RMS", ("accel",)),
    ("rms.residual_rms", "solver residual RMS", ("accel", "gyro")),
    ("poses", "per-pose residuals", ("accel",)),
    ("coverage", "pose coverage (fraction, largest gap)", ("accel",)),
)


# --------------------------------------------------------------------------------------------
# Loading


def load_for_report(path: str | os.PathLike[str]) -> Calibration:
    """Read the calibration a report is about.

    Parameters
    ----------
    path
        A calibration JSON, or a session ``.h5``; of a session the *last* calibration stored
        under ``/calibrations`` is used.  The kind is decided by the HDF5 signature.

    Returns
    -------
    Calibration
        The calibration as read; nothing is re-solved.

    Raises
    ------
    InputError
        The file is missing, unreadable, neither JSON nor HDF5, or a session without a stored
        calibration.  ``CalibrationFileError`` and ``SessionError`` (both ``InputError``) come
        from the readers for malformed files.
    """
    path = Path(path)
    what = "calibration JSON or session .h5"
    if is_hdf5_file(path, what=what):
        return _last_stored_calibration(path)
    data = read_input(path, what=what)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(
            f"{path}: neither a session (HDF5) nor a calibration (JSON) file"
        ) from None
    return calibration_from_json(text, str(path))


def _last_stored_calibration(path: Path) -> Calibration:
    """The last calibration under ``/calibrations`` of a session (names are zero-padded)."""
    session = read_session(path)
    if not session.calibrations:
        raise InputError(
            f"{path}: session has no stored calibration; run `imucal calibrate {path}` first"
        )
    name = max(session.calibrations)
    return calibration_from_json(session.calibrations[name], f"{path}:/calibrations/{name}")


# --------------------------------------------------------------------------------------------
# Building the report dict


def build_report(cal: Calibration) -> dict[str, Any]:
    """Everything the report shows, as a JSON-serialisable dict (the ``--json`` output).

    Parameters
    ----------
    cal
        A calibration as read from a file.  Optional solver fields may be missing; they are
        then ``None`` (or empty) in the report and named in each section's ``unavailable``.

    Returns
    -------
    dict
        ``format``, ``format_version``, ``session``, ``created``, ``sensor``,
        ``toolkit_version``, ``config`` (solver options used, if recorded), ``sensors``
        (``{"accel": ..., "gyro": ...}``, only those present, see :func:`_section_report`) and
        ``reference`` (the paper's published RMS before/after, for context).
    """
    extra = cal.extra or {}
    sections = {"accel": cal.accel, "gyro": cal.gyro}
    return {
        "format": REPORT_FORMAT,
        "format_version": REPORT_FORMAT_VERSION,
        "session": cal.session,
        "created": cal.created,
        "sensor": _text(extra.get("sensor")),
        "toolkit_version": _text(extra.get("toolkit_version")),
        "config": extra.get("config") if isinstance(extra.get("config"), dict) else None,
        "sensors": {
            kind: _section_report(kind, section)
            for kind, section in sections.items()
            if section is not None
        },
        "reference": dict(PAPER_REFERENCE),
    }


def _section_report(kind: str, sec: SensorCalibration) -> dict[str, Any]:
    """The report of one sensor section.

    Keys: ``solver``, ``variant``, ``gauge``, ``model``, ``units_in``, ``units_out``,
    ``matrix`` (3 x n), ``matrix_unit``, ``bias`` (n), ``bias_unit``, ``gravity``
    (``{"value", "stated"}`` or ``None``), ``parameters`` (``name``, ``value``, ``std``,
    ``unit``), ``misalignment_deg`` (``axes``, ``angle``, ``std``), ``sensitivity``
    (``values``, ``std``, ``unit``), ``fit`` (``init``, ``iterations``, ``converged``,
    ``message``, ``noise_scale``, ``weighting``, ``chi2``, ``dof``), ``rms`` (see
    :func:`_rms_report`), ``coverage`` (``fraction``, ``largest_gap_deg``, ``n_poses``,
    ``n_distinct``, ``cap_deg``, ``weakest_direction``), ``poses`` (the stored rows plus
    ``residual_mg``, ``residual_loo_mg``), ``rotation`` (the frame the matrix is in, as the
    solver states it), ``factorization`` (see :func:`_factorization`; ``None`` for other
    solvers), ``rotations`` (turns of known angle: ``segment``, ``label``,
    ``known_angle_deg``, ``measured_angle_deg``, ``angle_error_deg``), ``notes``, ``warnings``
    and ``unavailable`` (what this calibration does not carry).  Non-finite numbers read as
    ``None`` (strict JSON).
    """
    extra = sec.extra or {}
    units_in = _text(extra.get("units_in"))
    gravity = _gravity(kind, sec)
    mg_per_unit = 1000.0 / gravity["value"] if gravity else None
    report: dict[str, Any] = {
        "solver": sec.solver,
        "variant": _text(extra.get("variant")),
        "gauge": _text(extra.get("gauge")),
        "model": _text(extra.get("model")) or "calibrated = matrix @ (raw - bias)",
        "units_in": units_in,
        "units_out": sec.units,
        "matrix": np.asarray(sec.matrix, dtype=float).tolist(),
        "matrix_unit": f"{sec.units} per {units_in or 'raw unit'}",
        "bias": np.asarray(sec.bias, dtype=float).tolist(),
        "bias_unit": units_in or "raw units",
        "gravity": gravity,
        "parameters": _parameters(extra.get("parameters")),
        "misalignment_deg": _misalignment(
            extra.get("misalignment_deg"), extra.get("misalignment_std_deg")
        ),
        "sensitivity": _sensitivity(
            extra.get("sensitivity"), extra.get("sensitivity_std"), extra.get("sensitivity_unit")
        ),
        "fit": _fit(extra),
        "rms": _rms_report(sec, mg_per_unit),
        "coverage": _coverage(extra.get("coverage")),
        "poses": _poses(extra.get("poses"), mg_per_unit),
        "rotation": _text(extra.get("rotation")),
        "factorization": _factorization(kind, sec),
        "rotations": _rotations(extra.get("rotations")),
        "notes": [str(n) for n in _list(extra.get("notes"))],
        "warnings": [str(w) for w in _list(extra.get("warnings"))],
    }
    report["unavailable"] = _unavailable(kind, report)
    return report


def _gravity(kind: str, sec: SensorCalibration) -> dict[str, Any] | None:
    """Gravity for milli-g figures: the calibration's own, else standard for an accelerometer."""
    stated = _number(sec.extra.get("gravity"))
    if stated is not None and stated > 0:
        return {"value": stated, "stated": True}
    if kind == "accel" and sec.units == "m/s^2":
        return {"value": STANDARD_GRAVITY, "stated": False}
    return None


def _rms_report(sec: SensorCalibration, mg_per_unit: float | None) -> dict[str, Any]:
    """RMS figures as stored, each also in mg when the output is an acceleration.

    ``before``/``after``/``held_out`` are the solver's ``rms_before``/``rms_after``/``rms_loo``
    (gravity-magnitude RMS for the gravity solver); ``residual_rms`` is the standard field (what
    the solver minimised).  ``improvement`` = before / after, ``improvement_held_out`` =
    before / held_out.
    """
    extra = sec.extra
    figures = {
        "before": _number(extra.get("rms_before")),
        "after": _number(extra.get("rms_after")),
        "held_out": _number(extra.get("rms_loo")),
        "residual_rms": _number(sec.residual_rms),
    }
    gravity_magnitude = sec.solver == "gravity" or (
        sec.solver == "factorization" and sec.units == "m/s^2"
    )
    rms: dict[str, Any] = {
        "unit": sec.units,
        "quantity": "gravity-magnitude error" if gravity_magnitude else "solver residual",
        **figures,
    }
    for key, value in figures.items():
        rms[f"{key}_mg"] = _scaled(value, mg_per_unit)
    rms["improvement"] = _ratio(figures["before"], figures["after"])
    rms["improvement_held_out"] = _ratio(figures["before"], figures["held_out"])
    rms["before_basis"] = _text(extra.get("before_basis"))
    rms["held_out_method"] = _text(extra.get("loo_method"))
    return rms


def _parameters(raw: Any) -> list[dict[str, Any]]:
    rows = []
    for item in _list(raw):
        if isinstance(item, dict) and "name" in item:
            rows.append(
                {
                    "name": str(item["name"]),
                    "value": _number(item.get("value")),
                    "std": _number(item.get("std")),
                    "unit": _text(item.get("unit")),
                }
            )
    return rows


def _misalignment(angles: Any, stds: Any) -> list[dict[str, Any]]:
    if not isinstance(angles, dict):
        return []
    stds = stds if isinstance(stds, dict) else {}
    return [
        {"axes": str(axes), "angle": _number(angle), "std": _number(stds.get(axes))}
        for axes, angle in angles.items()
    ]


def _sensitivity(values: Any, stds: Any, unit: Any) -> dict[str, Any] | None:
    numbers = [_number(v) for v in _list(values)]
    if not numbers:
        return None
    std = [_number(v) for v in _list(stds)]
    return {
        "values": numbers,
        "std": std if len(std) == len(numbers) else None,
        "unit": _text(unit),
    }


def _fit(extra: dict[str, Any]) -> dict[str, Any] | None:
    fit = {
        "init": _text(extra.get("init")),
        "iterations": _integer(extra.get("iterations")),
        "converged": extra.get("converged") if isinstance(extra.get("converged"), bool) else None,
        "message": _text(extra.get("message")),
        "noise_scale": _number(extra.get("noise_scale")),
        "weighting": _text(extra.get("weighting")),
        "chi2": _number(extra.get("chi2")),
        "dof": _integer(extra.get("dof")),
    }
    return fit if any(v is not None for v in fit.values()) else None


def _coverage(raw: Any) -> dict[str, Any] | None:
    if not isinstance(raw, dict):
        return None
    return {
        "fraction": _number(raw.get("fraction")),
        "largest_gap_deg": _number(raw.get("largest_gap_deg")),
        "n_poses": _integer(raw.get("n_poses")),
        "n_distinct": _integer(raw.get("n_distinct")),
        "cap_deg": _number(raw.get("cap_deg")),
        "weakest_direction": _vector(raw.get("weakest_direction")),
    }


def _poses(raw: Any, mg_per_unit: float | None) -> list[dict[str, Any]]:
    rows = []
    for item in _list(raw):
        if not isinstance(item, dict):
            continue
        row = {
            "segment": _text(item.get("segment")),
            "label": _text(item.get("label")),
            "up": _vector(item.get("up")),
            "samples": _integer(item.get("samples")),
            "magnitude_before": _number(item.get("magnitude_before")),
            "magnitude_after": _number(item.get("magnitude_after")),
            "residual": _number(item.get("residual")),
            "residual_loo": _number(item.get("residual_loo")),
            "angle_to_up_deg": _number(item.get("angle_to_up_deg")),
            "direction": _vector(item.get("direction")),
        }
        row["residual_mg"] = _scaled(row["residual"], mg_per_unit)
        row["residual_loo_mg"] = _scaled(row["residual_loo"], mg_per_unit)
        rows.append(row)
    return rows


def _factorization(kind: str, sec: SensorCalibration) -> dict[str, Any] | None:
    """The factorization solver's own fields, laid out as the paper's Table I.

    Returns ``None`` for other solvers, else ``configuration``, ``case``, ``elements``,
    ``axis_names``, ``refined`` (bool: the nonlinear refinement ran), ``linear_method``,
    ``use``, ``constraints`` (their number), ``singular_values``, ``rows`` and
    ``constraint_rms`` (``linear``, ``refined``, ``unit``: the paper's ``C_err`` as an RMS of
    ``f_i . f_k - h_ik``).  ``rows`` lists, in Table I order, every element's bias
    (``b1``...), gain (``|s1|``...) and every pair's angle (``s1s2``, ``s1s3``, ...), each
    ``{"group", "name", "unit", "linear", "refined", "refined_std"}``; without refinement
    ``refined`` and ``refined_std`` are ``None`` and ``linear`` holds the final values.
    """
    extra = sec.extra or {}
    linear = extra.get("linear")
    if sec.solver != "factorization" and not isinstance(linear, dict):
        return None
    linear = linear if isinstance(linear, dict) else {}
    bias = [_number(v) for v in np.asarray(sec.bias, dtype=float).ravel()]
    n = len(bias)
    names = [str(a) for a in _list(extra.get("axis_names"))]
    if len(names) != n:
        names = list("xyz") if n == 3 else [str(i + 1) for i in range(n)]
    refined = extra.get("refined") if isinstance(extra.get("refined"), bool) else bool(linear)
    std_of = {p["name"]: p["std"] for p in _parameters(extra.get("parameters"))}
    units_in = _text(extra.get("units_in")) or "raw units"
    gain_unit = _text(extra.get("sensitivity_unit")) or f"{units_in} per {sec.units}"

    def element(values: Any, i: int) -> float | None:
        items = _list(values)
        return _number(items[i]) if i < len(items) else None

    def pair(matrix: Any, i: int, j: int) -> float | None:
        row = _list(matrix)[i] if i < len(_list(matrix)) else None
        return element(row, j)

    final = {
        "bias": lambda i: bias[i],
        "gain": lambda i: element(extra.get("sensitivity"), i),
        "angle": lambda i, j: pair(extra.get("angles_deg"), i, j),
    }
    final_std = {
        "bias": lambda i: std_of.get(f"b_{names[i]}"),
        "gain": lambda i: element(extra.get("sensitivity_std"), i),
        "angle": lambda i, j: pair(extra.get("angles_std_deg"), i, j),
    }
    first = {
        "bias": lambda i: element(linear.get("bias"), i),
        "gain": lambda i: element(linear.get("sensitivity"), i),
        "angle": lambda i, j: pair(linear.get("angles_deg"), i, j),
    }
    rows = []

    def add(group: str, name: str, unit: str, *index: int) -> None:
        lin = first[group](*index) if linear else final[group](*index)
        rows.append(
            {
                "group": group,
                "name": name,
                "unit": unit,
                "linear": lin,
                "refined": final[group](*index) if refined else None,
                "refined_std": final_std[group](*index) if refined else None,
            }
        )

    for i, a in enumerate(names):
        add("bias", f"b{a}", units_in, i)
    for i, a in enumerate(names):
        add("gain", f"|s{a}|", gain_unit, i)
    for i in range(n):
        for j in range(i + 1, n):
            add("angle", f"s{names[i]}s{names[j]}", "deg", i, j)
    final_rms = _number(extra.get("constraint_rms"))
    return {
        "configuration": _text(extra.get("configuration")),
        "case": _text(extra.get("case")),
        "elements": _integer(extra.get("elements")) or n,
        "axis_names": names,
        "refined": refined,
        "linear_method": _text(linear.get("method")),
        "use": _text(extra.get("use")),
        "constraints": _integer(extra.get("constraints")),
        "singular_values": [v for v in map(_number, _list(extra.get("singular_values")))],
        "rows": rows,
        "constraint_rms": {
            "linear": _number(linear.get("constraint_rms")) if linear else final_rms,
            "refined": final_rms if refined else None,
            "unit": "g^2" if kind == "accel" else f"({sec.units})^2",
        },
    }


def _rotations(raw: Any) -> list[dict[str, Any]]:
    rows = []
    for item in _list(raw):
        if isinstance(item, dict):
            rows.append(
                {
                    "segment": _text(item.get("segment")),
                    "label": _text(item.get("label")),
                    "known_angle_deg": _number(item.get("known_angle_deg")),
                    "measured_angle_deg": _number(item.get("measured_angle_deg")),
                    "angle_error_deg": _number(item.get("angle_error_deg")),
                }
            )
    return rows


def _unavailable(kind: str, report: dict[str, Any]) -> list[str]:
    """Human names of the optional items this section does not carry."""
    missing = []
    factorization = report["factorization"]
    for key, name, kinds in _OPTIONAL_ITEMS:
        if kind not in kinds:
            continue
        if key == "misalignment_deg" and factorization is not None:
            if not any(
                r["group"] == "angle" and r["linear"] is not None for r in factorization["rows"]
            ):
                missing.append("angles between sensitivity axes")
            continue
        value: Any = report
        for part in key.split("."):
            value = value.get(part) if isinstance(value, dict) else None
        if value is None or value == []:
            missing.append(name)
    poses = report["poses"]
    if poses and not any(p["direction"] for p in poses):
        missing.append("measured gravity directions (coverage map)")
    if factorization is not None and not report["rotation"]:
        missing.append("the frame of the matrix (how the free rotation was resolved)")
    if kind == "gyro" and factorization is not None and not report["rotations"]:
        missing.append("known-angle turns (measured vs known angle)")
    gravity = report["gravity"]
    if kind == "accel" and gravity and not gravity["stated"]:
        missing.append(f"local gravity (mg figures use standard {STANDARD_GRAVITY} m/s^2)")
    return missing


# Tolerant field readers: a malformed optional field reads as missing.


def _number(value: Any) -> float | None:
    """A finite number, else ``None`` (NaN marks "not determined" in solver output)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def _integer(value: Any) -> int | None:
    number = _number(value)
    return None if number is None else int(number)


def _text(value: Any) -> str | None:
    return None if value is None else str(value)


def _list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else []


def _vector(value: Any) -> list[float] | None:
    numbers = [_number(v) for v in _list(value)]
    if len(numbers) != 3 or any(n is None for n in numbers):
        return None
    return numbers


def _scaled(value: float | None, factor: float | None) -> float | None:
    return None if value is None or factor is None else value * factor


def _ratio(num: float | None, den: float | None) -> float | None:
    if num is None or den is None or den == 0:
        return None
    return num / den


# --------------------------------------------------------------------------------------------
# Rendering

# rms key -> (row name, key of its improvement factor)
_RMS_ROWS = {
    "before": ("before calibration", None),
    "after": ("after calibration", "improvement"),
    "held_out": ("held out (leave-one-pose-out)", "improvement_held_out"),
    "residual_rms": ("solver residual_rms", None),
}


def render_report(report: dict[str, Any], console: Console) -> None:
    """Draw a report dict (from :func:`build_report`) as rich tables.

    Parameters
    ----------
    report
        The dict :func:`build_report` returned.
    console
        Where to draw; the layout fits 100 columns.
    """
    console.print(_header(report))
    for kind, section in report["sensors"].items():
        console.print(Rule(Text(_section_title(kind, section)), style="bold"))
        if section["warnings"]:
            console.print(_bullet_panel(section["warnings"], "Warnings", "bold yellow"))
        console.print(_model_grid(section))
        console.print(_matrix_table(section))
        if section["parameters"]:
            console.print(_parameter_table(section["parameters"]))
        factorization = section["factorization"]
        if factorization is not None:
            console.print(_table_one(section))
            if section["misalignment_deg"]:  # another tool's extra field: still shown
                console.print(_angle_sensitivity_table({**section, "sensitivity": None}))
        else:
            angles = _angle_sensitivity_table(section)
            if angles is not None:
                console.print(angles)
        # The factorization's residual_rms is its constraint RMS, shown in the Table I layout.
        rms_rows = [k for k in _RMS_ROWS if factorization is None or k != "residual_rms"]
        if kind == "gyro":  # before/after/held out are gravity-pose figures: no rows of dashes
            rms_rows = [k for k in rms_rows if section["rms"][k] is not None]
        if any(section["rms"][key] is not None for key in rms_rows):
            reference = report["reference"] if _shows_paper_reference(kind, section) else None
            console.print(_rms_table(section, reference, rms_rows))
        if section["fit"]:
            console.print(_fit_line(section["fit"]))
        if section["rotations"]:
            console.print(_rotations_table(section["rotations"]))
        if section["poses"]:
            console.print(_pose_table(section))
        if section["coverage"] or any(p["direction"] for p in section["poses"]):
            console.print(_coverage_panel(section))
        if section["notes"]:
            console.print(_bullet_panel(section["notes"], "Notes", "dim"))
        if section["unavailable"]:
            console.print(_bullet_panel(section["unavailable"], "Not in this calibration", "dim"))
    if not report["sensors"]:
        console.print(Text("The calibration holds no sensor section.", style="yellow"))


def _header(report: dict[str, Any]) -> Panel:
    grid = Table.grid(padding=(0, 2))
    grid.add_column(style="bold")
    grid.add_column()
    for name, value in (
        ("session", report["session"]),
        ("created", report["created"]),
        ("sensor", report["sensor"]),
        ("toolkit", report["toolkit_version"]),
    ):
        if value:
            grid.add_row(name, Text(str(value)))
    if report["config"]:
        options = ", ".join(f"{k}={v}" for k, v in _flatten(report["config"]))
        grid.add_row("options", Text(options))
    return Panel(grid, title="imucal calibration report", expand=False)


def _flatten(options: dict[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """Nested solver options as ``(dotted.key, value)`` pairs."""
    pairs = []
    for key, value in options.items():
        if isinstance(value, dict):
            pairs.extend(_flatten(value, f"{prefix}{key}."))
        else:
            pairs.append((f"{prefix}{key}", value))
    return pairs


def _shows_paper_reference(kind: str, section: dict[str, Any]) -> bool:
    """Qureshi & Golnaraghi's figure is the gravity solver's context, and only that one's."""
    return kind == "accel" and section["solver"] == "gravity"


def _section_title(kind: str, section: dict[str, Any]) -> str:
    title = f"{kind}: {section['solver']} solver"
    variant = section["variant"]
    if variant:
        prefix = f"{section['solver']}, "  # "factorization, triad (n = 3), ...": no repeat
        title += f", {variant[len(prefix) :] if variant.startswith(prefix) else variant}"
    return title


def _model_grid(section: dict[str, Any]) -> Table:
    """Model equation, units in and out, gauge and gravity, one per line."""
    grid = Table.grid(padding=(0, 2))
    grid.add_column(style="bold")
    grid.add_column()
    units_in = section["units_in"] or "raw units (not stated)"
    rows = [
        ("model", section["model"]),
        ("units", f"raw {units_in} -> calibrated {section['units_out']}"),
    ]
    factorization = section["factorization"]
    if factorization is not None:
        rows.append(("design", _design_text(factorization)))
        # The frame: the constraints fix the matrix only up to a rotation (eq. 25); the
        # solver resolved it on purpose and says how.
        rows.append(("matrix frame", section["rotation"] or section["gauge"] or "not stated"))
        if section["gauge"] and section["gauge"] != section["rotation"] and section["rotation"]:
            rows.append(("gauge", section["gauge"]))
    elif section["gauge"]:
        rows.append(("gauge", section["gauge"]))
    if section["gravity"]:
        gravity = section["gravity"]
        origin = "local, from the calibration" if gravity["stated"] else "standard, not stated"
        rows.append(("gravity", f"{gravity['value']:.6g} {section['units_out']} ({origin})"))
    for name, value in rows:
        grid.add_row(name, Text(value))
    return grid


def _design_text(factorization: dict[str, Any]) -> str:
    """``redundant unit, 4 elements; magnitude-only constraints: 20, over per-pose means``."""
    unit = factorization["configuration"] or "unit"
    text = f"{unit} unit, {factorization['elements']} elements"
    if factorization["case"]:
        text += f"; {factorization['case']} constraints"
        details = []
        if factorization["constraints"] is not None:
            details.append(str(factorization["constraints"]))
        if factorization["use"]:
            details.append(f"over per-pose {factorization['use']}")
        if details:
            text += f": {', '.join(details)}"
    return text


def _matrix_table(section: dict[str, Any]) -> Table:
    """The matrix and bias exactly as stored, with their units in the title."""
    n_in = len(section["bias"])
    if section["factorization"] is not None:
        names = section["factorization"]["axis_names"]
        channels = [name if name in "xyz" else f"ch{name}" for name in names]
    else:
        channels = list("xyz") if n_in == 3 else [f"ch{i}" for i in range(n_in)]
    title = f"matrix [{section['matrix_unit']}] and bias [{section['bias_unit']}]"
    table = Table(title=Text(title), box=box.SIMPLE, title_justify="left")
    table.add_column("")
    for channel in channels:
        table.add_column(channel, justify="right")
    for axis, row in zip("xyz", section["matrix"], strict=False):
        table.add_row(axis, *(_fmt(v) for v in row))
    table.add_row(Text("bias", style="bold"), *(_fmt(v) for v in section["bias"]))
    return table


def _value_table(
    title: str, key: str, rows: list[tuple[str, float | None, float | None, str | None]]
) -> Table:
    """``name | value ± std unit`` rows; the ``± std`` only when the file gives any std."""
    with_std = any(std is not None for _, _, std, _ in rows)
    table = Table(title=Text(title), box=box.SIMPLE, title_justify="left", min_width=len(title))
    table.add_column(key)
    table.add_column("value ± std" if with_std else "value", justify="right")
    for name, value, std, unit in rows:
        text = _fmt_std(value, std, unit) if with_std else _fmt(value, unit)
        table.add_row(Text(name), Text(text))
    return table


def _parameter_table(parameters: list[dict[str, Any]]) -> Table:
    rows = [(p["name"], p["value"], p["std"], p["unit"]) for p in parameters]
    return _value_table("parameters", "name", rows)


def _angle_sensitivity_table(section: dict[str, Any]) -> Table | None:
    """Misalignment angles and sensitivities side by side (either may be absent)."""
    parts = []
    if section["misalignment_deg"]:
        rows = [(m["axes"], m["angle"], m["std"], "deg") for m in section["misalignment_deg"]]
        parts.append(_value_table("misalignment (angle - 90)", "axes", rows))
    if section["sensitivity"]:
        sens = section["sensitivity"]
        values = sens["values"]
        names = "xyz" if len(values) == 3 else [str(i) for i in range(len(values))]
        stds = sens["std"] or [None] * len(values)
        rows = list(zip(names, values, stds, [sens["unit"]] * len(values), strict=True))
        parts.append(_value_table("sensitivity", "axis", rows))
    if not parts:
        return None
    grid = Table.grid(padding=(0, 4))
    for _ in parts:
        grid.add_column()
    grid.add_row(*parts)
    return grid


def _rms_table(
    section: dict[str, Any], reference: dict[str, Any] | None, keys: list[str] | None = None
) -> Table:
    """RMS before / after / held-out in output units and mg, with the improvement factor."""
    rms = section["rms"]
    unit = rms["unit"]
    show_mg = any(rms[f"{k}_mg"] is not None for k in ("before", "after", "held_out"))
    table = Table(title=Text(f"RMS {rms['quantity']}"), box=box.SIMPLE, title_justify="left")
    table.add_column("")
    table.add_column("RMS", justify="right")
    if show_mg:
        table.add_column("RMS in mg", justify="right")
    table.add_column("improvement", justify="right")
    for key, (name, factor_key) in _RMS_ROWS.items():
        if keys is not None and key not in keys:
            continue
        cells = [name, _fmt(rms[key], unit)]
        if show_mg:
            cells.append(_fmt(rms[f"{key}_mg"], "mg", digits=3))
        factor = rms[factor_key] if factor_key else None
        cells.append(f"{factor:.1f} ×" if factor is not None else "")
        table.add_row(*map(Text, cells))
    if reference is not None and show_mg:
        cells = [
            "paper: Qureshi & Golnaraghi, Fig. 5",
            f"{reference['rms_before_g']} -> {reference['rms_after_g']} g",
            f"{reference['rms_before_mg']} -> {reference['rms_after_mg']} mg",
            f"{reference['improvement']:.1f} ×",
        ]
        table.add_row(*(Text(cell, style="dim") for cell in cells))
    notes = []
    if rms["before_basis"]:
        notes.append(f"before = {rms['before_basis']}")
    if rms["held_out_method"]:
        notes.append(f"held out = {rms['held_out_method']}")
    if notes:
        table.caption = Text("\n".join(notes))
        table.caption_justify = "left"
    return table


def _table_one(section: dict[str, Any]) -> Table:
    """Linear vs refined, as Hwangbo & Kanade's Table I: per element the bias and gain, per
    pair of sensitivity axes the angle, then the constraint RMS (``C_err``)."""
    fz = section["factorization"]
    refined = fz["refined"]
    linear_name = "linear" + (f" ({fz['linear_method']})" if fz["linear_method"] else "")
    title = "linear vs refined solution (layout of Hwangbo & Kanade, Table I)"
    if not refined:
        title = "linear solution, not refined (layout of Hwangbo & Kanade, Table I)"
    table = Table(title=Text(title), box=box.SIMPLE, title_justify="left", pad_edge=False)
    table.add_column("", no_wrap=True)
    table.add_column("", no_wrap=True)
    table.add_column(linear_name, justify="right", no_wrap=True)
    if refined:
        table.add_column("refined ± std", justify="right", no_wrap=True)
    previous = None
    for row in fz["rows"]:
        group = row["group"]
        label = f"{group} [{row['unit']}]" if group != previous else ""
        if group != previous and previous is not None:
            table.add_section()
        previous = group
        cells = [label, row["name"], _fmt_like(row["linear"], row["refined_std"])]
        if refined:
            cells.append(_fmt_std(row["refined"], row["refined_std"]))
        table.add_row(*map(Text, cells))
    table.add_section()
    crms = fz["constraint_rms"]
    cells = [f"C_err RMS [{crms['unit']}]", "", _fmt(crms["linear"], digits=4)]
    if refined:
        cells.append(_fmt(crms["refined"], digits=4))
    table.add_row(*map(Text, cells))
    motions = "motions in g" if section["units_out"] == "m/s^2" else "motions in rad/s"
    caption = [f"C_err: RMS of f_i . f_k - h_ik over the constraints ({motions})"]
    if section["rms"]["residual_rms"] is not None:
        caption.append(
            f"residual_rms (standard field, as stored): {_fmt(section['rms']['residual_rms'])}"
        )
    values = [v for v in fz["singular_values"] if v is not None]
    if values:
        caption.append("singular values (rank evidence): " + ", ".join(f"{v:.4g}" for v in values))
    table.caption = Text("\n".join(caption))
    table.caption_justify = "left"
    return table


def _rotations_table(rotations: list[dict[str, Any]]) -> Table:
    """Per rotation: the angle the calibrated gyro integrates against the reference one (a
    known angle, or the angle the calibrated accelerometer measured), or, for models without
    a reference angle, the mismatch of the gravity direction predicted after the turn."""
    reference = any(r["known_angle_deg"] is not None for r in rotations)
    title = (
        "rotations (error = gyro angle - reference angle, from the fixture or the accelerometer)"
        if reference
        else "rotations (error = angle between predicted and measured gravity after the turn)"
    )
    table = Table(title=Text(title), box=box.SIMPLE, title_justify="left", pad_edge=False)
    numbers = {"justify": "right", "no_wrap": True}
    table.add_column("seg", no_wrap=True)
    table.add_column("label", max_width=52, overflow="fold")
    if reference:
        table.add_column("reference deg", **numbers)
    table.add_column("gyro deg", **numbers)
    table.add_column("error deg", **numbers)
    for r in rotations:
        error = r["angle_error_deg"]
        table.add_row(
            *(
                Text(cell)
                for cell in (
                    r["segment"] or _MISSING,
                    r["label"] or _MISSING,
                    *([_fixed(r["known_angle_deg"], 3)] if reference else []),
                    _fixed(r["measured_angle_deg"], 4),
                    _MISSING if error is None else f"{error:+.3g}",
                )
            )
        )
    return table


def _fit_line(fit: dict[str, Any]) -> Text:
    parts = []
    if fit["init"]:
        parts.append(f"init {fit['init']}")
    if fit["iterations"] is not None:
        parts.append(f"{fit['iterations']} iterations")
    if fit["converged"] is not None:
        parts.append("converged" if fit["converged"] else "NOT converged")
    if fit["weighting"]:
        parts.append(f"weighting {fit['weighting']}")
    if fit["chi2"] is not None and fit["dof"] is not None:
        parts.append(f"chi2 {fit['chi2']:.3g} for {fit['dof']} dof")
    if fit["noise_scale"] is not None:
        parts.append(f"noise scale {fit['noise_scale']:.3g} (applied to covariances)")
    if fit["message"]:
        parts.append(fit["message"])
    return Text("solver: " + "; ".join(parts))


def _pose_table(section: dict[str, Any]) -> Table:
    """One row per pose; residuals in mg where the output is an acceleration."""
    poses = section["poses"]
    unit = section["units_out"]
    in_mg = any(p["residual_mg"] is not None or p["residual_loo_mg"] is not None for p in poses)
    residual_unit = "mg" if in_mg else unit
    title = "poses (n: samples averaged; angle: measured gravity to the labelled up)"
    table = Table(title=title, box=box.SIMPLE, title_justify="left", pad_edge=False)
    # Numbers never wrap; on a narrow terminal the label column wraps instead.
    numbers = {"justify": "right", "no_wrap": True}
    table.add_column("\n\nseg", no_wrap=True)
    table.add_column("\n\nlabel", max_width=22, overflow="fold")
    table.add_column("\n\nup", no_wrap=True)
    table.add_column("\n\nn", **numbers)
    table.add_column(f"|a|\nbefore\n{unit}", **numbers)
    table.add_column(f"|a|\nafter\n{unit}", **numbers)
    table.add_column(f"\nresidual\n{residual_unit}", **numbers)
    table.add_column(f"held\nout\n{residual_unit}", **numbers)
    table.add_column("\nangle\ndeg", **numbers)
    for p in poses:
        if in_mg:
            residual, held_out = p["residual_mg"], p["residual_loo_mg"]
        else:
            residual, held_out = p["residual"], p["residual_loo"]
        table.add_row(
            *(
                Text(cell)
                for cell in (
                    p["segment"] or _MISSING,
                    p["label"] or _MISSING,
                    _axis_name(p["up"]),
                    _MISSING if p["samples"] is None else str(p["samples"]),
                    _fixed(p["magnitude_before"], 4),
                    _fixed(p["magnitude_after"], 4),
                    _fixed(residual, 3, signed=True),
                    _fixed(held_out, 3, signed=True),
                    _fixed(p["angle_to_up_deg"], 2),
                )
            )
        )
    return table


def _coverage_panel(section: dict[str, Any]) -> Panel:
    """Equal-area maps of the two hemispheres with a mark per pose, the coverage figures beside."""
    directions = [p["direction"] for p in section["poses"] if p["direction"]]
    coverage = section["coverage"] or {}
    facts = []
    if coverage.get("fraction") is not None:
        facts.append(f"covered: {100 * coverage['fraction']:.0f} % of the sphere")
        if coverage["cap_deg"]:
            facts.append(f"  (within {coverage['cap_deg']:.0f} deg of a pose)")
    if coverage.get("largest_gap_deg") is not None:
        facts.append(f"largest gap: {coverage['largest_gap_deg']:.1f} deg")
    if coverage.get("n_poses") is not None:
        facts.append(f"poses: {coverage['n_poses']}")
    if coverage.get("n_distinct") is not None:
        facts.append(f"distinct poses: {coverage['n_distinct']}")
    if coverage.get("weakest_direction"):
        facts.append(f"weakest direction: {_axis_name(coverage['weakest_direction'])}")
    if not directions:
        facts.append("no measured directions stored: no map")
    grid = Table.grid(padding=(0, 3))
    grid.add_column(no_wrap=True)
    grid.add_column()
    map_text = "\n".join(coverage_map(directions)) if directions else ""
    grid.add_row(Text(map_text), Text("\n".join(["", *facts])))
    return Panel(grid, title="coverage of measured gravity directions", expand=False)


def _bullet_panel(items: list[str], title: str, style: str) -> Panel:
    body = Text("\n".join(f"- {item}" for item in items))
    return Panel(body, title=title, border_style=style, expand=False)


# Coverage map


def coverage_map(
    directions: list[list[float]], radius_cols: int = 11, radius_rows: int = 5
) -> list[str]:
    """Text map of unit directions on the sphere: two hemispheres side by side.

    Each hemisphere is an azimuthal equal-area projection about its pole (+Z left, -Z right),
    both drawn as seen from +Z (x to the right, y up), so an empty area of the disc is an
    uncovered area of the sphere.  ``.`` is the disc, ``+`` the pole, ``o`` one pose, a digit
    several poses in one cell.

    Parameters
    ----------
    directions
        Unit vectors (normalised here); z >= 0 goes to the +Z map.
    radius_cols, radius_rows
        Disc radius in character columns and rows (characters are about twice as tall as wide).

    Returns
    -------
    list of str
        Lines of text, the first a caption.
    """
    upper, lower = [], []
    for d in directions:
        norm = np.linalg.norm(d)
        if not norm > 0:
            continue
        x, y, z = np.asarray(d, dtype=float) / norm
        # Equal-area: distance from the pole r = 2 sin(polar angle / 2), here scaled to 1 at
        # the equator, i.e. r = sqrt(1 - |z|).
        r = math.sqrt(max(0.0, 1.0 - abs(z)))
        rho = math.hypot(x, y)
        point = (r * x / rho, r * y / rho) if rho > 0 else (0.0, 0.0)
        (upper if z >= 0 else lower).append(point)
    left = _hemisphere(upper, radius_cols, radius_rows)
    right = _hemisphere(lower, radius_cols, radius_rows)
    width = 2 * radius_cols + 1
    gap = " " * 4
    caption = f"{'+Z side (z >= 0)':^{width}}{gap}{'-Z side (z < 0)':^{width}}"
    rows = [f"{a}{gap}{b}" for a, b in zip(left, right, strict=True)]
    note = f"{'x ->, y up, both seen from +Z':^{2 * width + len(gap)}}"
    return [caption, *rows, note]


def _hemisphere(points: list[tuple[float, float]], radius_cols: int, radius_rows: int) -> list[str]:
    """One disc of the coverage map with the projected points marked."""
    height, width = 2 * radius_rows + 1, 2 * radius_cols + 1
    grid = [[" "] * width for _ in range(height)]
    half_u, half_v = 0.5 / radius_cols, 0.5 / radius_rows
    for i in range(height):
        for j in range(width):
            # A cell belongs to the disc when any of it does, so every projected point's cell
            # is drawn inside.
            u = max(abs(j - radius_cols) / radius_cols - half_u, 0.0)
            v = max(abs(radius_rows - i) / radius_rows - half_v, 0.0)
            if u * u + v * v <= 1.0:
                grid[i][j] = "."
    grid[radius_rows][radius_cols] = "+"
    counts = Counter(
        (round(radius_rows - radius_rows * py), round(radius_cols + radius_cols * px))
        for px, py in points
    )
    for (i, j), n in counts.items():
        grid[i][j] = "o" if n == 1 else (str(n) if n < 10 else "#")
    return ["".join(row) for row in grid]


# Number formatting


def _fmt(value: float | None, unit: str | None = None, digits: int = 5) -> str:
    """``value unit`` with ``digits`` significant digits, or a dash when missing."""
    if value is None:
        return _MISSING
    return f"{value:.{digits}g}" + (f" {unit}" if unit else "")


def _fmt_std(value: float | None, std: float | None, unit: str | None = None) -> str:
    """``value ± std unit`` with as many decimals as the std warrants."""
    if value is None:
        return _MISSING
    suffix = f" {unit}" if unit else ""
    if std is None or not math.isfinite(std) or std < 0 or not math.isfinite(value):
        return f"{value:.5g} ± n/a{suffix}"  # also a std a file got wrong (negative, inf)
    if std == 0:
        return f"{value:.5g} ± 0{suffix}"
    scale = max(abs(value), std)
    exponent = 3 * math.floor(math.log10(scale) / 3) if scale < 1e-2 or scale >= 1e6 else 0
    if exponent:
        value, std = value / 10.0**exponent, std / 10.0**exponent
    decimals = _decimals_for(std)
    text = f"{value:.{decimals}f} ± {std:.{decimals}f}"
    return (f"({text})e{exponent}" if exponent else text) + suffix


def _fmt_like(value: float | None, std: float | None) -> str:
    """A value with the decimals ``_fmt_std`` gives its neighbour ``value ± std`` (aligned
    columns); 6 significant digits without a std or for values shown with an exponent."""
    if value is None:
        return _MISSING
    if std is None or std <= 0 or not 1e-2 <= max(abs(value), std) < 1e6:
        return f"{value:.6g}"
    return f"{value:.{_decimals_for(std)}f}"


def _decimals_for(std: float) -> int:
    """Decimals that show a std with one significant digit (two when it starts with a 1)."""
    exponent = math.floor(math.log10(std))
    leading = std / 10**exponent
    decimals = -exponent + (1 if leading < 2 else 0)
    return min(max(decimals, 0), 9)


def _fixed(value: float | None, decimals: int, signed: bool = False) -> str:
    if value is None:
        return _MISSING
    return f"{value:+.{decimals}f}" if signed else f"{value:.{decimals}f}"


def _axis_name(up: list[float] | None) -> str:
    """``+Z``, ``-X``, ``+X+Z`` (a 45-degree edge) when the vector is one of those, else numbers."""
    if not up:
        return _MISSING
    vector = np.asarray(up, dtype=float)
    norm = np.linalg.norm(vector)
    if norm == 0:
        return _MISSING
    vector = vector / norm
    nonzero = np.abs(vector) > 1e-3
    magnitude = 1 / math.sqrt(nonzero.sum())
    if np.allclose(np.abs(vector[nonzero]), magnitude, atol=2e-3):
        return "".join(
            f"{'+' if c > 0 else '-'}{axis}"
            for axis, c in zip("XYZ", vector, strict=True)
            if abs(c) > 1e-3
        )
    return "[" + ",".join(f"{c:.2f}" for c in vector) + "]"


# --------------------------------------------------------------------------------------------
# History: several calibrations of the same sensor

HISTORY_FORMAT = "imucal-history"

DRIFT_SIGMAS = 3.0
"""A change from the first calibration larger than this many combined standard deviations
(``sqrt(std_first^2 + std_now^2)``) is flagged as drifted."""


def load_all_for_history(paths: list[str | os.PathLike[str]]) -> list[Calibration]:
    """Every calibration the paths hold: a JSON gives one, a session all it stores.

    Parameters
    ----------
    paths
        Calibration JSONs and/or session ``.h5`` files.

    Returns
    -------
    list of Calibration
        In the order given (a session's in the order they were stored).

    Raises
    ------
    InputError
        As :func:`load_for_report`.
    """
    out: list[Calibration] = []
    for item in paths:
        path = Path(item)
        if is_hdf5_file(path, what="calibration JSON or session .h5"):
            session = read_session(path)
            if not session.calibrations:
                raise InputError(
                    f"{path}: session has no stored calibration; run `imucal calibrate {path}` "
                    "first"
                )
            for name in sorted(session.calibrations):
                out.append(
                    calibration_from_json(
                        session.calibrations[name], f"{path}:/calibrations/{name}"
                    )
                )
        else:
            out.append(load_for_report(path))
    return out


def _history_rows(sec: SensorCalibration) -> list[dict[str, Any]]:
    """``name``, ``unit``, ``value``, ``std`` of each tracked figure of one section: the named
    parameters, sensitivities and misalignment angles; without named parameters, the bias and
    matrix elements (no std)."""
    extra = sec.extra or {}
    rows = [
        {"name": p["name"], "unit": p["unit"], "value": p["value"], "std": p["std"]}
        for p in _parameters(extra.get("parameters"))
    ]
    if not rows:
        bias = np.asarray(sec.bias, dtype=float).ravel()
        units_in = _text(extra.get("units_in")) or "raw units"
        rows += [
            {"name": f"bias[{i}]", "unit": units_in, "value": _number(v), "std": None}
            for i, v in enumerate(bias)
        ]
        matrix = np.asarray(sec.matrix, dtype=float)
        rows += [
            {"name": f"matrix[{i}][{j}]", "unit": f"{sec.units} per {units_in}",
             "value": _number(matrix[i, j]), "std": None}
            for i in range(matrix.shape[0]) for j in range(matrix.shape[1])
        ]  # fmt: skip
    sens = _sensitivity(extra.get("sensitivity"), extra.get("sensitivity_std"),
                        extra.get("sensitivity_unit"))  # fmt: skip
    if sens:
        names = "xyz" if len(sens["values"]) == 3 else [str(i) for i in range(len(sens["values"]))]
        stds = sens["std"] or [None] * len(sens["values"])
        rows += [
            {"name": f"sensitivity {a}", "unit": sens["unit"], "value": v, "std": s}
            for a, v, s in zip(names, sens["values"], stds, strict=True)
        ]
    for m in _misalignment(extra.get("misalignment_deg"), extra.get("misalignment_std_deg")):
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
        sensor = _text((cal.extra or {}).get("sensor"))
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
                # The reference: the first calibration that has this figure (an earlier one
                # may lack the section, e.g. an accelerometer-only run).
                ref = next(i for i, v in enumerate(values) if v is not None)
                change, z, flags = [], [], []
                for i, (v, s) in enumerate(zip(values, stds, strict=True)):
                    d = None if v is None or i < ref else v - values[ref]
                    combined = (
                        math.hypot(s, stds[ref])
                        if s is not None and stds[ref] is not None
                        else None
                    )
                    zz = None if d is None or not combined else d / combined
                    change.append(d)
                    z.append(zz)
                    flags.append(zz is not None and abs(zz) > DRIFT_SIGMAS)
                if any(flags):
                    drifted.append(f"{kind} {name}")
                rows.append({"name": name, "unit": unit, "values": values, "std": stds,
                             "reference": ref, "change": change, "z": z,
                             "drifted": flags})  # fmt: skip
            sections[kind] = {
                "solvers": [None if s is None else s.solver for s in secs],
                "rows": rows,
            }
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
                cells.append(Text(_fmt_std(row["values"][0], row["std"][0])))
                for i in range(1, len(cals)):
                    d, z, flag = row["change"][i], row["z"][i], row["drifted"][i]
                    if i == ref:  # first calibration with this figure: its value
                        cells.append(Text(_fmt_std(row["values"][i], row["std"][i]) + " (ref)"))
                        continue
                    if d is None:
                        cells.append(Text(_MISSING))
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
                _bullet_panel(entry["drifted"], "Drifted beyond the uncertainty", "bold red")
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
