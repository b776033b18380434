"""The input of ``imucal apply`` (:mod:`.apply`) read one block of ``chunk_rows`` samples at a
time: a session's ``/raw`` datasets (through :func:`~imucal_cli.formats.session.open_samples`,
the one reader of sessions block by block) or a CSV's lines (the ``imucal import`` column rules),
each checked against what the calibration applies (its sensors, their channels, raw units and
temperature).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.importers.recording import TIME_UNITS
from imucal_cli.formats.importers.text import (
    BLANK,
    check_time,
    cut_line_start,
    header_columns,
    is_delimited,
    parse_columns,
    parse_numbers,
    skipped_fields,
    split_fields,
)
from imucal_cli.formats.session import open_samples
from imucal_cli.model.calibration import SensorCalibration

CSV_NAMES = {"accel": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz"), "mag": ("mx", "my", "mz")}


@dataclass
class Block:
    time: np.ndarray
    raw: dict[str, np.ndarray]
    done: int  # progress units consumed up to the end of this block
    temperature: np.ndarray | None = None  # degrees C, when a section's bias depends on it


def needs_temperature(sections: dict[str, SensorCalibration]) -> list[str]:
    """The sensors whose calibration holds ``bias_tempco`` (issue 17.1)."""
    return [name for name, sec in sections.items() if sec.temperature_terms is not None]


def no_temperature(src: str, cal_src: str, names: list[str], where: str) -> InputError:
    return InputError(
        f"{src} has no temperature ({where}), but {cal_src} holds a temperature-dependent "
        f"{' and '.join(names)} bias (bias_tempco) that needs the temperature of each sample"
    )


def chunk_bounds(n: int, chunk_rows: int) -> list[tuple[int, int]]:
    """Half-open blocks of ``chunk_rows``; a last block of one row joins the one before.

    ``SensorCalibration.apply`` on one row takes numpy's matrix-vector path, which may round
    differently from the matrix-matrix path of longer blocks; joining keeps the output equal
    bit for bit to applying the calibration to the whole array at once.
    """
    bounds = [(start, min(start + chunk_rows, n)) for start in range(0, n, chunk_rows)]
    if len(bounds) >= 2 and bounds[-1][1] - bounds[-1][0] == 1:
        bounds[-2:] = [(bounds[-2][0], n)]
    return bounds


# --------------------------------------------------------------------------------------------
# Readers: iterators of blocks
# --------------------------------------------------------------------------------------------


def session_blocks(
    path: Path, sections: dict[str, SensorCalibration], cal_src: str, chunk_rows: int
) -> tuple[Iterator[Block], int, dict[str, str | None], Callable[[], None], str | None]:
    """Open a session (:func:`~imucal_cli.formats.session.open_samples`, the one reader of
    sessions block by block); return its block iterator, row count, raw units, a closer and
    the session's ``sensor`` (None: not named)."""
    src = str(path)
    samples = open_samples(path)
    try:
        names = list(sections)
        for name, sec in sections.items():
            width = samples.channels.get(name)
            if width is None:
                raise InputError(
                    f"{src} has no {name} data (/raw/{name}), but {cal_src} calibrates the {name}"
                )
            n_cal = sec.bias.shape[0]
            if width != n_cal:
                raise InputError(
                    f"{cal_src} calibrates {n_cal} {name} channels but {src} has "
                    f"{width} (/raw/{name} shape {(samples.n, width)})"
                )
        if needs_temperature(sections):
            if "temperature" not in samples.channels:
                raise no_temperature(src, cal_src, needs_temperature(sections),
                                      "/raw/temperature")  # fmt: skip
            names.append("temperature")
        units = {name: samples.units(name) for name in sections}
    except BaseException:
        samples.close()
        raise

    def blocks() -> Iterator[Block]:
        for start, stop in chunk_bounds(samples.n, chunk_rows):
            block = next(samples.blocks(("time", *names), start, stop, rows=stop - start))
            values = dict(zip(names, block[1:], strict=True))
            temp = values.pop("temperature", None)
            yield Block(time=block[0], raw=values, done=stop, temperature=temp)

    return blocks(), samples.n, units, samples.close, samples.sensor


