"""Several IMUs: each IMU of a set gets its own sections (issue 28 in the registry).

``sections.imu`` is NULL for the reference IMU (the only one of a single-IMU unit, and every
section a revision-0002 registry holds), else the name of another IMU of the set (a key of the
calibration's ``imus``).  The calibrations of sets recorded before this revision kept the other
IMUs' figures in their document only: their sections are derived here from the stored
document, as recording it anew would (:func:`~imucal_cli.registry.record.imu_figures`), so
that a lot's statistics and a unit's history count them like the ones recorded after.

Revision ID: 0003
Revises: 0002
"""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None

# The tables as this revision leaves them (not schema.py's: those follow the newest revision).
_sections = sa.table(
    "sections",
    sa.column("id", sa.Integer), sa.column("calibration_id", sa.Integer),
    sa.column("sensor", sa.String), sa.column("solver", sa.String), sa.column("units", sa.String),
    sa.column("units_in", sa.String), sa.column("basis", sa.Text), sa.column("layout", sa.Text),
    sa.column("values", sa.LargeBinary), sa.column("stds", sa.LargeBinary),
    sa.column("imu", sa.Text),
)  # fmt: skip
_figures = sa.table(
    "figures",
    sa.column("section_id", sa.Integer), sa.column("name", sa.String),
    sa.column("unit", sa.String), sa.column("value", sa.Float), sa.column("std", sa.Float),
    sa.column("tracked", sa.Boolean),
)  # fmt: skip
_documents = sa.table("documents", sa.column("calibration_id", sa.Integer),
                      sa.column("document", sa.Text))  # fmt: skip


def upgrade() -> None:
    with op.batch_alter_table("sections") as batch:
        batch.add_column(sa.Column("imu", sa.Text))
    _sections_of_recorded_sets(op.get_bind())


def downgrade() -> None:
    others = sa.select(_sections.c.id).where(_sections.c.imu.is_not(None))
    op.execute(_figures.delete().where(_figures.c.section_id.in_(others)))
    op.execute(_sections.delete().where(_sections.c.imu.is_not(None)))
    if op.get_bind().dialect.name == "sqlite":
        # SQLite >= 3.35 drops a column in place: a batch copy would drop the old table, and
        # with it (foreign keys on, as the registry connects) every figure row
        op.execute("ALTER TABLE sections DROP COLUMN imu")
    else:
        op.drop_column("sections", "imu")


def _sections_of_recorded_sets(conn: sa.engine.Connection) -> None:
    """The sections of the other IMUs of every set already recorded (a document with
    ``imus``); a document that no longer parses is left as it was (its reference's
    sections)."""
    from imucal_cli.errors import CalibrationFileError
    from imucal_cli.formats.calibration import calibration_from_json
    from imucal_cli.registry.record import imu_figures

    ids = conn.execute(
        sa.select(_documents.c.calibration_id).where(_documents.c.document.like('%"imus"%'))
        .order_by(_documents.c.calibration_id)
    ).scalars().all()  # fmt: skip
    for cal_id in ids:
        text = conn.execute(sa.select(_documents.c.document)
                            .where(_documents.c.calibration_id == cal_id)).scalar_one()  # fmt: skip
        try:
            cal = calibration_from_json(text, source=f"registry calibration {cal_id}")
        except CalibrationFileError:
            continue
        for name, figs in imu_figures(cal).items():
            _insert(conn, cal_id, name, figs)


def _insert(conn: sa.engine.Connection, cal_id: int, imu: str,
            figs: dict[str, dict[str, Any]]) -> None:  # fmt: skip
    """One IMU's sections and figure rows, as :func:`~imucal_cli.registry.record._figures`
    writes them."""
    from imucal_cli.registry.record import pack

    for sensor, sec in figs.items():
        layout, values, stds = pack(sec["rows"])
        section_id = conn.execute(
            _sections.insert().values(calibration_id=cal_id, imu=imu, sensor=sensor,
                                      solver=sec["solver"], units=sec["units"],
                                      units_in=sec["units_in"], basis=sec["basis"],
                                      layout=layout, values=values, stds=stds)
            .returning(_sections.c.id)
        ).scalar_one()  # fmt: skip
        rows = [{"section_id": section_id, "name": r["name"][:80],
                 "unit": None if r["unit"] is None else str(r["unit"])[:120],
                 "value": r["value"], "std": r["std"], "tracked": bool(r["tracked"])}
                for r in sec["rows"]]  # fmt: skip
        if rows:
            conn.execute(_figures.insert(), rows)
