"""`imucal import`: sessions from recorded text files, segmented by the data itself.

Two formats:

- ``csv``: one sample per line, fields separated by commas, tabs or spaces (detected per file);
  the fields are named by a column spec (:func:`parse_columns`) or, when none is given, by a
  header line (``acc_x``/``ax``/``accel_x``, ``gyr_x``/``gx``/``gyro_x``, ``t``/``time``/
  ``timestamp``, ...).  Without a ``t`` column, time is ``row / rate``.
- ``imu_tk``: imu_tk's pair of files (accelerometer, then gyroscope), each ``t x y z`` per
  line, whitespace separated; samples are matched by their time stamps.

Lines starting with ``#`` are comments; non-numeric lines before the first sample are header
lines; any other line that does not give the expected numbers is malformed: skipped and
counted, never fatal unless nothing is left.  Raw values are stored as read (never rescaled);
the units given become the session's ``accel_units``/``gyro_units``.

The static segments come from :func:`imucal_cli.solvers.segmentation.find_static`, the rotation
segments between them (where there is gyro data) from ``find_rotations``.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Segment, Session
from imucal_cli.solvers.segmentation import (
    estimate_noise,
    find_rotations,
    find_static,
)

__all__ = [
    "ACCEL_UNITS",
    "FIELDS",
    "FORMATS",
    "GYRO_UNITS",
    "ImportStats",
    "Recording",
    "TIME_UNITS",
    "import_files",
    "infer_columns",
    "parse_columns",
    "read_recording",
    "segment_recording",
]

FIELDS = ("t", "ax", "ay", "az", "gx", "gy", "gz", "temp")
"""Field names of a column spec; ``_`` skips a field."""

FORMATS = ("csv", "imu_tk")
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
ACCEL_UNITS = ("counts", "V", "g", "m/s^2")
GYRO_UNITS = ("counts", "V", "rad/s", "deg/s")

#: Header names (lower case, without spaces, dashes and brackets) and the field they mean.
HEADER_ALIASES: dict[str, str] = {}
for _field, _names in {
    "t": ("t", "time", "timestamp", "times", "time_s", "t_s", "sec", "seconds"),
    "temp": ("temp", "temperature", "temp_c"),
}.items():
    for _name in _names:
        HEADER_ALIASES[_name] = _field
for _axis in "xyz":
    for _name in ("a{}", "acc_{}", "acc{}", "accel_{}", "accel{}", "acceleration_{}", "acc_{}_raw"):
        HEADER_ALIASES[_name.format(_axis)] = "a" + _axis
    for _name in ("g{}", "gyr_{}", "gyr{}", "gyro_{}", "gyro{}", "gyroscope_{}", "gyr_{}_raw"):
        HEADER_ALIASES[_name.format(_axis)] = "g" + _axis

_MIN_STILL_S = 1.0


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
    """

    time: np.ndarray
    accel: np.ndarray | None
    gyro: np.ndarray | None
    temperature: np.ndarray | None
    rate_hz: float
    names: list[str]
    columns: list[str | None]
    stats: ImportStats = field(default_factory=ImportStats)


# --------------------------------------------------------------------------------------------
# Column specs
# --------------------------------------------------------------------------------------------


def parse_columns(text: str) -> list[str | None]:
    """Parse a column spec: comma-separated field names, ``_`` for a skipped field.

    Parameters
    ----------
    text : str
        E.g. ``"t,ax,ay,az,gx,gy,gz"`` or ``"_,ax,ay,az"``; names from :data:`FIELDS`,
        case-insensitive, spaces ignored.

    Returns
    -------
    list of (str or None)
        One entry per field of a line: its name, or None for ``_``.

    Raises
    ------
    InputError
        An unknown or repeated name, an empty field, or an accelerometer or gyroscope with
        some but not all of its three axes.
    """
    names = [part.strip().lower() for part in str(text).split(",")]
    if not names or any(not n for n in names):
        raise InputError(f"--columns {text!r}: empty field name (use _ to skip a field)")
    out: list[str | None] = []
    for n in names:
        if n == "_":
            out.append(None)
            continue
        if n not in FIELDS:
            raise InputError(
                f"--columns {text!r}: unknown field {n!r} (use {', '.join(FIELDS)} or _)"
            )
        if n in out:
            raise InputError(f"--columns {text!r}: field {n!r} appears twice")
        out.append(n)
    for sensor, what in (("a", "accelerometer"), ("g", "gyroscope")):
        have = [f"{sensor}{x}" in out for x in "xyz"]
        if any(have) and not all(have):
            raise InputError(
                f"--columns {text!r}: the {what} needs all three of {sensor}x,{sensor}y,{sensor}z"
            )
    if "ax" not in out and "gx" not in out:
        raise InputError(f"--columns {text!r}: names no accelerometer (ax,ay,az) or gyroscope")
    return out


