"""`imucal export`: a calibration for firmware (C, PX4, ArduPilot, Fusion), ROS and estimators
(imu_calib, Kalibr, OpenVINS, Basalt, sensor_msgs/Imu covariances) or scripts (JSON)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import typer

from imucal_cli.errors import InputError
from imucal_cli.formats.exporters import ExportOptions, parse_scale
from imucal_cli.formats.importers import check_sample_rate
from imucal_cli.formats.noise import read_noise
from imucal_cli.formats.output import check_output, write_output
from imucal_cli.use.export import EXPORT_FORMATS, FORMATS, format_for_suffix, load_input
from imucal_cli.use.export import export as export_text
from imucal_cli.use.export_set import pick_imu, with_device_ids

from . import completion
from .app import app
from .console import make_console
from .options import Force, calibration_argument, format_option, output_option, rate_option


def _scale_option(sensor: str, help: str):
    """``--<sensor>-scale SCALE``: the driver's SI units per raw unit of one sensor."""
    return typer.Option(None, f"--{sensor}-scale", metavar="SCALE", help=help)


@app.command()
def export(
    calibration: Path = calibration_argument(
        "Calibration JSON (from imucal calibrate); for kalibr-imu and ros-imu a noise JSON "
        "(imucal noise --json) is enough."
    ),
    fmt: str | None = format_option(
        "c-header, yaml (ROS imu_calib), json, kalibr-imu (noise imu.yaml), kalibr "
        "(M, A, C_gyro_i), openvins, basalt, px4, ardupilot, fusion, vins, orbslam3, ros-imu "
        "(covariances) "
        "[default: from OUTPUT's suffix .h/.yaml/.json/.params/.parm].",
        completion.choices(EXPORT_FORMATS),
    ),
    output: Path | None = output_option("FILE", "File to write [default: standard output]."),
    noise: Path | None = typer.Option(
        None, "--noise", metavar="NOISE.json",
        help="Noise figures from imucal noise SESSION --json (kalibr-imu, kalibr, openvins, "
        "basalt, vins, orbslam3, ros-imu).",
    ),  # fmt: skip
    rate: float | None = rate_option(
        "Rate the target runs at, Hz [default: the noise recording's]."
    ),
    topic: str = typer.Option(
        "/imu0", "--topic", metavar="TOPIC", help="ROS topic of the IMU (Kalibr, OpenVINS)."
    ),
    accel_scale: str | None = _scale_option(
        "accel",
        "Driver's m/s^2 per raw unit, for a calibration of counts or V exported to targets "
        "that read SI (kalibr, openvins, basalt, px4, ardupilot), e.g. 9.80665/16384.",
    ),
    gyro_scale: str | None = _scale_option(
        "gyro", "Driver's rad/s per raw unit, as --accel-scale."
    ),
    mag_scale: str | None = _scale_option(
        "mag",
        "Driver's uT per raw unit, for a magnetometer calibrated in counts exported to px4 "
        "or ardupilot, e.g. 0.15 (AK8963, 16-bit).",
    ),
    device_id: list[str] = typer.Option(
        [], "--device-id", metavar="N|NAME=N",
        help="px4: CAL_ACC0_ID/CAL_GYRO0_ID; ardupilot: INS_ACC_ID/INS_GYR_ID (the "
        "sensor_accel device_id of a ULog). Several IMUs: each one's as NAME=N, repeated or "
        "comma-separated (--device-id reference=2818058,imu1=3014666): px4 writes it at the "
        "IMU's instance (CAL_ACC1_ID, CAL_GYRO1_ID, ...), ardupilot INS_ACC2_ID, ...",
    ),  # fmt: skip
    prefix: str | None = typer.Option(
        None, "--prefix", metavar="NAME",
        help="c-header / fusion: name prefix, a C identifier [default: IMUCAL; fusion none].",
    ),  # fmt: skip
    fusion_version: str = typer.Option(
        "1.3", "--fusion-version", metavar="1.3|1.2",
        help="fusion: the Fusion release compiled against (1.3: FusionMatrix a flat array of "
        "9; 1.2: 3x3 nested).",
    ),  # fmt: skip
    drop: list[str] = typer.Option(
        [], "--drop", metavar="TERM",
        help="Export without a term the format cannot hold, said in the file: g-sensitivity "
        "(refused otherwise).",
    ),  # fmt: skip
    force: Force = False,
    imu: str | None = typer.Option(
        None, "--imu", metavar="NAME",
        help="A calibration of several IMUs: export IMU NAME alone (reference for the "
        "reference). Without it px4, ardupilot, kalibr and openvins hold every IMU (kalibr, "
        "openvins: an IMU chain with T_i_b and time_offset); other formats need it.",
    ),
) -> None:
    """Export a calibration for firmware, ROS, estimators or scripts.

    Every file states the equation the target applies, its direction and units. px4 and
    ardupilot hold only an offset and a diagonal scale: the file says how much misalignment
    (degrees) is lost. Targets reading SI values (kalibr, openvins, basalt, px4, ardupilot)
    need raw data in m/s^2, g, rad/s or deg/s, or --accel-scale/--gyro-scale (a magnetometer:
    uT, nT or gauss, or --mag-scale).
    An existing OUTPUT is replaced only with --force. Exit status: 0 written; 2 bad input.
    """
    fmt = _format(fmt, output)
    if rate is not None and not rate > 0:
        raise InputError(f"--rate {rate}: must be a positive number of Hz")
    if rate is not None:
        check_sample_rate(rate, None, "export")  # 1e300 Hz was written as the update rate
    scale = _scales(accel_scale, gyro_scale, mag_scale)
    if output is not None:
        check_output(output, force=force, inputs=[calibration, noise])
    cal, noise_in = load_input(calibration)
    single_id, named_ids = _device_ids(device_id)
    opts = ExportOptions(device_id=single_id, device_ids=named_ids)
    if cal is not None:
        opts = with_device_ids(cal, imu, opts)  # each IMU's own (issue 28)
    if imu is not None:  # one IMU of a set (issue 28)
        if cal is None:
            raise InputError("--imu picks an IMU of a calibration, not of noise figures")
        cal = pick_imu(cal, imu)
    if noise is not None:
        noise_in = read_noise(noise)
    unknown = sorted(set(drop) - DROPPABLE)
    if unknown:
        raise InputError(f"--drop {unknown[0]}: the terms that can be dropped are "
                         f"{', '.join(sorted(DROPPABLE))}")  # fmt: skip
    opts = replace(opts, noise=noise_in, rate_hz=rate, topic=topic, scale=scale, prefix=prefix,
                   fusion_version=fusion_version, drop=frozenset(drop))  # fmt: skip
    text = export_text(cal, fmt, options=opts)
    if output is None:
        typer.echo(text, nl=False)
        return
    write_output(output, text, force=force, inputs=[calibration, noise])
    make_console(stderr=True).print(f"wrote {output} ({fmt}: {_what(cal)})", markup=False)


