"""Acceptance: each calibration's verdict against its product's limits (issue 29.2).

``verdict`` is ``pass`` or ``fail`` (NULL: recorded without limits, as every calibration of a
revision-0001 registry), ``failed`` the failed checks (a JSON list of lines), ``limits`` the
product file judged against (JSON).

Revision ID: 0002
Revises: 0001
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("calibrations") as batch:
        batch.add_column(sa.Column("verdict", sa.String(8)))
        batch.add_column(sa.Column("failed", sa.Text))
        batch.add_column(sa.Column("limits", sa.Text))


def downgrade() -> None:
    columns = ("limits", "failed", "verdict")
    if op.get_bind().dialect.name == "sqlite":
        # SQLite >= 3.35 drops a column in place: a batch copy would drop the old table, and
        # with it (foreign keys on, as the registry connects) every section and figure row
        for name in columns:
            op.execute(f"ALTER TABLE calibrations DROP COLUMN {name}")
    else:
        for name in columns:
            op.drop_column("calibrations", name)
