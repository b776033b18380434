"""What the recorder checks while it records (issue 24.3): the device's time stamps against the
host clock, and the disk's free space against what the session still needs; and what to say
when no sample came.

**Time stamps.** A time unit off by a factor (ms stamps read as s) makes every rate and
integrated angle wrong by that factor; :func:`clock_problem` tells it from a healthy stream on a
busy host.  Serial lines queue while the host is busy (the capture starting up, a machine at
load 40): the first read can hold seconds of samples, so device time races ahead of the host's
time since the first arrival, and a burst says nothing about the rates.  The checks are
therefore bounds that a backlog cannot break:

- the device's own rate, samples per device second, lies within 1 Hz .. 10 kHz;
- the samples cannot span more device time than the host has had the port open (plus
  :data:`OPEN_SLACK_S` the device or its USB bridge may have held before), within
  :data:`CLOCK_TOLERANCE`: a backlog only delays samples, it never makes more of them;
- nor much less device time than passed on the host between the first samples' arrival and the
  latest's, within the same factor (a reader far behind the stream is behind by a bounded
  buffer, not by a factor).

Time units differ by a factor of 1000, so a tolerance of 10 tells them apart with room for any
backlog a serial buffer holds.

**Disk space.** HDF5 cannot close a file cleanly on a full disk, nor write a segment.  The
recorder stops *before* that: :func:`headroom` is what the rest of the capture needs (the
samples of the next few seconds, rounded up to whole chunks, the segments still to come, and
closing the file); when the free space falls below it the capture ends with ``disk-full`` and
every sample received is written.
"""

from __future__ import annotations

import math
import time as _time

from imucal_cli.formats.columns import TIME_UNITS

__all__ = [
    "CLOCK_CHECK_S",
    "CaptureEnded",
    "CLOCK_TOLERANCE",
    "CLOSE_BYTES",
    "DiskRoom",
    "OPEN_SLACK_S",
    "SEGMENTS_PER_S",
    "SEGMENT_BYTES",
    "clock_problem",
    "headroom",
    "no_data_reason",
]

class CaptureEnded(Exception):
    """Why a capture ended (used inside the recorder;
    :meth:`~imucal_cli.capture.recorder.Recorder.blocks` just stops).

    Attributes
    ----------
    kind : str
        One of :data:`~imucal_cli.capture.recorder.END_KINDS`.
    reason : str
        One line for the user.
    """

    def __init__(self, kind: str, reason: str) -> None:
        super().__init__(reason)
        self.kind = kind
        self.reason = reason


CLOCK_CHECK_S = 3.0
"""After this much host time with data, the device's time stamps are compared with the host
clock (issue 10.5)."""

CLOCK_TOLERANCE = 10.0
"""Device and host elapsed times may differ by this factor (serial buffering, a busy host);
time units differ by 1000."""

OPEN_SLACK_S = 1.0
"""Device seconds of samples a device (its USB bridge) may hold from before the port opened."""

MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 10_000.0
"""Sample rates a time unit can give, Hz (outside: the unit is wrong)."""

SEGMENT_BYTES = 4096
"""File space a segment takes: its row of the SWMR log (2 KiB) and its group at the close."""

SEGMENTS_PER_S = 1.0
"""Segments per device second a capture may add at its end (the unattended mode segments the
whole recording then): a still period of at least a second and the motion after it."""

CLOSE_BYTES = 16 * 1024
"""File space closing takes: HDF5's metadata at the close, the segment groups' container and
the root attributes written after it, with a margin."""

MIN_GAP_S = 1.0
"""Seconds of samples the headroom always holds (until the next check)."""

GAP_MARGIN = 1.5
"""The headroom holds the samples of this many times the longest gap between two checks."""


