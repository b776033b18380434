"""A throw-away PostgreSQL server for the registry's tests and bench (Debian's binaries).

:func:`start` initdb's a cluster in a fresh folder, starts it on a free localhost port and
returns a :class:`Server` (``url``: a ``postgresql+psycopg://`` URL of a new database);
:meth:`Server.stop` stops it and removes the folder.  PostgreSQL refuses to run as root: as
root the cluster is made and run as the ``postgres`` user (Debian's package makes it) or else
``nobody``.  :func:`unavailable` says why no server can start here (no binaries, no user to run
it), or None.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import socket
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Server", "bindir", "start", "unavailable"]


def bindir() -> Path | None:
    """The folder of ``initdb`` and ``pg_ctl``: Debian's newest ``/usr/lib/postgresql/N/bin``,
    else on PATH."""
    def version(path: str) -> int:
        part = Path(path).parts[-3]
        return int(part) if part.isdigit() else 0

    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=version)
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return Path(initdb).parent if initdb else None


def _run_as() -> str | None:
    """The user to run the server as: None when not root, else ``postgres`` or ``nobody``."""
    if os.geteuid() != 0:
        return None
    for name in ("postgres", "nobody"):
        try:
            pwd.getpwnam(name)
            return name
        except KeyError:
            continue
    return ""


def unavailable() -> str | None:
    """Why a server cannot start here, or None."""
    if bindir() is None:
        return ("PostgreSQL's initdb/pg_ctl not found (Debian: apt-get install postgresql; "
                ".ci/run installs it)")  # fmt: skip
    if _run_as() == "":
        return "running as root and no postgres or nobody user to run PostgreSQL as"
    try:
        import psycopg  # noqa: F401
    except ImportError:
        return "psycopg 3 is not installed (pip install 'imucal-cli[postgresql]')"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Server:
    """A running server: ``url`` of its database, ``folder`` (data and log)."""

    url: str
    folder: Path
    data: Path
    user: str | None
    port: int

    def _pg_ctl(self, *args: str) -> subprocess.CompletedProcess:
        return _run([str(bindir() / "pg_ctl"), "-D", str(self.data), *args], self.user)

    def cpu_s(self) -> float | None:
        """CPU seconds (user + system) the server has used so far: the postmaster's, its
        finished backends' and those running now (Linux ``/proc``); None where unreadable."""
        try:
            pid = int((self.data / "postmaster.pid").read_text().split()[0])
            ticks = _ticks(pid, children=True)
        except (OSError, ValueError, IndexError):
            return None
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit() and _parent(entry) == pid:
                try:
                    ticks += _ticks(int(entry.name))
                except (OSError, ValueError, IndexError):  # it has just ended
                    continue
        return ticks / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        """Stop the server (immediately) and remove its folder."""
        try:
            self._pg_ctl("-m", "immediate", "-w", "stop")
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)


def _stat(pid: int) -> list[str]:
    """The fields of ``/proc/PID/stat`` after the command name (the first is the state)."""
    return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()


def _ticks(pid: int, children: bool = False) -> int:
    """utime + stime of a process (and with ``children``, of its children it has waited for)."""
    fields = _stat(pid)
    return sum(int(f) for f in fields[11 : 15 if children else 13])


def _parent(entry: Path) -> int | None:
    try:
        return int(_stat(int(entry.name))[1])
    except (OSError, ValueError, IndexError):
        return None


def _run(cmd: list[str], user: str | None, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, user=user, capture_output=True, text=True, timeout=timeout,
                          check=False, cwd="/")  # fmt: skip


def start(database: str = "registry", *, fsync: bool = False) -> Server:
    """Make a cluster, start it on a free localhost port and create ``database``; ``fsync``
    False (tests) leaves durability to the operating system, True (the bench) as in production.

    Raises
    ------
    RuntimeError
        :func:`unavailable` says why, or initdb/pg_ctl failed (their output in the message).
    """
    why = unavailable()
    if why:
        raise RuntimeError(why)
    user = _run_as()
    folder = Path(tempfile.mkdtemp(prefix="imucal-pg-"))
    data = folder / "data"
    if user:
        entry = pwd.getpwnam(user)
        os.chown(folder, entry.pw_uid, entry.pw_gid)
    folder.chmod(0o700)
    bins = bindir()
    init = _run([str(bins / "initdb"), "-D", str(data), "-U", "imucal", "--auth=trust",
                 "--encoding=UTF8", "--no-sync"], user)  # fmt: skip
    if init.returncode:
        shutil.rmtree(folder, ignore_errors=True)
        raise RuntimeError(f"initdb failed: {init.stderr.strip() or init.stdout.strip()}")
    for _attempt in range(3):
        port = _free_port()
        options = (f"-p {port} -k {folder} -c listen_addresses=127.0.0.1 "
                   f"-c fsync={'on' if fsync else 'off'} -c max_connections=40")  # fmt: skip
        started = _run([str(bins / "pg_ctl"), "-D", str(data), "-o", options, "-l",
                        str(folder / "log"), "-w", "-t", "60", "start"], user)  # fmt: skip
        if started.returncode == 0:
            break
    else:
        log_file = folder / "log"
        log = log_file.read_text(errors="replace")[-800:] if log_file.exists() else ""
        shutil.rmtree(folder, ignore_errors=True)
        raise RuntimeError(f"pg_ctl start failed: {started.stderr.strip()} {log}")
    server = Server(f"postgresql+psycopg://imucal@127.0.0.1:{port}/{database}", folder, data,
                    user, port)  # fmt: skip
    try:
        import psycopg

        with psycopg.connect(f"host=127.0.0.1 port={port} user=imucal dbname=postgres",
                             autocommit=True) as conn:  # fmt: skip
            conn.execute(f'CREATE DATABASE "{database}"')
    except BaseException:
        server.stop()
        raise
    return server
