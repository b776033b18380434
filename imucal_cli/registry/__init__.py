"""The registry (issue 29): every calibration of every unit, kept by serial number across
stations and years, with its verdict against the product's limits, its session's hash and the
whole calibration.

Modules: :mod:`.store` (opening a SQLite file or a PostgreSQL URL, migrating it, transactions),
:mod:`.schema` (the tables), ``migrations/`` (Alembic), :mod:`.record` (recording one
calibration), :mod:`.queries` (units, a unit's history, records), :mod:`.transfer` (export and
import), :mod:`.lot` (a lot's distributions, Cpk, outliers, drift), :mod:`.lot_plot` (its
figure).

Import from the modules (``from imucal_cli.registry.store import open_registry``).
"""

REGISTRY_ENV = "IMUCAL_REGISTRY"
"""The environment variable naming the registry when ``--registry`` is not given."""
