"""Shell completion of option values: plan names, units, formats, serial ports.

``imucal --install-completion`` installs typer's completion script for the current shell; these
functions give it the values of the options it cannot guess (typer completes commands and
option names by itself).  Where a function offers nothing (a path, a TOML plan file), the
shell completes file names (bash ``complete -o default``, zsh ``_files``).  The plans and the
formats come from their registries, so a new plan or reader is completed without a change here;
the formats' completions are made by :func:`choices` in the command that imports their
registry (``import``, ``export``), so that the options every command shares load no reader.
"""

from __future__ import annotations

import glob

from imucal_cli.plans import PLANS

ACCEL_UNITS = ("counts", "V", "g", "m/s^2")
GYRO_UNITS = ("counts", "V", "rad/s", "deg/s")
TIME_UNITS = ("s", "ms", "us", "ns")
CAPTURE_PROTOCOLS = ("lines", "motioncal", "i2cdevlib", "witmotion")  # capture --protocol
SERVE_PROTOCOLS = ("lines", "motioncal", "i2cdevlib")  # simulate --serve --protocol


def _matching(values, incomplete: str) -> list[str]:
    return [v for v in values if v.startswith(incomplete)]


def plans(incomplete: str) -> list[str]:
    """Plan names of the registry as the person types them (``random:N`` completes to
    ``random:``); capture and simulate know the same plans."""
    names = [p.key + (":" if p.arg in ("count", "minutes") else "") for p in PLANS]
    return _matching(names, incomplete)


def choices(values):
    """The completion of one option's ``values``."""

    def complete(incomplete: str) -> list[str]:
        return _matching(values, incomplete)

    return complete


accel_units = choices(ACCEL_UNITS)
gyro_units = choices(GYRO_UNITS)
time_units = choices(TIME_UNITS)
simulate_units = choices(("counts", "m/s^2"))
capture_protocols = choices(CAPTURE_PROTOCOLS)
serve_protocols = choices(SERVE_PROTOCOLS)
apply_formats = choices(("h5", "csv"))


def ports(incomplete: str) -> list[str]:
    """Serial ports that exist (``/dev/ttyUSB*``, ``/dev/ttyACM*``, ...); else file names."""
    found = []
    for pattern in ("/dev/ttyUSB*", "/dev/ttyACM*", "/dev/tty.usb*", "/dev/cu.usb*", "/dev/pts/*"):
        found += [p for p in sorted(glob.glob(pattern)) if p.startswith(incomplete)]
    return found
