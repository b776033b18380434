"""Building the report: what a stored calibration says, as a JSON-ready dict.

:func:`build_report` reads a :class:`~imucal_cli.formats.calibration.Calibration` and lays out
what the solver wrote, section by section (see :func:`_section_report` for the keys).  Nothing is
re-solved; fields a calibration does not carry are ``None`` (or empty) and named in the
section's ``unavailable``.  New report content goes here, as data: the renderer draws every
section's ``warnings``, ``notes``, ``parameters`` and ``tables`` generically.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from imucal_cli.formats.calibration import Calibration, SensorCalibration

from .fields import (
    as_int,
    as_list,
    as_number,
    as_text,
    as_vector,
    ratio,
    read_fields,
    read_misalignment,
    read_parameters,
    read_sensitivity,
    scaled,
)
from .mag import add_mag_content

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

MISSING = "—"

# (report key, what the user is told is not in the file, sensors it applies to)
_OPTIONAL_ITEMS = (
    ("variant", "model variant", ("accel", "gyro")),
    ("units_in", "raw input units", ("accel", "gyro")),
    ("parameters", "named parameters with standard deviations", ("accel", "gyro", "mag")),
    ("misalignment_deg", "misalignment angles", ("accel", "gyro")),
    ("sensitivity", "sensitivities", ("accel", "gyro")),
    ("fit", "solver iterations / convergence", ("accel", "gyro", "mag")),
    ("rms.before", "RMS before calibration", ("accel",)),
    ("rms.after", "RMS after calibration", ("accel", "mag")),
    ("mag.quality", "quality figures (gaps, variance, wobble, fit error)", ("mag",)),
    ("rms.held_out", "leave-one-pose-out (held-out) RMS", ("accel",)),
    ("rms.residual_rms", "solver residual RMS", ("accel", "gyro")),
    ("poses", "per-pose residuals", ("accel",)),
    ("coverage", "pose coverage (fraction, largest gap)", ("accel",)),
)


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
        ``toolkit_version``, ``config`` (the solver options that shaped this calibration, if
        recorded: those of solvers that did not run are left out), ``sensors``
        (``{"accel": ..., "gyro": ..., "mag": ...}``, only those present, see
        :func:`_section_report`; a magnetometer's adds :func:`.mag.mag_report` as ``mag``) and
        ``reference`` (the paper's published RMS before/after, for context: only for a
        simulated session calibrated by the gravity solver, else ``None``); for a calibration
        another tool made, ``imported_from`` (``format``, ``file``) and ``created_basis`` (what
        ``created`` is, when the format records no date), else ``None``; ``left_out``: the
        sensors the calibrate step left out, with why (``{"accel": note}``; empty when none);
        ``complete``: the calibrate step's verdict (no sensor of the session left out), None
        when the calibration does not record it.
    """
    extra = cal.extra or {}
    sections = cal.sections()
    return {
        "format": REPORT_FORMAT,
        "format_version": REPORT_FORMAT_VERSION,
        "session": cal.session,
        "created": cal.created,
        "created_basis": as_text(extra.get("created_basis")),
        "imported_from": _imported_from(extra.get("imported_from")),
        "sensor": as_text(extra.get("sensor")),
        "toolkit_version": as_text(extra.get("toolkit_version")),
        "config": _relevant_config(extra.get("config"), cal),
        "sensors": {
            kind: _section_report(kind, section)
            for kind, section in sections.items()
            if section is not None
        },
        "reference": dict(PAPER_REFERENCE) if _paper_context(cal) else None,
        "left_out": {
            kind: as_text(extra.get(f"{kind}_note"))
            for kind in ("accel", "gyro", "mag")
            if extra.get(f"{kind}_note") and sections.get(kind) is None
        },
        "complete": _complete(extra),
    }


def _complete(extra: dict) -> bool | None:
    """The calibrate step's ``complete`` (issue 24.2: no sensor of the session left out), or
    None for a calibration that does not record it (older, or another tool's)."""
    value = extra.get("complete")
    return value if isinstance(value, bool) else None


def _imported_from(raw: Any) -> dict[str, str | None] | None:
    """``{"format", "file"}`` of a calibration read from another tool's file, else None."""
    if not isinstance(raw, dict):
        return None
    found = {"format": as_text(raw.get("format")), "file": as_text(raw.get("file"))}
    return found if any(found.values()) else None


# Option tables shared by several solvers of a section (the others are named after their solver).
_SHARED_OPTIONS = {"rotations": ("static", "dynamic", "full")}


