"""Opening a registry: a SQLite file (the default) or a PostgreSQL server by URL, migrated to
the newest schema on open, and the transactions every write goes through.

SQLite: the file is put in write-ahead-log mode (``journal_mode=WAL``: readers never wait for a
writer), a write transaction takes the write lock when it begins (``BEGIN IMMEDIATE``), and
writers queue on an advisory lock of ``PATH.lock`` (``flock``: a waiting process is woken the
moment the lock is free, where SQLite's own busy handler sleeps up to 100 ms between tries; the
kernel releases it when a process dies), with SQLite's ``busy_timeout`` of
:data:`BUSY_TIMEOUT_S` behind it for other programs.  Several processes writing at once queue
instead of failing, and a transaction is never half there: a process killed in the middle of
one leaves the file as it was before it (the write-ahead log), ``synchronous=FULL``: a
committed calibration survives a power cut too.

PostgreSQL (``postgresql+psycopg://user@host/db``; ``postgresql://`` is taken to mean psycopg 3):
each write is one transaction; the migrations run under a transaction-scoped advisory lock, so
that stations opening a new registry at once migrate it once.

The schema is migrated by Alembic (``migrations/``) whenever a registry is opened by a newer
imucal: a registry written by an older one is brought up to date, its records kept.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import sqlite3
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.script import ScriptDirectory
from sqlalchemy import create_engine, event, inspect, text
from sqlalchemy.engine import Connection, Engine, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, NoSuchModuleError, SQLAlchemyError

from imucal_cli.errors import InputError

from . import REGISTRY_ENV

__all__ = ["BUSY_TIMEOUT_S", "REGISTRY_ENV", "Registry", "RegistryError", "open_registry",
           "registry_url"]  # fmt: skip

BUSY_TIMEOUT_S = 60.0
"""How long a SQLite connection waits for another process's write lock."""

CONNECT_TIMEOUT_S = 10
"""How long a PostgreSQL connection is tried before the station says it cannot connect (unless
the URL gives ``connect_timeout``)."""

MIGRATION_LOCK = 72_290_029
"""PostgreSQL advisory lock key held while the schema is migrated."""

HEAD = "0003"
"""The newest schema revision (``migrations/versions``)."""


class RegistryError(InputError):
    """A registry that cannot be opened, read or written (one line; exit 2)."""


def registry_url(target: str) -> str:
    """The SQLAlchemy URL of ``target``: a URL as given (``postgresql://`` and ``postgres://``
    with psycopg 3), anything else a SQLite file path."""
    if "://" not in target:
        path = Path(target).expanduser().absolute()
        return f"sqlite:///{path}"
    for plain in ("postgresql://", "postgres://"):
        if target.startswith(plain):
            return "postgresql+psycopg://" + target[len(plain) :]
    return target


def _one_line(exc: BaseException) -> str:
    orig = getattr(exc, "orig", None) or exc
    lines = [ln.strip() for ln in str(orig).splitlines() if ln.strip()]
    return lines[0] if lines else type(orig).__name__


