"""`imucal import`: a session from recorded text files, segmented automatically."""

from __future__ import annotations

from functools import partial
from pathlib import Path

import typer

from imucal_cli.formats.importers import FORMATS, import_files
from imucal_cli.formats.output import check_output, check_session_output
from imucal_cli.formats.session import write_session

from . import completion
from .app import app
from .console import make_console, print_json, print_line
from .options import (
    AccelUnits,
    Force,
    GyroUnits,
    SensorText,
    argument,
    columns_option,
    field_ut_option,
    format_option,
    json_option,
    mag_units_option,
    output_option,
    rate_option,
    time_unit_option,
)


def default_output(first: Path) -> Path:
    """``data/run3.csv`` -> ``run3.h5`` in the current directory (the data may be read-only)."""
    return Path(first.stem + ".h5")


@app.command("import")
def import_(
    files: list[Path] = argument(
        "FILE", "Recorded file(s): one CSV, or for imu_tk the accelerometer file then the "
        "gyroscope file.",
    ),  # fmt: skip
    fmt: str | None = format_option(
        "csv (also EuRoC / TUM-VI imu0/data.csv), imu_tk, ros (.bag, ROS 2 bag folder, .mcap "
        "of ROS 2 or ROS 1 messages), ulog (.ulg), mavlink (.tlog, ArduPilot DataFlash .bin or "
        "its text .log), lines (MotionCal Raw:, i2cdevlib a/g:) or witmotion (0x55 frames) "
        "[default: recognised from the file].",
        completion.choices(FORMATS),
    ),
    topic: str | None = typer.Option(
        None, "--topic", metavar="TOPIC",
        help="ros: the sensor_msgs/Imu topic (listed when several); ulog: the topic and "
        "instance (sensor_accel_fifo, sensor_accel, vehicle_imu, sensor_combined; .N or N alone "
        "for an instance); mavlink: the message and instance (RAW_IMU.0, SCALED_IMU2, "
        "HIGHRES_IMU, IMU.1, ACC.0, ISB.0 for batch samples; listed when several).",
    ),  # fmt: skip
    mag_topic: str | None = typer.Option(
        None, "--mag-topic", metavar="TOPIC",
        help="The magnetometer to read with the IMU when the log has several: ros: a "
        "sensor_msgs/MagneticField topic; ulog: the sensor_mag instance N; mavlink: MAG.N "
        "[default: the one in the IMU's namespace or of its instance].",
    ),  # fmt: skip
    columns: str | None = columns_option(
        "Fields of a line, e.g. t,ax,ay,az,gx,gy,gz,mx,my,mz or _,ax,ay,az (_ skips a field) "
        "[default: from the header line]."
    ),
    time_unit: str = time_unit_option("Unit of the t column: s, ms, us or ns."),
    rate: float | None = rate_option(
        "Sample rate in Hz; required without a t column (time = row / rate)."
    ),
    accel_units: AccelUnits = None,
    gyro_units: GyroUnits = None,
    mag_units: str | None = mag_units_option(
        "Raw magnetometer units (columns mx,my,mz): counts, uT, nT or gauss."
    ),
    field_ut: float | None = field_ut_option(
        "Local geomagnetic field magnitude, microtesla, where known."
    ),
    skip_rows: int = typer.Option(
        0, "--skip-rows", metavar="N",
        help="Lines to skip at the top of each file (headers are also detected).",
    ),  # fmt: skip
    sensor: SensorText = None,
    sections: str | None = typer.Option(
        None, "--sections", metavar="FILE.json|COLUMN",
        help="Labelled sections instead of automatic segmentation: a MaD Lab section list "
        "(JSON {label: {start, end}}, rows end-exclusive) or the name of a column holding each "
        "row's label (e.g. part). Ferraris labels x_p x_a y_p y_a z_p z_a become faces with "
        "their up direction, x_rot y_rot z_rot 360-degree turns about that axis.",
    ),  # fmt: skip
    turn_angle: float | None = typer.Option(
        None, "--turn-angle", metavar="DEG",
        help="Signed angle of the sections' turns in degrees, e.g. -360 [default: 360 with the "
        "sign of the gyro's own integral].",
    ),  # fmt: skip
    output: Path | None = output_option(
        "FILE.h5", "Session file to write [default: FILE's name with .h5, here]."
    ),
    force: Force = False,
    json_output: bool = json_option(
        "Print what was read and written as JSON on stdout (nothing else)."
    ),
) -> None:
    """Import recorded samples into a session and find its still poses and rotations.

    Still periods are found from the recording's own noise (sliding-window variance with a
    chi-square threshold); rotations are the motions between them where the gyro moved.
    Exit status: 0 written; 2 bad input (missing or empty file, columns that do not fit,
    no time and no --rate, time that does not increase, no still period).
    """
    out = check_session_output(output or default_output(files[0]), "imucal import")
    out = check_output(out, force=force, inputs=files)
    session = import_files(
        files, fmt, columns, time_unit=time_unit, rate_hz=rate, skip_rows=skip_rows,
        accel_units=accel_units, gyro_units=gyro_units, sensor=sensor, sections=sections,
        turn_angle_deg=turn_angle, mag_units=mag_units, magnetic_field_uT=field_ut, topic=topic,
        mag_topic=mag_topic,
    )  # fmt: skip
    write_session(out, session, overwrite=force, inputs=files)
    _print_result(_result_json(out, files, session), json_output)