def _relevant_config(config: Any, cal: Calibration) -> dict[str, Any] | None:
    """The options that shaped this calibration: the root keys, and per section present its own
    keys and the table of the solver that ran (not every solver's defaults)."""
    if not isinstance(config, dict):
        return None
    out: dict[str, Any] = {}
    for key, value in config.items():
        sec = getattr(cal, key) if key in ("accel", "gyro") else None
        if not isinstance(value, dict) or key not in ("accel", "gyro"):
            out[key] = value
        elif sec is not None:  # else the sensor was not calibrated
            solver = sec.solver.removeprefix(f"{key}-")
            out[key] = {
                name: option
                for name, option in value.items()
                if not isinstance(option, dict)
                or name == solver
                or solver in _SHARED_OPTIONS.get(name, ())
            }
    return out


def _paper_context(cal: Calibration) -> bool:
    """Qureshi & Golnaraghi's published figure is context for a simulation of their design
    calibrated by their solver, not for the user's own sensor."""
    source = as_text((cal.extra or {}).get("source"))
    return cal.accel is not None and cal.accel.solver == "gravity" and source == "simulator"


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
    ``known_angle_deg``, ``measured_angle_deg``, ``angle_error_deg``), ``g_sensitivity``
    (``matrix`` n x 3, ``unit``: the gyro's response to the calibrated acceleration, or
    ``None``; drawn as a table when the parameters do not list it), ``tables`` (further
    tables, drawn as they are: ``title``, ``columns``, ``rows`` of cells, optional ``caption``;
    new report content is added here as data, see :func:`add_table`), ``notes``, ``warnings``
    and ``unavailable`` (what this calibration does not carry).  Non-finite numbers read as
    ``None`` (strict JSON).
    """
    extra = sec.extra or {}
    units_in = as_text(extra.get("units_in"))
    gravity = _gravity(kind, sec)
    mg_per_unit = 1000.0 / gravity["value"] if gravity else None
    g_sensitivity = _g_sensitivity(sec, units_in)
    model = as_text(extra.get("model")) or "calibrated = matrix @ (raw - bias)"
    if g_sensitivity is not None and "g_sensitivity" not in model:
        model = "calibrated = matrix @ (raw - bias - g_sensitivity @ a)"
    report: dict[str, Any] = {
        "solver": sec.solver,
        "variant": as_text(extra.get("variant")),
        "gauge": as_text(extra.get("gauge")),
        "model": model,
        "units_in": units_in,
        "units_out": sec.units,
        "matrix": np.asarray(sec.matrix, dtype=float).tolist(),
        "matrix_unit": f"{sec.units} per {units_in or 'raw unit'}",
        "bias": np.asarray(sec.bias, dtype=float).tolist(),
        "bias_unit": units_in or "raw units",
        "gravity": gravity,
        "parameters": read_parameters(extra.get("parameters")),
        "misalignment_deg": read_misalignment(
            extra.get("misalignment_deg"), extra.get("misalignment_std_deg")
        ),
        "sensitivity": read_sensitivity(
            extra.get("sensitivity"), extra.get("sensitivity_std"), extra.get("sensitivity_unit")
        ),
        "fit": _fit(extra),
        "rms": _rms_report(sec, mg_per_unit),
        "coverage": _coverage(extra.get("coverage")),
        "poses": _poses(extra.get("poses"), mg_per_unit),
        "rotation": as_text(extra.get("rotation")),
        "factorization": _factorization(kind, sec),
        "rotations": _rotations(extra.get("rotations")),
        "g_sensitivity": g_sensitivity,
        "tables": [],
        "notes": [str(n) for n in as_list(extra.get("notes"))],
        "warnings": [str(w) for w in as_list(extra.get("warnings"))],
    }
    if kind == "mag":
        add_mag_content(report, sec, add_table)
    if g_sensitivity is not None and not any(
        p["name"].startswith("g_") for p in report["parameters"]
    ):  # the matrix alone (another tool's file): as a table
        rows = [[axis, *row] for axis, row in zip("xyz", g_sensitivity["matrix"], strict=False)]
        add_table(report, f"g-sensitivity [{g_sensitivity['unit']}]", ["", "a_x", "a_y", "a_z"],
                  rows, caption="raw - bias - g_sensitivity @ a, with a the calibrated "
                  "acceleration in m/s^2")  # fmt: skip
    _terms_tables(report, extra)
    report["unavailable"] = _unavailable(kind, report)
    return report


def _g_sensitivity(sec: SensorCalibration, units_in: str | None) -> dict[str, Any] | None:
    """The section's g-sensitivity matrix and its unit, or None (absent or malformed)."""
    try:
        matrix = sec.g_sensitivity
    except Exception:  # noqa: BLE001  (a malformed optional field reads as missing)
        return None
    if matrix is None:
        return None
    unit = as_text(sec.extra.get("g_sensitivity_unit"))
    unit = unit.split(" (")[0] if unit else f"{units_in or 'raw units'} per m/s^2"
    return {"matrix": np.asarray(matrix, dtype=float).tolist(), "unit": unit}