class Registry:
    """An open registry: :meth:`write` and :meth:`read` give connections in a transaction.

    Attributes
    ----------
    engine : sqlalchemy.engine.Engine
    name : str
        The registry as shown to a user (a path, or the URL without its password).
    dialect : str
        ``"sqlite"`` or ``"postgresql"``.
    """

    def __init__(self, engine: Engine, name: str, lock_path: Path | None = None) -> None:
        self.engine = engine
        self.name = name
        self.dialect = engine.dialect.name
        self._lock_path = lock_path
        self._lock_fd: int | None = None

    @contextmanager
    def write(self) -> Iterator[Connection]:
        """A connection in a write transaction: committed when the block ends, rolled back on
        an exception; database errors become :class:`RegistryError`."""
        with self._errors(), self._writer_lock(), self.engine.connect() as conn:
            conn = conn.execution_options(sqlite_begin="IMMEDIATE")
            with conn.begin():
                yield conn

    @contextmanager
    def _writer_lock(self) -> Iterator[None]:
        """SQLite: hold ``PATH.lock`` exclusively (see the module notes); else nothing."""
        if self._lock_path is None:
            yield
            return
        if self._lock_fd is None:
            try:
                self._lock_fd = os.open(self._lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC,
                                        0o666)  # fmt: skip
            except OSError as exc:
                raise RegistryError(f"registry {self.name}: cannot write "
                                    f"({exc.strerror or exc})") from None  # fmt: skip
        deadline = time.monotonic() + BUSY_TIMEOUT_S
        while True:
            try:
                fcntl.flock(self._lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise RegistryError(f"registry {self.name}: another process has held it for "
                                        f"{BUSY_TIMEOUT_S:g} s") from None  # fmt: skip
                time.sleep(0.001)
        try:
            yield
        finally:
            fcntl.flock(self._lock_fd, fcntl.LOCK_UN)

    @contextmanager
    def read(self) -> Iterator[Connection]:
        """A connection in a read transaction (one consistent view of the registry)."""
        with self._errors(), self.engine.connect() as conn, conn.begin():
            yield conn

    @contextmanager
    def _errors(self) -> Iterator[None]:
        try:
            yield
        except RegistryError:
            raise
        except SQLAlchemyError as exc:
            raise RegistryError(f"registry {self.name}: {_one_line(exc)}") from None

    def close(self) -> None:
        self.engine.dispose()
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def __enter__(self) -> Registry:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_registry(target: str | os.PathLike, *, create: bool = True) -> Registry:
    """Open (and with ``create``, make) the registry ``target`` and migrate it to the newest
    schema.

    Parameters
    ----------
    target
        A SQLite file path, or a database URL (``postgresql+psycopg://user:pw@host/db``).
    create
        Make a SQLite file that does not exist yet (``calibrate``, ``import``); without it a
        missing file is an error (``list``, ``show``, ``lot``: a typo must not look like an
        empty registry).

    Raises
    ------
    RegistryError
        Unknown kind of URL, missing driver, a missing file (without ``create``), a file that
        is not a registry, a server that does not answer; one line.
    """
    target = str(target)
    url = registry_url(target)
    try:
        parsed = make_url(url)
    except ArgumentError:
        raise RegistryError(f"registry {target}: not a path or a database URL") from None
    name = target if "://" not in target else parsed.render_as_string(hide_password=True)
    lock = None
    if parsed.get_backend_name() == "sqlite":
        if not parsed.database or parsed.database == ":memory:":
            raise RegistryError(f"registry {name}: a SQLite registry is a file")
        _check_sqlite_path(Path(parsed.database), name, create)
        _check_sqlite_schema(Path(parsed.database), name, create)
        engine = _sqlite_engine(url)
        lock = Path(parsed.database + ".lock")
    elif parsed.get_backend_name() == "postgresql":
        timeout = {"connect_timeout": CONNECT_TIMEOUT_S}
        if "connect_timeout" in parsed.query:  # the URL's own
            timeout = {}
        try:
            engine = create_engine(url, pool_pre_ping=True, connect_args=timeout)
        except (NoSuchModuleError, ImportError):
            raise RegistryError(f"registry {name}: PostgreSQL needs psycopg 3: pip install "
                                "'imucal-cli[postgresql]'") from None  # fmt: skip
    else:
        raise RegistryError(f"registry {name}: only SQLite files and PostgreSQL URLs "
                            "(postgresql+psycopg://...) are supported")  # fmt: skip
    registry = Registry(engine, name, lock)
    try:
        _connect(registry)
        _migrate(registry)
    except BaseException:
        engine.dispose()
        raise
    return registry


def _check_sqlite_path(path: Path, name: str, create: bool) -> None:
    try:
        st = path.stat()
    except FileNotFoundError:
        if not create:
            raise RegistryError(f"registry {name}: no such file") from None
        if not path.parent.is_dir():
            raise RegistryError(f"registry {name}: no such folder {path.parent}") from None
        return
    except OSError as exc:
        raise RegistryError(f"registry {name}: cannot open ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise RegistryError(f"registry {name}: not a regular file")


def _check_sqlite_schema(path: Path, name: str, create: bool) -> None:
    """Refuse, before anything is written (the engine puts the file in WAL mode), a SQLite
    file without imucal's schema that holds another program's tables, or that is empty when
    the command makes no registry (``list`` of a path that exists but was never one).  A file
    that is not SQLite is left to the engine's own error."""
    if not path.exists():
        return
    try:
        with contextlib.closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro",
                                                uri=True, timeout=BUSY_TIMEOUT_S)) as db:
            tables = [row[0] for row in db.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table'")]  # fmt: skip
    except sqlite3.Error:
        return
    if "alembic_version" in tables:
        return
    if tables:
        shown = ", ".join(sorted(tables)[:5]) + (", ..." if len(tables) > 5 else "")
        raise RegistryError(f"registry {name}: a database of another program (tables {shown}), "
                            "not an imucal registry: give a registry, or a new file for one")
    if not create:
        raise RegistryError(f"registry {name}: an empty database, not an imucal registry "
                            "(imucal registry import or calibrate --registry makes one)")


def _sqlite_engine(url: str) -> Engine:
    """A SQLite engine whose transactions begin as asked (``sqlite_begin``) and whose
    connections wait for locks, in WAL mode."""
    engine = create_engine(url, connect_args={"timeout": BUSY_TIMEOUT_S})

    @event.listens_for(engine, "connect")
    def _connect(dbapi_connection, _record) -> None:
        dbapi_connection.isolation_level = None  # the transactions are begun below
        cursor = dbapi_connection.cursor()
        cursor.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}")
        cursor.execute("PRAGMA journal_mode = WAL")
        cursor.execute("PRAGMA synchronous = FULL")
        cursor.execute("PRAGMA foreign_keys = ON")
        cursor.close()

    @event.listens_for(engine, "begin")
    def _begin(conn) -> None:
        mode = conn.get_execution_options().get("sqlite_begin", "DEFERRED")
        conn.exec_driver_sql(f"BEGIN {mode}")

    return engine