def infer_columns(header: Sequence[str]) -> list[str | None] | None:
    """Fields from a header line's names, or None when it names no sensor axis.

    Names are matched case-insensitively after dropping units in brackets and turning spaces
    and dashes into ``_`` (``"Acc X [m/s^2]"`` -> ``acc_x``); unknown names become skipped
    fields.  A sensor with fewer than three recognised axes is ignored.
    """
    out: list[str | None] = []
    for raw in header:
        name = re.sub(r"[\[(].*?[\])]", "", raw).strip().strip("\"'").lower()
        name = re.sub(r"[\s\-]+", "_", name)
        f = HEADER_ALIASES.get(name)
        out.append(f if f is not None and f not in out else None)
    for sensor in "ag":
        axes = [f"{sensor}{x}" for x in "xyz"]
        if not all(a in out for a in axes):
            out = [None if f in axes else f for f in out]
    if not any(f in ("ax", "gx") for f in out):
        return None
    return out


# --------------------------------------------------------------------------------------------
# Reading text
# --------------------------------------------------------------------------------------------


def split_fields(line: str, comma: bool) -> list[str]:
    if comma:
        return [p.strip() for p in line.split(",")]
    return line.split()


def skipped_fields(spec) -> frozenset[int]:
    """Positions of the ``_`` (skipped) fields of a column spec (None: no spec yet)."""
    if spec is None:
        return frozenset()
    return frozenset(j for j, name in enumerate(spec) if name is None)


def parse_numbers(parts: list[str], skip: frozenset[int] = frozenset()) -> list[float] | None:
    """The fields of a line as numbers, or None when one is not a finite number. Fields at
    the positions in ``skip`` (``_`` in a column spec) may hold anything; they read as 0."""
    try:
        values = [0.0 if j in skip else float(p) for j, p in enumerate(parts)]
    except ValueError:
        return None
    if not all(np.isfinite(values)):
        return None
    return values


def _read_lines(path: Path) -> list[str]:
    src = str(path)
    if not path.exists():
        raise InputError(f"{src}: no such file")
    if path.is_dir():
        raise InputError(f"{src}: is a directory, not a recording")
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError(f"{src}: cannot read ({exc.strerror or exc})") from None
    if not text.strip():
        raise InputError(f"{src}: empty file")
    return text.splitlines()


def _read_table(
    path: Path,
    n_fields: int | None,
    skip_rows: int,
    stats: ImportStats,
    comma: bool | None = None,
    skip: frozenset[int] = frozenset(),
) -> tuple[np.ndarray, np.ndarray, list[str] | None]:
    """Numeric rows of a text file.

    Returns the rows (K, n_fields), their 1-based line numbers (K,) and the last header line's
    fields (or None).  ``n_fields`` None: the most common field count of the numeric rows.
    """
    src = str(path)
    lines = _read_lines(path)
    stats.lines += len(lines)
    header: list[str] | None = None
    rows: list[list[float]] = []
    numbers: list[int] = []
    bad: list[int] = []
    seen_data = False
    for i, raw in enumerate(lines):
        line = raw.strip().lstrip("\ufeff")
        if i < skip_rows:
            stats.header += 1
            continue
        if not line:
            stats.blank += 1
            continue
        if line.startswith("#"):
            stats.comments += 1
            continue
        if comma is None:
            comma = "," in line
        parts = split_fields(line, comma)
        values = parse_numbers(parts, skip)
        if values is None:
            if not seen_data:
                stats.header += 1
                header = parts
            else:
                bad.append(i + 1)
            continue
        seen_data = True
        rows.append(values)
        numbers.append(i + 1)
    if not rows:
        raise InputError(f"{src}: no numeric rows (only header or text lines)")
    lengths = np.array([len(r) for r in rows])
    if n_fields is None:
        counts = np.bincount(lengths)
        n_fields = int(np.argmax(counts))
    keep = lengths == n_fields
    if not keep.any():
        found = ", ".join(str(v) for v in sorted(set(lengths.tolist()))[:5])
        raise InputError(
            f"{src}: no row has the {n_fields} fields the columns name (rows have {found}); "
            "fix --columns"
        )
    bad.extend(np.asarray(numbers)[~keep].tolist())
    if bad:
        stats.malformed += len(bad)
        if stats.first_malformed is None:
            stats.first_malformed = f"{path.name}:{min(bad)}"
    data = np.array([r for r, k in zip(rows, keep, strict=True) if k], dtype=np.float64)
    return data, np.asarray(numbers)[keep], header