def _terms_tables(report: dict[str, Any], extra: dict[str, Any]) -> None:
    """Tables of the optional terms (issue 17): the bias temperature model and the sample
    clock, when the section has them."""
    model = extra.get("temperature_model")
    if isinstance(model, dict) and isinstance(extra.get("bias_tempco"), list):
        tc = np.asarray(extra["bias_tempco"], dtype=float)
        std = np.asarray(model.get("bias_tempco_std", np.zeros_like(tc)), dtype=float)
        unit = as_text(model.get("unit")) or "raw units per C^k"
        rows = []
        degrees = as_list(model.get("degree"))
        names = "xyz" if len(degrees) == 3 else [str(i) for i in range(len(degrees))]
        for i, deg in enumerate(degrees):
            cells = [names[i], deg]
            for k in range(3):
                cells += [float(tc[k, i]) if k < len(tc) else None,
                          float(std[k, i]) if k < len(std) else None]  # fmt: skip
            rows.append(cells)
        lo, hi = (as_list(model.get("range_c")) + [float("nan")] * 2)[:2]
        add_table(report, "bias temperature model", ["channel", "degree", "c1", "c1 std", "c2",
                  "c2 std", "c3", "c3 std"], rows,  # fmt: skip
                  caption=f"bias(T) = bias + sum_k c_k (T - {float(extra['temperature_ref']):.2f}"
                  f" C)^k, {unit}; fitted over {float(lo):.1f} .. {float(hi):.1f} C from "
                  f"{as_text(model.get('source'))}")  # fmt: skip
    clock = extra.get("sample_clock")
    if isinstance(clock, dict) and "ppm" in clock:
        add_table(report, "sample clock", ["scale [device s per s]", "error [ppm]",
                  "std [ppm]", "host jitter [ms]", "recording [s]"],  # fmt: skip
                  [[clock.get("scale"), clock.get("ppm"), clock.get("ppm_std"),
                    1000 * float(clock.get("jitter_s") or 0.0), clock.get("duration_s")]],
                  caption=f"the device's sample clock runs {clock['ppm']:+.1f} ± "
                  f"{clock.get('ppm_std', float('nan')):.2g} ppm against the host's arrival "
                  "times (error and std in ppm, jitter in ms, recording in s); "
                  + ("the gyro was calibrated in true seconds (corrected by it)"
                     if clock.get("applied", True) else "not corrected: within "
                     f"{float(clock.get('threshold_ppm') or 0.0):.3g} ppm (3 std) of a clock "
                     "that is right"))  # fmt: skip


def add_table(
    section: dict[str, Any],
    title: str,
    columns: list[str],
    rows: list[list[Any]],
    caption: str | None = None,
) -> None:
    """Append a generic table to a section of the report (drawn as is, after the coverage).

    Cells are numbers, strings or ``None`` (drawn as a dash); a column whose title ends in a
    unit in brackets (``"residual [mg]"``) says the unit of its numbers.
    """
    if any(len(row) != len(columns) for row in rows):
        raise ValueError(f"table {title!r}: every row needs {len(columns)} cells")
    section["tables"].append(
        {"title": title, "columns": list(columns), "rows": [list(r) for r in rows],
         "caption": caption}
    )  # fmt: skip


def _gravity(kind: str, sec: SensorCalibration) -> dict[str, Any] | None:
    """Gravity for milli-g figures: the calibration's own, else standard for an accelerometer."""
    stated = as_number(sec.extra.get("gravity"))
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
        "before": as_number(extra.get("rms_before")),
        "after": as_number(extra.get("rms_after")),
        "held_out": as_number(extra.get("rms_loo")),
        "residual_rms": as_number(sec.residual_rms),
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
        rms[f"{key}_mg"] = scaled(value, mg_per_unit)
    exact = extra.get("rms_after_below_noise") is True  # no factor of a fit below the noise
    rms["improvement"] = None if exact else ratio(figures["before"], figures["after"])
    rms["improvement_held_out"] = ratio(figures["before"], figures["held_out"])
    if exact:
        rms["after_note"] = (
            "the fit residual is below what the noise allows (too few spare equations): it "
            "says nothing about the accuracy; see the held-out figure"
        )
    rms["before_basis"] = as_text(extra.get("before_basis"))
    rms["held_out_method"] = as_text(extra.get("loo_method"))
    return rms


def _fit(extra: dict[str, Any]) -> dict[str, Any] | None:
    fit = {
        "init": as_text(extra.get("init")),
        "iterations": as_int(extra.get("iterations")),
        "converged": extra.get("converged") if isinstance(extra.get("converged"), bool) else None,
        "message": as_text(extra.get("message")),
        "noise_scale": as_number(extra.get("noise_scale")),
        "weighting": as_text(extra.get("weighting")),
        "chi2": as_number(extra.get("chi2")),
        "dof": as_int(extra.get("dof")),
    }
    return fit if any(v is not None for v in fit.values()) else None


