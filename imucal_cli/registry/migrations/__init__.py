"""Alembic migrations of the registry, run by :func:`imucal_cli.registry.store.open_registry`
(``env.py``; one file per revision in ``versions/``)."""
