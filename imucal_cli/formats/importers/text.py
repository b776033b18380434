"""Reading numbers from text files: the shared core of the text importers (``csv``,
``imu_tk``) and of ``imucal apply`` on CSV input.

Column specs name the fields of a line (:func:`parse_columns`, or :func:`infer_columns` from a
header line).  Lines starting with ``#`` are comments; non-numeric lines before the first sample
are header lines; any other line that does not give the expected numbers is malformed: skipped
and counted, never fatal unless nothing is left.  A last line without its line break was cut
short by the writer: dropped, with a warning (:func:`cut_line_start`).

A line's fields and numbers, and the scanners of a whole file, are :mod:`.text_scan`'s (its
line-level names importable from here).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_head, read_input

from .recording import ImportStats
from .text_scan import (
    BLANK,
    NUMBER,
    cut_line_number,
    cut_line_start,
    cut_line_warning,
    is_delimited,
    parse_numbers,
    scan_ascii,
    scan_lines,
    skipped_fields,
    split_fields,
    split_lines,
)

__all__ = [
    "BLANK",
    "FIELDS",
    "HEADER_ALIASES",
    "NUMBER",
    "check_time",
    "cut_line_number",
    "cut_line_start",
    "cut_line_warning",
    "first_fields",
    "header_columns",
    "infer_columns",
    "parse_columns",
    "parse_numbers",
    "read_table",
    "skipped_fields",
    "is_delimited",
    "split_fields",
    "split_lines",
]

FIELDS = ("t", "ax", "ay", "az", "gx", "gy", "gz", "mx", "my", "mz", "temp")
"""Field names of a column spec; ``_`` skips a field."""

#: Header names (lower case, without spaces, dashes and brackets) and the field they mean.
HEADER_ALIASES: dict[str, str] = {}
for _field, _names in {
    "t": ("t", "time", "timestamp", "times", "time_s", "t_s", "sec", "seconds"),
    "temp": ("temp", "temperature", "temp_c"),
}.items():
    for _name in _names:
        HEADER_ALIASES[_name] = _field
for _axis in "xyz":
    # EuRoC MAV / TUM-VI imu0/data.csv: w_RS_S_x [rad s^-1], a_RS_S_x [m s^-2]
    HEADER_ALIASES[f"a_rs_s_{_axis}"] = "a" + _axis
    HEADER_ALIASES[f"w_rs_s_{_axis}"] = "g" + _axis
    for _name in ("a{}", "acc_{}", "acc{}", "accel_{}", "accel{}", "acceleration_{}", "acc_{}_raw"):
        HEADER_ALIASES[_name.format(_axis)] = "a" + _axis
    for _name in ("g{}", "gyr_{}", "gyr{}", "gyro_{}", "gyro{}", "gyroscope_{}", "gyr_{}_raw"):
        HEADER_ALIASES[_name.format(_axis)] = "g" + _axis
    for _name in ("m{}", "mag_{}", "mag{}", "magn_{}", "magnetometer_{}", "mag_{}_raw"):
        HEADER_ALIASES[_name.format(_axis)] = "m" + _axis


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
        An unknown or repeated name, an empty field, or an accelerometer, gyroscope or
        magnetometer with some but not all of its three axes.
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
    for sensor, what in (("a", "accelerometer"), ("g", "gyroscope"), ("m", "magnetometer")):
        have = [f"{sensor}{x}" in out for x in "xyz"]
        if any(have) and not all(have):
            raise InputError(
                f"--columns {text!r}: the {what} needs all three of {sensor}x,{sensor}y,{sensor}z"
            )
    if "ax" not in out and "gx" not in out and "mx" not in out:
        raise InputError(
            f"--columns {text!r}: names no accelerometer (ax,ay,az), gyroscope or magnetometer"
        )
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
    for sensor in "agm":
        axes = [f"{sensor}{x}" for x in "xyz"]
        if not all(a in out for a in axes):
            out = [None if f in axes else f for f in out]
    if not any(f in ("ax", "gx", "mx") for f in out):
        return None
    return out


def header_columns(header: Sequence[str] | None, src: str) -> list[str | None]:
    """The fields a header line names (:func:`infer_columns`), or the error saying to pass
    ``--columns``.

    Raises
    ------
    InputError
        No header, or one that names no sensor axis.
    """
    spec = infer_columns(header) if header else None
    if spec is None:
        raise InputError(
            f"{src}: cannot tell which field is which (no header naming the axes): "
            "pass --columns, e.g. --columns t,ax,ay,az,gx,gy,gz"
        )
    return spec


#: A recording read whole is bounded by this (a day at 1 kHz as CSV is about 7 GB).
MAX_RECORDING_BYTES = 16 << 30


def _read_bytes(path: Path) -> bytes:
    """The bytes of a recording: a regular file (a FIFO would block), bounded in size."""
    return read_input(path, what="recording", max_bytes=MAX_RECORDING_BYTES)


def first_fields(path: Path, skip_rows: int = 0) -> list[str] | None:
    """The fields of the first line after ``skip_rows`` that is not blank or a comment (None:
    no such line in the first 64 KiB, or the file cannot be read: the reader will say why)."""
    try:
        head = read_head(path, 65536, what="recording")
    except InputError:
        return None
    lines = split_lines(head.decode("utf-8", errors="replace").lstrip("\ufeff"))
    for line in lines[skip_rows:-1] if len(head) == 65536 else lines[skip_rows:]:
        line = line.strip(BLANK)
        if line and not line.startswith("#"):
            return split_fields(line, is_delimited(line))
    return None


def read_lines(path: Path, raw: bytes | None = None) -> list[str]:
    """The lines of a text file (UTF-8, undecodable bytes replaced).

    Raises
    ------
    InputError
        Missing, unreadable or empty file, or a directory.
    """
    text = (_read_bytes(path) if raw is None else raw).decode("utf-8", errors="replace")
    if not text.strip():
        raise InputError(f"{path}: empty file")
    return split_lines(text)


def whole_lines(raw: bytes, path: Path, stats: ImportStats) -> tuple[bytes, str | None]:
    """``raw`` without a last line cut short (:func:`cut_line_start`), and that line's
    ``file:line`` (None: none cut), added to ``stats.cut_lines``."""
    cut = cut_line_start(raw)
    if cut is None:
        return raw, None
    stats.cut_lines.append(f"{path}:{cut_line_number(raw, cut)}")
    return raw[:cut], stats.cut_lines[-1]


def read_table(
    path: Path,
    n_fields: int | None,
    skip_rows: int,
    stats: ImportStats,
    comma: bool | None = None,
    skip: frozenset[int] = frozenset(),
) -> tuple[np.ndarray, np.ndarray, list[str] | None]:
    """Numeric rows of a text file.

    Lines before ``skip_rows`` and non-numeric lines before the first numeric one are header
    lines; blank and ``#`` lines are counted; any later line that does not give ``n_fields``
    finite numbers (fields in ``skip`` may hold anything and read as 0) is malformed: counted,
    the first one's ``file:line`` kept, and skipped.  A last line cut short (no line break
    after it: :func:`cut_line_start`) is dropped, its ``file:line`` in ``stats.cut_lines``.
    ``comma`` None: fields are separated by commas when the first line read has one, else by
    white space.

    The file is scanned with array operations, in pieces (:func:`scan_ascii`); files that are
    not plain ASCII, or hold a token that is not a number where a number is due, are read line
    by line (:func:`scan_lines`), with the same result.

    Returns
    -------
    data : ndarray, shape (K, n_fields)
    lines : ndarray of int, shape (K,)
        1-based line number of each row.
    header : list of str or None
        The fields of the last header line.

    Raises
    ------
    InputError
        Missing, unreadable or empty file, no numeric rows, no row with ``n_fields`` fields.
        ``n_fields`` None: the most common field count of the numeric rows.
    """
    raw, cut = whole_lines(_read_bytes(path), path, stats)
    scan = scan_ascii(raw, skip_rows, comma, skip)
    if scan is None:
        scan = scan_lines(read_lines(path, raw), skip_rows, comma, skip)
    stats.lines += scan.n_lines
    stats.header += scan.header
    stats.blank += scan.blank
    stats.comments += scan.comments
    if not len(scan.numbers):
        dropped = "" if cut is None else f"; the last line, {cut}, was cut short"
        raise InputError(f"{path}: no numeric rows (only header or text lines{dropped})")
    lengths = scan.lengths
    if n_fields is None:
        n_fields = int(np.argmax(np.bincount(lengths)))
    keep = lengths == n_fields
    if not keep.any():
        found = ", ".join(str(v) for v in np.unique(lengths)[:5].tolist())
        raise InputError(
            f"{path}: no row has the {n_fields} fields the columns name (rows have {found}); "
            "fix --columns"
        )
    bad = np.concatenate([scan.bad, scan.numbers[~keep]])
    if len(bad):
        stats.malformed += len(bad)
        if stats.first_malformed is None:
            stats.first_malformed = f"{path.name}:{int(bad.min())}"
    return scan.rows(keep, n_fields), scan.numbers[keep], scan.header_fields


def check_time(time: np.ndarray, lines: np.ndarray, src: str) -> None:
    dt = np.diff(time)
    bad = np.flatnonzero(~(dt > 0))
    if len(bad):
        j = int(bad[0])
        raise InputError(
            f"{src}: time does not increase at line {int(lines[j + 1])} ({time[j + 1]:.9g} s "
            f"after {time[j]:.9g} s at line {int(lines[j])}); {len(bad)} such step(s)"
        )
