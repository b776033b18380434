"""Shell completion of option values: plan names, units, formats, serial ports.

``imucal --install-completion`` installs typer's completion script for the current shell; these
functions give it the values of the options it cannot guess (typer completes commands and
option names by itself).  Where a function offers nothing (a path, a TOML plan file), the
shell completes file names (bash ``complete -o default``, zsh ``_files``).  They must be fast and
import nothing heavy: they run on every Tab.
"""

from __future__ import annotations

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
    from imucal_cli.plans import PLANS  # the registry; no numpy at its import

    names = [p.key + (":" if p.arg in ("count", "minutes") else "") for p in PLANS]
    return _matching(names, incomplete)


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


def capture_protocols(incomplete: str) -> list[str]:
    return _matching(CAPTURE_PROTOCOLS, incomplete)


def serve_protocols(incomplete: str) -> list[str]:
    return _matching(SERVE_PROTOCOLS, incomplete)


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
