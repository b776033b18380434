"""`imucal apply`: raw samples of a session or CSV file turned into SI units, streamed in chunks.

For each sensor the calibration holds, every raw sample becomes::

    calibrated = matrix @ (raw - bias)          # m/s^2 (accel), rad/s (gyro), uT (mag)

with the optional terms of the formats page applied: a ``bias_tempco`` section's bias at
each sample's temperature (``/raw/temperature``, or the CSV's ``temp`` column; refused when
the input has none), and a ``sample_clock_scale`` corrects the output times to true seconds
(``t0 + (t - t0) / scale``).

The input is read and the output written one block of ``chunk_rows`` samples at a time
(default 65536), so memory stays constant however long the file is.

Input
-----
- A session (HDF5, ``shared/spec/session-format.md``): ``/raw/time`` and the ``/raw/accel`` /
  ``/raw/gyro`` / ``/raw/mag`` datasets the calibration needs, read by slicing. Only the basics are
  checked (format attribute and version, datasets present, shapes, channel counts, time finite and
  strictly increasing); segments are not read. A file whose writer was killed opens in SWMR mode and
  is read up to its shortest ``/raw`` dataset, like :func:`imucal_cli.formats.session.read_session`
  does.
- A CSV (any other file): the same column mapping as ``imucal import``
  (:func:`imucal_cli.formats.importers.parse_columns` / ``infer_columns``: ``--columns`` or a
  header line; commas, tabs or spaces; ``#`` comments; non-numeric lines before the data are
  the header; later lines that do not give the expected numbers are skipped and counted).
  Without a ``t`` column the time of kept row i is ``i / rate``.

Only the sensors the calibration holds are applied; each must be in the input with as many
channels as its ``bias`` has.

Output: HDF5 (``imucal-calibrated``, version 1)
-----------------------------------------------
A new file (written to a fresh temporary file next to it and renamed when complete, see
:mod:`imucal_cli.formats.output`):

======================  ============  =====================================================
dataset                 shape, dtype  meaning
======================  ============  =====================================================
``/calibrated/time``    (N,) float64  seconds, as in the input (attribute ``units = "s"``)
``/calibrated/accel``   (N, 3) f8     m/s^2, only if the calibration has ``accel``
``/calibrated/gyro``    (N, 3) f8     rad/s, only if the calibration has ``gyro``
``/calibrated/mag``     (N, 3) f8     uT (or units of the local field), if it has ``mag``
======================  ============  =====================================================

The datasets are chunked and resizable (``maxshape = (None, ...)``).  Each sensor dataset has
attributes ``units`` (output units), ``units_in`` (raw units, when known), ``solver`` and
``channels_in`` (the raw channel count).  Root attributes: ``format = "imucal-calibrated"``,
``format_version = 1``, ``created`` (ISO 8601 UTC, when written), ``model`` (the equation
above), ``source`` (the input file), ``calibration`` (the calibration file), ``calibration_json``
(its content), ``calibration_created``, and, when known, ``calibration_session`` and ``sensor``;
``toolkit_version``.

Output: CSV
-----------
The header ``t,ax,ay,az,gx,gy,gz,mx,my,mz`` (the columns of the calibrated sensors only), then a
comment line (``#``, no commas) naming the model, the calibration and the units, then one line
per sample: time as Python's shortest round-trip repr, values with 10 significant digits.

The input, read block by block and checked against the calibration: :mod:`.apply_input`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from imucal_cli import __version__
from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.formats.importers import check_sample_rate
from imucal_cli.formats.importers.recording import TIME_UNITS
from imucal_cli.formats.importers.text import cut_line_warning
from imucal_cli.formats.inputs import is_hdf5_file
from imucal_cli.formats.output import OutputFile, check_output
from imucal_cli.formats.session import one_line, utc_now_iso
from imucal_cli.formats.session.disk import WRITE_ERRORS
from imucal_cli.model.calibration import MODEL_EQUATION, Calibration, SensorCalibration
from imucal_cli.model.session import io_reason
from imucal_cli.use.apply_input import CSV_NAMES, Block, CsvBlocks, csv_input, session_input

__all__ = [
    "DEFAULT_CHUNK_ROWS",
    "FORMAT",
    "FORMAT_VERSION",
    "OUTPUT_FORMATS",
    "ApplySummary",
    "apply_calibration",
    "output_format",
]

FORMAT = "imucal-calibrated"
FORMAT_VERSION = 1
DEFAULT_CHUNK_ROWS = 65536
OUTPUT_FORMATS = ("h5", "csv")
SENSORS = ("accel", "gyro", "mag")

_SUFFIXES = {".h5": "h5", ".hdf5": "h5", ".hdf": "h5", ".csv": "csv", ".txt": "csv"}
_NAMES = {"h5": "HDF5", "csv": "CSV"}
_EXAMPLE = {"h5": ".h5", "csv": ".csv"}
_H5_CHUNK_ROWS = 8192  # rows per HDF5 chunk of the output datasets
_VALUE_FMT = "%.10g"

Progress = Callable[[int, int], None]
"""``progress(done, total)``: rows of ``total`` rows (HDF5) or bytes of ``total`` bytes (CSV)."""


@dataclass
class ApplySummary:
    """What :func:`apply_calibration` did.

    Attributes
    ----------
    input, output : Path
        The files read and written.
    input_kind : {"session", "csv"}
    output_format : {"h5", "csv"}
    sensors : tuple of str
        The sensors calibrated, in the order ``accel``, ``gyro``.
    samples : int
        Samples written.
    duration_s : float
        Time span of the samples written, s (0 for fewer than two).
    malformed : int
        CSV: lines skipped because they did not give the expected numbers.
    first_malformed : str or None
        CSV: ``file:line`` of the first of them.
    cut_line : str or None
        CSV: ``file:line`` of its last line, dropped: cut short (no line break after it; one
        of the ``warnings``).
    chunks : int
        Blocks read and written.
    nonfinite : int
        Samples whose raw input (or temperature, for a temperature-dependent bias) held NaN or
        inf (a dropout): written as NaN, never as a number.
    clock_scale : float or None
        The calibration's ``sample_clock_scale``: output times are true seconds,
        ``t0 + (t - t0) / scale``.
    input_sensor : str or None
        A session's ``sensor`` (part, serial), where it names one.
    warnings : list of str
        What the output is written despite: a calibration made on a unit whose ``sensor``
        differs from the input's (:func:`other_unit`); a CSV's last line cut short.
    """

    input: Path
    output: Path
    input_kind: str
    output_format: str
    sensors: tuple[str, ...]
    samples: int = 0
    duration_s: float = 0.0
    malformed: int = 0
    first_malformed: str | None = None
    cut_line: str | None = None
    chunks: int = 0
    nonfinite: int = 0
    clock_scale: float | None = None
    input_sensor: str | None = None
    warnings: list[str] = field(default_factory=list)
    _first_time: float | None = field(default=None, repr=False)


def _clock_scale(sections: dict[str, SensorCalibration]) -> float | None:
    """``sample_clock_scale`` of the calibration (the gyro's first), or None."""
    for sec in sections.values():
        if sec.sample_clock_scale is not None:
            return sec.sample_clock_scale
    return None


def output_format(path: str | os.PathLike, fmt: str | None = None) -> str:
    """Return the output format: ``fmt`` when given, else from the suffix of ``path``.

    Raises
    ------
    InputError
        An unknown ``fmt``, a ``fmt`` the suffix contradicts (``-f h5 -o x.csv``), or no
        ``fmt`` and a suffix that is not ``.h5``/``.hdf5``/``.hdf`` (HDF5) or ``.csv``/``.txt``
        (CSV).
    """
    suffix = Path(path).suffix.lower()
    if fmt is not None:
        if fmt not in OUTPUT_FORMATS:
            raise InputError(f"--format {fmt!r}: use h5 or csv")
        if _SUFFIXES.get(suffix, fmt) != fmt:
            raise InputError(f"{path}: --format {fmt} would write {_NAMES[fmt]} under a "
                             f"{suffix} name: name it {_EXAMPLE[fmt]}, or leave out --format")
        return fmt
    if suffix not in _SUFFIXES:
        raise InputError(
            f"{path}: cannot tell the output format from the suffix {suffix or '(none)'!r}: "
            "name it .h5 or .csv, or pass --format h5|csv"
        )
    return _SUFFIXES[suffix]


def _sections(cal: Calibration) -> dict[str, SensorCalibration]:
    return {name: getattr(cal, name) for name in SENSORS if getattr(cal, name) is not None}


# --------------------------------------------------------------------------------------------
# Writers
# --------------------------------------------------------------------------------------------


class _H5Writer:
    def __init__(
        self,
        out: OutputFile,
        sections: dict[str, SensorCalibration],
        cal: Calibration,
        cal_src: str,
        input_path: Path,
        units_in: dict[str, str | None],
    ) -> None:
        self.file = out.h5()
        self.n = 0
        attrs = self.file.attrs
        attrs["format"] = FORMAT
        attrs["format_version"] = FORMAT_VERSION
        attrs["created"] = utc_now_iso()
        attrs["model"] = MODEL_EQUATION
        attrs["source"] = str(input_path)
        attrs["calibration"] = cal_src
        attrs["calibration_json"] = calibration_to_json(cal)
        attrs["calibration_created"] = cal.created
        if cal.session is not None:
            attrs["calibration_session"] = cal.session
        if cal.sensor is not None:
            attrs["sensor"] = cal.sensor
        attrs["toolkit_version"] = __version__
        group = self.file.create_group("calibrated")
        self.datasets = {
            "time": group.create_dataset(
                "time", shape=(0,), maxshape=(None,), dtype="f8", chunks=(_H5_CHUNK_ROWS,)
            )
        }
        self.datasets["time"].attrs["units"] = "s"
        for name, sec in sections.items():
            ds = group.create_dataset(
                name, shape=(0, 3), maxshape=(None, 3), dtype="f8", chunks=(_H5_CHUNK_ROWS, 3)
            )
            ds.attrs["units"] = sec.units
            ds.attrs["solver"] = sec.solver
            ds.attrs["channels_in"] = int(sec.bias.shape[0])
            unit = units_in.get(name) or sec.units_in
            if isinstance(unit, str) and unit != "unknown":
                ds.attrs["units_in"] = unit
            self.datasets[name] = ds

    def write(self, time: np.ndarray, values: dict[str, np.ndarray]) -> None:
        start, stop = self.n, self.n + len(time)
        for name, ds in self.datasets.items():
            ds.resize(stop, axis=0)
            ds[start:stop] = time if name == "time" else values[name]
        self.n = stop

    def close(self) -> None:
        """Flush and close the file, once.  A flush that fails (a full disk) empties the
        datasets before the file is closed and raises: HDF5 crashed the process at its exit
        (a segmentation fault) after the close of a file holding unwritten data failed."""
        file, self.file = self.file, None
        if file is None:
            return
        datasets, self.datasets = self.datasets, {}
        try:
            file.flush()
        except WRITE_ERRORS:
            for ds in datasets.values():
                try:
                    ds.resize(0, axis=0)
                except WRITE_ERRORS:
                    pass
            try:
                file.close()
            except WRITE_ERRORS:
                pass
            raise
        file.close()


class _CsvWriter:
    def __init__(
        self,
        out: OutputFile,
        sections: dict[str, SensorCalibration],
        cal_src: str,
        input_path: Path,
    ) -> None:
        self.handle = out.open("w")
        self.names = list(sections)
        units = "; ".join(f"{' '.join(CSV_NAMES[n])} {sections[n].units}" for n in self.names)
        # The header first (readers such as numpy.genfromtxt(names=True) take the first line
        # for the names), then one comment line without commas: what made the numbers.
        self.handle.write(",".join(["t", *(c for n in self.names for c in CSV_NAMES[n])]) + "\n")
        comment = f"# imucal apply: {MODEL_EQUATION} with {cal_src} on {input_path}; units: "
        comment += f"t s; {units}"
        self.handle.write(comment.replace(",", " ") + "\n")
        self.row_fmt = ",".join(["%s", *([_VALUE_FMT] * (3 * len(self.names)))]) + "\n"

    def write(self, time: np.ndarray, values: dict[str, np.ndarray]) -> None:
        data = np.column_stack([values[n] for n in self.names]).tolist()
        fmt = self.row_fmt
        self.handle.writelines(
            fmt % (repr(t), *row) for t, row in zip(time.tolist(), data, strict=True)
        )

    def close(self) -> None:
        self.handle.close()


# --------------------------------------------------------------------------------------------
# The whole job
# --------------------------------------------------------------------------------------------


def _write_block(writer, block: Block, sections, summary: ApplySummary, output_path) -> None:
    values: dict[str, np.ndarray] = {}
    for name, sec in sections.items():  # accel first: the gyro's g_sensitivity needs it
        values[name] = sec.apply(block.raw[name], accel=values.get("accel"),
                                 temperature=block.temperature)  # fmt: skip
    inputs = [*block.raw.values(), *([] if block.temperature is None else [block.temperature])]
    if not all(np.isfinite(x).all() for x in inputs):  # a dropout: count its samples
        bad = np.zeros(len(block.time), dtype=bool)
        for x in inputs:
            bad |= ~np.isfinite(x).reshape(len(x), -1).all(axis=1)
        summary.nonfinite += int(bad.sum())
    else:
        bad = np.zeros(len(block.time), dtype=bool)
    for name, out in values.items():  # finite in, not finite out: the numbers overflowed
        over = ~np.isfinite(out).all(axis=1) & ~bad
        if over.any():
            raise InputError(f"{summary.input}: the {name} calibration turns sample "
                             f"{summary.samples + int(np.argmax(over))} into a number past the "
                             "float range (its bias or matrix is no calibration)")  # fmt: skip
    if summary._first_time is None:
        summary._first_time = float(block.time[0])
    time = block.time
    if summary.clock_scale is not None:  # device seconds to true seconds (sample_clock_scale)
        time = summary._first_time + (block.time - summary._first_time) / summary.clock_scale
    try:
        writer.write(time, values)
    except (OSError, RuntimeError) as exc:
        raise InputError(f"{output_path}: cannot write ({one_line(exc)})") from None
    summary.samples += len(block.time)
    summary.duration_s = float(block.time[-1]) - summary._first_time
    summary.chunks += 1


def apply_calibration(
    cal: Calibration,
    input_path: str | os.PathLike,
    output_path: str | os.PathLike,
    *,
    cal_source: str = "<calibration>",
    fmt: str | None = None,
    columns: str | None = None,
    time_unit: str = "s",
    rate_hz: float | None = None,
    chunk_rows: int = DEFAULT_CHUNK_ROWS,
    overwrite: bool = False,
    progress: Progress | None = None,
) -> ApplySummary:
    """Calibrate every sample of a session or CSV file and write them, block by block.

    Parameters
    ----------
    cal : Calibration
        What to apply: every sensor section it holds.
    input_path : path-like
        An HDF5 session, or a CSV (any file that is not HDF5).
    output_path : path-like
        The file to write (see the module docstring for the formats).  Written to
        a fresh temporary file first and renamed when complete, so a failure leaves no partial
        file (:mod:`imucal_cli.formats.output`).
    cal_source : str
        Name of the calibration file, for messages and the output's attributes.
    fmt : {"h5", "csv"}, optional
        Output format; default from the suffix of ``output_path``.
    columns : str, optional
        CSV input: the column spec of ``imucal import`` (``t,ax,ay,az,gx,gy,gz``; ``_`` skips);
        default from the header line.
    time_unit : {"s", "ms", "us"}
        CSV input: unit of the ``t`` column.
    rate_hz : float, optional
        CSV input without a ``t`` column: sample rate, Hz (time of kept row i is ``i / rate``).
    chunk_rows : int
        Samples per block read, calibrated and written (at least 2 are used).  Memory is
        proportional to it.
    overwrite : bool
        Replace an existing output file instead of refusing.
    progress : callable, optional
        ``progress(done, total)`` after each block: rows (session) or bytes (CSV).

    Returns
    -------
    ApplySummary

    Raises
    ------
    InputError
        Missing or unreadable input; not a session / columns that do not fit; a sensor of the
        calibration missing from the input; a channel count that differs from the
        calibration's (the message names both); raw units that differ from those the
        calibration was made for; time not increasing; an output that exists (without
        ``overwrite``), is the input, or cannot be written.
    """
    input_path, output_path = Path(input_path), Path(output_path)
    summary, sections = _prepare(cal, input_path, output_path, cal_source, fmt, chunk_rows,
                                 time_unit, rate_hz, overwrite)  # fmt: skip
    # Blocks of one row take numpy's matrix-vector path, which may round differently from
    # the matrix-matrix path of longer blocks (see apply_input.chunk_bounds): at least 2 rows
    # per block.
    chunk_rows = max(chunk_rows, 2)
    blocks, total, units_in, close_input = _open_input(summary, sections, cal_source, columns,
                                                       time_unit, rate_hz, chunk_rows)  # fmt: skip
    try:
        _write_all(blocks, total, summary, sections, cal, cal_source, units_in, overwrite,
                   progress)  # fmt: skip
    finally:
        close_input()
    if isinstance(blocks, CsvBlocks):
        summary.malformed, summary.first_malformed = blocks.malformed, blocks.first_malformed
        summary.cut_line = blocks.cut_line
        summary.warnings += [cut_line_warning(blocks.cut_line)] if blocks.cut_line else []
    summary.warnings += other_unit(cal.sensor, summary.input_sensor, cal_source,
                                   str(input_path))  # fmt: skip
    return summary


def other_unit(cal_sensor: str | None, input_sensor: str | None, cal_source: str,
               input_source: str) -> list[str]:
    """A warning when the calibration was made on a unit its ``sensor`` names and the input
    names another (a calibration belongs to one unit: another's biases and gains give wrong
    numbers); none when either does not name one (a capture names its port, an import may
    name nothing)."""  # fmt: skip
    a, b = ((x or "").strip() for x in (cal_sensor, input_sensor))
    if not a or not b or a.casefold() == b.casefold():
        return []
    return [f"{cal_source} was made on '{a}' but {input_source} is from '{b}': a calibration "
            "belongs to one unit; apply that unit's calibration (or name both the same with "
            "capture --sensor, import --sensor or label --sensor)"]  # fmt: skip


def _prepare(cal: Calibration, input_path: Path, output_path: Path, cal_source: str,
             fmt: str | None, chunk_rows, time_unit: str, rate_hz: float | None,
             overwrite: bool) -> tuple[ApplySummary, dict[str, SensorCalibration]]:  # fmt: skip
    """Every check before a sample is read (options, the input, the output, what the
    calibration holds); the summary to fill and the sections to apply."""
    out_fmt = output_format(output_path, fmt)
    _check_options(chunk_rows, time_unit, rate_hz, input_path)
    check_output(output_path, force=overwrite, inputs=[input_path, cal_source])
    sections = _sections(cal)
    gyro = sections.get("gyro")
    if gyro is not None and gyro.g_term is not None and "accel" not in sections:
        raise InputError(
            f"{cal_source}: the gyro calibration holds g_sensitivity but there is no "
            "accelerometer calibration to give the specific force it needs"
        )
    is_session = is_hdf5_file(input_path, what="session or CSV file")
    if not is_session and input_path.suffix.lower() in (".h5", ".hdf5", ".hdf"):
        raise InputError(f"{input_path}: not an HDF5 file")
    summary = ApplySummary(
        input=input_path,
        output=output_path,
        input_kind="session" if is_session else "csv",
        output_format=out_fmt,
        sensors=tuple(sections),
        clock_scale=_clock_scale(sections),
    )
    return summary, sections


def _open_input(summary: ApplySummary, sections: dict[str, SensorCalibration], cal_source: str,
                columns: str | None, time_unit: str, rate_hz: float | None, chunk_rows: int):
    """The input's blocks, its size (rows of a session, bytes of a CSV), raw units (a
    session's) and closer."""  # fmt: skip
    if summary.input_kind == "session":
        if columns is not None:
            raise InputError(f"{summary.input}: --columns applies to CSV input, not to a session")
        blocks, total, units, close, sensor = session_input(summary.input, sections,
                                                            cal_source, chunk_rows)  # fmt: skip
        summary.input_sensor = sensor
        return blocks, total, units, close
    blocks, total, close = csv_input(summary.input, sections, cal_source, columns, time_unit,
                                      rate_hz, chunk_rows)  # fmt: skip
    return blocks, total, {}, close


def _check_options(chunk_rows, time_unit: str, rate_hz: float | None, input_path: Path) -> None:
    """Refuse a bad block size, time unit or rate, and an input that is no file."""
    src = str(input_path)
    if isinstance(chunk_rows, bool) or not isinstance(chunk_rows, int) or chunk_rows < 1:
        raise InputError(f"chunk size must be a positive number of rows, got {chunk_rows!r}")
    if time_unit not in TIME_UNITS:
        raise InputError(f"unknown time unit {time_unit!r}: use {', '.join(TIME_UNITS)}")
    if rate_hz is not None and not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate must be a positive number of Hz, got {rate_hz:g}")
    if rate_hz is not None:  # 1e300 Hz stamped every row 1e-300 s apart, exit 0
        check_sample_rate(rate_hz, None, src)
    if not input_path.exists():
        raise InputError(f"{src}: no such file")
    if input_path.is_dir():
        raise InputError(f"{src}: is a directory, not a session or CSV file")


def _write_all(blocks, total: int, summary: ApplySummary, sections, cal: Calibration,
               cal_source: str, units_in: dict, overwrite: bool,
               progress: Progress | None) -> None:  # fmt: skip
    """Calibrate and write every block into a fresh output (committed when complete,
    discarded on any failure)."""
    input_path, output_path = summary.input, summary.output
    writer: _H5Writer | _CsvWriter | None = None
    out: OutputFile | None = None
    try:
        try:
            out = OutputFile(output_path, force=overwrite, inputs=[input_path, cal_source])
            if summary.output_format == "h5":
                writer = _H5Writer(out, sections, cal, cal_source, input_path, units_in)
            else:
                writer = _CsvWriter(out, sections, cal_source, input_path)
        except OSError as exc:
            raise InputError(f"{output_path}: cannot write ({one_line(exc)})") from None
        for block in blocks:
            _write_block(writer, block, sections, summary, output_path)
            if progress is not None:
                progress(block.done, total)
        if summary.samples == 0:
            raise InputError(f"{input_path}: no samples to calibrate")
        writer.close()
        writer = None
        out.commit()
    except WRITE_ERRORS as exc:  # h5py says a full disk as RuntimeError too
        raise InputError(f"{output_path}: cannot write ({io_reason(exc)})") from None
    finally:
        if writer is not None:
            try:
                writer.close()
            except WRITE_ERRORS:
                pass
        if out is not None and not out.published:
            out.discard()
