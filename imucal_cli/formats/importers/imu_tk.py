"""``--format imu_tk``: imu_tk's pair of files (accelerometer, then gyroscope), each ``t x y z``
per line, whitespace separated; samples are matched by their time stamps."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError

from .recording import TIME_UNITS, ImportStats, ReadOptions, Recording
from .text import check_time, read_table

NAME = "imu_tk"
FILES = "the accelerometer file, then the gyroscope file"


def read(paths: Sequence[Path], options: ReadOptions, stats: ImportStats) -> Recording:
    """Read and match an imu_tk accelerometer/gyroscope pair.

    Raises
    ------
    InputError
        Not two files, a column spec (the layout is fixed), unreadable or non-numeric files,
        time that does not increase, no time stamp common to both files.
    """
    if len(paths) != 2:
        raise InputError(
            f"--format imu_tk takes two files, the accelerometer file then the gyroscope "
            f"file; got {len(paths)}"
        )
    if options.columns is not None:
        raise InputError("--columns does not apply to --format imu_tk (always t x y z)")
    tables = [read_table(p, 4, options.skip_rows, stats, comma=False) for p in paths]
    for (data, lines, _), p in zip(tables, paths, strict=True):
        data[:, 0] *= TIME_UNITS[options.time_unit]
        check_time(data[:, 0], lines, str(p))
    (acc, _, _), (gyr, _, _) = tables
    if acc.shape == gyr.shape and np.array_equal(acc, gyr, equal_nan=True):
        raise InputError(  # the accelerometer's numbers were written as the gyroscope's, exit 0
            f"{paths[0]} and {paths[1]}: the same numbers twice; give the accelerometer file "
            "then the gyroscope file"
        )
    common, ia, ig = np.intersect1d(acc[:, 0], gyr[:, 0], return_indices=True)
    stats.unmatched = len(acc) + len(gyr) - 2 * len(common)
    if len(common) == 0:
        raise InputError(
            f"{paths[0]} and {paths[1]}: no time stamp appears in both files "
            "(imu_tk files share their time stamps)"
        )
    return Recording(
        time=common,
        accel=acc[ia, 1:],
        gyro=gyr[ig, 1:],
        temperature=None,
        rate_hz=float("nan"),
        names=[p.name for p in paths],
        columns=["t", "ax", "ay", "az"],
        stats=stats,
    )
