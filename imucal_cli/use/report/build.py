"""Building the report: what a stored calibration says, as a JSON-ready dict.

:func:`build_report` reads a :class:`~imucal_cli.model.calibration.Calibration` and lays out
what the solver wrote, section by section (see :func:`_section_report` for the keys).  Nothing is
re-solved; fields a calibration does not carry are ``None`` (or empty) and named in the
section's ``unavailable``.  New report content goes here, as data: the renderer draws every
section's ``warnings``, ``notes``, ``parameters`` and ``tables`` generically.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from imucal_cli.model.accel import Coverage, PoseRow
from imucal_cli.model.calibration import Calibration, SensorCalibration
from imucal_cli.model.gyro import RotationRow
from imucal_cli.model.parts import Factorization, FitStatistics, ImportedFrom, Linear

from .fields import (
    as_list,
    as_number,
    as_vector,
    member,
    ratio,
    read_misalignment,
    read_parameters,
    read_sensitivity,
    scaled,
)
from .imus import imus_report
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
    sections = cal.sections()
    return {
        "format": REPORT_FORMAT,
        "format_version": REPORT_FORMAT_VERSION,
        "session": cal.session,
        "created": cal.created,
        "created_basis": cal.created_basis,
        "imported_from": _imported_from(cal.imported_from),
        "sensor": cal.sensor,
        "toolkit_version": cal.toolkit_version,
        "config": _relevant_config(cal.config, cal),
        "sensors": {
            kind: _section_report(kind, section)
            for kind, section in sections.items()
            if section is not None
        },
        "reference": dict(PAPER_REFERENCE) if _paper_context(cal) else None,
        "left_out": {
            kind: cal.note(kind)
            for kind in ("accel", "gyro", "mag")
            if cal.note(kind) and sections.get(kind) is None
        },
        "complete": cal.complete,  # None: not recorded (older, or another tool's)
        "imus": imus_report(cal, _section_report),  # a set's other IMUs ({} for one IMU)
    }


def _imported_from(found: ImportedFrom | None) -> dict[str, str | None] | None:
    """``{"format", "file"}`` of a calibration read from another tool's file, else None."""
    if found is None or not (found.format or found.file):
        return None
    return {"format": found.format, "file": found.file}


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
    return cal.accel is not None and cal.accel.solver == "gravity" and cal.source == "simulator"


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
    units_in = sec.units_in
    gravity = _gravity(kind, sec)
    mg_per_unit = 1000.0 / gravity["value"] if gravity else None
    g_sensitivity = _g_sensitivity(sec, units_in)
    model = sec.model or "calibrated = matrix @ (raw - bias)"
    if g_sensitivity is not None and "g_sensitivity" not in model:
        model = "calibrated = matrix @ (raw - bias - g_sensitivity @ a)"
    report: dict[str, Any] = {
        "solver": sec.solver,
        "variant": sec.variant,
        "gauge": sec.gauge,
        "model": model,
        "units_in": units_in,
        "units_out": sec.units,
        "matrix": np.asarray(sec.matrix, dtype=float).tolist(),
        "matrix_unit": f"{sec.units} per {units_in or 'raw unit'}",
        "bias": np.asarray(sec.bias, dtype=float).tolist(),
        "bias_unit": units_in or "raw units",
        "gravity": gravity,
        "parameters": read_parameters(sec.parameters),
        "misalignment_deg": read_misalignment(sec.misalignment_deg, sec.misalignment_std_deg),
        "sensitivity": read_sensitivity(sec.sensitivity, sec.sensitivity_std,
                                        sec.sensitivity_unit),  # fmt: skip
        "fit": _fit(sec.fit),
        "rms": _rms_report(sec, mg_per_unit),
        "coverage": _coverage(member(sec, "coverage") if kind == "accel" else None),
        "poses": _poses(member(sec, "poses") if kind == "accel" else None, mg_per_unit),
        "rotation": _frame_words(sec),
        "factorization": _factorization(kind, sec),
        "rotations": _rotations(member(sec, "rotations")),
        "g_sensitivity": g_sensitivity,
        "tables": [],
        "notes": list(sec.notes or []),
        "warnings": list(sec.warnings or []),
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
    _terms_tables(report, sec)
    _partial_table(report, sec)
    report["unavailable"] = _unavailable(kind, report)
    return report


def _partial_table(report: dict[str, Any], sec: SensorCalibration) -> None:
    """Which parameters the session measured and which are assumed (issue 27.3: a design
    that cannot fix the whole model), with the prior and what capture would measure the
    rest, as a table."""
    part = sec.partial
    if part is None:
        return
    rows = []
    for p in sec.parameters or []:
        if p.status is None:
            continue
        rows.append([p.name, p.status, as_number(p.value), as_number(p.std),
                     as_number(p.prior_std), p.unit])  # fmt: skip
    caption = f"prior: {part.prior}. {part.rule}."
    if part.capture:
        caption += f" To measure the rest: {part.capture}."
    add_table(report, "measured and assumed", ["parameter", "status", "value", "std",
                                               "prior std", "unit"], rows, caption)  # fmt: skip


def _g_sensitivity(sec: SensorCalibration, units_in: str | None) -> dict[str, Any] | None:
    """The section's g-sensitivity matrix and its unit, or None (absent or malformed)."""
    try:
        matrix = sec.g_term
    except Exception:  # noqa: BLE001  (a malformed optional field reads as missing)
        return None
    if matrix is None:
        return None
    unit = sec.g_sensitivity_unit
    unit = unit.split(" (")[0] if unit else f"{units_in or 'raw units'} per m/s^2"
    return {"matrix": np.asarray(matrix, dtype=float).tolist(), "unit": unit}


def _prior_table(report: dict[str, Any], model, names, unit: str) -> None:
    """How much of each temperature term's std comes from the prior of the terms the poses
    cannot fit (a ramp's cubic), when the fit carried one."""
    used, part = model.prior_tempco_mg_per_c, model.bias_tempco_std_prior
    if used is None or part is None:
        return
    part = np.asarray(part, dtype=float)
    rows = [[names[i], float(used[i])] + [float(part[k, i]) if k < len(part) else None
                                          for k in range(2)] for i in range(len(used))]
    add_table(report, "temperature terms' std from the prior", ["channel",
              "prior tempco [mg/C]", "c1 std from prior", "c2 std from prior"], rows,
              caption=f"{unit}; each std^2 = noise^2 + prior^2: the terms the poses cannot fit "
              "(the cubic) are carried from a prior within the linear tempco shown "
              "([temperature] accel_tempco_mg_per_c, or the fitted one where it is larger)")


def _terms_tables(report: dict[str, Any], sec: SensorCalibration) -> None:
    """Tables of the optional terms (issue 17): the bias temperature model and the sample
    clock, when the section has them."""
    model = sec.temperature_model
    if model is not None and sec.bias_tempco is not None:
        tc = np.asarray(sec.bias_tempco, dtype=float).reshape(-1, sec.bias.size)
        std = np.asarray(model.bias_tempco_std if model.bias_tempco_std is not None
                         else np.zeros_like(tc), dtype=float)  # fmt: skip
        unit = model.unit or "raw units per C^k"
        rows = []
        degrees = list(model.degree or [])
        names = "xyz" if len(degrees) == 3 else [str(i) for i in range(len(degrees))]
        for i, deg in enumerate(degrees):
            cells = [names[i], deg]
            for k in range(3):
                cells += [float(tc[k, i]) if k < len(tc) else None,
                          float(std[k, i]) if k < len(std) else None]  # fmt: skip
            rows.append(cells)
        lo, hi = (list(model.range_c or []) + [float("nan")] * 2)[:2]
        add_table(report, "bias temperature model", ["channel", "degree", "c1", "c1 std", "c2",
                  "c2 std", "c3", "c3 std"], rows,  # fmt: skip
                  caption=f"bias(T) = bias + sum_k c_k (T - {float(sec.temperature_ref):.2f}"
                  f" C)^k, {unit}; fitted over {float(lo):.1f} .. {float(hi):.1f} C from "
                  f"{model.source}")  # fmt: skip
        _prior_table(report, model, names, unit)
    clock = member(sec, "sample_clock")
    if clock is not None and clock.ppm is not None:
        ppm_std = float("nan") if clock.ppm_std is None else clock.ppm_std
        add_table(report, "sample clock", ["scale [device s per s]", "error [ppm]",
                  "std [ppm]", "host jitter [ms]", "recording [s]"],  # fmt: skip
                  [[clock.scale, clock.ppm, clock.ppm_std,
                    1000 * float(clock.jitter_s or 0.0), clock.duration_s]],
                  caption=f"the device's sample clock runs {clock.ppm:+.1f} ± "
                  f"{ppm_std:.2g} ppm against the host's arrival "
                  "times (error and std in ppm, jitter in ms, recording in s); "
                  + ("the gyro was calibrated in true seconds (corrected by it)"
                     if clock.applied in (None, True) else "not corrected: within "
                     f"{float(clock.threshold_ppm or 0.0):.3g} ppm (3 std) of a clock "
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
    stated = as_number(member(sec, "gravity"))
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
    figures = {
        "before": as_number(member(sec, "rms_before")),
        "after": as_number(member(sec, "rms_after")),
        "held_out": as_number(member(sec, "rms_loo")),
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
    exact = member(sec, "rms_after_below_noise") is True  # no factor of a fit below the noise
    rms["improvement"] = None if exact else ratio(figures["before"], figures["after"])
    rms["improvement_held_out"] = ratio(figures["before"], figures["held_out"])
    if exact:
        rms["after_note"] = (
            "the fit residual is below what the noise allows (too few spare equations): it "
            "says nothing about the accuracy; see the held-out figure"
        )
    rms["before_basis"] = member(sec, "before_basis")
    rms["held_out_method"] = member(sec, "loo_method")
    return rms


def _frame_words(sec: SensorCalibration) -> str | None:
    """How the free rotation of a factorization was fixed (the section's ``rotation``)."""
    found = member(sec, "factorization")
    return None if found is None else found.rotation


def _fit(fit: FitStatistics | None) -> dict[str, Any] | None:
    if fit is None:
        return None
    out = {
        "init": fit.init,
        "iterations": fit.iterations,
        "converged": fit.converged,
        "message": fit.message,
        "noise_scale": as_number(fit.noise_scale),
        "weighting": fit.weighting,
        "chi2": as_number(fit.chi2),
        "dof": fit.dof,
    }
    return out if any(v is not None for v in out.values()) else None


def _coverage(cover: Coverage | None) -> dict[str, Any] | None:
    if cover is None:
        return None
    return {"fraction": as_number(cover.fraction),
            "largest_gap_deg": as_number(cover.largest_gap_deg), "n_poses": cover.n_poses,
            "n_distinct": cover.n_distinct, "cap_deg": as_number(cover.cap_deg),
            "weakest_direction": as_vector(cover.weakest_direction)}  # fmt: skip


def _poses(poses: list[PoseRow] | None, mg_per_unit: float | None) -> list[dict[str, Any]]:
    rows = []
    for item in poses or []:
        row = {
            "segment": item.segment,
            "label": item.label,
            "up": as_vector(item.up),
            "samples": item.samples,
            "magnitude_before": as_number(item.magnitude_before),
            "magnitude_after": as_number(item.magnitude_after),
            "residual": as_number(item.residual),
            "residual_loo": as_number(item.residual_loo),
            "angle_to_up_deg": as_number(item.angle_to_up_deg),
            "direction": as_vector(item.direction),
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
    fz = member(sec, "factorization")
    if sec.solver != "factorization" and (fz is None or fz.linear is None):
        return None
    fz = fz or Factorization()
    linear = fz.linear
    n = np.asarray(sec.bias, dtype=float).size
    names = list(fz.axis_names or [])
    if len(names) != n:
        names = list("xyz") if n == 3 else [str(i + 1) for i in range(n)]
    refined = fz.refined if fz.refined is not None else linear is not None
    rows = _table_one_rows(sec, fz, names, refined)
    final_rms = as_number(fz.constraint_rms)
    return {
        "configuration": fz.configuration,
        "case": fz.case,
        "elements": fz.elements or n,
        "axis_names": names,
        "refined": refined,
        "linear_method": None if linear is None else linear.method,
        "use": fz.use,
        "constraints": fz.constraints,
        "singular_values": [as_number(v) for v in fz.singular_values or []],
        "rows": rows,
        "constraint_rms": {
            "linear": as_number(linear.constraint_rms) if linear else final_rms,
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
    sec: SensorCalibration, fz: Factorization, names: list[str], refined: bool
) -> list[dict[str, Any]]:
    """Table I rows: per element its bias and gain, per pair the angle (see `_factorization`)."""
    linear = fz.linear or Linear()
    bias = [as_number(v) for v in np.asarray(sec.bias, dtype=float).ravel()]
    std_of = {p["name"]: p["std"] for p in read_parameters(sec.parameters)}
    units_in = sec.units_in or "raw units"
    gain_unit = sec.sensitivity_unit or f"{units_in} per {sec.units}"
    final = {
        "bias": lambda i: bias[i],
        "gain": lambda i: _element(sec.sensitivity, i),
        "angle": lambda i, j: _pair(fz.angles_deg, i, j),
    }
    final_std = {
        "bias": lambda i: std_of.get(f"b_{names[i]}"),
        "gain": lambda i: _element(sec.sensitivity_std, i),
        "angle": lambda i, j: _pair(fz.angles_std_deg, i, j),
    }
    first = {
        "bias": lambda i: _element(linear.bias, i),
        "gain": lambda i: _element(linear.sensitivity, i),
        "angle": lambda i, j: _pair(linear.angles_deg, i, j),
    }
    rows = []

    def add(group: str, name: str, unit: str, *index: int) -> None:
        lin = first[group](*index) if fz.linear is not None else final[group](*index)
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


def _rotations(rotations: list[RotationRow] | None) -> list[dict[str, Any]]:
    return [{"segment": r.segment, "label": r.label,
             "known_angle_deg": as_number(r.known_angle_deg),
             "measured_angle_deg": as_number(r.measured_angle_deg),
             "angle_error_deg": as_number(r.angle_error_deg)}
            for r in rotations or []]  # fmt: skip


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
