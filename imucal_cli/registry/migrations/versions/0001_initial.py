"""The first registry: units, their calibrations (and documents), sections and figures.

Revision ID: 0001
Revises:
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "units",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("serial", sa.String(200), nullable=False),
        sa.Column("product", sa.String(200)),
        sa.Column("lot", sa.String(200)),
        sa.Column("first_recorded", sa.String(32), nullable=False),
        sa.Column("last_recorded", sa.String(32), nullable=False),
        sa.PrimaryKeyConstraint("id", name="pk_units"),
        sa.UniqueConstraint("serial", name="uq_units_serial"),
    )
    op.create_index("ix_units_lot", "units", ["lot"])
    op.create_index("ix_units_product", "units", ["product"])
    op.create_table(
        "calibrations",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("uid", sa.String(32), nullable=False),
        sa.Column("unit_id", sa.Integer, nullable=False),
        sa.Column("product", sa.String(200)),
        sa.Column("lot", sa.String(200)),
        sa.Column("station", sa.String(200)),
        sa.Column("operator", sa.String(200)),
        sa.Column("created", sa.String(40), nullable=False),
        sa.Column("recorded_at", sa.String(32), nullable=False),
        sa.Column("session", sa.Text),
        sa.Column("session_sha256", sa.String(64)),
        sa.Column("toolkit_version", sa.String(40)),
        sa.Column("document_sha256", sa.String(64), nullable=False),
        sa.PrimaryKeyConstraint("id", name="pk_calibrations"),
        sa.UniqueConstraint("uid", name="uq_calibrations_uid"),
        sa.UniqueConstraint("unit_id", "document_sha256", name="uq_calibrations_unit_document"),
        sa.ForeignKeyConstraint(["unit_id"], ["units.id"], ondelete="CASCADE",
                                name="fk_calibrations_unit_id_units"),
    )  # fmt: skip
    op.create_index("ix_calibrations_unit_id", "calibrations", ["unit_id"])
    op.create_table(
        "documents",
        sa.Column("calibration_id", sa.Integer, nullable=False),
        sa.Column("document", sa.Text, nullable=False),
        sa.PrimaryKeyConstraint("calibration_id", name="pk_documents"),
        sa.ForeignKeyConstraint(["calibration_id"], ["calibrations.id"], ondelete="CASCADE",
                                name="fk_documents_calibration_id_calibrations"),
    )  # fmt: skip
    op.create_table(
        "sections",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("calibration_id", sa.Integer, nullable=False),
        sa.Column("sensor", sa.String(8), nullable=False),
        sa.Column("solver", sa.String(80), nullable=False),
        sa.Column("units", sa.String(40), nullable=False),
        sa.Column("units_in", sa.String(80)),
        sa.Column("basis", sa.Text, nullable=False),
        sa.Column("layout", sa.Text, nullable=False),
        sa.Column("values", sa.LargeBinary, nullable=False),
        sa.Column("stds", sa.LargeBinary, nullable=False),
        sa.PrimaryKeyConstraint("id", name="pk_sections"),
        sa.ForeignKeyConstraint(["calibration_id"], ["calibrations.id"], ondelete="CASCADE",
                                name="fk_sections_calibration_id_calibrations"),
    )  # fmt: skip
    op.create_index("ix_sections_calibration_id", "sections", ["calibration_id"])
    op.create_table(
        "figures",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("section_id", sa.Integer, nullable=False),
        sa.Column("name", sa.String(80), nullable=False),
        sa.Column("unit", sa.String(120)),
        sa.Column("value", sa.Float),
        sa.Column("std", sa.Float),
        sa.Column("tracked", sa.Boolean, nullable=False),
        sa.PrimaryKeyConstraint("id", name="pk_figures"),
        sa.ForeignKeyConstraint(["section_id"], ["sections.id"], ondelete="CASCADE",
                                name="fk_figures_section_id_sections"),
    )  # fmt: skip
    op.create_index("ix_figures_section_id", "figures", ["section_id"])


def downgrade() -> None:
    for table in ("figures", "sections", "documents", "calibrations", "units"):
        op.drop_table(table)
