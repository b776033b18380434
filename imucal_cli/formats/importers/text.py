"""Reading numbers from text files: the shared core of the text importers (``csv``,
``imu_tk``) and of ``imucal apply`` on CSV input.

Column specs name the fields of a line (:func:`parse_columns`, or :func:`infer_columns` from a
header line).  Lines starting with ``#`` are comments; non-numeric lines before the first sample
are header lines; any other line that does not give the expected numbers is malformed: skipped
and counted, never fatal unless nothing is left.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_input

from .recording import ImportStats

__all__ = [
    "FIELDS",
    "HEADER_ALIASES",
    "check_time",
    "infer_columns",
    "parse_columns",
    "parse_numbers",
    "read_table",
    "skipped_fields",
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


# --------------------------------------------------------------------------------------------
# Reading text
# --------------------------------------------------------------------------------------------


#: A number as a recording writes it: ASCII digits, an optional sign, point and exponent.
#: Python's float() also takes ``1_000.5``, non-ASCII digits (``"١٢"``), ``inf`` and ``nan``:
#: none of those is a sample (issue 11.2, found by the import fuzzer).
NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")
_BLANKS = re.compile(r"[ \t]+")
#: What may surround a line or a field: ASCII blanks only (a vertical tab, U+2028 or another
#: control character inside a line makes it malformed, never two lines or a cut number).
BLANK = " \t\r\n"


def split_fields(line: str, comma: bool) -> list[str]:
    """The fields of a line: comma-separated, or separated by spaces and tabs."""
    if comma:
        return [p.strip(BLANK) for p in line.split(",")]
    return [p for p in _BLANKS.split(line.strip(BLANK)) if p]


def split_lines(text: str) -> list[str]:
    """Lines split at ``\n`` only (``\r\n`` too); ``str.splitlines`` would also split at a
    vertical tab, a form feed, U+0085, U+2028 and U+2029 and keep the halves as two lines."""
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return [line[:-1] if line.endswith("\r") else line for line in lines]


def skipped_fields(spec) -> frozenset[int]:
    """Positions of the ``_`` (skipped) fields of a column spec (None: no spec yet)."""
    if spec is None:
        return frozenset()
    return frozenset(j for j, name in enumerate(spec) if name is None)


def parse_numbers(parts: list[str], skip: frozenset[int] = frozenset()) -> list[float] | None:
    """The fields of a line as numbers, or None when one is not a finite number. Fields at
    the positions in ``skip`` (``_`` in a column spec) may hold anything; they read as 0."""
    values = []
    for j, part in enumerate(parts):
        if j in skip:
            values.append(0.0)
        elif NUMBER.match(part):
            values.append(float(part))
        else:
            return None
    if not all(np.isfinite(values)):  # 1e999
        return None
    return values


#: A recording read whole is bounded by this (a day at 1 kHz as CSV is about 7 GB).
MAX_RECORDING_BYTES = 16 << 30


def read_lines(path: Path) -> list[str]:
    """The lines of a text recording (a regular file, read without blocking on a FIFO)."""
    data = read_input(path, what="recording", max_bytes=MAX_RECORDING_BYTES)
    text = data.decode("utf-8", errors="replace")
    if not text.strip():
        raise InputError(f"{path}: empty file")
    return split_lines(text)


def read_table(
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
    lines = read_lines(path)
    stats.lines += len(lines)
    header: list[str] | None = None
    rows: list[list[float]] = []
    numbers: list[int] = []
    bad: list[int] = []
    seen_data = False
    for i, raw in enumerate(lines):
        line = raw.lstrip("\ufeff").strip(BLANK)
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
