"""A sensor whose channel is dead, stuck, saturated or disconnected is refused before any
solver runs, in one line that names the sensor, the axis and what it reads (issue 24.6):
the solvers would otherwise fail on it with a singular matrix, a fit that does not converge,
or a calibration of an axis that measures nothing."""

from __future__ import annotations

import numpy as np

from imucal_cli.calibrate.common import adc_range, session_name
from imucal_cli.design.channel_faults import channel_faults
from imucal_cli.errors import InputError
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Session
from imucal_cli.model.session import RAW_UNITS

#: (session dataset, units attribute, the sensor's name in a message, config section)
SENSORS = (("accel", "accel_units", "accelerometer", "accel"),
           ("gyro", "gyro_units", "gyroscope", "gyro"),
           ("mag", "mag_units", "magnetometer", "mag"))  # fmt: skip
AXES = "xyz"


def _limits(x: np.ndarray, counts: bool, configured) -> tuple[float, float] | None:
    if configured is not None:
        return float(configured[0]), float(configured[1])
    if not counts:
        return None
    finite = x[np.isfinite(x)]
    return None if not len(finite) else adc_range(float(finite.min()), float(finite.max()))


def _axis(c: int, n: int) -> str:
    return AXES[c] if n == 3 else f"channel {c + 1}"


def _check_units(session: Session, name: str, units_attr: str) -> None:
    """Refuse raw units the session format does not name (``accel_units`` 'furlongs'): the
    calibration would carry them as its ``units_in`` into every export and report."""
    unit = getattr(session, units_attr, None)
    if unit is not None and unit not in RAW_UNITS[name]:
        raise InputError(f"{session_name(session)}: {units_attr} is {unit!r}, units imucal does "
                         f"not know ({', '.join(RAW_UNITS[name])}): state them with `imucal "
                         f"label SESSION --{name}-units UNITS`")  # fmt: skip


def check_channels(session: Session, cfg: Config, *, skip: tuple[str, ...] = ()) -> None:
    """Refuse a session whose sensor to be calibrated has a faulty channel.

    ``skip``: sensors not calibrated from this session (``--accel CAL.json``). A sensor whose
    ``[...] solver`` is ``"none"`` is not judged.

    Raises
    ------
    InputError
        Naming every faulty channel of the first faulty sensor (exit status 2).
    """
    for name, units_attr, label, section in SENSORS:
        x = getattr(session, name, None)
        if x is None or name in skip or getattr(getattr(cfg, section), "solver", None) == "none":
            continue
        _check_units(session, name, units_attr)
        x = np.asarray(x, float)
        counts = getattr(session, units_attr, None) == "counts"
        configured = getattr(cfg.gyro, "range", None) if name == "gyro" else None
        if not np.isfinite(x).any():
            continue  # no reading at all: the sensor's own step says so (its topic, column)
        faults = channel_faults(x, counts=counts, limits=_limits(x, counts, configured))
        if not faults:
            continue
        parts = [f"{_axis(f.channel, x.shape[1])} axis is {f.kind} ({f.detail})" for f in faults]
        raise InputError(
            f"{session_name(session)}: the {label}'s {'; its '.join(parts)}: a fault of the part "
            "or its wiring that no calibration can mend; check the sensor and its connection "
            f"and record again (or leave the {label} out: [{section}] solver = \"none\")"
        )
