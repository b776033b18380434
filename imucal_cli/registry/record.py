"""Recording a calibration in the registry: one transaction per calibration (its unit, the
calibration with its whole JSON, its sections and figures), so a record is there whole or not
at all.  A unit of several IMUs (a calibration with ``imus``) gets the sections of each: the
reference IMU's with ``imu`` NULL, as a single IMU's, each other IMU's under its name."""

from __future__ import annotations

import hashlib
import json
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import and_, or_, select, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import Connection

from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.formats.text import clean_text
from imucal_cli.model.calibration import Calibration
from imucal_cli.use.limits import Acceptance, ProductLimits, unit_figures

from .schema import calibrations, documents, figures, sections, units
from .store import Registry, RegistryError

__all__ = ["Recorded", "UnitInfo", "check_serial", "imu_figures", "now_iso",
           "record_calibration"]  # fmt: skip

MAX_TEXT = 200
"""Longest serial, product, lot, station or operator name."""


def now_iso() -> str:
    """Now, UTC, ISO 8601 with microseconds (sorts as text)."""
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


@dataclass(frozen=True)
class UnitInfo:
    """Who and where: the unit's serial, product and lot; the station and operator."""

    serial: str
    product: str | None = None
    lot: str | None = None
    station: str | None = None
    operator: str | None = None


@dataclass(frozen=True)
class Recorded:
    """What :func:`record_calibration` did: ``new`` False when this calibration of this unit
    was already in the registry (the same JSON, e.g. imported twice)."""

    uid: str
    calibration_id: int
    serial: str
    recorded_at: str
    verdict: str | None
    new: bool


def check_serial(serial: str | None, what: str = "serial") -> str:
    """A serial (or product, lot, station, operator) as the registry keeps it: printable,
    one line, at most :data:`MAX_TEXT` characters.

    Raises
    ------
    RegistryError
        Empty, too long, or with control characters.
    """
    text = (serial or "").strip()
    if not text:
        raise RegistryError(f"the {what} is empty")
    if clean_text(text) != text or "\n" in text:
        raise RegistryError(f"the {what} {clean_text(text)!r} has control characters")
    if len(text) > MAX_TEXT:
        raise RegistryError(f"the {what} is longer than {MAX_TEXT} characters")
    return text


def _optional(value: str | None, what: str) -> str | None:
    return None if value is None or not value.strip() else check_serial(value, what)


def record_calibration(
    registry: Registry,
    cal: Calibration,
    info: UnitInfo,
    *,
    session_sha256: str | None = None,
    acceptance: Acceptance | None = None,
    limits: ProductLimits | None = None,
    uid: str | None = None,
    recorded_at: str | None = None,
) -> Recorded:
    """Record one calibration of the unit ``info.serial`` (made when first seen).

    Parameters
    ----------
    registry
        From :func:`~imucal_cli.registry.store.open_registry`.
    cal
        The calibration, kept whole (its JSON as ``calibrate`` writes it).
    info
        Serial, product, lot, station, operator; a product or lot given updates the unit's.
    session_sha256
        The session's content hash (:func:`~imucal_cli.formats.session.digest.session_digest`).
    acceptance, limits
        The verdict and the product file it was judged against (both or neither).
    uid, recorded_at
        Kept as given (an import of an export); new ones by default.

    Returns
    -------
    Recorded

    Raises
    ------
    RegistryError
        A bad serial or name, or the database refused the write (nothing is recorded then).
    """
    serial = check_serial(info.serial)
    product, lot = _optional(info.product, "product"), _optional(info.lot, "lot")
    document = calibration_to_json(cal)
    sha = hashlib.sha256(document.encode()).hexdigest()
    uid = uid or uuid.uuid4().hex
    when = recorded_at or now_iso()
    row = _calibration_row(cal, info, uid, when, sha, session_sha256, acceptance, limits)
    with registry.write() as conn:
        unit_id = _unit(conn, registry.dialect, serial, product, lot, when)
        row["unit_id"] = unit_id
        cal_id = conn.execute(
            _insert(registry.dialect, calibrations).values(**row)
            .on_conflict_do_nothing().returning(calibrations.c.id)
        ).scalar()  # fmt: skip
        if cal_id is None:  # this unit already has this very calibration
            return _recorded_before(conn, serial, unit_id, uid, sha)
        conn.execute(documents.insert().values(calibration_id=cal_id, document=document))
        _figures(conn, cal_id, unit_figures(cal))
        for name, of_imu in imu_figures(cal).items():
            _figures(conn, cal_id, of_imu, imu=name)
    return Recorded(uid, cal_id, serial, when, row["verdict"], new=True)


