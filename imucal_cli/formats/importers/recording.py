"""What every importer returns: the samples of a recording, before segmentation, and what
reading them found.  Format-neutral: text, ROS bags and logs all fill the same :class:`Recording`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.columns import TIME_UNITS as COLUMN_TIME_UNITS
from imucal_cli.model.session import ACCEL_UNITS, GYRO_UNITS, MAG_UNITS

__all__ = [
    "ACCEL_UNITS", "GYRO_UNITS", "MAG_UNITS", "STAMPS_KEPT", "TIME_UNITS", "ImportStats",
    "ReadOptions", "Recording", "SeveralStreams", "choose_time", "increasing",
]  # fmt: skip

TIME_UNITS = COLUMN_TIME_UNITS  # one table for capture, import and apply (s, ms, us, ns)


class SeveralStreams(InputError):
    """A log holds several IMU streams and none was chosen (``--topic``): the refusal a single
    IMU gets, carrying the streams, so that ``import`` can bring them all into one session of
    several IMUs (issue 28).

    Attributes
    ----------
    labels : list of str
        Every stream, as ``--topic`` names it.
    """

    def __init__(self, message: str, labels: list[str]) -> None:
        super().__init__(message)
        self.labels = list(labels)


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
    mag_topic : str, optional
        Logs of several magnetometers: the one to read with the IMU (ROS topic, ULog
        ``sensor_mag`` instance, DataFlash ``MAG`` instance).
    """

    columns: str | list[str | None] | None = None
    time_unit: str = "s"
    rate_hz: float | None = None
    skip_rows: int = 0
    topic: str | None = None
    mag_topic: str | None = None


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
    unpaired : int
        Logs with separate accelerometer and gyroscope messages (ULog, DataFlash ACC/GYR,
        batch samples): samples with no sample of the other sensor at their time.
    dropped : int
        Binary formats: samples left out because their time did not follow the previous
        sample's (a repeated or earlier stamp), or a value was not a finite number.
    cut_lines : list of str
        Text formats: ``file:line`` of each last line dropped as cut short (no line break
        after it: :func:`~.text_scan.cut_line_start`), each a warning of the import.
    """

    lines: int = 0
    samples: int = 0
    comments: int = 0
    header: int = 0
    blank: int = 0
    malformed: int = 0
    first_malformed: str | None = None
    unmatched: int = 0
    unpaired: int = 0
    dropped: int = 0
    cut_lines: list[str] = field(default_factory=list)


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
    warnings : list of str
        What the user should know about the data kept (samples left out of a sensor, a log
        rate too low to calibrate from, gaps inside turns): ``--json``'s ``warnings``.
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
    warnings: list[str] = field(default_factory=list)


def increasing(time: np.ndarray, finite: np.ndarray) -> np.ndarray:
    """Rows to keep: ``finite``, and later than every finite row before them."""
    t = np.where(finite, time, -np.inf)
    before = np.maximum.accumulate(np.concatenate([[-np.inf], t[:-1]]))
    return finite & (t > before)


STAMPS_KEPT = 0.99
"""The device's own time stamps are used when they are all set and keep this share of the
samples in increasing order (or all but two, in a short log); the few that repeat or go back
are left out (counted).  One repeated stamp switched a whole recording to receive time before
(issue 26)."""


def _spikes(t: np.ndarray, k: int = 2) -> np.ndarray:
    """Stamps out of order with a neighbour and far from the median of their ``2 k``
    neighbours (more than 100 median steps): a damaged stamp far ahead would otherwise leave
    out every sample after it."""
    n = len(t)
    if n < 2 * k + 1:
        return np.zeros(n, bool)
    step = float(np.median(np.abs(np.diff(t))))
    padded = np.pad(t, k, mode="reflect")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * k + 1)
    around = np.median(np.delete(windows, k, axis=1), axis=1)
    far = np.abs(t - around) > 100.0 * max(step, 1e-12) + 1e-9 * np.abs(around)
    out_of_order = np.zeros(n, bool)  # a gap in a recording is in order: its edges are kept
    out_of_order[:-1] |= t[:-1] >= t[1:]
    out_of_order[1:] |= t[1:] <= t[:-1]
    return far & out_of_order


def choose_time(device: np.ndarray, received: np.ndarray | None,
                finite: np.ndarray) -> tuple[np.ndarray, bool, int]:  # fmt: skip
    """The time base of a log that records both the device's stamps and when each message was
    received.

    Parameters
    ----------
    device : ndarray (N,)
        The device's stamps, s (0 where unset).
    received : ndarray (N,) or None
        When the log received each message, s (None: none recorded).
    finite : ndarray of bool (N,)
        Rows whose values are finite numbers (the others are left out anyway).

    Returns
    -------
    time : ndarray (N,)
        ``device`` (unset stamps and lone spikes as -inf, so that they are left out) when its
        stamps are set
        and increasing for :data:`STAMPS_KEPT` of the finite rows (all but two at least), else
        ``received`` (``device`` when there is none).
    use_device : bool
    out_of_order : int
        Finite rows whose device stamp is unset or does not follow the previous one (left
        out), when the device's time is used.
    """
    n = int(np.count_nonzero(finite))
    if n > 0:  # unset stamps (0) and lone spikes are left out like repeated ones, when as few
        usable = (device > 0) & ~_spikes(device)
        keep = increasing(device, finite & usable)
        kept = int(np.count_nonzero(keep))
        if received is None or n - kept <= max((1.0 - STAMPS_KEPT) * n, 2):
            return np.where(usable, device, -np.inf), True, n - kept
    return (device, True, 0) if received is None else (received, False, 0)
