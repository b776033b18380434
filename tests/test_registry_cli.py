"""The registry from the command line (issue 29.1, 29.2, 29.4): ``calibrate --limits
--registry`` on real sessions (exit 4 for a rejected unit), and ``imucal registry
list|show|export|import|lot``."""

from __future__ import annotations

import json
import shutil

import h5py
import pytest

from imucal_cli.formats.session.digest import session_digest

from .cli_helpers import assert_one_line_error, run
from .registry_helpers import SESSION
from .test_partial_capture import capture_guided, serve
from .test_virtual import start_capture

LOOSE = """
[product]
name = "SIM-16"
[limits.accel]
units = "m/s^2"
bias_max = 0.8
nominal_sensitivity = 835.0
gain_error_max_pct = 4.0
misalignment_max_deg = 1.0
noise_max = 0.05
residual_rms_max = 0.005
held_out_rms_max = 0.01
[limits.gyro]
bias_max = 0.1
"""
STRICT = LOOSE.replace("residual_rms_max = 0.005", "residual_rms_max = 0.0001")


@pytest.fixture(scope="module")
def line(tmp_path_factory):
    """A production line's morning: one unit accepted, then the same unit rejected against
    stricter limits at another station, both recorded; a third calibration as --json."""
    folder = tmp_path_factory.mktemp("line")
    (folder / "loose.toml").write_text(LOOSE)
    (folder / "strict.toml").write_text(STRICT)
    db = folder / "reg.db"
    session = folder / "unit.h5"
    shutil.copy(SESSION, session)
    common = ["--registry", db, "--lot", "LOT-7", "--operator", "ann", "--force"]
    ok = run("calibrate", session, "-o", folder / "a.json", "--limits", folder / "loose.toml",
             "--station", "st-1", *common)  # fmt: skip
    # The same unit's data under other names: each calibration a document of its own (the same
    # session calibrated twice within a second gives the same document, recorded once).
    second = folder / "unit-b.h5"
    shutil.copy(SESSION, second)
    bad = run("calibrate", second, "-o", folder / "b.json", "--limits", folder / "strict.toml",
              "--station", "st-2", *common)  # fmt: skip
    again = folder / "unit-c.h5"
    shutil.copy(SESSION, again)
    js = run("calibrate", again, "-o", folder / "c.json", "--limits", folder / "strict.toml",
             "--station", "st-2", "--json", *common)  # fmt: skip
    return {"folder": folder, "db": db, "session": session, "ok": ok, "bad": bad, "json": js}


def test_a_unit_within_its_limits_is_accepted_and_recorded(line):
    proc = line["ok"]
    assert proc.returncode == 0, proc.stderr
    assert "accepted (SIM-16)" in proc.stdout
    assert "recorded sim-16bit seed 1 in" in proc.stdout


def test_a_unit_outside_its_limits_exits_4_naming_the_figure(line):
    proc = line["bad"]
    assert proc.returncode == 4, proc.stderr
    assert "REJECTED (SIM-16)" in proc.stdout
    assert "failed: accel residual rms:" in proc.stdout and "> 0.0001" in proc.stdout
    assert (line["folder"] / "b.json").is_file()  # saved all the same
    doc = json.loads(line["json"].stdout)
    assert line["json"].returncode == 4
    assert doc["acceptance"]["verdict"] == "fail"
    assert any(f.startswith("accel residual rms") for f in doc["acceptance"]["failed"])
    assert doc["registry"]["recorded"] and doc["registry"]["serial"] == "sim-16bit seed 1"
    assert doc["registry"]["session_sha256"] == session_digest(line["session"])
    assert doc["registry"]["new"]


