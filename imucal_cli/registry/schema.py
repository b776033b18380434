"""The registry's tables (SQLAlchemy Core), as the newest migration leaves them.

- ``units``: one row per serial number: its product and lot (the latest given), when it was
  first and last recorded.
- ``calibrations``: one row per recorded calibration: who, where and when (``station``,
  ``operator``, ``created`` by the calibration, ``recorded_at`` by the registry), the session's
  content hash, the SHA-256 of the calibration JSON, the acceptance ``verdict`` (``pass``/
  ``fail``, NULL when no limits were given), the ``failed`` checks (a JSON list of lines) and
  the ``limits`` judged against (the product file as JSON).
- ``documents``: the whole calibration JSON of each (apart, so that the rows a lot's query
  reads stay small).
- ``sections``: one row per calibrated sensor of each IMU of a calibration: ``imu`` (NULL for
  the reference IMU, the one of a single-IMU unit; else the name of another IMU of a set, a
  key of the calibration's ``imus``), ``sensor``, solver, units and the history's
  *basis* (what makes two calibrations comparable: :func:`~imucal_cli.use.report.history.
  section_basis`), and its figures packed for a lot's statistics: ``layout`` (JSON ``[[name,
  unit, tracked], ...]``), ``values`` and ``stds`` (float64 little-endian, NaN for none).
- ``figures``: the same numbers, one row each (``name``, ``unit``, ``value``, ``std``), for SQL:
  the history's tracked parameters (``tracked``) and the acceptance figures
  (:func:`~imucal_cli.use.limits.section_figures`).

Times are ISO 8601 UTC text (``2026-11-28T13:42:00.123456Z``): they sort as text on every
database.  A change of these tables is a new migration in ``migrations/versions`` (the test
``test_registry.py::test_migrations_match_the_schema`` compares the two).
"""

from __future__ import annotations

from sqlalchemy import (
    Boolean,
    Column,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Table,
    Text,
    UniqueConstraint,
)

NAMING = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

metadata = MetaData(naming_convention=NAMING)

units = Table(
    "units", metadata,
    Column("id", Integer, primary_key=True),
    Column("serial", String(200), nullable=False, unique=True),
    Column("product", String(200)),
    Column("lot", String(200)),
    Column("first_recorded", String(32), nullable=False),
    Column("last_recorded", String(32), nullable=False),
)  # fmt: skip
Index("ix_units_lot", units.c.lot)
Index("ix_units_product", units.c.product)

calibrations = Table(
    "calibrations", metadata,
    Column("id", Integer, primary_key=True),
    Column("uid", String(32), nullable=False, unique=True),
    Column("unit_id", Integer, ForeignKey("units.id", ondelete="CASCADE"), nullable=False),
    Column("product", String(200)),
    Column("lot", String(200)),
    Column("station", String(200)),
    Column("operator", String(200)),
    Column("created", String(40), nullable=False),
    Column("recorded_at", String(32), nullable=False),
    Column("session", Text),
    Column("session_sha256", String(64)),
    Column("toolkit_version", String(40)),
    Column("document_sha256", String(64), nullable=False),
    # revision 0002: acceptance
    Column("verdict", String(8)),
    Column("failed", Text),
    Column("limits", Text),
    UniqueConstraint("unit_id", "document_sha256", name="uq_calibrations_unit_document"),
)  # fmt: skip
Index("ix_calibrations_unit_id", calibrations.c.unit_id)

documents = Table(
    "documents", metadata,
    Column("calibration_id", Integer, ForeignKey("calibrations.id", ondelete="CASCADE"),
           primary_key=True),
    Column("document", Text, nullable=False),
)  # fmt: skip

sections = Table(
    "sections", metadata,
    Column("id", Integer, primary_key=True),
    Column("calibration_id", Integer, ForeignKey("calibrations.id", ondelete="CASCADE"),
           nullable=False),
    Column("sensor", String(8), nullable=False),
    Column("solver", String(80), nullable=False),
    Column("units", String(40), nullable=False),
    Column("units_in", String(80)),
    Column("basis", Text, nullable=False),
    Column("layout", Text, nullable=False),
    Column("values", LargeBinary, nullable=False),
    Column("stds", LargeBinary, nullable=False),
    # revision 0003: several IMUs
    Column("imu", Text),
)  # fmt: skip
Index("ix_sections_calibration_id", sections.c.calibration_id)

figures = Table(
    "figures", metadata,
    Column("id", Integer, primary_key=True),
    Column("section_id", Integer, ForeignKey("sections.id", ondelete="CASCADE"), nullable=False),
    Column("name", String(80), nullable=False),
    Column("unit", String(120)),
    Column("value", Float),
    Column("std", Float),
    Column("tracked", Boolean, nullable=False),
)  # fmt: skip
Index("ix_figures_section_id", figures.c.section_id)