def _calibration_row(cal: Calibration, info: UnitInfo, uid: str, when: str, sha: str,
                     session_sha256: str | None, acceptance: Acceptance | None,
                     limits: ProductLimits | None) -> dict[str, Any]:  # fmt: skip
    """The ``calibrations`` row of one calibration (its unit's id added by the caller)."""
    return {
        "uid": uid, "product": _optional(info.product, "product"),
        "lot": _optional(info.lot, "lot"), "station": _optional(info.station, "station"),
        "operator": _optional(info.operator, "operator"),
        "created": cal.created, "recorded_at": when, "session": cal.session,
        "session_sha256": session_sha256,
        "toolkit_version": _text(cal.toolkit_version),
        "document_sha256": sha,
        "verdict": None if acceptance is None else acceptance.verdict,
        "failed": None if acceptance is None else json.dumps(acceptance.failed),
        "limits": None if limits is None else json.dumps(limits.to_dict()),
    }  # fmt: skip


def _recorded_before(conn: Connection, serial: str, unit_id: int, uid: str,
                     sha: str) -> Recorded:  # fmt: skip
    """The calibration already recorded that a new one conflicted with: the same uid, or the
    same document of the same unit (:class:`Recorded` with ``new=False``)."""
    old = conn.execute(
        select(calibrations.c.id, calibrations.c.uid, calibrations.c.recorded_at,
               calibrations.c.verdict)
        .where(or_(calibrations.c.uid == uid,
                   and_(calibrations.c.unit_id == unit_id,
                        calibrations.c.document_sha256 == sha)))
    ).first()  # fmt: skip
    if old is None:  # pragma: no cover - a conflict is one of the two
        raise RegistryError(f"calibration {uid} of {serial} was not recorded")
    return Recorded(old.uid, old.id, serial, old.recorded_at, old.verdict, new=False)


def _text(value: Any) -> str | None:
    return value[:40] if isinstance(value, str) else None


def _insert(dialect: str, table):
    return (postgresql if dialect == "postgresql" else sqlite).insert(table)


def _unit(conn: Connection, dialect: str, serial: str, product: str | None, lot: str | None,
          when: str) -> int:  # fmt: skip
    """The unit's id (inserted when new); a product or lot given replaces the unit's."""
    conn.execute(
        _insert(dialect, units).values(serial=serial, product=product, lot=lot,
                                       first_recorded=when, last_recorded=when)
        .on_conflict_do_nothing(index_elements=["serial"])
    )  # fmt: skip
    unit_id = conn.execute(select(units.c.id).where(units.c.serial == serial)).scalar_one()
    changes: dict[str, Any] = {"last_recorded": when}
    if product is not None:
        changes["product"] = product
    if lot is not None:
        changes["lot"] = lot
    conn.execute(update(units).where(units.c.id == unit_id).values(**changes))
    return unit_id


def pack(rows: list[dict[str, Any]]) -> tuple[str, bytes, bytes]:
    """A section's figure rows packed as the ``sections`` table keeps them: the layout (JSON
    ``[[name, unit, tracked], ...]``), values and stds (float64 little-endian, NaN for None)."""
    layout = json.dumps([[r["name"], r["unit"], bool(r["tracked"])] for r in rows])
    values = np.array([np.nan if r["value"] is None else r["value"] for r in rows], "<f8")
    stds = np.array([np.nan if r["std"] is None else r["std"] for r in rows], "<f8")
    return layout, values.tobytes(), stds.tobytes()


def imu_figures(cal: Calibration) -> dict[str, dict[str, dict[str, Any]]]:
    """Every figure of each other IMU of a set, ``{name: unit_figures of its sections}`` in the
    calibration's order (empty for a single IMU); an IMU with no section is left out."""
    out = {}
    for name, entry in (cal.imus or {}).items():
        figs = unit_figures(entry)  # type: ignore[arg-type]  # an ImuEntry has sections()
        if figs:
            out[name] = figs
    return out


def _figures(conn: Connection, cal_id: int, figs: dict[str, dict[str, Any]],
             imu: str | None = None) -> None:  # fmt: skip
    """A section row per sensor (its figures packed) and its figure rows; ``imu``: the IMU of
    a set they are of (None: the reference)."""
    for sensor, sec in figs.items():
        layout, values, stds = pack(sec["rows"])
        section_id = conn.execute(
            sections.insert().values(calibration_id=cal_id, imu=imu, sensor=sensor,
                                     solver=sec["solver"],
                                     units=sec["units"], units_in=sec["units_in"],
                                     basis=sec["basis"], layout=layout, values=values,
                                     stds=stds)
            .returning(sections.c.id)
        ).scalar_one()  # fmt: skip
        rows = [{"section_id": section_id, "name": r["name"][:80],
                 "unit": None if r["unit"] is None else str(r["unit"])[:120],
                 "value": r["value"], "std": r["std"], "tracked": bool(r["tracked"])}
                for r in sec["rows"]]  # fmt: skip
        if rows:
            conn.execute(figures.insert(), rows)
