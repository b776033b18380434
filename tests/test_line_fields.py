"""Issue 26: an empty field between two separators, or a carriage return inside a line, makes
the line malformed (counted) in every line format, never a number moved into the next column
(``-305,-4,\\r19`` kept gy = +19; ``a/g:\\t179\\t8673\\t,392`` kept az = +392); semicolons
separate fields in ``imucal import`` as they do in ``imucal capture``, and both read the same
line alike.  The lines are written as the sketches print them (``printf`` of the values)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imucal_cli.capture.stream import LineProtocol, PrefixedLineProtocol
from imucal_cli.formats.columns import ColumnSpec
from imucal_cli.formats.importers import read_recording
from imucal_cli.formats.importers.serial_lines import parse_line, read_serial_lines

from .cli_helpers import run

N = 300


def rows(n=N) -> np.ndarray:
    rng = np.random.default_rng(26)
    return np.column_stack([np.arange(n) / 100.0, rng.integers(-4000, 4000, (n, 6))])


def write(path: Path, lines: list[str], line_path: bool) -> Path:
    """The lines, with a comment of non-ASCII text when ``line_path`` (the reader then reads
    line by line instead of with its array scanner: both must agree)."""
    text = "\n".join(lines) + "\n"
    if line_path:
        text = "# température\n" + text
    path.write_bytes(text.encode())
    return path


def csv_lines(data: np.ndarray, sep: str) -> list[str]:
    return [sep.join(["t", "ax", "ay", "az", "gx", "gy", "gz"])] + [
        f"{r[0]:.2f}" + "".join(f"{sep}{int(v)}" for v in r[1:]) for r in data
    ]


@pytest.mark.parametrize("line_path", [False, True])
@pytest.mark.parametrize(
    "sep, broken",
    [
        (",", "{t},1,2,3,-305,-4,\r19"),  # a character lost where the CR stands
        (",", "{t},1,2,3,-305,,19,7"),  # an empty field and one field more
        (";", "{t};1;2;3;-305;;19;7"),
        ("\t", "{t}\t1\t2\t3\t-305\t\t19\t7"),  # two tabs around an empty field
        ("\t", "{t}\t1\t2\t3\t-305 \t \t19\t7"),
    ],
)
def test_csv_counts_an_empty_field_as_malformed(tmp_path, sep, broken, line_path):
    data = rows()
    lines = csv_lines(data, sep)
    lines[11] = broken.format(t=f"{data[10, 0]:.2f}")
    rec = read_recording([write(tmp_path / "r.csv", lines, line_path)], "csv")
    assert rec.stats.malformed == 1
    assert rec.stats.first_malformed == f"r.csv:{12 + line_path}"
    keep = np.delete(np.arange(N), 10)
    np.testing.assert_array_equal(rec.time, data[keep, 0])
    np.testing.assert_array_equal(np.hstack([rec.accel, rec.gyro]), data[keep, 1:])


@pytest.mark.parametrize("line_path", [False, True])
def test_semicolons_separate_fields_in_import(tmp_path, line_path):
    data = rows()
    rec = read_recording([write(tmp_path / "r.csv", csv_lines(data, ";"), line_path)], "csv")
    assert rec.stats.malformed == 0 and rec.columns == ["t", "ax", "ay", "az", "gx", "gy", "gz"]
    np.testing.assert_array_equal(np.column_stack([rec.time, rec.accel, rec.gyro]), data)
    mixed = csv_lines(data, "; ")  # blanks around the separator
    rec = read_recording([write(tmp_path / "m.csv", mixed, line_path)], "csv")
    np.testing.assert_array_equal(np.column_stack([rec.time, rec.accel, rec.gyro]), data)


@pytest.mark.parametrize("line_path", [False, True])
def test_imu_tk_counts_an_empty_field_or_inner_cr_as_malformed(tmp_path, line_path):
    data = rows()
    acc = [f"{r[0]:.2f} {int(r[1])} {int(r[2])} {int(r[3])}" for r in data]
    gyr = [f"{r[0]:.2f}\t{int(r[4])}\t{int(r[5])}\t{int(r[6])}" for r in data]
    acc[20] = f"{data[20, 0]:.2f} {int(data[20, 1])} -4 \r19"
    gyr[30] = f"{data[30, 0]:.2f}\t{int(data[30, 4])}\t\t{int(data[30, 6])}\t5"
    rec = read_recording([write(tmp_path / "a.txt", acc, line_path),
                          write(tmp_path / "g.txt", gyr, line_path)], "imu_tk")  # fmt: skip
    assert rec.stats.malformed == 2 and rec.stats.unmatched == 2
    keep = np.delete(np.arange(N), [20, 30])
    np.testing.assert_array_equal(np.column_stack([rec.time, rec.accel, rec.gyro]), data[keep])


def motioncal(r) -> str:  # PJRC's sketch: Serial.print("Raw:"); then values and commas
    return "Raw:" + ",".join(str(int(v)) for v in [*r[1:], 100, -200, 300])


def i2cdevlib(r) -> str:  # MPU6050_raw: Serial.print("a/g:\t"); then values and tabs
    return "a/g:\t" + "\t".join(str(int(v)) for v in r[1:])


@pytest.mark.parametrize(
    "fmt, make, broken",
    [
        ("motioncal", motioncal, "Raw:1,2,3,-305,-4,,19,100,-200,300"),
        ("motioncal", motioncal, "Raw:1,2,3,-305,-4,\r19,100,-200,300"),
        ("i2cdevlib", i2cdevlib, "a/g:\t179\t8673\t,392\t1\t2\t3"),
        ("i2cdevlib", i2cdevlib, "a/g:\t179\t8673\t\t392\t1\t2"),
    ],
)
def test_prefixed_lines_count_an_empty_field_as_malformed(tmp_path, fmt, make, broken):
    data = rows()
    lines = [make(r) for r in data]
    lines[40] = broken
    assert parse_line(fmt, broken) is None
    rec = read_serial_lines(write(tmp_path / "r.log", lines, False), 100.0)
    assert rec.malformed == 1 and len(rec.accel) == N - 1
    keep = np.delete(np.arange(N), 40)
    np.testing.assert_array_equal(np.hstack([rec.accel, rec.gyro]), data[keep, 1:])
    np.testing.assert_allclose(rec.time, keep / 100.0)  # the lost line leaves its gap
    proto = PrefixedLineProtocol()  # capture reads the line alike
    block = proto.feed(("\n".join(lines) + "\n").encode(), 1.0)
    assert proto.stats["malformed"] == 1 and len(block) == N - 1


@pytest.mark.parametrize(
    "line",
    ["0.5,1,2,3", "0.5;1;2;3", "0.5; 1 ;2;3", "0.5 1 2 3", "0.5\t1\t2\t3", "0.5,1,,2,3",
     "0.5;1;;2;3", "0.5\t1\t\t2\t3", "0.5,1;2,3", "0.5,,1,2"],
)  # fmt: skip
def test_import_and_capture_read_a_line_alike(tmp_path, line):
    """Between lines of the same separators (import decides them per file, capture per line)."""
    spec = "t,ax,ay,az"
    sep = next((c for c in ",;\t " if c in line), ",")
    text = f"0.1{sep}0{sep}0{sep}9\n{line}\n0.9{sep}0{sep}0{sep}9\n"
    proto = LineProtocol(ColumnSpec.parse(spec))
    block = proto.feed(text.encode(), 1.0)
    path = tmp_path / "one.csv"
    path.write_text(text)
    rec = read_recording([path], "csv", spec, rate_hz=None)
    assert proto.stats["malformed"] == rec.stats.malformed, line
    np.testing.assert_array_equal(block.accel, rec.accel)


def test_apply_reads_semicolon_csv(tmp_path):
    cal = tmp_path / "cal.json"
    cal.write_text(
        '{"format": "imucal-calibration", "format_version": 1, "created": "2026-01-01T00:00:00Z",'
        ' "accel": {"solver": "x", "units": "m/s^2", "bias": [1, 2, 3], "matrix": '
        "[[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]]}}"
    )
    data = rows(20)
    path = tmp_path / "r.csv"
    path.write_text("\n".join(csv_lines(data, ";")) + "\n")
    out = tmp_path / "out.csv"
    proc = run("apply", cal, path, "-o", out)
    assert proc.returncode == 0, proc.stderr
    got = np.loadtxt(out, delimiter=",", skiprows=2)
    np.testing.assert_allclose(got[:, 1:4], (data[:, 1:4] - [1, 2, 3]) * 0.01, rtol=1e-9)