def _coverage(raw: Any) -> dict[str, Any] | None:
    if not isinstance(raw, dict):
        return None
    return read_fields(raw, fraction=as_number, largest_gap_deg=as_number, n_poses=as_int,
                       n_distinct=as_int, cap_deg=as_number, weakest_direction=as_vector)


def _poses(raw: Any, mg_per_unit: float | None) -> list[dict[str, Any]]:
    rows = []
    for item in as_list(raw):
        if not isinstance(item, dict):
            continue
        row = {
            "segment": as_text(item.get("segment")),
            "label": as_text(item.get("label")),
            "up": as_vector(item.get("up")),
            "samples": as_int(item.get("samples")),
            "magnitude_before": as_number(item.get("magnitude_before")),
            "magnitude_after": as_number(item.get("magnitude_after")),
            "residual": as_number(item.get("residual")),
            "residual_loo": as_number(item.get("residual_loo")),
            "angle_to_up_deg": as_number(item.get("angle_to_up_deg")),
            "direction": as_vector(item.get("direction")),
        }
        row["residual_mg"] = scaled(row["residual"], mg_per_unit)
        row["residual_loo_mg"] = scaled(row["residual_loo"], mg_per_unit)
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
    n = np.asarray(sec.bias, dtype=float).size
    names = [str(a) for a in as_list(extra.get("axis_names"))]
    if len(names) != n:
        names = list("xyz") if n == 3 else [str(i + 1) for i in range(n)]
    refined = extra.get("refined") if isinstance(extra.get("refined"), bool) else bool(linear)
    rows = _table_one_rows(sec, names, linear, refined)
    final_rms = as_number(extra.get("constraint_rms"))
    return {
        "configuration": as_text(extra.get("configuration")),
        "case": as_text(extra.get("case")),
        "elements": as_int(extra.get("elements")) or n,
        "axis_names": names,
        "refined": refined,
        "linear_method": as_text(linear.get("method")),
        "use": as_text(extra.get("use")),
        "constraints": as_int(extra.get("constraints")),
        "singular_values": [v for v in map(as_number, as_list(extra.get("singular_values")))],
        "rows": rows,
        "constraint_rms": {
            "linear": as_number(linear.get("constraint_rms")) if linear else final_rms,
            "refined": final_rms if refined else None,
            "unit": "g^2" if kind == "accel" else f"({sec.units})^2",
        },
    }


def _element(values: Any, i: int) -> float | None:
    items = as_list(values)
    return as_number(items[i]) if i < len(items) else None


def _pair(matrix: Any, i: int, j: int) -> float | None:
    row = as_list(matrix)[i] if i < len(as_list(matrix)) else None
    return _element(row, j)


def _table_one_rows(
    sec: SensorCalibration, names: list[str], linear: dict[str, Any], refined: bool
) -> list[dict[str, Any]]:
    """Table I rows: per element its bias and gain, per pair the angle (see `_factorization`)."""
    extra = sec.extra or {}
    bias = [as_number(v) for v in np.asarray(sec.bias, dtype=float).ravel()]
    std_of = {p["name"]: p["std"] for p in read_parameters(extra.get("parameters"))}
    units_in = as_text(extra.get("units_in")) or "raw units"
    gain_unit = as_text(extra.get("sensitivity_unit")) or f"{units_in} per {sec.units}"
    final = {
        "bias": lambda i: bias[i],
        "gain": lambda i: _element(extra.get("sensitivity"), i),
        "angle": lambda i, j: _pair(extra.get("angles_deg"), i, j),
    }
    final_std = {
        "bias": lambda i: std_of.get(f"b_{names[i]}"),
        "gain": lambda i: _element(extra.get("sensitivity_std"), i),
        "angle": lambda i, j: _pair(extra.get("angles_std_deg"), i, j),
    }
    first = {
        "bias": lambda i: _element(linear.get("bias"), i),
        "gain": lambda i: _element(linear.get("sensitivity"), i),
        "angle": lambda i, j: _pair(linear.get("angles_deg"), i, j),
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
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            add("angle", f"s{names[i]}s{names[j]}", "deg", i, j)
    return rows


def _rotations(raw: Any) -> list[dict[str, Any]]:
    rows = []
    for item in as_list(raw):
        if isinstance(item, dict):
            rows.append(
                {
                    "segment": as_text(item.get("segment")),
                    "label": as_text(item.get("label")),
                    "known_angle_deg": as_number(item.get("known_angle_deg")),
                    "measured_angle_deg": as_number(item.get("measured_angle_deg")),
                    "angle_error_deg": as_number(item.get("angle_error_deg")),
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
