"""`imucal export`: a calibration as a C header (firmware), imu_calib YAML (ROS) or JSON."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from .app import app

_SUFFIX_FORMATS = {".h": "c-header", ".yaml": "yaml", ".yml": "yaml", ".json": "json"}


@app.command()
def export(
    calibration: Path = typer.Argument(
        ..., help="Calibration JSON (from imucal calibrate).", show_default=False
    ),
    fmt: str | None = typer.Option(
        None,
        "--format",
        "-f",
        help="c-header (C99 constants and inline apply functions), yaml (ROS imu_calib: SM, "
        "bias) or json (standard fields) [default: from OUTPUT's suffix .h/.yaml/.json].",
    ),
    output: Path | None = typer.Option(
        None, "--output", "-o", help="File to write [default: standard output]."
    ),
    force: bool = typer.Option(False, "--force", help="Replace an existing OUTPUT."),
    prefix: str | None = typer.Option(
        None,
        "--prefix",
        help="c-header: name prefix, a C identifier (IMUCAL_ACCEL_MATRIX, imucal_accel_apply) "
        "[default: IMUCAL].",
    ),
) -> None:
    """Export a calibration for firmware, ROS or scripts.

    c-header: per sensor MATRIX[3][N], BIAS[N] as float constants and
    <prefix>_<sensor>_apply(raw, out) computing out = M (raw - b); C99, no libm.
    yaml: imu_calib's SM (9, row-major) and bias (3); imu_calib applies SM * raw - bias, so
    bias is written as matrix @ bias in m/s^2 (3-channel sensors only; gyro under gyro:).
    json: the standard fields only, one line. An existing OUTPUT is replaced only with
    --force. Exit status: 0 written; 2 bad input.
    """
    from imucal_cli.errors import InputError
    from imucal_cli.formats.calibration import read_calibration
    from imucal_cli.formats.output import check_output, write_output
    from imucal_cli.use.export import export as export_text

    if fmt is None:
        fmt = _SUFFIX_FORMATS.get(output.suffix.lower()) if output is not None else None
        if fmt is None:
            raise InputError("pass --format c-header, yaml or json")
    if output is not None:
        check_output(output, force=force, inputs=[calibration])
    cal = read_calibration(calibration)
    text = export_text(cal, fmt, prefix=prefix)
    if output is None:
        typer.echo(text, nl=False)
        return
    write_output(output, text, force=force, inputs=[calibration])
    sensors = ", ".join(
        f"{name} 3x{sec.bias.shape[0]}"
        for name, sec in (("accel", cal.accel), ("gyro", cal.gyro))
        if sec is not None
    )
    Console(stderr=True).print(f"wrote {output} ({fmt}: {sensors})", highlight=False)