def check_time(time: np.ndarray, lines: np.ndarray, src: str) -> None:
    dt = np.diff(time)
    bad = np.flatnonzero(~(dt > 0))
    if len(bad):
        j = int(bad[0])
        raise InputError(
            f"{src}: time does not increase at line {int(lines[j + 1])} ({time[j + 1]:.9g} s "
            f"after {time[j]:.9g} s at line {int(lines[j])}); {len(bad)} such step(s)"
        )


def read_recording(
    paths: Sequence[str | os.PathLike],
    fmt: str = "csv",
    columns: str | Sequence[str | None] | None = None,
    *,
    time_unit: str = "s",
    rate_hz: float | None = None,
    skip_rows: int = 0,
) -> Recording:
    """Read the samples of recorded text files.

    Parameters
    ----------
    paths : sequence of path-like
        ``csv``: one file.  ``imu_tk``: the accelerometer file, then the gyroscope file.
    fmt : {"csv", "imu_tk"}
    columns : str or list, optional
        ``csv``: the column spec (:func:`parse_columns`); default from the header line.
        Not used by ``imu_tk`` (always ``t x y z``).
    time_unit : {"s", "ms", "us"}
        Unit of the ``t`` column.
    rate_hz : float, optional
        Sample rate, Hz; required when there is no ``t`` column (time = row / rate).
    skip_rows : int
        Lines skipped at the top of each file before anything else.

    Returns
    -------
    Recording

    Raises
    ------
    InputError
        Missing or empty file, no numeric rows, a spec that does not fit the rows, no time and
        no rate, time that does not increase (the message gives the line).
    """
    paths = [Path(p) for p in paths]
    if fmt not in FORMATS:
        raise InputError(f"unknown format {fmt!r}: use {' or '.join(FORMATS)}")
    if time_unit not in TIME_UNITS:
        raise InputError(f"unknown time unit {time_unit!r}: use s, ms or us")
    if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate must be a positive number of Hz, got {rate_hz:g}")
    if skip_rows < 0:
        raise InputError(f"--skip-rows must be >= 0, got {skip_rows}")
    stats = ImportStats()
    names = [p.name for p in paths]
    if fmt == "imu_tk":
        if len(paths) != 2:
            raise InputError(
                f"--format imu_tk takes two files, the accelerometer file then the gyroscope "
                f"file; got {len(paths)}"
            )
        if columns is not None:
            raise InputError("--columns does not apply to --format imu_tk (always t x y z)")
        tables = [_read_table(p, 4, skip_rows, stats, comma=False) for p in paths]
        for (data, lines, _), p in zip(tables, paths, strict=True):
            data[:, 0] *= TIME_UNITS[time_unit]
            check_time(data[:, 0], lines, str(p))
        (acc, acc_lines, _), (gyr, _, _) = tables
        common, ia, ig = np.intersect1d(acc[:, 0], gyr[:, 0], return_indices=True)
        stats.unmatched = len(acc) + len(gyr) - 2 * len(common)
        if len(common) == 0:
            raise InputError(
                f"{paths[0]} and {paths[1]}: no time stamp appears in both files "
                "(imu_tk files share their time stamps)"
            )
        time, accel, gyro, temp = common, acc[ia, 1:], gyr[ig, 1:], None
        used: list[str | None] = ["t", "ax", "ay", "az"]
    else:
        if len(paths) != 1:
            raise InputError(f"--format csv takes one file, got {len(paths)}")
        path = paths[0]
        spec = parse_columns(columns) if isinstance(columns, str) else columns
        data, lines, header = _read_table(
            path,
            None if spec is None else len(spec),
            skip_rows,
            stats,
            skip=skipped_fields(spec),
        )
        if spec is None:
            spec = infer_columns(header) if header else None
            if spec is None:
                raise InputError(
                    f"{path}: cannot tell which field is which (no header naming the axes): "
                    "pass --columns, e.g. --columns t,ax,ay,az,gx,gy,gz"
                )
            if len(spec) != data.shape[1]:
                raise InputError(
                    f"{path}: the header names {len(spec)} fields but rows have "
                    f"{data.shape[1]}: pass --columns"
                )
        used = list(spec)

        def col(name: str) -> int | None:
            return used.index(name) if name in used else None

        if col("t") is not None:
            time = data[:, col("t")] * TIME_UNITS[time_unit]
            check_time(time, lines, str(path))
        elif rate_hz is None:
            raise InputError(
                f"{path}: no time column (t) in the columns: pass --rate HZ to stamp row i "
                "at i / rate"
            )
        else:
            time = np.arange(len(data)) / rate_hz
        accel = data[:, [col(a) for a in ("ax", "ay", "az")]] if "ax" in used else None
        gyro = data[:, [col(g) for g in ("gx", "gy", "gz")]] if "gx" in used else None
        temp = data[:, col("temp")] if "temp" in used else None
    stats.samples = len(time)
    if len(time) >= 2:
        rate = rate_hz if rate_hz is not None else float(1.0 / np.median(np.diff(time)))
    else:
        rate = rate_hz or float("nan")
    return Recording(
        time=np.asarray(time, np.float64),
        accel=accel,
        gyro=gyro,
        temperature=temp,
        rate_hz=float(rate),
        names=names,
        columns=used,
        stats=stats,
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
    static = find_static(rec.time, rec.accel, rec.gyro, min_still_s=min_still_s, window_s=window_s)
    if not static:
        noise = estimate_noise(rec.time, rec.accel, rec.gyro, window_s=window_s)
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
    return [
        Segment(name=f"{i:04d}", kind=s.kind, start=s.start, stop=s.stop, label=s.label)
        for i, s in enumerate(segments)
    ]


def import_files(
    paths: Sequence[str | os.PathLike],
    fmt: str = "csv",
    columns: str | Sequence[str | None] | None = None,
    *,
    time_unit: str = "s",
    rate_hz: float | None = None,
    skip_rows: int = 0,
    accel_units: str | None = None,
    gyro_units: str | None = None,
    sensor: str | None = None,
    min_still_s: float = _MIN_STILL_S,
) -> Session:
    """Read recorded text files and segment them into a session (not yet written).

    Parameters are those of :func:`read_recording`, plus the raw units (``accel_units`` from
    :data:`ACCEL_UNITS`, ``gyro_units`` from :data:`GYRO_UNITS`), a ``sensor`` description and
    the shortest still period kept, s.

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
    if accel_units is not None and accel_units not in ACCEL_UNITS:
        raise InputError(f"--accel-units {accel_units!r}: use {', '.join(ACCEL_UNITS)}")
    if gyro_units is not None and gyro_units not in GYRO_UNITS:
        raise InputError(f"--gyro-units {gyro_units!r}: use {', '.join(GYRO_UNITS)}")
    rec = read_recording(
        paths, fmt, columns, time_unit=time_unit, rate_hz=rate_hz, skip_rows=skip_rows
    )
    segments = segment_recording(rec, min_still_s=min_still_s)
    try:
        mtime = os.path.getmtime(paths[0])
        created = datetime.fromtimestamp(mtime, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    except OSError:
        created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    session = Session(
        time=rec.time,
        accel=rec.accel,
        gyro=rec.gyro,
        temperature=rec.temperature,
        segments=segments,
        created=created,
        sensor=sensor,
        source="import:" + ",".join(rec.names),
        sample_rate_hz=rec.rate_hz,
        accel_units=accel_units if rec.accel is not None else None,
        gyro_units=gyro_units if rec.gyro is not None else None,
    )
    session.import_stats = rec.stats  # type: ignore[attr-defined]
    return session
