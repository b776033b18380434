"""Reading the registry: its units, one unit's calibrations and history, a whole record."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

from sqlalchemy import func, select

from imucal_cli.formats.calibration import calibration_from_json
from imucal_cli.model.calibration import Calibration
from imucal_cli.use.report.history import build_history

from .schema import calibrations, documents, units
from .store import Registry, RegistryError

__all__ = ["LIST_FORMAT", "UNIT_FORMAT", "calibration_of", "iter_records", "list_units",
           "record_meta", "unit_report"]  # fmt: skip

LIST_FORMAT = "imucal-registry-list"
UNIT_FORMAT = "imucal-registry-unit"

_META = (
    calibrations.c.id, calibrations.c.uid, units.c.serial, calibrations.c.product,
    calibrations.c.lot, calibrations.c.station, calibrations.c.operator, calibrations.c.created,
    calibrations.c.recorded_at, calibrations.c.session, calibrations.c.session_sha256,
    calibrations.c.toolkit_version, calibrations.c.document_sha256, calibrations.c.verdict,
    calibrations.c.failed, calibrations.c.limits,
)  # fmt: skip


def record_meta(row) -> dict[str, Any]:
    """A calibration row's metadata as a JSON-ready dict (``failed`` and ``limits`` parsed)."""
    meta = {c.name: getattr(row, c.name) for c in _META}
    meta["failed"] = None if row.failed is None else json.loads(row.failed)
    meta["limits"] = None if row.limits is None else json.loads(row.limits)
    return meta


def list_units(registry: Registry, *, product: str | None = None,
               lot: str | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Every unit (or those of ``product``/``lot``) with its number of calibrations and its
    latest one's time, station and verdict, in serial order."""
    latest = (
        select(calibrations.c.unit_id, func.max(calibrations.c.id).label("last_id"),
               func.count().label("n"))
        .group_by(calibrations.c.unit_id).subquery()
    )  # fmt: skip
    query = (
        select(units.c.serial, units.c.product, units.c.lot, units.c.first_recorded,
               latest.c.n, calibrations.c.created, calibrations.c.recorded_at,
               calibrations.c.station, calibrations.c.verdict)
        .join(latest, latest.c.unit_id == units.c.id)
        .join(calibrations, calibrations.c.id == latest.c.last_id)
        .order_by(units.c.serial)
    )  # fmt: skip
    if product is not None:
        query = query.where(units.c.product == product)
    if lot is not None:
        query = query.where(units.c.lot == lot)
    with registry.read() as conn:
        rows = conn.execute(query).all()
    return [{"serial": r.serial, "product": r.product, "lot": r.lot, "calibrations": r.n,
             "first_recorded": r.first_recorded, "last_created": r.created,
             "last_recorded": r.recorded_at, "last_station": r.station,
             "last_verdict": r.verdict} for r in rows]  # fmt: skip


def _unit_rows(conn, serial: str) -> list:
    query = (
        select(*_META, documents.c.document)
        .join(units, units.c.id == calibrations.c.unit_id)
        .join(documents, documents.c.calibration_id == calibrations.c.id)
        .where(units.c.serial == serial)
        .order_by(calibrations.c.created, calibrations.c.id)
    )  # fmt: skip
    return conn.execute(query).all()


def _parse(row) -> Calibration:
    return calibration_from_json(row.document, source=f"registry record {row.uid}")


def unit_report(registry: Registry, serial: str) -> dict[str, Any]:
    """A unit's record: identity, every calibration's metadata (oldest first) and the history
    of its parameters with today's drift test (:func:`~imucal_cli.use.report.history.
    build_history` over its calibrations).

    Raises
    ------
    RegistryError
        No unit of that serial.
    """
    with registry.read() as conn:
        unit = conn.execute(select(units).where(units.c.serial == serial)).first()
        rows = _unit_rows(conn, serial) if unit is not None else []
    if unit is None:
        raise RegistryError(f"registry {registry.name}: no unit {serial!r}")
    cals = []
    for row in rows:
        cal = _parse(row)
        cal.sensor = serial  # the history groups by sensor: the registry's serial
        cals.append(cal)
    return {
        "format": UNIT_FORMAT, "format_version": 1, "serial": unit.serial,
        "product": unit.product, "lot": unit.lot, "first_recorded": unit.first_recorded,
        "last_recorded": unit.last_recorded,
        "calibrations": [record_meta(r) for r in rows],
        "history": build_history(cals),
    }  # fmt: skip


def calibration_of(registry: Registry, serial: str,
                   uid: str | None = None) -> tuple[dict[str, Any], Calibration]:  # fmt: skip
    """The latest calibration of ``serial`` (or the one ``uid``) and its metadata.

    Raises
    ------
    RegistryError
        No such unit or calibration.
    """
    with registry.read() as conn:
        rows = _unit_rows(conn, serial)
    if not rows:
        raise RegistryError(f"registry {registry.name}: no unit {serial!r}")
    if uid is not None:
        rows = [r for r in rows if r.uid == uid]
        if not rows:
            raise RegistryError(f"registry {registry.name}: {serial} has no calibration {uid}")
    row = rows[-1]
    return record_meta(row), _parse(row)


def iter_records(registry: Registry, *, serials: list[str] | None = None,
                 lot: str | None = None, batch: int = 500) -> Iterator[dict[str, Any]]:  # fmt: skip
    """Every calibration (or those of ``serials``/``lot``) as an export record: metadata and
    the whole calibration (``calibration``), in recording order, read ``batch`` at a time."""
    last = 0
    while True:
        query = (
            select(*_META, documents.c.document)
            .join(units, units.c.id == calibrations.c.unit_id)
            .join(documents, documents.c.calibration_id == calibrations.c.id)
            .where(calibrations.c.id > last)
            .order_by(calibrations.c.id).limit(batch)
        )  # fmt: skip
        if serials:
            query = query.where(units.c.serial.in_(serials))
        if lot is not None:
            query = query.where(units.c.lot == lot)
        with registry.read() as conn:
            rows = conn.execute(query).all()
        if not rows:
            return
        for row in rows:
            meta = record_meta(row)
            meta.pop("id")
            meta["calibration"] = json.loads(row.document)
            yield meta
        last = rows[-1].id
