"""What every importer returns: the samples of a recording, before segmentation, and what
reading them found.  Format-neutral: text, ROS bags and logs all fill the same :class:`Recording`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal_cli.formats.columns import TIME_UNITS as COLUMN_TIME_UNITS

__all__ = [
    "ACCEL_UNITS", "GYRO_UNITS", "MAG_UNITS", "TIME_UNITS", "ImportStats", "ReadOptions",
    "Recording",
]  # fmt: skip

TIME_UNITS = COLUMN_TIME_UNITS  # one table for capture, import and apply (s, ms, us, ns)
ACCEL_UNITS = ("counts", "V", "g", "m/s^2")
GYRO_UNITS = ("counts", "V", "rad/s", "deg/s")
MAG_UNITS = ("counts", "uT", "nT", "gauss")


@dataclass(frozen=True)
class ReadOptions:
    """How to read a recording (the ``imucal import`` options an importer may use).

    Attributes
    ----------
    columns : str or list of (str or None), optional
        Column spec (:func:`imucal_cli.formats.importers.text.parse_columns`); formats with
        named channels refuse it.
    time_unit : {"s", "ms", "us"}
        Unit of a time column.
    rate_hz : float, optional
        Sample rate, Hz, for recordings without time stamps.
    skip_rows : int
        Text formats: lines skipped at the top of each file.
    topic : str, optional
        Logs of several streams: the one to read (ROS topic, ULog instance).
    """

    columns: str | list[str | None] | None = None
    time_unit: str = "s"
    rate_hz: float | None = None
    skip_rows: int = 0
    topic: str | None = None


@dataclass
class ImportStats:
    """What reading one or more text files found.

    Attributes
    ----------
    lines : int
        Lines read (all files).
    samples : int
        Samples kept.
    comments : int
        ``#`` lines.
    header : int
        Header lines skipped (``--skip-rows`` and detected non-numeric lines before the data).
    blank : int
        Empty lines.
    malformed : int
        Lines skipped because they did not give the expected numbers.
    first_malformed : str or None
        ``file:line`` of the first malformed line.
    unmatched : int
        imu_tk: samples of one file with no sample of the same time in the other.
    """

    lines: int = 0
    samples: int = 0
    comments: int = 0
    header: int = 0
    blank: int = 0
    malformed: int = 0
    first_malformed: str | None = None
    unmatched: int = 0


@dataclass
class Recording:
    """Samples read from text files, before segmentation.

    Attributes
    ----------
    time : ndarray, shape (N,)
        Seconds, strictly increasing.
    accel, gyro : ndarray, shape (N, 3), or None
        Raw values as read.
    temperature : ndarray, shape (N,), or None
        Degrees C.
    rate_hz : float
        Nominal rate: the one given, else from the median time step, Hz.
    names : list of str
        File names (no directories).
    columns : list of (str or None)
        The fields of the (first) file, as used.
    stats : ImportStats
    lines : ndarray of int, shape (N,), or None
        Text formats: the 1-based line number of each sample in the (first) file.
    header : list of str or None
        Text formats: the fields of the header line, when there is one.
    mag : ndarray, shape (N, 3), or None
        Raw magnetometer values as read.
    accel_units, gyro_units, mag_units : str or None
        Units the format itself fixes (ROS: m/s^2, rad/s, uT; ULog: m/s^2, rad/s, gauss;
        binary and serial formats: counts); ``--accel-units`` ... override them.
    notes : list of str
        What the reader chose or left out (topic, time base, pairing), for the summary.
    host_time : ndarray, shape (N,), or None
        When the host received each sample, s of its clock, where the format records it beside
        the device's own time (a MAVLink telemetry log's receive stamps): the session's
        ``/raw/host_time``.
    """

    time: np.ndarray
    accel: np.ndarray | None
    gyro: np.ndarray | None
    temperature: np.ndarray | None
    rate_hz: float
    names: list[str]
    columns: list[str | None]
    stats: ImportStats = field(default_factory=ImportStats)
    lines: np.ndarray | None = None
    header: list[str] | None = None
    mag: np.ndarray | None = None
    accel_units: str | None = None
    gyro_units: str | None = None
    mag_units: str | None = None
    notes: list[str] = field(default_factory=list)
    host_time: np.ndarray | None = None
