"""`imucal label`: set or correct the labels of an existing session (never its raw data)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import calibration_from_json, read_calibration
from imucal_cli.formats.importers import ACCEL_UNITS, GYRO_UNITS
from imucal_cli.formats.session import as_unit_vector, read_session, rewrite_labels
from imucal_cli.use.labels import call_faces, face_label, set_segment

from .app import app
from .console import make_console, print_json
from .options import (
    AccelUnits,
    GyroUnits,
    calibration_option,
    gravity_option,
    json_option,
    session_argument,
)


def _vector(text: str | None, option: str):
    if text is None:
        return None

    try:
        v = np.array([float(p) for p in text.replace(" ", "").split(",")])
    except ValueError:
        v = np.zeros(0)
    unit = as_unit_vector(v) if v.shape == (3,) else None
    if unit is None:
        raise InputError(f"{option} {text!r}: give 3 numbers, not all zero, e.g. 0,0,1")
    return unit


@app.command("label")
def label(
    session: Path = session_argument("Session file (.h5) to relabel."),
    faces: bool = typer.Option(
        False,
        "--faces",
        help="Label each static segment within --tolerance of a +-axis as that face (up = what "
        "the accelerometer reads, divided by g).",
    ),
    tolerance: float = typer.Option(
        15.0, "--tolerance", metavar="DEG", help="--faces: largest angle from a +-axis, degrees."
    ),
    calibration: Path | None = calibration_option(
        "--faces: calibration JSON turning raw readings into directions [default: the "
        "session's last stored one; else the raw units, or a fit to the poses themselves]."
    ),
    segment: str | None = typer.Option(
        None, "--segment", metavar="NAME", help="Segment to change by hand (its name, e.g. 0003)."
    ),
    text: str | None = typer.Option(
        None, "--label", metavar="TEXT", help="--segment: its new label."
    ),
    up: str | None = typer.Option(
        None, "--up", metavar="X,Y,Z", help="--segment: its up, e.g. 0,0,1."
    ),
    axis: str | None = typer.Option(
        None, "--axis", metavar="X,Y,Z", help="--segment: its turn axis, e.g. 0,0,1."
    ),
    angle: float | None = typer.Option(
        None, "--angle", metavar="DEG",
        help="--segment: its known turn angle, degrees (signed, right hand).",
    ),  # fmt: skip
    sensor: str | None = typer.Option(
        None, "--sensor", metavar="TEXT", help="Part and serial number."
    ),
    accel_units: AccelUnits = None,
    gyro_units: GyroUnits = None,
    gravity: float | None = gravity_option("Local gravity, m/s^2."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Show the labels, write nothing."),
    json_output: bool = json_option("Print the labels found and what changed as JSON on stdout."),
) -> None:
    """Set or correct the labels of SESSION: faces from the measured directions, one segment
    by hand, the sensor, units and gravity.

    Only /segments and root attributes change; /raw is never rewritten.
    Exit status: 0 written (or shown with --dry-run); 2 bad input.
    """
    attrs = _root_attributes(sensor, accel_units, gyro_units, gravity)
    if segment is None and any(v is not None for v in (text, up, axis, angle)):
        raise InputError("--label, --up, --axis and --angle change one segment: pass --segment")
    s = read_session(session)
    if accel_units is not None:
        s.accel_units = accel_units
    segments = list(s.segments)
    console = make_console(stderr=json_output)  # with --json, stdout holds the JSON alone
    found: list[dict] = []
    if faces:
        segments, found = _faces(s, session, segments, tolerance, calibration, console)
    if segment is not None:
        segments = set_segment(segments, segment, label=text, up=_vector(up, "--up"),
                               axis=_vector(axis, "--axis"), angle_deg=angle)  # fmt: skip
    if not faces and segment is None and not attrs:
        raise InputError("nothing to change: pass --faces, --segment ..., or a root label")
    changed = sum(a != b for a, b in zip(segments, s.segments, strict=True))
    if not dry_run:
        rewrite_labels(session, segments, attrs)
    _say(console, session, json_output, dry_run, found, changed, attrs)


def _say(console, session: Path, json_output: bool, dry_run: bool, found: list[dict],
         changed: int, attrs: dict) -> None:  # fmt: skip
    """What was found and changed: JSON on stdout, or a line."""
    if json_output:
        print_json({"format": "imucal-label", "format_version": 1, "session": str(session),
                    "dry_run": dry_run, "faces": found, "changed_segments": changed,
                    "attributes": attrs})  # fmt: skip
    elif dry_run:
        console.print("dry run: nothing written")
    else:
        extra = f" and {', '.join(attrs)}" if attrs else ""
        console.print(f"relabelled {changed} segment(s){extra} in {session} (raw data untouched)")


def _root_attributes(sensor, accel_units, gyro_units, gravity) -> dict:
    """The root attributes to set (those given), each checked."""
    for name, value, allowed in (("--accel-units", accel_units, ACCEL_UNITS),
                                 ("--gyro-units", gyro_units, GYRO_UNITS)):  # fmt: skip
        if value is not None and value not in allowed:
            raise InputError(f"{name} {value!r}: use {', '.join(allowed)}")
    if gravity is not None and not 9.7 <= gravity <= 9.9:
        raise InputError(f"--gravity {gravity:g} m/s^2: gravity on earth is 9.78 to 9.84")
    return {k: v for k, v in (("sensor", sensor), ("accel_units", accel_units),
            ("gyro_units", gyro_units), ("gravity", gravity)) if v is not None}  # fmt: skip


def _faces(s, session: Path, segments: list, tolerance: float, calibration: Path | None,
           console) -> tuple[list, list[dict]]:  # fmt: skip
    """``--faces``: each static segment within ``tolerance`` of an axis labelled as that
    face (directions through ``calibration``, else the session's last stored one, else the raw
    units); prints each call. Returns the segments and what was found."""
    cal = None
    if calibration is not None:
        cal = read_calibration(calibration).accel
    elif s.calibrations:
        last = sorted(s.calibrations)[-1]
        cal = calibration_from_json(s.calibrations[last], f"{session}:{last}").accel
    calls, basis = call_faces(s, tolerance_deg=tolerance, calibration=cal)
    console.print(f"directions from {basis}; faces within {tolerance:g} deg of an axis:")
    named = {c.segment: c for c in calls}
    segments, found = list(segments), []
    for i, seg in enumerate(segments):
        c = named.get(seg.name)
        if c is None:
            continue
        d = ", ".join(f"{v:+.3f}" for v in c.direction)
        found.append({"segment": seg.name, "direction": [float(v) for v in c.direction],
                      "off_deg": float(c.off_deg),
                      "label": None if c.up is None else face_label(c.up)})  # fmt: skip
        if c.up is None:
            console.print(f"  {seg.name}  [{d}]  {c.off_deg:5.1f} deg off: no face (kept)")
            continue
        new = face_label(c.up)
        console.print(f"  {seg.name}  [{d}]  {c.off_deg:5.1f} deg off: {new}")
        segments[i] = set_segment([seg], seg.name, label=new, up=c.up)[0]
    return segments, found
