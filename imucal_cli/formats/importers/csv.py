"""``--format csv``: one sample per line, fields separated by commas, tabs or spaces (detected
per file).

The fields are named by a column spec (:func:`~.text.parse_columns`) or, when none is given, by
a header line (``acc_x``/``ax``/``accel_x``, ``gyr_x``/``gx``/``gyro_x``, ``mag_x``/``mx``,
``t``/``time``/``timestamp``, ...).  Without a ``t`` column, time is ``row / rate``.

The IMU files of the EuRoC MAV and TUM-VI datasets (``mav0/imu0/data.csv``, Burri et al. 2016;
Schubert et al. 2018) are recognised by their header, a comment line
``#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y ...,a_RS_S_x [m s^-2],...``: the time unit comes
from its ``[ns]`` and the units are rad/s and m/s^2.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_head

from .recording import TIME_UNITS, ImportStats, ReadOptions, Recording
from .text import (
    check_time,
    first_fields,
    header_columns,
    infer_columns,
    is_delimited,
    parse_columns,
    parse_numbers,
    read_table,
    skipped_fields,
    split_fields,
    split_lines,
)

NAME = "csv"
FILES = "one CSV or text file"


def read(paths: Sequence[Path], options: ReadOptions, stats: ImportStats) -> Recording:
    """Read one delimited text file; see the module notes.

    Raises
    ------
    InputError
        Not one file, no numeric rows, a spec that does not fit the rows, no header naming the
        axes and no spec, no time column and no rate, time that does not increase.
    """
    if len(paths) != 1:
        raise InputError(f"--format csv takes one file, got {len(paths)}" + (
            " (imu_tk's accelerometer and gyroscope files: --format imu_tk)"
            if len(paths) == 2 else ""))  # fmt: skip
    path = paths[0]
    spec, dataset, options = _spec(path, options)
    data, lines, header = read_table(
        path,
        None if spec is None else len(spec),
        options.skip_rows,
        stats,
        skip=skipped_fields(spec),
    )
    if spec is None:
        spec = header_columns(header, str(path))
        if len(spec) != data.shape[1]:
            raise InputError(
                f"{path}: the header names {len(spec)} fields but rows have "
                f"{data.shape[1]}: pass --columns"
            )
    used = list(spec)

    def col(name: str) -> int | None:
        return used.index(name) if name in used else None

    time = _time(path, data, col("t"), lines, options)
    accel = data[:, [col(a) for a in ("ax", "ay", "az")]] if "ax" in used else None
    gyro = data[:, [col(g) for g in ("gx", "gy", "gz")]] if "gx" in used else None
    mag = data[:, [col(m) for m in ("mx", "my", "mz")]] if "mx" in used else None
    temp = data[:, col("temp")] if "temp" in used else None
    rec = Recording(
        time=time,
        accel=accel,
        gyro=gyro,
        temperature=temp,
        rate_hz=float("nan"),
        names=[path.name],
        columns=used,
        stats=stats,
        lines=lines,
        header=header,
        mag=mag,
    )
    if dataset is not None:
        rec.accel_units, rec.gyro_units = "m/s^2", "rad/s"
        rec.notes.append(f"EuRoC / TUM-VI IMU file: time in {options.time_unit} (the header's "
                         "#timestamp), w_RS_S_* rad/s, a_RS_S_* m/s^2")  # fmt: skip
    return rec


def _spec(path: Path, options: ReadOptions):
    """The file's column spec before its rows are read: ``--columns``, else an EuRoC / TUM-VI
    header (which also gives the time unit: ``options`` returned with it), else a header
    naming the axes (which also says which fields to skip: text labels); None where only the
    header row read with the table can say.

    Returns
    -------
    spec : list of str or None
    dataset : tuple or None
        :func:`euroc_header`'s ``(spec, time unit)`` where the file is EuRoC's.
    options : ReadOptions
    """
    columns = options.columns
    spec = parse_columns(columns) if isinstance(columns, str) else columns
    dataset = euroc_header(path, options.skip_rows) if spec is None else None
    if dataset is not None:
        spec, unit = dataset
        options = replace(options, time_unit=unit)
    if spec is None:  # a header naming the axes also says which fields to skip (text labels)
        first = first_fields(path, options.skip_rows)
        if first is not None and parse_numbers(first) is None:
            spec = infer_columns(first)
    return spec, dataset, options


def _time(path: Path, data: np.ndarray, t_col: int | None, lines, options: ReadOptions):
    """Each row's time, s: column ``t_col`` in ``options.time_unit`` (checked to increase),
    else row i at ``i / options.rate_hz``.

    Raises
    ------
    InputError
        No time column and no rate, or time that does not increase.
    """
    if t_col is not None:
        time = data[:, t_col] * TIME_UNITS[options.time_unit]
        check_time(time, lines, str(path))
    elif options.rate_hz is None:
        raise InputError(
            f"{path}: no time column (t) in the columns: pass --rate HZ to stamp row i at i / rate"
        )
    else:
        time = np.arange(len(data)) / options.rate_hz
    return time


_HEADER_UNITS = {"[ns]": "ns", "[us]": "us", "[ms]": "ms", "[s]": "s"}


def euroc_header(path: Path, skip_rows: int = 0) -> tuple[list[str | None], str] | None:
    """The column spec and time unit of an EuRoC / TUM-VI IMU file (its first line, a comment
    naming ``#timestamp [ns]``, ``w_RS_S_*`` and ``a_RS_S_*``), else None."""
    try:
        head = read_head(path, 4096, what="recording")
    except InputError:
        return None
    lines = split_lines(head.decode("utf-8", errors="replace").lstrip("\ufeff"))[skip_rows:]
    first = next((line.strip() for line in lines if line.strip()), "")
    if not first.startswith("#"):
        return None
    fields = split_fields(first[1:], is_delimited(first))
    names = [f.strip().lower() for f in fields]
    if not (names and names[0].startswith("timestamp") and any("w_rs_s_x" in n for n in names)
            and any("a_rs_s_x" in n for n in names)):  # fmt: skip
        return None
    spec = infer_columns(fields)
    unit = next((u for tag, u in _HEADER_UNITS.items() if tag in names[0].replace(" ", "")), "s")
    return spec, unit