def _current(conn: Connection) -> str | None:
    """The schema revision Alembic recorded (``alembic_version``), None for a new database
    (read with plain SQL: Alembic's own context is set up only to migrate)."""
    if not inspect(conn).has_table("alembic_version"):
        return None
    return conn.execute(text("SELECT version_num FROM alembic_version")).scalar()


def _connect(registry: Registry) -> None:
    """Connect once, so that a server that does not answer (or a file that is not a
    database) is said as such, before anything is read."""
    try:
        with registry.engine.connect():
            pass
    except SQLAlchemyError as exc:
        if registry.dialect == "sqlite":
            raise RegistryError(f"registry {registry.name}: {_one_line(exc)} "
                                f"{_sqlite_hint(exc)}") from None  # fmt: skip
        raise RegistryError(f"registry {registry.name}: cannot connect ({_one_line(exc)})"
                            ) from None  # fmt: skip


def _sqlite_hint(exc: BaseException) -> str:
    """What a SQLite error opening a registry likely means: a disk or permission problem (the
    registry is opened in WAL mode: its ``-wal`` and ``-shm`` files are written even to read),
    or a file that is no registry (a full disk was said as 'not an imucal registry?')."""
    text = _one_line(exc).lower()
    if any(w in text for w in ("disk i/o", "disk is full", "readonly", "unable to open")):
        return "(a full disk, or a folder or file this user cannot write?)"
    return "(not an imucal registry?)"


def _migrate(registry: Registry) -> None:
    """Bring the schema to :data:`HEAD` (nothing when it is there already)."""
    try:
        with registry.read() as conn:
            current = _current(conn)
    except RegistryError as exc:
        raise RegistryError(f"{exc} {_sqlite_hint(exc)}") from None
    if current == HEAD:
        return
    config = Config()
    config.set_main_option("script_location", str(Path(__file__).parent / "migrations"))
    with registry.write() as conn:
        if registry.dialect == "postgresql":
            conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK})
        current = _current(conn)  # another process may have migrated it meanwhile
        if current == HEAD:
            return
        _check_known(config, current, registry.name)
        config.attributes["connection"] = conn
        try:
            command.upgrade(config, HEAD)
        except DBAPIError:
            raise
        except Exception as exc:  # noqa: BLE001  alembic's own errors: one line
            raise RegistryError(f"registry {registry.name}: cannot migrate ({exc})") from None


def _check_known(config, current: str | None, name: str) -> None:
    """Refuse a registry migrated by a newer imucal (a revision this one does not have)."""
    known = {s.revision for s in ScriptDirectory.from_config(config).walk_revisions()}
    if current is not None and current not in known:
        raise RegistryError(f"registry {name}: schema revision {current} is newer than this "
                            "imucal knows (upgrade imucal)")  # fmt: skip
