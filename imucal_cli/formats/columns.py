"""The ``--columns`` spec: which field of a text line is which channel.

``ColumnSpec.parse("t,ax,ay,az,gx,gy,gz,temp")`` names the fields of a line in order:

==========  =====================================================================
name        meaning
==========  =====================================================================
``t``       device time stamp, in ``time_unit`` (``s``, ``ms``, ``us`` or ``ns``)
``ax``      accelerometer channels 1, 2, 3 (``ay``, ``az``); a redundant unit adds
            ``a4``, ``a5``, ... (channel 4, 5, ...)
``gx``      gyroscope channels 1, 2, 3 (``gy``, ``gz``); more as ``g4``, ``g5``, ...
``mx``      magnetometer channels 1, 2, 3 (``my``, ``mz``); more as ``m4``, ...
``temp``    temperature, degrees C
``_``       a field that is read but ignored (may repeat)
==========  =====================================================================

A line must carry every named field: lines with fewer or more fields are malformed.
Without a ``t`` field the reader stamps each line with the host clock.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from imucal_cli.errors import InputError

__all__ = ["DEFAULT_COLUMNS", "TIME_UNITS", "ColumnSpec", "SampleBlock"]

DEFAULT_COLUMNS = "t,ax,ay,az,gx,gy,gz,temp"
"""What ``imucal simulate --serve`` prints, and the default of ``imucal capture --columns``."""

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
"""Device time units and their length in seconds."""

_SEPARATORS = re.compile(r"[,\s;]+")
_CHANNEL = re.compile(r"([agm])(x|y|z|\d+)")
_AXIS_NUMBER = {"x": 1, "y": 2, "z": 3}


@dataclass(frozen=True)
class ColumnSpec:
    """Positions of the channels in a line of ``n_fields`` numbers.

    Attributes
    ----------
    names : tuple of str
        The field names as given (``"_"`` for skipped fields).
    time : int or None
        Field index of the device time, or None (host clock).
    accel, gyro : tuple of int
        Field indices of the accelerometer / gyroscope channels, in channel order (empty:
        the device has no such sensor).
    mag : tuple of int
        Field indices of the magnetometer channels (empty: none).
    temperature : int or None
        Field index of the temperature.
    time_unit : str
        Unit of the ``t`` field: ``s``, ``ms``, ``us`` or ``ns``.
    """

    names: tuple[str, ...]
    time: int | None
    accel: tuple[int, ...]
    gyro: tuple[int, ...]
    temperature: int | None
    time_unit: str = "s"
    mag: tuple[int, ...] = ()

    @property
    def n_fields(self) -> int:
        """Number of fields every data line has."""
        return len(self.names)

    @property
    def time_scale(self) -> float:
        """Seconds per unit of the ``t`` field."""
        return TIME_UNITS[self.time_unit]

    def __str__(self) -> str:
        return ",".join(self.names)

    @classmethod
    def parse(cls, text: str, time_unit: str = "s") -> ColumnSpec:
        """Parse a spec such as ``"t,ax,ay,az,gx,gy,gz,temp"`` (commas or spaces).

        Parameters
        ----------
        text : str
            Field names in line order; see the module notes.
        time_unit : str
            Unit of the ``t`` field: ``s``, ``ms``, ``us`` or ``ns``.

        Returns
        -------
        ColumnSpec

        Raises
        ------
        InputError
            An unknown or repeated name, a sensor with fewer than 3 channels or with a gap in
            its channel numbers, no sensor at all, or an unknown time unit.
        """
        where = f"--columns {text!r}"
        if time_unit not in TIME_UNITS:
            raise InputError(f"time unit {time_unit!r} is unknown: use {', '.join(TIME_UNITS)}")
        names = tuple(n for n in _SEPARATORS.split(text.strip().lower()) if n)
        if not names:
            raise InputError(f"{where}: no fields (example: {DEFAULT_COLUMNS})")
        time = temperature = None
        channels: dict[str, dict[int, int]] = {"a": {}, "g": {}, "m": {}}
        seen: set[str] = set()
        for index, name in enumerate(names):
            if name == "_":
                continue
            if name in seen:
                raise InputError(f"{where}: field {name!r} appears twice")
            seen.add(name)
            if name == "t":
                time = index
                continue
            if name == "temp":
                temperature = index
                continue
            match = _CHANNEL.fullmatch(name)
            number = None
            if match:
                axis = match.group(2)
                number = _AXIS_NUMBER.get(axis) or int(axis)
                if axis.isdigit() and number <= 3:
                    number = None  # a1..a3 are spelled ax, ay, az
            if number is None:
                raise InputError(
                    f"{where}: unknown field {name!r} (known: t, ax, ay, az, a4.., "
                    "gx, gy, gz, g4.., mx, my, mz, temp, _ to skip)"
                )
            sensor = channels[match.group(1)]
            if number in sensor:
                raise InputError(f"{where}: field {name!r} appears twice")
            sensor[number] = index
        ordered = {}
        for key, label in (("a", "accelerometer"), ("g", "gyroscope"), ("m", "magnetometer")):
            numbers = sorted(channels[key])
            if numbers and numbers != list(range(1, len(numbers) + 1)):
                raise InputError(
                    f"{where}: {label} channels must be {key}x, {key}y, {key}z "
                    f"(then {key}4, {key}5, ...) without gaps"
                )
            if numbers and len(numbers) < 3:
                raise InputError(f"{where}: the {label} needs at least 3 channels ({key}x..{key}z)")
            ordered[key] = tuple(channels[key][n] for n in numbers)
        if not ordered["a"] and not ordered["g"] and not ordered["m"]:
            raise InputError(
                f"{where}: no accelerometer, gyroscope or magnetometer channels (ax.., gx.., mx..)"
            )
        return cls(names, time, ordered["a"], ordered["g"], temperature, time_unit, ordered["m"])

    def to_block(self, rows: np.ndarray, host_time: np.ndarray | None = None):
        """Split parsed lines into a :class:`~imucal_cli.capture.stream.SampleBlock`.

        Parameters
        ----------
        rows : ndarray, shape (k, n_fields)
            The numbers of k lines.
        host_time : ndarray, shape (k,), optional
            Time stamps, s, used when the spec has no ``t`` field.

        Returns
        -------
        SampleBlock
            Time in seconds (device time times :attr:`time_scale`, else ``host_time``).
        """
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, self.n_fields)
        k = rows.shape[0]
        if self.time is not None:
            time = rows[:, self.time] * self.time_scale
        elif host_time is not None:
            time = np.asarray(host_time, dtype=np.float64).reshape(k)
        else:
            raise ValueError("host_time is needed: the spec has no t field")
        return SampleBlock(
            time=time,
            accel=rows[:, list(self.accel)] if self.accel else None,
            gyro=rows[:, list(self.gyro)] if self.gyro else None,
            temperature=rows[:, self.temperature] if self.temperature is not None else None,
            mag=rows[:, list(self.mag)] if self.mag else None,
        )


# --------------------------------------------------------------------------------------------
# Blocks of samples
# --------------------------------------------------------------------------------------------


@dataclass
class SampleBlock:
    """k consecutive samples; a sensor the device does not have is None.

    Attributes
    ----------
    time : ndarray, shape (k,)
        Seconds, strictly increasing (device clock, else host clock since the start).
    accel : ndarray, shape (k, na), or None
        Raw accelerometer channels, exactly as received.
    gyro : ndarray, shape (k, ng), or None
        Raw gyroscope channels.
    temperature : ndarray, shape (k,), or None
        Degrees C.
    mag : ndarray, shape (k, nm), or None
        Raw magnetometer channels.
    host_time : ndarray, shape (k,), or None
        When ``time`` is the device's clock: the host's clock when each sample arrived, s
        (recorded as ``/raw/host_time``: it measures the device clock, issue 17.2).
    """

    time: np.ndarray
    accel: np.ndarray | None = None
    gyro: np.ndarray | None = None
    temperature: np.ndarray | None = None
    mag: np.ndarray | None = None
    host_time: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.time.shape[0])

    @classmethod
    def empty(cls) -> SampleBlock:
        """A block of no samples (what a UI tick gets when nothing arrived)."""
        return cls(time=np.empty(0))

    def take(self, mask: np.ndarray) -> SampleBlock:
        """The samples where ``mask`` (boolean or index array) selects."""

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[mask]

        return SampleBlock(self.time[mask], pick(self.accel), pick(self.gyro),
                           pick(self.temperature), pick(self.mag),
                           pick(self.host_time))  # fmt: skip

    @staticmethod
    def concatenate(blocks: list[SampleBlock]) -> SampleBlock:
        """One block of all samples of ``blocks`` (empty blocks are skipped)."""
        blocks = [b for b in blocks if len(b)]
        if not blocks:
            return SampleBlock.empty()
        first = blocks[0]

        def cat(name: str) -> np.ndarray | None:
            if getattr(first, name) is None:
                return None
            return np.concatenate([getattr(b, name) for b in blocks])

        return SampleBlock(cat("time"), cat("accel"), cat("gyro"), cat("temperature"), cat("mag"),
                           cat("host_time"))  # fmt: skip