def _result_json(out: Path, files: list[Path], session) -> dict:
    """What was read and written (``--json``, and the summary's figures)."""
    stats = session.import_stats
    static = session.static_segments()
    skipped = {"header": stats.header, "comments": stats.comments, "malformed": stats.malformed,
               "first_malformed": stats.first_malformed, "unmatched": stats.unmatched,
               "unpaired": stats.unpaired, "dropped": stats.dropped}  # fmt: skip
    return {
        "format": "imucal-import", "format_version": 1, "output": str(out),
        "files": [str(f) for f in files], "samples": int(stats.samples),
        "duration_s": float(session.time[-1] - session.time[0]),
        "sample_rate_hz": float(session.sample_rate_hz),
        "static_segments": len(static), "rotation_segments": len(session.rotation_segments()),
        "still_s": float(sum(s.n_samples for s in static) / session.sample_rate_hz),
        "skipped_lines": skipped, "notes": list(getattr(session, "import_notes", [])),
        "mag_channels": None if session.mag is None else int(session.mag.shape[1]),
        "mag_units": session.mag_units,
        "warnings": list(getattr(session, "import_warnings", []))
        + ([UNITS_WARNING] if session.accel is not None and not session.accel_units else []),
    }  # fmt: skip


#: Issue 10.4: said when an import leaves the accelerometer units unstated.
UNITS_WARNING = (
    "accelerometer units not stated (--accel-units counts, g or m/s^2): calibrate will infer "
    "them from the magnitude; set them with `imucal label SESSION --accel-units UNITS`"
)


def _print_result(result: dict, json_output: bool) -> None:
    """The result as JSON (``--json``), or a summary for people."""
    if json_output:
        print_json(result)
        return
    line = partial(print_line, make_console())
    files = ", ".join(result["files"])
    line(
        f"read {result['samples']} samples ({result['duration_s']:.1f} s at "
        f"{result['sample_rate_hz']:.4g} Hz) from {files}"
    )
    s = result["skipped_lines"]
    skipped = []
    if s["header"]:
        skipped.append(f"{s['header']} header")
    if s["comments"]:
        skipped.append(f"{s['comments']} comment")
    if s["malformed"]:
        skipped.append(f"{s['malformed']} malformed (first at {s['first_malformed']})")
    if s["unmatched"]:
        skipped.append(f"{s['unmatched']} unmatched (no sample of that time in the other file)")
    if skipped:
        line("  skipped lines: " + ", ".join(skipped))
    left = []
    if s["unpaired"]:
        left.append(f"{s['unpaired']} unpaired (an accelerometer or gyroscope sample with no "
                    "sample of the other sensor at its time)")  # fmt: skip
    if s["dropped"]:
        left.append(f"{s['dropped']} whose time did not follow the previous sample's or whose "
                    "values were not finite")  # fmt: skip
    if left:
        line("  samples left out: " + ", ".join(left))
    line(
        f"  {result['static_segments']} static segments ({result['still_s']:.1f} s still), "
        f"{result['rotation_segments']} rotation segments"
    )
    for note in result["notes"]:
        line(f"  {note}")
    for warning in result["warnings"]:
        line(f"  warning: {warning}")
    if result["mag_channels"] is not None:
        units = result["mag_units"] or "units not given"
        line(f"  magnetometer: {result['mag_channels']} channels ({units})")
    line(f"wrote {result['output']}")
