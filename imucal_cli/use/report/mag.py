"""The magnetometer's part of a report: field, alignment, MotionCal-style quality with its
verdict, static poses, readings and the coverage map, as data (tables and a map) that the
renderer draws without code of its own."""

from __future__ import annotations

from typing import Any

from imucal_cli.model.calibration import SensorCalibration
from imucal_cli.model.codec import encode
from imucal_cli.model.mag import MagCalibration, MagCoverage, RowsLeftOut

from .fields import as_number, as_vector, member


def mag_report(sec: SensorCalibration) -> dict[str, Any]:
    """The ``mag`` fields of a section as stored (what its class does not hold, or the file
    did not give, is ``None``).

    Keys: ``field_uT``, ``field_source``, ``field_estimate_uT``, ``inclination_deg``,
    ``inclination_std_deg``, ``aligned``, ``frame``, ``axes``, ``rotation_std_deg``,
    ``hard_iron_out``, ``hard_iron_out_magnitude``, ``soft_iron_axis_ratio_pct``,
    ``variance_before_pct``, ``dip_rms_deg``, ``readings``, ``quality`` (``verdict``,
    ``failed``, ``checks``: ``name``, ``value_pct``, ``limit_pct``, ``meaning``, ``ok``),
    ``coverage`` (``fraction``, ``gaps_pct``), ``poses`` and ``directions``.
    """
    m = sec if isinstance(sec, MagCalibration) else MagCalibration(
        field_uT=member(sec, "field_uT"), inclination_deg=member(sec, "inclination_deg"),
        frame=sec.frame)  # a truth section: its field only  # fmt: skip
    quality = m.quality
    coverage = m.coverage or MagCoverage()
    return {
        "field_uT": as_number(m.field_uT), "field_source": m.field_source,
        "field_estimate_uT": as_number(m.field_estimate_uT),
        "inclination_deg": as_number(m.inclination_deg),
        "inclination_std_deg": as_number(m.inclination_std_deg), "aligned": m.aligned,
        "frame": m.frame, "axes": list(m.axes or []),
        "rotation_std_deg": as_number(m.rotation_std_deg),
        "hard_iron_out": as_vector(m.hard_iron_out),
        "hard_iron_out_magnitude": as_number(m.hard_iron_out_magnitude),
        "soft_iron_axis_ratio_pct": as_number(m.soft_iron_axis_ratio_pct),
        "variance_before_pct": as_number(m.variance_before_pct),
        "dip_rms_deg": as_number(m.dip_rms_deg),
        "readings": m.readings,
        "quality": None if quality is None else {
            "verdict": quality.verdict,
            "failed": list(quality.failed or []),
            "checks": [{"name": c.name, "value_pct": as_number(c.value_pct),
                        "limit_pct": as_number(c.limit_pct), "meaning": c.meaning, "ok": c.ok,
                        "held_pct": as_number(c.held_pct)}
                       for c in quality.checks or []],
        },
        "coverage": {"fraction": as_number(coverage.fraction),
                     "gaps_pct": as_number(coverage.gaps_pct)},
        "poses": [{"segment": p.segment, "label": p.label, "samples": p.samples,
                   "magnitude_after": as_number(p.magnitude_after),
                   "residual": as_number(p.residual),
                   "dip_residual_deg": as_number(p.dip_residual_deg)} for p in m.poses or []],
        "directions": [d for d in (as_vector(v) for v in m.directions or []) if d],
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
    rms["held_out"] = as_number(member(sec, "rms_held_out"))
    rms["held_out_method"] = "2-fold: alternate 1 s blocks and poses, each fitted without"
    _field_table(section, mag, unit, add_table)
    _quality_table(section, mag["quality"], add_table)
    if mag["poses"]:
        add_table(
            section, "static poses (n: distinct readings; dip resid.: angle gravity-field "
            "minus the fitted one)",
            ["seg", "label", "n", f"|B| [{unit}]", f"residual [{unit}]", "dip resid. [deg]"],
            [[p["segment"], p["label"], p["samples"], p["magnitude_after"], p["residual"],
              p["dip_residual_deg"]] for p in mag["poses"]],
        )  # fmt: skip
    readings = mag["readings"]
    if readings is not None:
        left = readings.left_out or RowsLeftOut()
        section["notes"].append(
            f"readings: {readings.motion} in motion, {readings.poses} static "
            f"poses; left out {left.nonfinite or 0} without a value, "
            f"{left.clipped or 0} clipped, {left.repeated or 0} repeated"
        )
        mag["readings"] = encode(readings)  # the report is JSON
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


def _quality_table(section: dict[str, Any], q: dict[str, Any] | None, add_table) -> None:
    """MotionCal's figures of the fit as a table, and a warning when they say recapture."""
    if not q or not q["checks"]:
        return
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
    if verdict == "pass":
        return
    failed = ", ".join(
        f"{c['name']} {c['value_pct']:.1f} % > {c['limit_pct']:g} %"
        + ("" if c.get("held_pct") is None else
           f", |B| there held only to {c['held_pct']:.2g} % (2 std)")
        for c in q["checks"] if not c["ok"] and c["value_pct"] is not None
    )  # fmt: skip
    section["warnings"].append(
        f"magnetometer quality: recapture ({failed or 'figures missing'}): turn the "
        "unit through every direction, slowly, away from steel and magnets"
    )


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
