"""The registry (issue 29): every calibration of every unit, kept by serial number across
stations and years, with its verdict against the product's limits, its session's hash and the
whole calibration.

Modules: :mod:`.store` (opening a SQLite file or a PostgreSQL URL, migrating it, transactions),
:mod:`.schema` (the tables), ``migrations/`` (Alembic), :mod:`.record` (recording one
calibration), :mod:`.queries` (units, a unit's history, records), :mod:`.transfer` (export and
import), :mod:`.lot` (a lot's distributions, Cpk, outliers, drift), :mod:`.lot_plot` (its
figure).
"""

from .lot import lot_statistics
from .queries import calibration_of, iter_records, list_units, unit_report
from .record import Recorded, UnitInfo, record_calibration
from .store import REGISTRY_ENV, Registry, RegistryError, open_registry, registry_url
from .transfer import export_records, import_files

__all__ = [
    "REGISTRY_ENV", "Recorded", "Registry", "RegistryError", "UnitInfo", "calibration_of",
    "export_records", "import_files", "iter_records", "list_units", "lot_statistics",
    "open_registry", "record_calibration", "registry_url", "unit_report",
]  # fmt: skip
