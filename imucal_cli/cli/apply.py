"""`imucal apply`: turn raw samples into SI units with a calibration, streaming in chunks."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from . import completion
from .app import app
from .console import make_console, print_json


@app.command("apply")
def apply_(
    calibration: Path = typer.Argument(
        ...,
        metavar="CAL.json",
        help="Calibration JSON (from imucal calibrate).",
        show_default=False,
    ),
    input_file: Path = typer.Argument(
        ...,
        metavar="INPUT",
        help="Session (.h5) or CSV of raw samples.",
        show_default=False,
    ),
    output: Path = typer.Option(
        ...,
        "--output",
        "-o",
        metavar="OUTPUT",
        help="File to write: .h5 (datasets /calibrated/time, accel, gyro) or .csv.",
        show_default=False,
    ),
    fmt: str | None = typer.Option(
        None,
        "--format",
        "-f",
        metavar="h5|csv",
        help="h5 or csv [default: from OUTPUT's suffix].",
        autocompletion=completion.apply_formats,
    ),
    columns: str | None = typer.Option(
        None,
        "--columns",
        metavar="SPEC",
        help="CSV input: fields of a line, as for imucal import (t,ax,ay,az,gx,gy,gz; _ skips) "
        "[default: from the header line].",
    ),
    time_unit: str = typer.Option(
        "s",
        "--time-unit",
        metavar="s|ms|us|ns",
        help="CSV input: unit of the t column: s, ms, us or ns.",
        autocompletion=completion.time_units,
    ),
    rate: float | None = typer.Option(
        None, "--rate", metavar="HZ", help="CSV input without a t column: sample rate in Hz."
    ),
    force: bool = typer.Option(False, "--force", help="Overwrite OUTPUT."),
    json_output: bool = typer.Option(
        False, "--json", help="Print what was written as JSON on stdout (nothing else)."
    ),
) -> None:
    """Apply a calibration to every sample: calibrated = matrix @ (raw - bias).

    Writes m/s^2 (accel) and rad/s (gyro) for the sensors the calibration holds; each must be
    in INPUT with the calibration's number of channels. Reads and writes in blocks, so a file
    of any length needs the same memory. Exit status: 0 written; 2 bad input (missing file,
    missing sensor, channel count or units that differ, time not increasing, OUTPUT exists).
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from imucal_cli.formats.calibration import read_calibration
    from imucal_cli.use.apply import apply_calibration

    cal = read_calibration(calibration)
    err = Console(stderr=True)
    bar: Progress | None = None
    task = None

    def progress(done: int, total: int) -> None:
        nonlocal bar, task
        if bar is None:
            # A bar only on a terminal and for inputs longer than one block.
            if not err.is_terminal or done >= total:
                return
            bar = Progress(
                TextColumn("applying"),
                BarColumn(),
                TextColumn("{task.percentage:>3.0f}%"),
                TimeRemainingColumn(),
                console=err,
                transient=True,
            )
            bar.start()
            task = bar.add_task("apply", total=total)
        bar.update(task, completed=done)

    try:
        summary = apply_calibration(
            cal,
            input_file,
            output,
            cal_source=str(calibration),
            fmt=fmt,
            columns=columns,
            time_unit=time_unit,
            rate_hz=rate,
            overwrite=force,
            progress=progress,
        )
    finally:
        if bar is not None:
            bar.stop()
    if json_output:
        print_json(
            {"format": "imucal-apply", "format_version": 1, "output": str(output),
             "output_format": summary.output_format, "input": str(input_file),
             "calibration": str(calibration), "samples": int(summary.samples),
             "duration_s": float(summary.duration_s), "sensors": list(summary.sensors),
             "malformed": int(summary.malformed), "first_malformed": summary.first_malformed,
             "nonfinite": int(summary.nonfinite)}
        )  # fmt: skip
        return
    skipped = ""
    if summary.malformed:
        skipped = (
            f"; skipped {summary.malformed} malformed line(s), first {summary.first_malformed}"
        )
    if summary.nonfinite:
        skipped += (
            f"; warning: {summary.nonfinite} sample(s) had NaN or inf in the raw input and are "
            "NaN in the output"
        )
    make_console().print(
        f"calibrated {summary.samples} samples ({summary.duration_s:.6g} s; "
        f"{', '.join(summary.sensors)}) from {input_file} with {calibration} "
        f"-> {output} ({summary.output_format}){skipped}",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
