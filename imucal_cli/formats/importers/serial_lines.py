"""Text lines common Arduino sketches print, recognised by their prefix:

=====================================  =============================================  =========
line                                    sketch                                         fields
=====================================  =============================================  =========
``Raw:ax,ay,az,gx,gy,gz,mx,my,mz``      PJRC/Adafruit sketches feeding MotionCal       9 ints
``a/g:\\tax\\tay\\taz\\tgx\\tgy\\tgz``  i2cdevlib ``MPU6050_raw``                      6 ints
``a/g/m:\\tax ... gz\\tmx\\tmy\\tmz``   i2cdevlib ``MPU9150_raw``                      9 ints
=====================================  =============================================  =========

The values are raw counts (MotionCal's convention: 8192 per g, 16 per deg/s, 10 per uT, as its
sketches scale them; i2cdevlib: the part's registers).  Other lines (MotionCal's ``Uni:`` and
``Cal1:``, banners, partial lines) are counted and skipped.  Neither format carries a time, so
the rate is needed (``--rate``).  :func:`detect_line_format` tells the format from the first
lines, so ``imucal import`` needs no ``--format`` for them; :func:`line_format` and
:func:`parse_line` read one line, for the importer and for ``imucal capture`` alike.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_input

from .ros import Channels, one_file, to_recording
from .text import (
    BLANK,
    MAX_RECORDING_BYTES,
    NUMBER,
    cut_line_number,
    cut_line_start,
    is_delimited,
    split_fields,
    split_lines,
)

__all__ = [
    "LINE_FORMATS", "LineRecording", "detect_line_format", "line_format", "parse_line",
    "read_serial_lines",
]  # fmt: skip

# name -> (prefix, number of values, what the values are)
LINE_FORMATS = {
    "motioncal": ("Raw:", 9, "MotionCal Raw: accel, gyro, mag counts"),
    "i2cdevlib": ("a/g:", 6, "i2cdevlib a/g: accel, gyro counts"),
    "i2cdevlib-mag": ("a/g/m:", 9, "i2cdevlib a/g/m: accel, gyro, mag counts"),
}
_LONGEST_FIRST = sorted(LINE_FORMATS, key=lambda name: -len(LINE_FORMATS[name][0]))


def line_format(line: str, formats=tuple(LINE_FORMATS)) -> str | None:
    """The :data:`LINE_FORMATS` name (among ``formats``) whose prefix starts ``line`` (blanks
    around it ignored; ``a/g/m:`` before ``a/g:``), else None."""
    stripped = line.strip(BLANK)
    for name in _LONGEST_FIRST:
        if name in formats and stripped.startswith(LINE_FORMATS[name][0]):
            return name
    return None


def detect_line_format(head: str) -> str | None:
    """The :data:`LINE_FORMATS` name of the first line with a known prefix, else None."""
    for line in head.splitlines()[:200]:
        name = line_format(line)
        if name is not None:
            return name
    return None


def parse_line(fmt: str, line: str) -> list[float] | None:
    """The values of one line of format ``fmt``: a list of its count of finite numbers; None
    for a line of the format that does not hold them (malformed: cut, a field that is not a
    number or is empty, a control character).  Call it on lines whose :func:`line_format` is
    ``fmt``.

    Shared by the importer (:func:`read_serial_lines`) and ``imucal capture`` (its MotionCal
    and i2cdevlib protocol), so that a line means the same live and from a file.
    """
    prefix, count, _ = LINE_FORMATS[fmt]
    rest = line.strip(BLANK)[len(prefix) :].strip(BLANK)
    # MotionCal's sketches separate by commas, i2cdevlib's by tabs: one kind of separator per
    # line, and an empty field between two is malformed (issue 26: ``a/g:\t179\t8673\t,392``
    # kept az = +392), as is a carriage return inside the line.
    fields = split_fields(rest, is_delimited(rest))
    if len(fields) != count or not all(NUMBER.match(f) for f in fields):
        return None
    values = [float(f) for f in fields]
    return values if all(np.isfinite(values)) else None


@dataclass
class LineRecording:
    """Samples of a line-format file, counts; ``cut_line``: ``file:line`` of a last line
    dropped as cut short (:func:`~.text_scan.cut_line_start`)."""

    time: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    mag: np.ndarray | None
    fmt: str
    notes: list[str] = field(default_factory=list)
    lines: int = 0
    skipped: int = 0
    malformed: int = 0
    first_malformed: str | None = None
    cut_line: str | None = None


def read_serial_lines(
    path: str | os.PathLike, rate_hz: float | None, fmt: str | None = None
) -> LineRecording:
    """Read a MotionCal or i2cdevlib log (format detected when ``fmt`` is None).

    Raises
    ------
    InputError
        Unreadable file, no known line, no ``rate_hz``.
    """
    src = str(path)
    data = read_input(path, what="recording", max_bytes=MAX_RECORDING_BYTES)
    cut = cut_line_start(data)
    rec = LineRecording(np.empty(0), np.empty((0, 3)), np.empty((0, 3)), None, fmt or "")
    if cut is not None:  # the writer stopped mid-line: its numbers may be cut short
        rec.cut_line, data = f"{src}:{cut_line_number(data, cut)}", data[:cut]
    text = data.decode("utf-8", errors="replace")
    fmt = fmt or detect_line_format(text)
    if fmt is None or fmt not in LINE_FORMATS:
        raise InputError(f"{src}: no MotionCal 'Raw:' or i2cdevlib 'a/g:' line found")
    if rate_hz is None:
        raise InputError(f"{src}: {LINE_FORMATS[fmt][2]} lines carry no time: pass --rate "
                         "(the sketch's sample rate, Hz)")  # fmt: skip
    prefix, count, what = LINE_FORMATS[fmt]
    rec.fmt = fmt
    rows, slots = [], []
    slot = 0  # each line of the format is one sample period, a malformed one too
    for number, line in enumerate(split_lines(text), 1):
        if not line.strip(BLANK):
            continue
        rec.lines += 1
        if line_format(line) != fmt:
            rec.skipped += 1
            continue
        values = parse_line(fmt, line)
        slot += 1
        if values is None:
            rec.malformed += 1
            rec.first_malformed = rec.first_malformed or f"{src}:{number}"
            continue
        rows.append(values)
        slots.append(slot - 1)
    if not rows:
        raise InputError(f"{src}: no complete {prefix} line ({count} numbers)")
    data = np.asarray(rows, np.float64)
    rec.time = np.asarray(slots, np.float64) / float(rate_hz)  # a malformed line leaves a gap
    rec.accel, rec.gyro = data[:, 0:3], data[:, 3:6]
    rec.mag = data[:, 6:9] if count == 9 else None
    rec.notes.append(f"{what}; time = line of the format / {rate_hz:g} Hz (a malformed line "
                     "leaves its gap)")
    if fmt == "motioncal":
        rec.notes.append("MotionCal's sketches scale to 8192 counts per g, 16 per deg/s, 10 per "
                         "uT")  # fmt: skip
    return rec


NAME = "lines"
FILES = "one MotionCal (Raw:) or i2cdevlib (a/g:) serial log"


def read(paths, options, stats):
    """``imucal import --format lines`` (or ``motioncal``, ``i2cdevlib``): the format of the
    lines is detected; the rate is ``--rate``."""
    path = one_file(paths, options, NAME, FILES)
    rec = read_serial_lines(path, options.rate_hz)
    stats.lines, stats.malformed = rec.lines, rec.malformed
    stats.first_malformed, stats.comments = rec.first_malformed, rec.skipped
    stats.cut_lines += [rec.cut_line] if rec.cut_line else []
    ch = Channels(rec.time, rec.accel, rec.gyro, "counts", "counts", mag=rec.mag,
                  mag_units=None if rec.mag is None else "counts", notes=rec.notes)  # fmt: skip
    return to_recording(ch, paths, stats)
