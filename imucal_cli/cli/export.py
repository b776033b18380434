"""`imucal export`: a calibration as a C header (firmware), imu_calib YAML (ROS) or JSON."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from . import completion
from .app import app
from .console import make_console

_SUFFIX_FORMATS = {".h": "c-header", ".yaml": "yaml", ".yml": "yaml", ".json": "json"}


@app.command()
def export(
    calibration: Path = typer.Argument(
        ...,
        metavar="CAL.json",
        help="Calibration JSON (from imucal calibrate).",
        show_default=False,
    ),
    fmt: str | None = typer.Option(
        None,
        "--format",
        "-f",
        metavar="FORMAT",
        help="c-header (C99 constants and inline apply functions), yaml (ROS imu_calib: SM, "
        "bias) or json (standard fields) [default: from OUTPUT's suffix .h/.yaml/.json].",
        autocompletion=completion.export_formats,
    ),
    output: Path | None = typer.Option(
        None,
        "--output",
        "-o",
        metavar="FILE",
        help="File to write [default: standard output].",
    ),
    prefix: str | None = typer.Option(
        None,
        "--prefix",
        metavar="NAME",
        help="c-header: name prefix, a C identifier (IMUCAL_ACCEL_MATRIX, imucal_accel_apply) "
        "[default: IMUCAL].",
    ),
) -> None:
    """Export a calibration for firmware, ROS or scripts.

    c-header: per sensor MATRIX[3][N], BIAS[N] as float constants and
    <prefix>_<sensor>_apply(raw, out) computing out = M (raw - b); C99, no libm.
    yaml: imu_calib's SM (9, row-major) and bias (3); imu_calib applies SM * raw - bias, so
    bias is written as matrix @ bias in m/s^2 (3-channel sensors only; gyro under gyro:).
    json: the standard fields only, one line. Exit status: 0 written; 2 bad input.
    """
    from imucal_cli.errors import InputError
    from imucal_cli.formats.calibration import read_calibration
    from imucal_cli.use.export import export as export_text

    if fmt is None:
        fmt = _SUFFIX_FORMATS.get(output.suffix.lower()) if output is not None else None
        if fmt is None:
            raise InputError("pass --format c-header, yaml or json")
    cal = read_calibration(calibration)
    text = export_text(cal, fmt, prefix=prefix)
    if output is None:
        typer.echo(text, nl=False)
        return
    tmp = output.with_name(output.name + ".tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, output)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise InputError(f"{output}: cannot write ({exc.strerror or exc})") from None
    sensors = ", ".join(
        f"{name} 3x{sec.bias.shape[0]}"
        for name, sec in (("accel", cal.accel), ("gyro", cal.gyro))
        if sec is not None
    )
    make_console(stderr=True).print(f"wrote {output} ({fmt}: {sensors})", markup=False)
