"""`imucal import`: a session from recorded text files, segmented automatically."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from .app import app


def default_output(first: Path) -> Path:
    """``data/run3.csv`` -> ``run3.h5`` in the current directory (the data may be read-only)."""
    return Path(first.stem + ".h5")


@app.command("import")
def import_(
    files: list[Path] = typer.Argument(
        ...,
        help="Recorded file(s): one CSV, or for imu_tk the accelerometer file then the "
        "gyroscope file.",
        show_default=False,
    ),
    fmt: str = typer.Option("csv", "--format", "-f", help="csv or imu_tk."),
    columns: str | None = typer.Option(
        None,
        "--columns",
        help="Fields of a line, e.g. t,ax,ay,az,gx,gy,gz,mx,my,mz or _,ax,ay,az (_ skips a field) "
        "[default: from the header line].",
    ),
    time_unit: str = typer.Option("s", "--time-unit", help="Unit of the t column: s, ms or us."),
    rate: float | None = typer.Option(
        None, "--rate", help="Sample rate in Hz; required without a t column (time = row / rate)."
    ),
    accel_units: str | None = typer.Option(
        None, "--accel-units", help="Raw accelerometer units: counts, V, g or m/s^2."
    ),
    gyro_units: str | None = typer.Option(
        None, "--gyro-units", help="Raw gyroscope units: counts, V, rad/s or deg/s."
    ),
    mag_units: str | None = typer.Option(
        None, "--mag-units", help="Raw magnetometer units (columns mx,my,mz): counts, uT, nT or "
        "gauss."
    ),
    field_ut: float | None = typer.Option(
        None, "--field-uT", help="Local geomagnetic field magnitude, microtesla, where known."
    ),
    skip_rows: int = typer.Option(
        0, "--skip-rows", help="Lines to skip at the top of each file (headers are also detected)."
    ),
    sensor: str | None = typer.Option(None, "--sensor", help="Free text: part and serial number."),
    output: Path | None = typer.Option(
        None, "--output", "-o", help="Session file to write [default: FILE's name with .h5, here]."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite the output file."),
) -> None:
    """Import recorded samples into a session and find its still poses and rotations.

    Still periods are found from the recording's own noise (sliding-window variance with a
    chi-square threshold); rotations are the motions between them where the gyro moved.
    Exit status: 0 written; 2 bad input (missing or empty file, columns that do not fit,
    no time and no --rate, time that does not increase, no still period).
    """
    from imucal_cli.formats.importers import import_files
    from imucal_cli.formats.output import check_output
    from imucal_cli.formats.session import write_session

    out = check_output(output or default_output(files[0]), force=force, inputs=files)
    session = import_files(
        files,
        fmt,
        columns,
        time_unit=time_unit,
        rate_hz=rate,
        skip_rows=skip_rows,
        accel_units=accel_units,
        gyro_units=gyro_units,
        sensor=sensor,
        mag_units=mag_units,
        magnetic_field_uT=field_ut,
    )
    write_session(out, session, overwrite=force, inputs=files)

    stats = session.import_stats
    static = session.static_segments()
    rotations = session.rotation_segments()
    dt = 1.0 / session.sample_rate_hz
    held = sum(s.n_samples for s in static) * dt
    console = Console()
    duration = session.time[-1] - session.time[0]
    console.print(
        f"read {stats.samples} samples ({duration:.1f} s at {session.sample_rate_hz:.4g} Hz) "
        f"from {', '.join(str(f) for f in files)}",
        markup=False,
    )
    skipped = []
    if stats.header:
        skipped.append(f"{stats.header} header")
    if stats.comments:
        skipped.append(f"{stats.comments} comment")
    if stats.malformed:
        skipped.append(f"{stats.malformed} malformed (first at {stats.first_malformed})")
    if stats.unmatched:
        skipped.append(f"{stats.unmatched} unmatched (no sample of that time in the other file)")
    if skipped:
        console.print("  skipped lines: " + ", ".join(skipped), markup=False)
    console.print(
        f"  {len(static)} static segments ({held:.1f} s still), {len(rotations)} rotation segments"
    )
    if session.mag is not None:
        units = session.mag_units or "units not given"
        console.print(f"  magnetometer: {session.mag.shape[1]} channels ({units})", markup=False)
    console.print(f"wrote {out}", markup=False)