def test_registry_list_and_show(line):
    proc = run("registry", "list", "--registry", line["db"], "--json")
    units = json.loads(proc.stdout)["units"]
    assert [(u["serial"], u["lot"], u["calibrations"], u["last_verdict"], u["last_station"])
            for u in units] == [("sim-16bit seed 1", "LOT-7", 3, "fail", "st-2")]  # fmt: skip
    shown = run("registry", "show", "sim-16bit seed 1", "--registry", line["db"])
    assert shown.returncode == 0 and "history of sim-16bit seed 1: 3 calibrations" in shown.stdout
    assert "st-1" in shown.stdout and "FAIL" in shown.stdout
    record = json.loads(run("registry", "show", "sim-16bit seed 1", "--registry", line["db"],
                            "--json").stdout)  # fmt: skip
    assert [c["verdict"] for c in record["calibrations"]] == ["pass", "fail", "fail"]
    # the same session three times: the history finds no drift
    assert record["history"]["sensors"][0]["drifted"] == []
    assert_one_line_error(run("registry", "show", "nobody", "--registry", line["db"]),
                          "no unit 'nobody'")  # fmt: skip


def test_the_environment_names_the_registry(line, monkeypatch):
    monkeypatch.setenv("IMUCAL_REGISTRY", str(line["db"]))
    proc = run("registry", "list")
    assert proc.returncode == 0 and "sim-16bit seed 1" in proc.stdout
    monkeypatch.delenv("IMUCAL_REGISTRY")
    assert_one_line_error(run("registry", "list"), "no registry", "IMUCAL_REGISTRY")


def test_export_import_and_lot_from_the_command_line(line, tmp_path):
    out = tmp_path / "all.jsonl"
    proc = run("registry", "export", "--registry", line["db"], "-o", out)
    assert proc.returncode == 0 and "wrote 3 records" in proc.stderr
    other = tmp_path / "other.db"
    assert run("registry", "import", out, "--registry", other).returncode == 0
    a = json.loads(run("registry", "show", "sim-16bit seed 1", "--registry", line["db"],
                       "--json").stdout)  # fmt: skip
    b = json.loads(run("registry", "show", "sim-16bit seed 1", "--registry", other,
                       "--json").stdout)  # fmt: skip
    assert a["calibrations"] == [{**c, "id": a["calibrations"][i]["id"]}
                                 for i, c in enumerate(b["calibrations"])]  # fmt: skip
    again = run("registry", "import", out, "--registry", other, "--json")
    assert len(json.loads(again.stdout)["skipped"]) == 3
    # a calibration file under another serial
    proc = run("registry", "import", line["folder"] / "a.json", "--registry", other, "--serial",
               "SN-X", "--lot", "LOT-7", "--limits", line["folder"] / "strict.toml")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lot = run("registry", "lot", "LOT-7", "--registry", other, "--json")
    stats = json.loads(lot.stdout)
    assert stats["units"] == 2 and stats["verdicts"] == {"pass": 0, "fail": 2, "not judged": 0}
    plot = tmp_path / "lot.png"
    drawn = run("registry", "lot", "LOT-7", "--registry", other, "--plot", plot)
    assert drawn.returncode == 0 and "Cpk" in drawn.stdout and "drift alarm" in drawn.stdout
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert_one_line_error(run("registry", "lot", "NOPE", "--registry", other), "no unit in lot")


def test_bad_input_is_refused_before_anything_is_solved(tmp_path):
    session = tmp_path / "s.h5"
    shutil.copy(SESSION, session)
    out = tmp_path / "s.cal.json"
    (tmp_path / "bad.toml").write_text("[limits.accel]\nbias_max = -1\n")
    assert_one_line_error(run("calibrate", session, "-o", out, "--limits", tmp_path / "bad.toml"),
                          "bias_max", "positive")  # fmt: skip
    assert_one_line_error(run("calibrate", session, "-o", out, "--serial", "X"), "--registry")
    assert_one_line_error(run("calibrate", session, "-o", out, "--registry",
                              tmp_path / "no" / "reg.db"), "no such folder")  # fmt: skip
    assert_one_line_error(run("calibrate", session, "-o", out, "--registry", "mysql://u@h/db"),
                          "only SQLite files and PostgreSQL URLs")  # fmt: skip
    # a PostgreSQL server that does not answer (nothing listens on port 1)
    assert_one_line_error(run("calibrate", session, "-o", out, "--registry",
                              "postgresql://u@127.0.0.1:1/db"), "cannot connect")  # fmt: skip
    with h5py.File(session, "r+") as f:
        del f.attrs["sensor"]
    assert_one_line_error(run("calibrate", session, "-o", out, "--registry", tmp_path / "r.db"),
                          "names no sensor", "--serial")  # fmt: skip
    assert not out.exists()
    proc = run("calibrate", session, "-o", out, "--registry", tmp_path / "r.db", "--serial",
               "SN-1")  # fmt: skip
    assert proc.returncode == 0 and "recorded SN-1" in proc.stdout


