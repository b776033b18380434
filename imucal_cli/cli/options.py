"""Options and arguments several commands share, defined once.

Two forms, both read by typer:

- ``Annotated`` aliases, for an option every command words the same:
  ``force: Force = False``, ``accel_units: AccelUnits = None``;
- factories, for an option whose help each command words for itself (the flag, its short
  form, metavar and completion stay the same): ``json_output: bool = json_option("Print ...")``,
  ``output: Path | None = output_option("FILE.h5", "Session file to write ...")``.

A command that adopts one keeps its ``--help`` byte for byte (tests/test_cli_conformance.py).
"""

from __future__ import annotations

from typing import Annotated

import typer

from imucal_cli.plans import plan_help

from . import completion

__all__ = [
    "AccelUnits",
    "Force",
    "ForcePlot",
    "GyroUnits",
    "SensorText",
    "argument",
    "calibration_argument",
    "columns_option",
    "field_ut_option",
    "format_option",
    "gravity_option",
    "json_option",
    "mag_units_option",
    "output_option",
    "plan_option",
    "plot_option",
    "rate_option",
    "session_argument",
    "time_unit_option",
]

Force = Annotated[bool, typer.Option("--force", help="Overwrite the output file.")]
"""``--force`` of a command writing one file (capture, import, export)."""

ForcePlot = Annotated[bool, typer.Option("--force", help="Replace an existing --plot file.")]
"""``--force`` of a command whose only file is its ``--plot`` (report, noise)."""

def _raw_units(flag: str, sensor: str, units: str, complete):
    """``--<sensor>-units UNITS`` stored into a session: the raw units of one sensor."""
    help_ = f"Raw {sensor} units: {units}."
    return Annotated[
        str | None, typer.Option(flag, metavar="UNITS", help=help_, autocompletion=complete)
    ]


AccelUnits = _raw_units(
    "--accel-units", "accelerometer", "counts, V, g or m/s^2", completion.accel_units
)
"""``--accel-units`` stored into a session (import, label)."""

GyroUnits = _raw_units(
    "--gyro-units", "gyroscope", "counts, V, rad/s or deg/s", completion.gyro_units
)
"""``--gyro-units`` stored into a session (import, label)."""

SensorText = Annotated[
    str | None,
    typer.Option(
        "--sensor", metavar="TEXT", help="Free text stored in the session (part, serial)."
    ),
]
"""``--sensor`` of a command that writes a new session (capture, import)."""


def plan_option(default: str | None, lead: str):
    """``--plan NAME|FILE.toml``: every registry plan with its summary (one list for all)."""
    return typer.Option(
        default,
        "--plan",
        metavar="NAME|FILE.toml",
        help=f"{lead} {plan_help()}",
        autocompletion=completion.plans,
    )


def json_option(help: str):
    """``--json``: the command's result as JSON on stdout; ``help`` says what it holds."""
    return typer.Option(False, "--json", help=help)


def output_option(metavar: str, help: str, *, required: bool = False):
    """``--output/-o FILE``; ``required``: no default (and none shown)."""
    if required:
        return typer.Option(..., "--output", "-o", metavar=metavar, help=help,
                            show_default=False)  # fmt: skip
    return typer.Option(None, "--output", "-o", metavar=metavar, help=help)


def format_option(help: str, autocompletion, metavar: str = "FORMAT"):
    """``--format/-f FORMAT``: which reader or writer (default: from a file name)."""
    return typer.Option(None, "--format", "-f", metavar=metavar, help=help,
                        autocompletion=autocompletion)  # fmt: skip


def rate_option(help: str, default: float | None = None):
    """``--rate HZ``: a sample rate."""
    return typer.Option(default, "--rate", metavar="HZ", help=help)


def columns_option(help: str, default: str | None = None):
    """``--columns SPEC``: the fields of a text line (:mod:`imucal_cli.formats.columns`)."""
    return typer.Option(default, "--columns", metavar="SPEC", help=help)


def time_unit_option(help: str):
    """``--time-unit s|ms|us|ns``: the unit of the ``t`` field (default s)."""
    return typer.Option("s", "--time-unit", metavar="s|ms|us|ns", help=help,
                        autocompletion=completion.time_units)  # fmt: skip


def mag_units_option(help: str, default: str | None = None, metavar: str = "UNITS"):
    """``--mag-units``: raw magnetometer units."""
    return typer.Option(default, "--mag-units", metavar=metavar, help=help)


def field_ut_option(help: str, default: float | None = None):
    """``--field-uT UT``: the local geomagnetic field magnitude, microtesla."""
    return typer.Option(default, "--field-uT", metavar="UT", help=help)


def gravity_option(help: str):
    """``--gravity M/S^2``: local gravity."""
    return typer.Option(None, "--gravity", metavar="M/S^2", help=help)


def plot_option(help: str):
    """``--plot FILE.png``: also draw a figure (matplotlib)."""
    return typer.Option(None, "--plot", metavar="FILE.png", help=help)


def argument(metavar: str, help: str):
    """A required argument shown as ``metavar`` (no default)."""
    return typer.Argument(..., metavar=metavar, help=help, show_default=False)


def session_argument(help: str):
    """``SESSION.h5``: the session file(s) a command reads."""
    return argument("SESSION.h5", help)


def calibration_argument(help: str):
    """``CAL.json``: the calibration a command reads."""
    return argument("CAL.json", help)
