"""The magnetometer's part of a report: field, alignment, MotionCal-style quality with its
verdict, static poses, readings and the coverage map, as data (tables and a map) that the
renderer draws without code of its own."""

from __future__ import annotations

from typing import Any

from imucal_cli.formats.calibration import SensorCalibration

from .fields import as_list, as_number, as_text, as_vector, read_fields


def as_bool(value: Any) -> bool | None:
    return value if isinstance(value, bool) else None


def mag_report(sec: SensorCalibration) -> dict[str, Any]:
    """The ``mag`` fields of a section as stored (malformed fields read as ``None``).

    Keys: ``field_uT``, ``field_source``, ``field_estimate_uT``, ``inclination_deg``,
    ``inclination_std_deg``, ``aligned``, ``frame``, ``axes``, ``rotation_std_deg``,
    ``hard_iron_out``, ``hard_iron_out_magnitude``, ``soft_iron_axis_ratio_pct``,
    ``variance_before_pct``, ``dip_rms_deg``, ``readings``, ``quality`` (``verdict``,
    ``failed``, ``checks``: ``name``, ``value_pct``, ``limit_pct``, ``meaning``, ``ok``),
    ``coverage`` (``fraction``, ``gaps_pct``), ``poses`` and ``directions``.
    """
    x = sec.extra or {}
    quality = x.get("quality") if isinstance(x.get("quality"), dict) else None
    checks = []
    for c in as_list(quality.get("checks") if quality else None):
        if isinstance(c, dict):
            checks.append(read_fields(c, name=as_text, value_pct=as_number, limit_pct=as_number,
                                      meaning=as_text, ok=as_bool))  # fmt: skip
    coverage = x.get("coverage") if isinstance(x.get("coverage"), dict) else {}
    poses = []
    for p in as_list(x.get("poses")):
        if isinstance(p, dict):
            poses.append(read_fields(
                p, segment=as_text, label=as_text, samples=as_number, magnitude_after=as_number,
                residual=as_number, dip_residual_deg=as_number,
            ))  # fmt: skip
    return {
        **read_fields(x, field_uT=as_number, field_source=as_text, field_estimate_uT=as_number,
                      inclination_deg=as_number, inclination_std_deg=as_number, aligned=as_bool,
                      frame=as_text),
        "axes": [str(a) for a in as_list(x.get("axes"))],
        **read_fields(x, rotation_std_deg=as_number, hard_iron_out=as_vector,
                      hard_iron_out_magnitude=as_number, soft_iron_axis_ratio_pct=as_number,
                      variance_before_pct=as_number, dip_rms_deg=as_number),
        "readings": x.get("readings") if isinstance(x.get("readings"), dict) else None,
        "quality": None if quality is None else {
            "verdict": as_text(quality.get("verdict")),
            "failed": [str(f) for f in as_list(quality.get("failed"))],
            "checks": checks,
        },
        "coverage": {"fraction": as_number(coverage.get("fraction")),
                     "gaps_pct": as_number(coverage.get("gaps_pct"))},
        "poses": poses,
        "directions": [d for d in (as_vector(v) for v in as_list(x.get("directions"))) if d],
    }  # fmt: skip


