"""Options and arguments several commands share, defined once.

Two forms, both read by typer:

- ``Annotated`` aliases, for an option every command words the same:
  ``force: Force = False``, ``accel_units: AccelUnits = None``;
- factories, for an option whose help each command words for itself (the flag, its short
  form, metavar and completion stay the same): ``json_output: bool = json_option("Print ...")``,
  ``output: Path | None = output_option("FILE.h5", "Session file to write ...")``.

A command with many options (capture, simulate) declares each as an ``Annotated`` alias beside
it, and a factory's option becomes one with :func:`alias`: ``Rate = alias(float,
rate_option("Sample rate, Hz."))``, then ``rate: Rate = 100.0`` (the default after ``=``).

A command that adopts one keeps its ``--help`` byte for byte (tests/test_cli_conformance.py).
"""

from __future__ import annotations

from copy import copy
from typing import Annotated

import typer

from imucal_cli.plans import plan_help
from imucal_cli.registry import REGISTRY_ENV

from . import completion

__all__ = [
    "AccelUnits",
    "Force",
    "ForcePlot",
    "GyroUnits",
    "SensorText",
    "alias",
    "argument",
    "baud_option",
    "calibration_argument",
    "calibration_option",
    "columns_option",
    "duration_option",
    "field_ut_option",
    "force_option",
    "format_option",
    "gravity_option",
    "hold_option",
    "json_option",
    "mag_units_option",
    "output_option",
    "plan_option",
    "plot_option",
    "protocol_option",
    "rate_option",
    "registry_option",
    "session_argument",
    "time_unit_option",
    "units_option",
]

def alias(kind, option):
    """``Annotated[kind, option]`` of a factory's ``option``: the same flags, metavar, help and
    completion, its default left to the parameter's ``=`` (as typer wants with ``Annotated``)."""
    info = copy(option)
    info.default = ...
    return Annotated[kind, info]


def force_option(help: str):
    """``--force``: replace what exists; ``help`` says what."""
    return typer.Option(False, "--force", help=help)


Force = alias(bool, force_option("Overwrite the output file."))
"""``--force`` of a command writing one file (capture, import, export)."""

ForcePlot = alias(bool, force_option("Replace an existing --plot file."))
"""``--force`` of a command whose only file is its ``--plot`` (report, noise)."""

_UNITS_COMPLETION = {"accel": completion.accel_units, "gyro": completion.gyro_units}


def units_option(sensor: str, help: str):
    """``--<sensor>-units UNITS`` (``accel`` or ``gyro``): the raw units of one sensor."""
    return typer.Option(None, f"--{sensor}-units", metavar="UNITS", help=help,
                        autocompletion=_UNITS_COMPLETION[sensor])  # fmt: skip


AccelUnits = alias(
    str | None, units_option("accel", "Raw accelerometer units: counts, V, g or m/s^2.")
)
"""``--accel-units`` stored into a session (import, label)."""

GyroUnits = alias(
    str | None, units_option("gyro", "Raw gyroscope units: counts, V, rad/s or deg/s.")
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


def registry_option(help: str):
    """``--registry PATH|URL`` (or ``$IMUCAL_REGISTRY``)."""
    return typer.Option(None, "--registry", metavar="PATH|URL", envvar=REGISTRY_ENV, help=help)


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


def baud_option(help: str, *short: str):
    """``--baud N``: the serial line's baud rate (default 115200)."""
    return typer.Option(115200, "--baud", *short, metavar="N", help=help)


def protocol_option(help: str, autocompletion):
    """``--protocol NAME``: what a line of the serial stream is (default ``lines``)."""
    return typer.Option("lines", "--protocol", metavar="NAME", help=help,
                        autocompletion=autocompletion)  # fmt: skip


def duration_option(help: str):
    """``--duration SECONDS``: how long at the most (default: no limit)."""
    return typer.Option(None, "--duration", metavar="SECONDS", help=help)


def hold_option(help: str, default: float | None):
    """``--hold SECONDS``: time held still in each pose."""
    return typer.Option(default, "--hold", metavar="SECONDS", help=help)


def calibration_option(help: str, *short: str):
    """``--calibration CAL.json``: a calibration a command uses beside its input."""
    return typer.Option(None, "--calibration", *short, metavar="CAL.json", help=help)


def argument(metavar: str, help: str):
    """A required argument shown as ``metavar`` (no default)."""
    return typer.Argument(..., metavar=metavar, help=help, show_default=False)


def session_argument(help: str):
    """``SESSION.h5``: the session file(s) a command reads."""
    return argument("SESSION.h5", help)


def calibration_argument(help: str):
    """``CAL.json``: the calibration a command reads."""
    return argument("CAL.json", help)