def clock_problem(
    device_s: float, samples: int, since_open_s: float, since_first_s: float, unit: str
) -> str | None:
    """Why the device's time stamps cannot be right, or None (see the module notes).

    Parameters
    ----------
    device_s : float
        Device time between the first and the last sample received, s (as read in ``unit``).
    samples : int
        Samples received.
    since_open_s : float
        Host time since the port was opened, s.
    since_first_s : float
        Host time between the arrival of the first samples and of the latest, s.
    unit : str
        The ``--time-unit`` the stamps were read in.

    Returns
    -------
    str or None
        One line naming the ``--time-unit`` that fits when a unit factor explains it.
    """
    if _fits(device_s, samples, since_open_s, since_first_s):
        return None
    rate = (samples - 1) / device_s if device_s > 0 else math.inf
    said = (
        f"the device's time stamps (read in {unit}) advanced {device_s:.4g} s in "
        f"{since_first_s:.3g} s of host time ({rate:.4g} Hz)"
    )
    stamps = device_s / TIME_UNITS[unit]
    fits = [
        u
        for u, factor in TIME_UNITS.items()
        if u != unit and _fits(stamps * factor, samples, since_open_s, since_first_s)
    ]
    if fits:
        return f"{said}: they look like {fits[0]}; capture again with --time-unit {fits[0]}"
    return f"{said}: check the t column (--columns) and --time-unit"


def _fits(device_s: float, samples: int, since_open_s: float, since_first_s: float) -> bool:
    """Whether ``device_s`` of ``samples`` is a possible stream (the module notes' bounds)."""
    if not device_s > 0:
        return False
    rate = (samples - 1) / device_s
    if not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
        return False
    if device_s > CLOCK_TOLERANCE * (since_open_s + OPEN_SLACK_S):
        return False  # more device time than the port was open: stamps run too fast
    return device_s * CLOCK_TOLERANCE >= since_first_s  # far less: stamps run too slow


def headroom(
    rate_hz: float, gap_s: float, chunk_rows: int, chunk_bytes: int, segments_to_come: float,
    *, pending: int = 0,
) -> int:
    """Bytes the capture still needs on the disk to end cleanly with every sample received.

    Parameters
    ----------
    rate_hz : float
        Samples per second (device time).
    gap_s : float
        Longest host time between two checks, s (a busy host checks less often): the samples
        of :data:`GAP_MARGIN` times that, and at least of :data:`MIN_GAP_S`, are held.
    chunk_rows, chunk_bytes : int
        Rows per HDF5 chunk of the ``/raw`` datasets, and the bytes a new chunk of every one
        of them takes.
    segments_to_come : float
        Segments the capture may still add.
    pending : int
        Samples received and not written yet.

    Returns
    -------
    int
        Bytes: the samples pending and those of the gap in whole chunks (plus the chunk being
        filled), the segments and :data:`CLOSE_BYTES`.
    """
    rows = pending + max(rate_hz, 1.0) * max(GAP_MARGIN * gap_s, MIN_GAP_S)
    chunks = math.ceil(rows / max(chunk_rows, 1)) + 1
    return int(chunks * chunk_bytes + SEGMENT_BYTES * max(segments_to_come, 0.0) + CLOSE_BYTES)


