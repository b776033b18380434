"""`imucal apply`: turn raw samples into SI units with a calibration, streaming in chunks."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from imucal_cli.formats.calibration import read_calibration
from imucal_cli.use.apply import apply_calibration
from imucal_cli.use.apply_set import apply_set

from . import completion
from .app import app
from .console import make_console, print_json
from .imu_set import set_summary
from .options import (
    argument,
    calibration_argument,
    columns_option,
    force_option,
    format_option,
    json_option,
    output_option,
    rate_option,
    time_unit_option,
)


@app.command("apply")
def apply_(
    calibration: Path = calibration_argument("Calibration JSON (from imucal calibrate)."),
    input_file: Path = argument("INPUT", "Session (.h5) or CSV of raw samples."),
    output: Path = output_option(
        "OUTPUT", "File to write: .h5 (datasets /calibrated/time, accel, gyro, mag) or .csv.",
        required=True,
    ),  # fmt: skip
    fmt: str | None = format_option(
        "h5 or csv [default: from OUTPUT's suffix].", completion.apply_formats, metavar="h5|csv"
    ),
    columns: str | None = columns_option(
        "CSV input: fields of a line, as for imucal import (t,ax,ay,az,gx,gy,gz; _ skips) "
        "[default: from the header line]."
    ),
    time_unit: str = time_unit_option("CSV input: unit of the t column: s, ms, us or ns."),
    rate: float | None = rate_option("CSV input without a t column: sample rate in Hz."),
    force: bool = force_option("Overwrite OUTPUT."),
    json_output: bool = json_option("Print what was written as JSON on stdout (nothing else)."),
    imu: str | None = typer.Option(
        None, "--imu", metavar="NAME",
        help="A session of several IMUs: calibrate IMU NAME alone (h5 or csv); without it "
        "every IMU goes to the .h5 (/calibrated and /calibrated_imus/NAME).",
    ),
    reference_frame: bool = typer.Option(
        False, "--reference-frame",
        help="Several IMUs: each IMU rotated into the reference IMU's calibrated frame and its "
        "times shifted onto the reference's (rotation_to_reference, time_offset_s).",
    ),
) -> None:
    """Apply a calibration to every sample: calibrated = matrix @ (raw - bias).

    Writes m/s^2 (accel), rad/s (gyro) and uT (mag) for the sensors the calibration holds; each must
    be in INPUT with the calibration's number of channels. Reads and writes in blocks, so a file of
    any length needs the same memory. Exit status: 0 written; 2 bad input (missing file, missing
    sensor, channel count or units that differ, time not increasing, OUTPUT exists).
    """
    cal = read_calibration(calibration)
    if imu is not None or reference_frame or cal.imus:  # several IMUs (issue 28)
        summary = apply_set(cal, input_file, output, cal_source=str(calibration), imu=imu,
                            reference_frame=reference_frame, fmt=fmt, overwrite=force)
        set_summary(summary, input_file, calibration, output, json_output)
        return
    with _ProgressBar() as bar:
        summary = apply_calibration(
            cal, input_file, output, cal_source=str(calibration), fmt=fmt, columns=columns,
            time_unit=time_unit, rate_hz=rate, overwrite=force, progress=bar.update,
        )  # fmt: skip
    if json_output:
        print_json(
            {"format": "imucal-apply", "format_version": 1, "output": str(output),
             "output_format": summary.output_format, "input": str(input_file),
             "calibration": str(calibration), "samples": int(summary.samples),
             "duration_s": float(summary.duration_s), "sensors": list(summary.sensors),
             "malformed": int(summary.malformed), "first_malformed": summary.first_malformed,
             "nonfinite": int(summary.nonfinite), "warnings": list(summary.warnings)}
        )  # fmt: skip
        return
    _print_summary(summary, input_file, calibration, output)


class _ProgressBar:
    """A progress bar on stderr, shown only on a terminal and for inputs longer than one block;
    ``update(done, total)`` is :func:`~imucal_cli.use.apply.apply_calibration`'s ``progress``."""

    def __init__(self) -> None:
        self.err = Console(stderr=True)
        self.bar = None
        self.task = None

    def update(self, done: int, total: int) -> None:
        if self.bar is None:
            if not self.err.is_terminal or done >= total:
                return

            self.bar = Progress(
                TextColumn("applying"),
                BarColumn(),
                TextColumn("{task.percentage:>3.0f}%"),
                TimeRemainingColumn(),
                console=self.err,
                transient=True,
            )
            self.bar.start()
            self.task = self.bar.add_task("apply", total=total)
        self.bar.update(self.task, completed=done)

    def __enter__(self) -> _ProgressBar:
        return self

    def __exit__(self, *exc_info: object) -> None:
        if self.bar is not None:
            self.bar.stop()


def _print_summary(summary, input_file: Path, calibration: Path, output: Path) -> None:
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
    for w in summary.warnings:
        make_console().print(f"warning: {w}", markup=False, highlight=False, soft_wrap=True)
