"""Alembic's environment for the registry: always run on a connection the registry gives
(``config.attributes["connection"]``, inside its transaction), never from a URL in a file."""

from __future__ import annotations

from alembic import context

from imucal_cli.registry.schema import metadata

connection = context.config.attributes["connection"]
context.configure(
    connection=connection,
    target_metadata=metadata,
    render_as_batch=connection.dialect.name == "sqlite",
    transactional_ddl=True,
)
with context.begin_transaction():
    context.run_migrations()