def test_exit_status_4_is_documented():
    assert any(line.strip().startswith("4  calibrate --limits")
               for line in run("--help").stdout.splitlines())  # fmt: skip
    text = " ".join(run("calibrate", "--help").stdout.split())
    assert "4 saved, and outside the limits of --limits" in text


def test_several_sessions_are_each_judged_and_recorded(tmp_path):
    sessions = []
    for name in ("a", "b"):
        sessions.append(tmp_path / f"{name}.h5")
        shutil.copy(SESSION, sessions[-1])
    with h5py.File(sessions[1], "r+") as f:
        f.attrs["sensor"] = "unit-B"
    (tmp_path / "strict.toml").write_text(STRICT)
    proc = run("calibrate", *sessions, "--registry", tmp_path / "r.db", "--limits",
               tmp_path / "strict.toml", "--json")  # fmt: skip
    assert proc.returncode == 4, proc.stderr
    rows = json.loads(proc.stdout)["results"]
    assert [r["exit_code"] for r in rows] == [4, 4]
    assert {r["registry"]["serial"] for r in rows} == {"sim-16bit seed 1", "unit-B"}


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["unattended", "guided"])
def test_the_production_line_path_from_a_serial_device(tmp_path, mode):
    """The user's path: a unit on a serial port (``imucal simulate --serve``), captured
    (unattended, or guided as an operator would), calibrated with its product's limits into the
    registry, shown, certified."""
    # a guided capture holds each pose 2 s from when it sees the unit still: longer holds
    hold = "4" if mode == "guided" else "1.5"
    server, port = serve("--plan", "six", "--hold", hold, "--move", "0.8", "--seed", "4")
    out = tmp_path / "unit.h5"
    try:
        if mode == "guided":
            code, said = capture_guided(port, out, "six")
        else:
            cap = start_capture(port, out, "--plan", "six")
            stdout, stderr = cap.communicate(timeout=240)
            code, said = cap.returncode, stdout + stderr
    finally:
        server.kill()
        server.communicate()
    assert code == 0, said
    (tmp_path / "p.toml").write_text("[product]\nname = \"SIM-16\"\n[limits.accel]\n"
                                      "bias_max = 0.8\nresidual_rms_max = 0.05\n")  # fmt: skip
    db = tmp_path / "line.db"
    proc = run("calibrate", out, "--registry", db, "--limits", tmp_path / "p.toml", "--serial",
               "SN-LINE-1", "--lot", "L", "--station", "st-9", "--json")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["acceptance"]["verdict"] == "pass" and doc["registry"]["serial"] == "SN-LINE-1"
    assert doc["registry"]["session_sha256"] == session_digest(out)
    shown = json.loads(run("registry", "show", "SN-LINE-1", "--registry", db, "--json").stdout)
    assert [(c["station"], c["verdict"]) for c in shown["calibrations"]] == [("st-9", "pass")]
    cert = tmp_path / "cert.html"
    assert run("certificate", "SN-LINE-1", "--registry", db, "-o", cert).returncode == 0
    assert "SN-LINE-1" in cert.read_text() and doc["registry"]["session_sha256"] in cert.read_text()