def add_mag_content(section: dict[str, Any], sec: SensorCalibration, add_table) -> None:
    """Fill a report section of a magnetometer: ``section["mag"]``, its tables, its map, the
    held-out RMS, and a warning when the quality says recapture."""
    mag = mag_report(sec)
    section["mag"] = mag
    section["poses"] = []  # the magnetometer's poses and coverage are its own tables and map
    section["coverage"] = None
    unit = sec.units
    rms = section["rms"]
    rms["quantity"] = "field-magnitude error |B| - F"
    rms["held_out"] = as_number((sec.extra or {}).get("rms_held_out"))
    rms["held_out_method"] = "2-fold: alternate 1 s blocks and poses, each fitted without"
    _field_table(section, mag, unit, add_table)
    q = mag["quality"]
    if q and q["checks"]:
        verdict = q["verdict"] or "?"
        caption = (
            "verdict: pass" if verdict == "pass"
            else f"verdict: recapture ({', '.join(q['failed'])} over the limit)"
        )  # fmt: skip
        add_table(
            section, "quality of the fit (MotionCal's figures)",
            ["figure", "value [%]", "limit [%]", "meaning", "ok"],
            [[c["name"], c["value_pct"], c["limit_pct"], c["meaning"],
              "yes" if c["ok"] else "NO"] for c in q["checks"]],
            caption=caption,
        )  # fmt: skip
        if verdict != "pass":
            failed = ", ".join(
                f"{c['name']} {c['value_pct']:.1f} % > {c['limit_pct']:g} %"
                for c in q["checks"] if not c["ok"] and c["value_pct"] is not None
            )  # fmt: skip
            section["warnings"].append(
                f"magnetometer quality: recapture ({failed or 'figures missing'}): turn the "
                "unit through every direction, slowly, away from steel and magnets"
            )
    if mag["poses"]:
        add_table(
            section, "static poses (n: distinct readings; dip resid.: angle gravity-field "
            "minus the fitted one)",
            ["seg", "label", "n", f"|B| [{unit}]", f"residual [{unit}]", "dip resid. [deg]"],
            [[p["segment"], p["label"], p["samples"], p["magnitude_after"], p["residual"],
              p["dip_residual_deg"]] for p in mag["poses"]],
        )  # fmt: skip
    readings = mag["readings"] or {}
    left = readings.get("left_out") if isinstance(readings.get("left_out"), dict) else {}
    if readings:
        section["notes"].append(
            f"readings: {readings.get('motion')} in motion, {readings.get('poses')} static "
            f"poses; left out {left.get('nonfinite', 0)} without a value, "
            f"{left.get('clipped', 0)} clipped, {left.get('repeated', 0)} repeated"
        )
    cov = mag["coverage"]
    facts = []
    if cov["fraction"] is not None:
        facts.append(f"covered: {100 * cov['fraction']:.0f} % of 100 equal areas")
    if cov["gaps_pct"] is not None:
        facts.append(f"gaps (MotionCal): {cov['gaps_pct']:.1f} %")
    section.setdefault("maps", []).append({
        "title": "coverage of measured field directions",
        "directions": mag["directions"], "facts": facts,
    })  # fmt: skip


def _field_table(section, mag: dict[str, Any], unit: str, add_table) -> None:
    rows: list[list[Any]] = []
    if mag["field_uT"] is not None:
        rows.append(["field magnitude F", f"{mag['field_uT']:g} uT ({mag['field_source']})"])
    else:
        est = mag["field_estimate_uT"]
        rows.append([
            "field magnitude F",
            "unknown: output in units of the local field (|B| = 1)"
            + (f"; about {est:.3g} uT from the raw units" if est is not None else "")
            + "; set [mag] field_uT for uT",
        ])  # fmt: skip
    if mag["inclination_deg"] is not None:
        rows.append([
            "inclination (below horizontal)",
            f"{mag['inclination_deg']:.3f} ± {mag['inclination_std_deg'] or 0:.3f} deg",
        ])  # fmt: skip
    rows.append(["output frame", mag["frame"] or "—"])
    if mag["axes"]:
        rows.append(["magnetometer axes in it", ", ".join(mag["axes"])])
    if mag["rotation_std_deg"] is not None:
        rows.append(["rotation uncertainty", f"{mag['rotation_std_deg']:.3f} deg (1 sigma)"])
    if mag["hard_iron_out"]:
        h = mag["hard_iron_out"]
        rows.append([
            "hard iron, as a field",
            f"{mag['hard_iron_out_magnitude']:.4g} {unit} "
            f"({', '.join(f'{v:.4g}' for v in h)})",
        ])  # fmt: skip
    if mag["soft_iron_axis_ratio_pct"] is not None:
        rows.append([
            "soft iron", f"longest / shortest ellipsoid axis - 1 = "
            f"{mag['soft_iron_axis_ratio_pct']:.2f} %",
        ])  # fmt: skip
    if mag["variance_before_pct"] is not None:
        rows.append(["|raw| spread before", f"{mag['variance_before_pct']:.1f} % of its mean"])
    if mag["dip_rms_deg"] is not None:
        rows.append(["gravity-field angle RMS over the holds", f"{mag['dip_rms_deg']:.3f} deg"])
    add_table(section, "field and alignment", ["quantity", "value"], rows)
