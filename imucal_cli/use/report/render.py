"""Rendering a report dict (from :func:`~imucal_cli.use.report.build.build_report`) with rich.

The renderer only draws what the dict holds; it never reads a calibration file.  Each section
is drawn in a fixed order: warnings, model, matrix, parameters, angles/sensitivities (or the
factorization's Table I), RMS, fit, rotations, poses, coverage, generic ``tables``, notes and
what the calibration does not carry.
"""

from __future__ import annotations

from typing import Any

from rich import box
from rich.console import Console
from rich.panel import Panel
from rich.rule import Rule
from rich.table import Table
from rich.text import Text

from .coverage_map import coverage_map
from .fmt import MISSING, axis_name, fixed, fmt, fmt_like, fmt_std
from .imus import place_text
from .out import show_bullets, show_fields, show_table, show_text

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
    show_fields(console, _header_rows(report), "imucal calibration report")
    left_out = report.get("left_out") or {}
    if left_out:
        show_bullets(console, list(left_out.values()), "Not calibrated", "bold yellow")
    for kind, section in report["sensors"].items():
        console.print(Rule(Text(_section_title(kind, section)), style="bold"))
        _render_section(kind, section, report, console)
    if not report["sensors"]:
        show_text(console, Text("The calibration holds no sensor section.", style="yellow"))
    for name, imu in (report.get("imus") or {}).items():  # a set's other IMUs
        console.print(Rule(Text(place_text(name, imu)), style="bold"))
        notes = [*(imu.get("left_out") or {}).values(), *(imu.get("warnings") or [])]
        if notes:
            show_bullets(console, notes, f"{name}: warnings", "bold yellow")
        for kind, section in imu["sensors"].items():
            console.print(Rule(Text(f"{name} {_section_title(kind, section)}"), style="bold"))
            _render_section(kind, section, report, console)


def _render_section(kind: str, section: dict[str, Any], report: dict[str, Any], console) -> None:
    """One sensor section, in a fixed order (see the module notes)."""
    if section["warnings"]:
        show_bullets(console, section["warnings"], "Warnings", "bold yellow")
    show_fields(console, _model_rows(section))
    show_table(console, _matrix_table(section))
    if section["parameters"]:
        show_table(console, _parameter_table(section["parameters"]))
    factorization = section["factorization"]
    if factorization is not None:
        show_table(console, _table_one(section))
        if section["misalignment_deg"]:  # another tool's extra field: still shown
            _show_angles(console, {**section, "sensitivity": None})
    else:
        _show_angles(console, section)
    # The factorization's residual_rms is its constraint RMS, shown in the Table I layout.
    rms_rows = [k for k in _RMS_ROWS if factorization is None or k != "residual_rms"]
    if kind == "gyro":  # before/after/held out are gravity-pose figures: no rows of dashes
        rms_rows = [k for k in rms_rows if section["rms"][k] is not None]
    if any(section["rms"][key] is not None for key in rms_rows):
        reference = report.get("reference") if _shows_paper_reference(kind, section) else None
        show_table(console, _rms_table(section, reference, rms_rows))
    if section["fit"]:
        show_text(console, _fit_line(section["fit"]))
    if section["rotations"]:
        show_table(console, _rotations_table(section["rotations"]))
    if section["poses"]:
        show_table(console, _pose_table(section))
    if section["coverage"] or any(p["direction"] for p in section["poses"]):
        _show_coverage(console, section)
    for spec in section.get("tables", []):
        show_table(console, _generic_table(spec))
    for spec in section.get("maps", []):
        _show_map(console, spec)
    if section["notes"]:
        show_bullets(console, section["notes"], "Notes", "dim")
    if section["unavailable"]:
        show_bullets(console, section["unavailable"], "Not in this calibration", "dim")


def _show_angles(console: Console, section: dict[str, Any]) -> None:
    """Misalignment angles and sensitivities side by side in a terminal, one after the other
    elsewhere (so their titles are whole lines)."""
    parts = _angle_sensitivity_tables(section)
    if not parts:
        return
    if not console.is_terminal:
        for part in parts:
            show_table(console, part)
        return
    grid = Table.grid(padding=(0, 4))
    for _ in parts:
        grid.add_column()
    grid.add_row(*parts)
    console.print(grid)


def _generic_table(spec: dict[str, Any]) -> Table:
    """A table from a section's ``tables`` (see :func:`~.build.add_table`): text left, numbers
    right-aligned with 5 significant digits."""
    rows = spec["rows"]
    numeric = [
        all(isinstance(r[j], int | float) or r[j] is None for r in rows) and rows
        for j in range(len(spec["columns"]))
    ]
    title = spec["title"]
    table = Table(title=Text(title), box=box.SIMPLE, title_justify="left", pad_edge=False,
                  min_width=len(title))  # fmt: skip
    for name, is_number in zip(spec["columns"], numeric, strict=True):
        # Text: a unit in brackets ("[uT]") is not rich markup
        table.add_column(Text(name), justify="right" if is_number else "left",
                         no_wrap=bool(is_number))  # fmt: skip
    for row in rows:
        table.add_row(*(Text(MISSING if v is None else fmt(v) if isinstance(v, float) else str(v))
                        for v in row))  # fmt: skip
    if spec.get("caption"):
        table.caption = Text(spec["caption"])
        table.caption_justify = "left"
    return table


