"""``imucal registry export`` and ``import``: records out as JSON Lines, calibration files and
exports in.

An export is JSON Lines: a header line ``{"format": "imucal-registry-export",
"format_version": 1, ...}``, then one record per line: the metadata the registry keeps (``uid``,
``serial``, ``product``, ``lot``, ``station``, ``operator``, ``created``, ``recorded_at``,
``session``, ``session_sha256``, ``verdict``, ``failed``, ``limits``, ...) and the whole
``calibration``.  Importing an export into another registry recreates every record with its
``uid`` and times (its sections and figures, every IMU's of a set, derived anew from its
``calibration`` as :func:`~imucal_cli.registry.record.record_calibration` derives them); a record
already there is skipped.  A calibration file (``imucal
calibrate``'s JSON, or any file :func:`~imucal_cli.formats.calibration.read_calibration`
reads) is recorded under its ``sensor`` (or ``--serial``).
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from imucal_cli.errors import CalibrationFileError, InputError
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.text import clean_text
from imucal_cli.model.calibration import Calibration
from imucal_cli.use.limits import ProductLimits, judge_calibration, limits_from_dict

from .queries import iter_records
from .record import Recorded, UnitInfo, record_calibration
from .store import Registry

__all__ = ["EXPORT_FORMAT", "ImportResult", "export_records", "import_files"]

EXPORT_FORMAT = "imucal-registry-export"


def export_records(registry: Registry, out: IO[str], *, serials: list[str] | None = None,
                   lot: str | None = None) -> int:  # fmt: skip
    """Write the header and every matching record to ``out`` (text); returns the count."""
    header = {"format": EXPORT_FORMAT, "format_version": 1, "registry": registry.name,
              "serials": serials or None, "lot": lot}  # fmt: skip
    out.write(json.dumps(header) + "\n")
    n = 0
    for record in iter_records(registry, serials=serials, lot=lot):
        out.write(json.dumps(record, allow_nan=False) + "\n")
        n += 1
    return n


@dataclass
class ImportResult:
    """``recorded`` (new), ``skipped`` (already there), per file; ``failed`` verdicts."""

    recorded: list[Recorded] = field(default_factory=list)
    skipped: list[Recorded] = field(default_factory=list)


def _is_export(path: Path) -> bool:
    """Whether the file starts with an export's header line."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(200)
    except OSError:
        return False
    return head.lstrip().startswith(b"{") and EXPORT_FORMAT.encode() in head.split(b"\n")[0]


def _check_regular(path: Path) -> None:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{path}: not a regular file (a calibration JSON or a registry export)")


def import_files(
    registry: Registry,
    paths: Iterable[Path],
    info: UnitInfo,
    *,
    limits: ProductLimits | None = None,
    progress: Callable[[Recorded], None] | None = None,
) -> ImportResult:
    """Record calibration files and exports.

    Parameters
    ----------
    info
        For calibration files: the serial (else each file's ``sensor``), product, lot, station,
        operator.  Exports keep their own metadata.
    limits
        Judge every imported calibration file against these (exports keep their verdicts).

    Raises
    ------
    InputError
        A file that is neither; a calibration naming no sensor without ``--serial``; a damaged
        export line (its number named).  The files before it are recorded.
    """
    result = ImportResult()
    for path in paths:
        path = Path(path)
        _check_regular(path)
        records = _export_records(path) if _is_export(path) else _calibration_record(path, info)
        for cal, unit, extra in records:
            acceptance, used = extra.pop("acceptance", None), extra.pop("limits", None)
            if acceptance is None and limits is not None and not extra:
                acceptance, used = judge_calibration(cal, limits), limits
            done = record_calibration(registry, cal, unit, acceptance=acceptance, limits=used,
                                      **extra)  # fmt: skip
            (result.recorded if done.new else result.skipped).append(done)
            if progress is not None:
                progress(done)
    return result


def _calibration_record(path: Path, info: UnitInfo) -> Iterator[tuple]:
    cal = read_calibration(path)
    serial = info.serial or cal.sensor
    if not isinstance(serial, str) or not serial.strip():
        raise InputError(f"{path}: the calibration names no sensor: give --serial")
    yield cal, UnitInfo(serial, info.product, info.lot, info.station, info.operator), {}


class _Stored:
    """A verdict as an export carries it (what :func:`record_calibration` reads of it)."""

    def __init__(self, verdict: str, failed: list[str]) -> None:
        self.verdict = verdict
        self.failed = failed


def _export_records(path: Path) -> Iterator[tuple[Calibration, UnitInfo, dict[str, Any]]]:
    with open(path, encoding="utf-8") as handle:
        next(handle)  # the header
        for number, line in enumerate(handle, start=2):
            if not line.strip():
                continue
            where = f"{path}:{number}"
            try:
                record = json.loads(line)
                cal = Calibration.from_dict(record["calibration"], source=where)
                unit = UnitInfo(record["serial"], record.get("product"), record.get("lot"),
                                record.get("station"), record.get("operator"))
            except (ValueError, KeyError, TypeError) as exc:
                raise CalibrationFileError(f"{where}: not an export record "
                                           f"({clean_text(str(exc))})") from None  # fmt: skip
            extra: dict[str, Any] = {"uid": record.get("uid"),
                                     "recorded_at": record.get("recorded_at"),
                                     "session_sha256": record.get("session_sha256")}  # fmt: skip
            if record.get("verdict") in ("pass", "fail"):
                extra["acceptance"] = _Stored(record["verdict"], list(record.get("failed") or []))
                if isinstance(record.get("limits"), dict):
                    extra["limits"] = limits_from_dict(record["limits"], where)
            yield cal, unit, extra
