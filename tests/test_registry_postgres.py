"""The registry on a real PostgreSQL server (issue 29.5): Debian's PostgreSQL started by the
fixture in a temporary cluster (bench/pg_server.py), never mocked; skipped, saying why, where
it cannot start (no binaries: apt-get install postgresql, as .ci/run does)."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest
from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine, text

from bench import pg_server
from imucal_cli.registry import store as store_module
from imucal_cli.registry.lot import lot_statistics
from imucal_cli.registry.queries import list_units, unit_report
from imucal_cli.registry.record import UnitInfo, record_calibration
from imucal_cli.registry.store import open_registry
from imucal_cli.use.limits import judge_calibration, limits_from_dict

from .cli_helpers import run
from .registry_helpers import (
    assert_whole,
    calibrate_copy,
    make_set_template,
    make_template,
    recorded_lines,
    section_rows,
    set_unit,
    unit,
    write_as_0002,
    writer,
)


@pytest.fixture(scope="module")
def server():
    why = pg_server.unavailable()
    if why:
        pytest.skip(f"no PostgreSQL server: {why}")
    try:
        srv = pg_server.start("imucal_test")
    except RuntimeError as exc:
        pytest.skip(f"PostgreSQL did not start: {exc}")
    yield srv
    srv.stop()


_DB = iter(range(1_000_000))


@pytest.fixture
def url(server) -> str:
    """A new empty database on the server for each test."""
    import psycopg

    name = f"t{next(_DB)}"
    with psycopg.connect(f"host=127.0.0.1 port={server.port} user=imucal dbname=postgres",
                         autocommit=True) as conn:  # fmt: skip
        conn.execute(f'CREATE DATABASE "{name}"')
    return f"postgresql+psycopg://imucal@127.0.0.1:{server.port}/{name}"


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> dict:
    return make_template(tmp_path_factory)


def test_record_list_show_and_lot_on_postgresql(url, template):
    limits = limits_from_dict({"limits": {"accel": {"bias_max": 0.5}}}, "test")
    with open_registry(url) as reg:
        assert reg.dialect == "postgresql" and "imucal@127.0.0.1" in reg.name
        for i in range(5):
            cal = unit(template, i)
            verdict = judge_calibration(cal, limits)
            record_calibration(reg, cal, UnitInfo(cal.sensor, "P", "L"),
                               acceptance=verdict, limits=limits)  # fmt: skip
        assert [r["serial"] for r in list_units(reg, lot="L")] == [f"SN{i:06d}" for i in range(5)]
        assert unit_report(reg, "SN000002")["calibrations"][0]["limits"] == limits.to_dict()
        stats = lot_statistics(reg, "L")
        assert stats["units"] == 5 and stats["verdicts"]["pass"] + stats["verdicts"]["fail"] == 5


@pytest.mark.slow  # make test has the SQLite case; make test-all this one
def test_four_writer_processes_on_postgresql_lose_nothing(url, template):
    """They also create and migrate the new database at once (the advisory lock)."""
    procs = [writer(url, template["path"], 6 * i, 6) for i in range(4)]
    expected = {}
    for proc, lines in procs:
        assert proc.wait(timeout=600) == 0
        expected.update(recorded_lines(lines.text().splitlines()))
    assert len(expected) == 24 + 1  # unit 1 is calibrated twice (bench.registry.plan)
    assert_whole(url, expected)


@pytest.mark.slow  # make test has the SQLite case; make test-all this one
def test_a_writer_killed_mid_transaction_on_postgresql(url, template):
    open_registry(url).close()
    proc, lines = writer(url, template["path"], 10, 10, "L", "--hang-after", "3")
    lines.wait_for(lambda line: line.startswith("mid-write"))
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    before = recorded_lines(lines.text().splitlines())
    assert len(before) == 3
    assert_whole(url, before)  # the server rolled the half record back
    proc, lines = writer(url, template["path"], 110, 2)
    assert proc.wait(timeout=120) == 0
    assert_whole(url, {**before, **recorded_lines(lines.text().splitlines())})


def test_an_older_postgresql_registry_is_migrated(url, template):
    engine = create_engine(url)
    with engine.begin() as conn:
        config = Config()
        folder = Path(store_module.__file__).parent / "migrations"
        config.set_main_option("script_location", str(folder))
        config.attributes["connection"] = conn
        command.upgrade(config, "0001")
        conn.execute(text("INSERT INTO units (serial, first_recorded, last_recorded) VALUES "
                          "('OLD', '2025-01-01T00:00:00Z', '2025-01-01T00:00:00Z')"))  # fmt: skip
    engine.dispose()
    with open_registry(url) as reg:
        with reg.read() as conn:
            assert MigrationContext.configure(conn).get_current_revision() == store_module.HEAD
        cal = unit(template, 1)
        record_calibration(reg, cal, UnitInfo("OLD"))
        assert [(r["serial"], r["calibrations"]) for r in list_units(reg)] == [("OLD", 1)]


def test_sets_of_a_revision_0002_postgresql_registry_are_migrated(url, tmp_path_factory):
    """A PostgreSQL registry of revision 0002 holding a set (its other IMUs in the document
    only): migrated, the other IMUs' sections derived; a set recorded after has its own; the
    lot counts every IMU of both."""
    template = make_set_template(tmp_path_factory)
    write_as_0002(url, [("S1", set_unit(template, 0))])
    with open_registry(url) as reg:
        record_calibration(reg, set_unit(template, 1), UnitInfo("S2", lot="OLD"))
        stats = lot_statistics(reg, "OLD")
    imus = [r[1] for r in section_rows(url)]
    assert sorted(imus, key=lambda m: m or "") == [None] * 4 + ["imu1"] * 4 + ["imu2"] * 4
    p = next(p for p in stats["parameters"] if p.get("imu") == "imu2" and p["name"] == "b_x")
    assert p["n"] == 2


def test_calibrate_records_into_postgresql(url, tmp_path):
    """The user's path: imucal calibrate --registry postgresql://..., then registry show."""
    plain = url.replace("postgresql+psycopg://", "postgresql://")  # taken as psycopg 3
    calibrate_copy(tmp_path, "--registry", plain, "--lot", "PG-LOT", "--station", "s9")
    proc = run("registry", "list", "--registry", plain, "--json")
    assert proc.returncode == 0, proc.stderr
    assert "PG-LOT" in proc.stdout and "s9" in proc.stdout
