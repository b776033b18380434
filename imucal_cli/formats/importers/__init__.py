"""`imucal import`: sessions from recordings of other tools, segmented by the data itself.

One module per format, each a sibling of this file with ``NAME``, ``FILES`` (what the paths
are, for messages) and ``read(paths, options, stats) -> Recording``
(:class:`~.recording.Recording`, :class:`~.recording.ReadOptions`):

- ``csv`` (:mod:`.csv`): one sample per line, delimited text; fields named by ``--columns`` or
  a header line.
- ``imu_tk`` (:mod:`.imu_tk`): imu_tk's pair of files (accelerometer, then gyroscope).

A new format is a new module plus one line in :data:`FORMATS`; a module whose reader library
is an optional extra (rosbags, mcap, pyulog, pymavlink) imports it when it reads.  The shared
text reader is :mod:`.text`.  Raw values are stored as read (never rescaled); the units given
become the session's ``accel_units``/``gyro_units``.

This module dispatches to the reader, checks what every format must satisfy (increasing time,
a rate), and segments the recording: static segments from
:func:`imucal_cli.design.segmentation.find_static`, the rotation segments between them (where
there is gyro data) from ``find_rotations``.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from imucal_cli.design.gaps import find_gaps, gaps_within
from imucal_cli.design.segmentation import (
    Interval,
    NoiseEstimate,
    estimate_noise,
    find_rotations,
    find_static,
    find_steps,
)
from imucal_cli.errors import InputError
from imucal_cli.formats.session import TURN_ANGLE_RULE, Segment, Session, as_turn_angle
from imucal_cli.formats.set_columns import imu_number_name, split_columns, split_header
from imucal_cli.model.session import (
    MAX_FIELD_UT,
    RATE_RANGE_HZ,
    RAW_LIMIT,
    first_beyond_raw_limit,
)

from . import csv, imu_tk, mavlink, ros, serial_lines, ulog, witmotion
from .imu_set import imu_name, imu_stream, set_streams
from .mavlink import looks_like_dataflash, looks_like_dataflash_text, looks_like_tlog
from .recording import (
    ACCEL_UNITS,
    GYRO_UNITS,
    MAG_UNITS,
    TIME_UNITS,
    ImportStats,
    ReadOptions,
    Recording,
    SeveralStreams,
)
from .sections import labelled_segments, read_section_list, sections_of_column
from .serial_lines import detect_line_format
from .text import (
    FIELDS,
    check_time,
    cut_line_warning,
    first_fields,
    infer_columns,
    parse_columns,
    parse_numbers,
    skipped_fields,
    split_fields,
)
from .witmotion import looks_like_witmotion

__all__ = [
    "ACCEL_UNITS",
    "FIELDS",
    "FORMATS",
    "GYRO_UNITS",
    "ImportStats",
    "MAG_UNITS",
    "ReadOptions",
    "Recording",
    "TIME_UNITS",
    "RATE_RANGE_HZ",
    "check_sample_rate",
    "check_time",
    "detect_format",
    "import_files",
    "infer_columns",
    "parse_columns",
    "parse_numbers",
    "read_recording",
    "reader",
    "segment_recording",
    "skipped_fields",
    "split_steps",
    "split_fields",
]

FORMATS = {
    "csv": csv,
    "imu_tk": imu_tk,
    "ros": ros,
    "ulog": ulog,
    "lines": serial_lines,
    "motioncal": serial_lines,
    "i2cdevlib": serial_lines,
    "witmotion": witmotion,
    "mavlink": mavlink,
    "tlog": mavlink,
    "dataflash": mavlink,
}
"""``--format`` names and the sibling module that reads each."""

_MIN_STILL_S = 1.0


def reader(fmt: str):
    """The module reading format ``fmt``.

    Raises
    ------
    InputError
        An unknown format (the message lists the known ones).
    """
    if fmt not in FORMATS:
        raise InputError(f"unknown format {fmt!r}: use {' or '.join(FORMATS)}")
    return FORMATS[fmt]


def detect_format(paths: Sequence[str | os.PathLike]) -> str:
    """The format of ``paths`` by suffix, then by content: a ROS 2 bag folder, ``.bag``,
    ``.mcap``, ``.db3`` (``ros``); ``.ulg`` or the ULog magic (``ulog``); ``.tlog``, a
    DataFlash log's first FMT message or telemetry-log records (``mavlink``); WitMotion frames
    (``witmotion``); MotionCal or i2cdevlib lines (``lines``); else ``csv`` (two files:
    ``imu_tk`` must be asked for)."""
    if len(paths) != 1:
        return "csv"
    path = Path(paths[0])
    if path.is_dir():
        return "ros" if (path / "metadata.yaml").is_file() else "csv"
    suffix = path.suffix.lower()
    if suffix in (".bag", ".mcap", ".db3"):
        return "ros"
    if suffix == ".ulg":
        return "ulog"
    if suffix == ".tlog":
        return "mavlink"
    try:
        with open(path, "rb") as f:
            head = f.read(8192)
    except OSError:
        return "csv"  # the csv reader names the problem
    if head.startswith(b"ULog\x01\x12\x35"):
        return "ulog"
    if head.startswith((b"#ROSBAG", b"\x89MCAP")):
        return "ros"

    if looks_like_dataflash(head) or looks_like_tlog(head) or looks_like_dataflash_text(head):
        return "mavlink"
    if looks_like_witmotion(head):
        return "witmotion"
    if detect_line_format(head.decode("utf-8", errors="replace")) is not None:
        return "lines"
    return "csv"


def read_recording(
    paths: Sequence[str | os.PathLike],
    fmt: str | None = "csv",
    columns: str | Sequence[str | None] | None = None,
    *,
    time_unit: str = "s",
    rate_hz: float | None = None,
    skip_rows: int = 0,
    topic: str | None = None,
    mag_topic: str | None = None,
) -> Recording:
    """Read the samples of a recording in format ``fmt``.

    Parameters
    ----------
    paths : sequence of path-like
        The format's files (``csv``: one file; ``imu_tk``: the accelerometer file, then the
        gyroscope file).
    fmt : str
        A key of :data:`FORMATS`.
    columns : str or list, optional
        ``csv``: the column spec (:func:`parse_columns`); default from the header line.
        Formats with a fixed layout refuse it.
    time_unit : {"s", "ms", "us"}
        Unit of the time column.
    rate_hz : float, optional
        Sample rate, Hz; required when there is no ``t`` column (time = row / rate).
    skip_rows : int
        Lines skipped at the top of each text file before anything else.

    Returns
    -------
    Recording
        ``rate_hz`` the one given, else from the median time step.

    Raises
    ------
    InputError
        Unknown format or time unit, bad rate or skip count, and whatever the format's reader
        refuses (missing or empty file, no numeric rows, a spec that does not fit the rows, no
        time and no rate, time that does not increase: the message gives the line).
    """
    paths = [Path(p) for p in paths]
    for p in paths:
        if not (p.exists() or p.is_symlink()):  # before a reader library's own wording
            raise InputError(f"{p}: no such file")
    fmt = detect_format(paths) if fmt is None else fmt
    read = reader(fmt).read
    if mag_topic is not None and FORMATS[fmt] not in (ros, ulog, mavlink):
        raise InputError(f"--mag-topic applies to ros, ulog and mavlink logs, not --format {fmt}")
    if time_unit not in TIME_UNITS:
        raise InputError(f"unknown time unit {time_unit!r}: use {', '.join(TIME_UNITS)}")
    if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate must be a positive number of Hz, got {rate_hz:g}")
    if skip_rows < 0:
        raise InputError(f"--skip-rows must be >= 0, got {skip_rows}")
    options = ReadOptions(columns=columns, time_unit=time_unit, rate_hz=rate_hz,
                          skip_rows=skip_rows, topic=topic, mag_topic=mag_topic)  # fmt: skip
    rec = read(paths, options, ImportStats())
    rec.warnings += [cut_line_warning(where) for where in rec.stats.cut_lines]
    time = np.asarray(rec.time, np.float64)
    rec.time = time
    rec.stats.samples = len(time)
    where = " and ".join(str(p) for p in paths)
    _check_readings(rec, where)
    stamped = rate_hz is None or rec.columns.count("t") > 0
    measured = float(1.0 / np.median(np.diff(time))) if len(time) >= 2 else float("nan")
    if stamped and np.isfinite(measured):
        check_sample_rate(measured, time_unit, where)
    if rate_hz is not None:
        check_sample_rate(rate_hz, None, where)
        if stamped and np.isfinite(measured) and abs(measured / rate_hz - 1.0) > 0.1:
            raise InputError(
                f"{where}: the time stamps (read in {_UNIT_NAMES[time_unit]}) give "
                f"{measured:.4g} Hz but --rate says {rate_hz:g} Hz: drop --rate, or fix "
                "--time-unit"
            )
    rec.rate_hz = float(rate_hz) if rate_hz is not None else measured
    return rec


def _check_readings(rec: Recording, where: str) -> None:
    """Refuse readings no sensor gives (beyond :data:`RAW_LIMIT` in any unit: 1e303 from a
    damaged line overflowed the still-period search and the solvers)."""
    for name in ("accel", "gyro", "mag", "temperature"):
        values = getattr(rec, name, None)
        row = None if values is None else first_beyond_raw_limit(values)
        if row is not None:
            value = float(np.max(np.abs(np.atleast_1d(values[row]))))
            raise InputError(f"{where}: {name} reads {value:.3g} at sample {row}, beyond "
                             f"any sensor (at most {RAW_LIMIT:g} in any unit): not raw "
                             "readings, or a damaged file")  # fmt: skip



_UNIT_NAMES = {"s": "seconds", "ms": "milliseconds", "us": "microseconds", "ns": "nanoseconds"}


def check_sample_rate(rate_hz: float, time_unit: str | None, where: str) -> None:
    """Refuse a sample rate no IMU has (outside :data:`RATE_RANGE_HZ`).

    Parameters
    ----------
    rate_hz : float
        The rate, Hz: from the median step of time stamps read in ``time_unit``, or given
        (``time_unit`` None: ``--rate``).
    time_unit : str or None
        The unit the stamps were read in; when another unit of :data:`TIME_UNITS` gives a
        plausible rate, the message names ``--time-unit`` with it.
    where : str
        The file(s), for the message.

    Raises
    ------
    InputError
        The rate is implausible (the message says what to pass).
    """
    lo, hi = RATE_RANGE_HZ
    if lo <= rate_hz <= hi:
        return
    plausible = f"an IMU samples at {lo:g} Hz to {hi / 1000:g} kHz"
    if time_unit is None:
        raise InputError(f"{where}: --rate {rate_hz:g} Hz is implausible ({plausible})")
    scale = TIME_UNITS[time_unit]
    fits = {
        unit: rate_hz * scale / factor
        for unit, factor in TIME_UNITS.items()
        if unit != time_unit and lo <= rate_hz * scale / factor <= hi
    }
    step = 1.0 / rate_hz / scale
    said = f"time stamps {step:.4g} apart read as {_UNIT_NAMES[time_unit]} give {rate_hz:.4g} Hz"
    if fits:
        unit, rate = min(fits.items(), key=lambda kv: abs(np.log10(kv[1] / 100.0)))
        raise InputError(
            f"{where}: {said} ({plausible}); the stamps look like {_UNIT_NAMES[unit]}: pass "
            f"--time-unit {unit} ({rate:.4g} Hz)"
        )
    raise InputError(
        f"{where}: {said} ({plausible}); check the t column and --time-unit, or pass --rate"
    )


# --------------------------------------------------------------------------------------------
# Segmentation and the session
# --------------------------------------------------------------------------------------------


def segment_recording(
    rec: Recording, *, min_still_s: float = _MIN_STILL_S, window_s: float = 0.5
) -> list[Segment]:
    """Static segments where the unit was still, rotation segments between them (with gyro).

    Raises
    ------
    InputError
        No accelerometer data, too few samples for one still period, or no still period.
    """
    where = " and ".join(rec.names)
    if rec.accel is None:
        raise InputError(f"{where}: no accelerometer columns (ax,ay,az): static segments need them")
    n = len(rec.time)
    duration = rec.time[-1] - rec.time[0] if n > 1 else 0.0
    need = max(int(np.ceil((min_still_s + window_s) * rec.rate_hz)), 3) if n > 1 else 3
    if n < need:
        raise InputError(
            f"{where}: too few samples ({n}, {duration:.3g} s) to hold a still period of "
            f"{min_still_s:g} s plus a {window_s:g} s window; record longer"
        )
    noise = estimate_noise(rec.time, rec.accel, rec.gyro, window_s=window_s)
    static = find_static(
        rec.time, rec.accel, rec.gyro, min_still_s=min_still_s, window_s=window_s, noise=noise
    )
    static = split_steps(static, rec.accel, noise, min_n=int(np.ceil(min_still_s * rec.rate_hz)))
    if not static:
        shown = ", ".join(f"{s:.3g}" for s in noise.accel)
        raise InputError(
            f"{where}: no still period of at least {min_still_s:g} s found in {duration:.3g} s "
            f"(expected the unit held still about 2 s in each pose, the accelerometer varying no "
            f"more than its noise, about {shown} per axis)"
        )
    segments = [
        Segment(name="", kind="static", start=s.start, stop=s.stop, label=f"still {k + 1}")
        for k, s in enumerate(static)
    ]
    if rec.gyro is not None:
        for r in find_rotations(rec.time, rec.gyro, static):
            segments.append(Segment(name="", kind="rotation", start=r.start, stop=r.stop))
    segments.sort(key=lambda s: (s.start, s.kind))
    return [dataclasses.replace(s, name=f"{i:04d}") for i, s in enumerate(segments)]


def split_steps(
    static: list[Interval], accel: np.ndarray, noise: NoiseEstimate, min_n: int
) -> list[Interval]:
    """Still periods cut where their level jumps (two poses with no motion between, as in
    concatenated recordings): each part is kept, less half a window on each side of the step,
    when it still lasts ``min_n`` samples; never one period averaging two poses."""
    out: list[Interval] = []
    half = max(1, noise.window // 2)
    for s in static:
        cuts = [s.start + k for k in find_steps(accel[s.start : s.stop], noise.accel, noise.window)]
        bounds = [s.start, *cuts, s.stop]
        for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
            a2 = a + half if k > 0 else a
            b2 = b - half if k < len(cuts) else b
            if b2 - a2 >= max(min_n, 2):
                out.append(Interval(a2, b2))
    return out


def import_files(
    paths: Sequence[str | os.PathLike],
    fmt: str | None = "csv",
    columns: str | Sequence[str | None] | None = None,
    *,
    time_unit: str = "s",
    rate_hz: float | None = None,
    skip_rows: int = 0,
    accel_units: str | None = None,
    gyro_units: str | None = None,
    sensor: str | None = None,
    min_still_s: float = _MIN_STILL_S,
    sections: str | os.PathLike | None = None,
    turn_angle_deg: float | None = None,
    mag_units: str | None = None,
    magnetic_field_uT: float | None = None,
    topic: str | None = None,
    mag_topic: str | None = None,
) -> Session:
    """Read recorded text files and segment them into a session (not yet written).

    Parameters are those of :func:`read_recording`, plus the raw units (``accel_units`` from
    :data:`ACCEL_UNITS`, ``gyro_units`` from :data:`GYRO_UNITS`, ``mag_units`` from
    :data:`MAG_UNITS`), a ``sensor`` description, the shortest still period kept, s, and the
    local field magnitude ``magnetic_field_uT`` where known.  A recording with a magnetometer
    and no accelerometer has no segments (the magnetometer needs none).  ``sections``: a MaD
    Lab section list (JSON file) or the name of a column holding each row's label, whose
    labelled sections replace the automatic segmentation (:mod:`.sections`);
    ``turn_angle_deg``: the signed angle of their turns.

    Returns
    -------
    Session
        ``source = "import:<file names>"``, the reading statistics in ``session.import_stats``
        (an extra attribute, not written to the file).

    Raises
    ------
    InputError
        See :func:`read_recording` and :func:`segment_recording`; unknown units.
    """
    _check_units(accel_units, gyro_units, mag_units, magnetic_field_uT)
    if turn_angle_deg is not None and as_turn_angle(turn_angle_deg) is None:
        raise InputError(f"--turn-angle must be {TURN_ANGLE_RULE}, got {turn_angle_deg:g}")
    given_units = (accel_units, gyro_units, mag_units)
    recs = _read_set(
        paths, fmt, columns, time_unit=time_unit, rate_hz=rate_hz, skip_rows=skip_rows,
        topic=topic, mag_topic=mag_topic,
    )  # one recording per IMU, the reference first (several IMUs: issue 28)
    names = list(recs)
    rec = recs[names[0]]
    accel_units = accel_units or rec.accel_units
    gyro_units = gyro_units or rec.gyro_units
    mag_units = mag_units or rec.mag_units
    segments, notes = _segments(rec, Path(paths[0]), sections, turn_angle_deg, min_still_s)
    session = Session(
        time=rec.time,
        accel=rec.accel,
        gyro=rec.gyro,
        temperature=rec.temperature,
        segments=segments,
        created=_created(paths[0]),
        sensor=sensor,
        source="import:" + ",".join(rec.names),
        sample_rate_hz=rec.rate_hz,
        accel_units=accel_units if rec.accel is not None else None,
        gyro_units=gyro_units if rec.gyro is not None else None,
        mag=rec.mag,
        mag_units=mag_units if rec.mag is not None else None,
        magnetic_field_uT=magnetic_field_uT,
        host_time=rec.host_time,
    )
    if len(names) > 1:
        session.imus = {n: imu_stream(recs[n], given_units) for n in names[1:]}
        session.reference_name = names[0]
        notes.append(f"{len(names)} IMUs: {names[0]} (the reference, /raw), "
                     f"{', '.join(names[1:])} (/imus), each with its own time stamps")
    session.import_stats = rec.stats  # type: ignore[attr-defined]
    session.import_notes = notes  # type: ignore[attr-defined]
    session.import_warnings = rec.warnings + _gap_warnings(rec, segments)  # type: ignore[attr-defined]
    return session


def _read_set(paths, fmt, columns, **options) -> dict[str, Recording]:
    """Each IMU's recording, the reference first: one for a single IMU; every IMU of a log
    whose reader found several streams and none was chosen (:func:`.imu_set.set_streams`),
    or of a CSV whose columns name several (``ax.1``, :mod:`imucal_cli.formats.set_columns`)."""
    used = detect_format(paths) if fmt is None else fmt
    if used == "csv" and len(paths) == 1:
        specs = _csv_specs(Path(paths[0]), columns, options["skip_rows"])
        if specs is not None:
            return {imu_number_name(k): read_recording(paths, used, spec, **options)
                    for k, spec in specs.items()}  # fmt: skip
    try:
        return {"reference": read_recording(paths, fmt, columns, **options)}
    except SeveralStreams as exc:
        streams = set_streams(exc.labels) if options["topic"] is None else []
        if len(streams) < 2:
            raise
        recs = {}
        for label in streams:
            name = imu_name(label)
            if name in recs:
                raise InputError(f"{paths[0]}: two streams would be IMU {name!r}") from None
            recs[name] = read_recording(paths, fmt, columns, **{**options, "topic": label})
        return recs


def _csv_specs(path: Path, columns, skip_rows: int) -> dict[int, object] | None:
    """Per IMU number the column spec of a CSV naming several IMUs: from ``--columns``, else
    from its header line; None for one IMU."""
    if isinstance(columns, str):
        return split_columns(columns)
    if columns is not None:
        return None
    first = first_fields(path, skip_rows) if path.is_file() else None
    if first is None or parse_numbers(first) is not None:
        return None
    split = split_header(first)
    if split is None:
        return None
    specs = {k: infer_columns(v) for k, v in split.items()}
    return specs if all(s is not None for s in specs.values()) else None


def _gap_warnings(rec: Recording, segments: list[Segment]) -> list[str]:
    """Gaps in the sample times (:func:`~imucal_cli.design.gaps.find_gaps`), said at import:
    inside a rotation segment the turn cannot be integrated (calibrate leaves it out)."""
    gaps = find_gaps(rec.time)
    if not gaps:
        return []
    step = float(np.median(np.diff(rec.time)))
    worst = max(gaps, key=lambda g: g.length_s)
    out = [f"{len(gaps)} gap(s) in the sample times longer than 5 sample intervals "
           f"({step * 1e3:.3g} ms); the longest {worst.length_s:.3g} s after {worst.time_s:.6g} s"]
    for seg in segments:
        inside = gaps_within(gaps, seg.start, seg.stop) if seg.kind == "rotation" else []
        if inside:
            g = max(inside, key=lambda g: g.length_s)
            out.append(f"rotation segment {seg.name} has a gap of {g.length_s:.3g} s after "
                       f"{g.time_s:.6g} s: the turn is unknown across it (calibrate leaves it "
                       "out); turn again without losing samples")  # fmt: skip
    return out


def _check_units(accel_units: str | None, gyro_units: str | None, mag_units: str | None,
                 magnetic_field_uT: float | None) -> None:  # fmt: skip
    """Refuse units the session format does not name, and a field that is no magnitude."""
    if accel_units is not None and accel_units not in ACCEL_UNITS:
        raise InputError(f"--accel-units {accel_units!r}: use {', '.join(ACCEL_UNITS)}")
    if gyro_units is not None and gyro_units not in GYRO_UNITS:
        raise InputError(f"--gyro-units {gyro_units!r}: use {', '.join(GYRO_UNITS)}")
    if mag_units is not None and mag_units not in MAG_UNITS:
        raise InputError(f"--mag-units {mag_units!r}: use {', '.join(MAG_UNITS)}")
    if magnetic_field_uT is not None and not (
        np.isfinite(magnetic_field_uT) and 0 < magnetic_field_uT <= MAX_FIELD_UT
    ):
        raise InputError(f"--field-uT must be a positive number of microtesla, at most "
                         f"{MAX_FIELD_UT:.0f} uT, got {magnetic_field_uT:g}")  # fmt: skip


def _segments(
    rec: Recording, first: Path, sections: str | os.PathLike | None,
    turn_angle_deg: float | None, min_still_s: float,
) -> tuple[list[Segment], list[str]]:  # fmt: skip
    """The recording's segments and the reader's notes: the labelled sections given
    (:mod:`.sections`), none for a magnetometer alone, else found by the data itself."""
    notes: list[str] = list(rec.notes)
    if sections is not None:
        where = " and ".join(rec.names)
        spec = Path(sections)
        if spec.suffix.lower() == ".json" or spec.is_file():
            ranges = read_section_list(spec)
        else:
            ranges = sections_of_column(rec, first, str(sections))
        segments, section_notes = labelled_segments(
            rec, ranges, turn_angle_deg=turn_angle_deg, where=where
        )
        return segments, notes + section_notes
    if rec.accel is None and rec.mag is not None:
        return [], notes
    return segment_recording(rec, min_still_s=min_still_s), notes


def _created(path: str | os.PathLike) -> str:
    """When the recording was made, as the session's ``created``: its file's modification
    time (now, when that cannot be read)."""
    try:
        mtime = os.path.getmtime(path)
        return datetime.fromtimestamp(mtime, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    except OSError:
        return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