class CsvBlocks:
    """Blocks of a CSV read line by line (the ``imucal import`` column rules); iterate once.

    ``malformed`` and ``first_malformed`` count the lines skipped so far; ``cut_line`` is
    ``file:line`` of a last line dropped as cut short (:func:`~.text_scan.cut_line_start`:
    no line break after it, the lines before it ended with one)."""

    def __init__(self, path: Path, handle: IO[bytes], sections: dict[str, SensorCalibration],
                 cal_src: str, columns: str | None, time_unit: str, rate_hz: float | None,
                 chunk_rows: int) -> None:  # fmt: skip
        self.path, self.src, self.handle = path, str(path), handle
        self.sections, self.cal_src = sections, cal_src
        self.time_unit, self.rate_hz, self.chunk_rows = time_unit, rate_hz, chunk_rows
        self.spec = None if columns is None else parse_columns(columns)
        self.spec_from_header = False
        self.header: list[str] | None = None
        self.rows: list[list[float]] = []
        self.lines: list[int] = []
        self.done = 0  # bytes read
        self.n_kept = 0
        self.last_time: float | None = None
        self.last_line = 0
        self.malformed = 0
        self.first_malformed: str | None = None
        self.cut_line: str | None = None

    def _col(self, name: str) -> int | None:
        return self.spec.index(name) if name in self.spec else None

    def _check_spec(self) -> None:
        """At the first numeric row: the columns (from the header unless given) hold every
        sensor the calibration needs, the temperature it needs, and a time or a rate."""
        src, cal_src = self.src, self.cal_src
        if self.spec is None:
            self.spec = header_columns(self.header, src)
            self.spec_from_header = True
        for name, sec in self.sections.items():
            axes = CSV_NAMES[name]
            if axes[0] not in self.spec:
                how = "--columns" if not self.spec_from_header else "the header"
                raise InputError(
                    f"{src} has no {name} columns ({','.join(axes)} in {how}), but {cal_src} "
                    f"calibrates the {name}"
                )
            if sec.bias.shape[0] != 3:
                raise InputError(
                    f"{cal_src} calibrates {sec.bias.shape[0]} {name} channels but {src} has 3 "
                    f"({','.join(axes)})"
                )
        if needs_temperature(self.sections) and self._col("temp") is None:
            raise no_temperature(src, cal_src, needs_temperature(self.sections),
                                  "no temp column")  # fmt: skip
        if self._col("t") is None and self.rate_hz is None:
            raise InputError(
                f"{src}: no time column (t) in the columns: pass --rate HZ to stamp row i "
                "at i / rate"
            )

    def _block(self, k: int) -> Block:
        """The first ``k`` rows kept, as a block (times checked against the block before)."""
        data = np.array(self.rows[:k], dtype=np.float64)
        numbers = np.array(self.lines[:k])
        del self.rows[:k], self.lines[:k]
        t_col = self._col("t")
        if t_col is not None:
            t = data[:, t_col] * TIME_UNITS[self.time_unit]
            if self.last_time is None:
                check_time(t, numbers, self.src)
            else:
                check_time(np.r_[self.last_time, t], np.r_[self.last_line, numbers], self.src)
        else:
            t = np.arange(self.n_kept, self.n_kept + k) / self.rate_hz
        self.n_kept += k
        self.last_time, self.last_line = float(t[-1]), int(numbers[-1])
        raw = {name: data[:, [self._col(a) for a in CSV_NAMES[name]]] for name in self.sections}
        temp = data[:, self._col("temp")] if needs_temperature(self.sections) else None
        return Block(time=t, raw=raw, done=self.done, temperature=temp)

    def _skip(self, number: int) -> None:
        self.malformed += 1
        if self.first_malformed is None:
            self.first_malformed = f"{self.path.name}:{number}"

    def __iter__(self) -> Iterator[Block]:
        comma: bool | None = None
        seen_data = False
        for number, raw_line in enumerate(self.handle, start=1):
            self.done += len(raw_line)
            if number > 1 and cut_line_start(b"\n" + raw_line) == 1:  # the last line, cut
                self.cut_line = f"{self.path.name}:{number}"
                continue
            line = raw_line.decode("utf-8", errors="replace").lstrip("\ufeff").strip(BLANK)
            if not line or line.startswith("#"):
                continue
            if comma is None:
                comma = is_delimited(line)
            parts = split_fields(line, comma)
            values = parse_numbers(parts, skipped_fields(self.spec))
            if values is None and not seen_data:
                self.header = parts
                continue
            if not seen_data and values is not None:
                seen_data = True
                self._check_spec()
                if self.spec_from_header and len(values) != len(self.spec):
                    raise InputError(
                        f"{self.src}: the header names {len(self.spec)} fields but rows have "
                        f"{len(values)}: pass --columns"
                    )
            if values is None or len(values) != len(self.spec):
                self._skip(number)
                continue
            self.rows.append(values)
            self.lines.append(number)
            # Keep at least 2 rows back so that the last block never has a single row.
            if len(self.rows) >= self.chunk_rows + 2:
                yield self._block(self.chunk_rows)
        if not seen_data:
            raise InputError(f"{self.src}: no numeric rows (only header or text lines)")
        if self.n_kept == 0 and not self.rows:
            raise InputError(
                f"{self.src}: no row has the {len(self.spec)} fields the columns name; fix "
                "--columns"
            )
        if self.rows:
            yield self._block(len(self.rows))


def session_input(path: Path, sections: dict[str, SensorCalibration], cal_source: str,
                   chunk_rows: int):  # fmt: skip
    """A session's blocks, rows, raw units, closer and ``sensor`` name; refused when a
    sensor's raw units differ from those the calibration was made for."""
    blocks, total, units_in, close_input, sensor = session_blocks(path, sections, cal_source,
                                                                  chunk_rows)  # fmt: skip
    for name, sec in sections.items():
        want = sec.units_in
        have = units_in.get(name)
        if (
            isinstance(want, str)
            and have is not None
            and "unknown" not in (want, have)
            and want != have
        ):
            close_input()
            raise InputError(
                f"{path} records the {name} in {have} but {cal_source} was made for {want}"
            )
    return blocks, total, units_in, close_input, sensor


def csv_input(path: Path, sections: dict[str, SensorCalibration], cal_source: str,
               columns: str | None, time_unit: str, rate_hz: float | None, chunk_rows: int):
    """A CSV's blocks (:class:`CsvBlocks`), its size in bytes and its closer."""  # fmt: skip
    try:
        handle = open(path, "rb")
        total = os.fstat(handle.fileno()).st_size
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if total == 0:
        handle.close()
        raise InputError(f"{path}: empty file")
    blocks = CsvBlocks(path, handle, sections, cal_source, columns, time_unit, rate_hz,
                        chunk_rows)  # fmt: skip
    return blocks, total, handle.close