def _header_rows(report: dict[str, Any]) -> list[tuple[str, str]]:
    imported = report.get("imported_from")
    created = report["created"]
    if created and report.get("created_basis"):
        created = f"{created}, {report['created_basis']}"
    rows = [
        (name, str(value))
        for name, value in (
            ("imported from", imported and " file ".join(filter(None, imported.values()))),
            ("session", report["session"]),
            ("created", created),
            ("sensor", report["sensor"]),
            ("toolkit", report["toolkit_version"]),
        )
        if value
    ]
    if report["config"]:
        rows.append(("options", ", ".join(f"{k}={v}" for k, v in _flatten(report["config"]))))
    return rows


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


def _model_rows(section: dict[str, Any]) -> list[tuple[str, str]]:
    """Model equation, units in and out, gauge and gravity, one per line."""
    units_in = section["units_in"] or "units (not stated)"
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
    return rows


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
        table.add_row(axis, *(fmt(v) for v in row))
    table.add_row(Text("bias", style="bold"), *(fmt(v) for v in section["bias"]))
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
        text = fmt_std(value, std, unit) if with_std else fmt(value, unit)
        table.add_row(Text(name), Text(text))
    return table


def _parameter_table(parameters: list[dict[str, Any]]) -> Table:
    rows = [(p["name"] + (" (assumed)" if p.get("status") == "assumed" else ""), p["value"],
             p["std"], p["unit"]) for p in parameters]  # fmt: skip
    return _value_table("parameters", "name", rows)


def _angle_sensitivity_tables(section: dict[str, Any]) -> list[Table]:
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
    return parts


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
        cells = [name, fmt(rms[key], unit)]
        if show_mg:
            cells.append(fmt(rms[f"{key}_mg"], "mg", digits=3))
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
    if rms.get("after_note"):
        notes.append(f"after: {rms['after_note']}")
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
        cells = [label, row["name"], fmt_like(row["linear"], row["refined_std"])]
        if refined:
            cells.append(fmt_std(row["refined"], row["refined_std"]))
        table.add_row(*map(Text, cells))
    table.add_section()
    crms = fz["constraint_rms"]
    cells = [f"C_err RMS [{crms['unit']}]", "", fmt(crms["linear"], digits=4)]
    if refined:
        cells.append(fmt(crms["refined"], digits=4))
    table.add_row(*map(Text, cells))
    motions = "motions in g" if section["units_out"] == "m/s^2" else "motions in rad/s"
    caption = [f"C_err: RMS of f_i . f_k - h_ik over the constraints ({motions})"]
    if section["rms"]["residual_rms"] is not None:
        caption.append(
            f"residual_rms (standard field, as stored): {fmt(section['rms']['residual_rms'])}"
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
                    r["segment"] or MISSING,
                    r["label"] or MISSING,
                    *([fixed(r["known_angle_deg"], 3)] if reference else []),
                    fixed(r["measured_angle_deg"], 4),
                    MISSING if error is None else f"{error:+.3g}",
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
    if fit["message"] and fit["converged"] is False:  # the optimiser's words only when they matter
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
                    p["segment"] or MISSING,
                    p["label"] or MISSING,
                    axis_name(p["up"]),
                    MISSING if p["samples"] is None else str(p["samples"]),
                    fixed(p["magnitude_before"], 4),
                    fixed(p["magnitude_after"], 4),
                    fixed(residual, 3, signed=True),
                    fixed(held_out, 3, signed=True),
                    fixed(p["angle_to_up_deg"], 2),
                )
            )
        )
    return table


def _show_coverage(console: Console, section: dict[str, Any]) -> None:
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
        facts.append(f"weakest direction: {axis_name(coverage['weakest_direction'])}")
    if not directions:
        facts.append("no measured directions stored: no map")
    _show_map(console, {"title": "coverage of measured gravity directions",
                        "directions": directions, "facts": facts})  # fmt: skip


def _show_map(console: Console, spec: dict[str, Any]) -> None:
    """A section's ``maps`` entry: ``title``, unit ``directions``, ``facts`` beside the map."""
    grid = Table.grid(padding=(0, 3))
    grid.add_column(no_wrap=True)
    grid.add_column()
    directions = spec.get("directions") or []
    map_text = "\n".join(coverage_map(directions)) if directions else ""
    grid.add_row(Text(map_text), Text("\n".join(["", *spec.get("facts", [])])))
    title = spec.get("title", "coverage")
    if console.is_terminal:
        console.print(Panel(grid, title=title, expand=False))
    else:
        show_text(console, Text(title, style="bold"))
        console.print(grid)
