"""Shell completion of option values: plan names, units, formats, serial ports.

``imucal --install-completion`` installs typer's completion script for the current shell; these
functions give it the values of the options it cannot guess (typer completes commands and
option names by itself).  Where a function offers nothing (a path, a TOML plan file), the
shell completes file names (bash ``complete -o default``, zsh ``_files``).  They must be fast and
import nothing heavy: they run on every Tab.
"""

from __future__ import annotations

# Plan names as the person types them (``random:N`` etc. complete to their prefix).
CAPTURE_PLANS = ("six", "qureshi18", "random:", "gyro-axes", "hwangbo-iron", "still:",
                 "warmup:")  # fmt: skip
SIMULATE_PLANS = ("six", "qureshi18", "random:", "gyro-axes", "hwangbo-iron", "hk-redundant",
                  "hk-gyro", "qureshi-axes", "free:")  # fmt: skip
ACCEL_UNITS = ("counts", "V", "g", "m/s^2")
GYRO_UNITS = ("counts", "V", "rad/s", "deg/s")
TIME_UNITS = ("s", "ms", "us", "ns")


def _matching(values, incomplete: str) -> list[str]:
    return [v for v in values if v.startswith(incomplete)]


def capture_plan(incomplete: str) -> list[str]:
    return _matching(CAPTURE_PLANS, incomplete)


def simulate_plan(incomplete: str) -> list[str]:
    return _matching(SIMULATE_PLANS, incomplete)


def accel_units(incomplete: str) -> list[str]:
    return _matching(ACCEL_UNITS, incomplete)


def gyro_units(incomplete: str) -> list[str]:
    return _matching(GYRO_UNITS, incomplete)


def time_units(incomplete: str) -> list[str]:
    return _matching(TIME_UNITS, incomplete)


def simulate_units(incomplete: str) -> list[str]:
    return _matching(("counts", "m/s^2"), incomplete)


def import_formats(incomplete: str) -> list[str]:
    from imucal_cli.formats.importers import FORMATS  # the registry: new readers appear here

    return _matching(FORMATS, incomplete)


def apply_formats(incomplete: str) -> list[str]:
    return _matching(("h5", "csv"), incomplete)


def export_formats(incomplete: str) -> list[str]:
    from imucal_cli.use.export import EXPORT_FORMATS  # the registry

    return _matching(EXPORT_FORMATS, incomplete)


def ports(incomplete: str) -> list[str]:
    """Serial ports that exist (``/dev/ttyUSB*``, ``/dev/ttyACM*``, ...); else file names."""
    import glob

    found = []
    for pattern in ("/dev/ttyUSB*", "/dev/ttyACM*", "/dev/tty.usb*", "/dev/cu.usb*", "/dev/pts/*"):
        found += [p for p in sorted(glob.glob(pattern)) if p.startswith(incomplete)]
    return found