class DiskRoom:
    """The free space against what the rest of a capture needs, checked with every block:
    remembers the longest time between two checks (a busy host checks less often) and the
    samples' arrival rate over the last second (a backlog arrives faster than the device
    samples)."""

    def __init__(self) -> None:
        self.longest_gap_s = 0.0
        self.arrival_rate_hz = 0.0  # samples per host second over the last second
        self._last: float | None = None  # host time of the last check
        self._reference: tuple[float, int] | None = None  # host time and samples, a second ago

    def short(
        self, room: int | None, *, written: int, pending: int, arriving: int,
        device_rate_hz: float, chunk_rows: int, chunk_bytes: int, since_segment_s: float,
    ) -> tuple[int, int] | None:  # fmt: skip
        """``(room, fits)`` when ``room`` (bytes free) is less than :func:`headroom` (the
        capture must end now; ``fits``: how many of the ``arriving`` samples can still be
        written, leaving room for the segments and closing), else None.

        Parameters
        ----------
        room : int or None
            Bytes free for the session (None: unknown, never short).
        written, pending, arriving : int
            Samples in the file, received and not written yet, arriving now.
        device_rate_hz : float
            Samples per device second (0: not known yet, 100 Hz assumed).
        chunk_rows, chunk_bytes : int
            The session's HDF5 chunk: rows, and bytes of a chunk of every ``/raw`` dataset.
        since_segment_s : float
            Device time since the last segment was added (segments come at
            :data:`SEGMENTS_PER_S` at most).
        """
        now, n = _time.monotonic(), written + pending + arriving
        if self._last is not None:
            self.longest_gap_s = max(self.longest_gap_s, now - self._last)
        self._last = now
        t_ref, n_ref = self._reference or (now, n - arriving)
        if now - t_ref >= 1.0:
            self.arrival_rate_hz = (n - n_ref) / (now - t_ref)
            t_ref, n_ref = now, n
        self._reference = t_ref, n_ref
        if room is None:
            return None
        rate = max(device_rate_hz or 100.0, self.arrival_rate_hz)
        segments = SEGMENT_BYTES * (SEGMENTS_PER_S * since_segment_s + 1)
        need = headroom(rate, self.longest_gap_s, chunk_rows, chunk_bytes, 0.0,
                        pending=pending + arriving) + int(segments)  # fmt: skip
        if room >= need:
            return None
        # what still fits: the rest of the chunk being filled, and whole new chunks
        chunks = max(int((room - segments - CLOSE_BYTES) // chunk_bytes), 0)
        rows = (-(written + pending)) % chunk_rows + chunks * chunk_rows
        return int(room), int(min(max(rows, 0), arriving))


def no_data_reason(stats: dict, where: str, n_fields: int | None,
                   not_numbers: dict[str, int] | None = None) -> str:
    """Why no sample came, from the protocol's counters (``stats``); ``where``: the source and
    the wait (``"/dev/ttyUSB0 at 115200 baud in 10 s"``); ``n_fields``: the fields a line of
    ``--columns`` has (None: not lines of numbers); ``not_numbers``: per field, the lines of
    the right length whose field was ``nan`` or ``inf``."""
    if stats.get("bytes", 0) == 0:
        return (f"no data from {where}: check the port, the baud rate and that the sketch "
                "prints lines")  # fmt: skip
    if stats.get("lines", 0) == stats.get("comments", 0) and stats.get("malformed", 0) == 0:
        return (
            f"received {stats['bytes']} bytes from {where} but no data line "
            f"({stats.get('comments', 0)} comment lines): check that the sketch prints numbers"
        )
    bad = {k: n for k, n in (not_numbers or {}).items() if 2 * n > stats.get("malformed", 0)}
    if bad:  # lines of the right length, a field nan in most: an axis the sketch cannot read
        fields = ", ".join(f"{k} (nan or inf in {n} lines)" for k, n in bad.items())
        return (f"received {stats['bytes']} bytes from {where} but no valid line: field(s) "
                f"{fields} not a number: a disconnected or unread sensor axis; check the "
                "sensor's wiring and the sketch")  # fmt: skip
    expected = f", {n_fields} fields per line expected" if n_fields else ""
    return (
        f"received {stats['bytes']} bytes from {where} but no valid line "
        f"({stats.get('malformed', 0)} malformed{expected}): wrong baud rate? "
        "(or check --columns)"
    )


#: The line is said to fall behind when the samples took this much longer to arrive than the
#: device time they span (and at least :data:`BEHIND_MIN_S` longer, over
#: :data:`BEHIND_SPAN_S` of device time or more).
BEHIND_RATIO = 1.1
BEHIND_MIN_S = 2.0
BEHIND_SPAN_S = 10.0


def fell_behind(device_s: float, host_s: float, rate_hz: float | None) -> str | None:
    """Why the samples arrived slower than the device's clock ran, or None: ``device_s`` of
    device time (s) arrived over ``host_s`` of host time (first to last arrival, s).  A line
    that cannot carry the stream (too low a baud rate for the rate and the line's length)
    queues the samples in the device or the adapter, which in the end drops or slows them;
    the samples' device times stay right, so the capture is kept."""
    if not (device_s >= BEHIND_SPAN_S and host_s > BEHIND_RATIO * device_s
            and host_s - device_s >= BEHIND_MIN_S):  # fmt: skip
        return None
    rate = "" if rate_hz is None else f" {rate_hz:.4g} Hz"
    return (f"the samples of {device_s:.1f} s of device time took {host_s:.1f} s to arrive "
            f"({100 * device_s / host_s:.0f} % of the pace): the line fell "
            f"{host_s - device_s:.1f} s behind the{rate} stream (a baud rate too low for its "
            "lines, or a device that buffers); the device times are kept, but a real device "
            "drops or slows samples it cannot send: raise --baud (at both ends) or lower "
            "the rate")  # fmt: skip