DROPPABLE = frozenset({"g-sensitivity"})
"""Terms ``--drop`` names (a format that cannot hold one refuses it otherwise)."""


def _what(cal) -> str:
    """What an export holds: ``accel 3x3, gyro 3x3``, or the noise figures alone."""
    if cal is None:
        return "noise figures"
    return ", ".join(
        f"{name} 3x{sec.bias.shape[0]}"
        for name, sec in (("accel", cal.accel), ("gyro", cal.gyro))
        if sec is not None
    )


def _format(fmt: str | None, output: Path | None) -> str:
    """``--format``, else the one ``output``'s suffix names; refused when neither says."""
    if fmt is None:
        fmt = format_for_suffix(output) if output is not None else None
        if fmt is None:
            raise InputError(f"pass --format ({', '.join(FORMATS)})")
    return fmt


def _device_ids(values: list[str]) -> tuple[int | None, dict[str, int]]:
    """``--device-id`` as given: one id ``N``, or ids by IMU name (``NAME=N``, repeated or
    comma-separated); an id is an int32 or uint32 (a ULog's ``device_id``), not 0."""
    single, named = None, {}
    for item in (part.strip() for value in values for part in value.split(",")):
        name, eq, number = item.rpartition("=")
        name = name.strip()
        try:
            n = int(number.strip(), 0)
        except ValueError:
            n = 0
        if n == 0 or not -(1 << 31) <= n < 1 << 32:
            raise InputError(f"--device-id {item}: a device id is a non-zero 32-bit integer "
                             "(N, or NAME=N for one IMU of a set)")  # fmt: skip
        if (not eq and single is not None) or (eq and (not name or name in named)):
            raise InputError(f"--device-id {item}: " + (
                "one N names one device: with several IMUs give each one's as NAME=N"
                if not eq else f"IMU {name} given twice" if name else "no IMU name before '='"))
        if eq:
            named[name] = n
        else:
            single = n
    return single, named


def _scales(accel_scale: str | None, gyro_scale: str | None, mag_scale: str | None) -> dict:
    """The drivers' scales given (``--accel-scale`` ...), per sensor, parsed."""
    scale = {}
    for name, text in (("accel", accel_scale), ("gyro", gyro_scale), ("mag", mag_scale)):
        if text is not None:
            scale[name] = parse_scale(text, f"--{name}-scale")
    return scale
