"""The certificate of a unit of several IMUs (issue 28): one document listing every IMU, each
one's place in the set (rotation to the reference, time offset, with their std) and each one's
terms with their std, as ``imucal report`` reads them (nothing re-solved)."""

from __future__ import annotations

import re

import pytest

from imucal_cli.calibrate.imu_set import calibrate_set
from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.config import Config
from imucal_cli.simulate.imu_set import simulate_set
from imucal_cli.use.export_set import pick_imu

from .cli_helpers import run

LIMITS = """
[product]
name = "SET-3"
[limits.accel]
bias_max = 5.0
"""


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A set of 3 IMUs calibrated, its calibration JSON written."""
    session, _ = simulate_set(3, seed=8, units="m/s^2", created="2026-01-01T00:00:00Z")
    cal = calibrate_set(session, Config(), name="set.h5")
    folder = tmp_path_factory.mktemp("setcert")
    write_calibration(folder / "set.cal.json", cal)
    return cal, folder


def _table(html: str, table_id: str) -> str:
    found = re.search(rf'<table[^>]* id="{re.escape(table_id)}">(.*?)</table>', html, re.S)
    assert found, f"no table {table_id}"
    return found.group(1)


def _row(table: str, name: str) -> list[str]:
    """The cells of the row whose first cell is ``name``."""
    for row in re.findall(r"<tr[^>]*>(.*?)</tr>", table, re.S):
        cells = [c.strip() for c in re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", row, re.S)]
        if cells and cells[0] == name:
            return cells
    raise AssertionError(f"no row {name}")


def _shown(section, name: str) -> tuple[str, str]:
    p = next(p for p in section.to_dict()["parameters"] if p["name"] == name)
    return f"{p['value']:.6g}", f"± {p['std']:.6g}"


def test_a_set_certificate_lists_every_imu_with_its_terms(calibrated, tmp_path):
    cal, folder = calibrated
    cert = tmp_path / "cert.html"
    proc = run("certificate", folder / "set.cal.json", "--serial", "SET-1", "-o", cert)
    assert proc.returncode == 0, proc.stderr
    html = cert.read_text()
    places = _table(html, "imus")
    assert _row(places, "reference")[-1] == "accel, gyro"
    for name in ("imu1", "imu2"):
        entry = cal.imus[name]
        cells = _row(places, name)
        assert cells[1] == f"{entry.rotation_deg:.6g} deg"
        assert cells[2] == ", ".join(f"{s:.6g}" for s in entry.rotation_std_deg) + " deg"
        assert cells[3] == f"{1e3 * entry.time_offset_s:.6g} ms"
        assert cells[4] == f"± {1e3 * entry.time_offset_std_s:.6g} ms"
        for kind, section in (("accel", entry.accel), ("gyro", entry.gyro)):
            table = _table(html, f"parameters-{name}-{kind}")
            assert _row(table, "b_x")[1:3] == list(_shown(section, "b_x"))
            assert _table(html, f"residuals-{name}-{kind}")
        assert f"<h2>{name}: Accelerometer</h2>" in html
    # The reference's own terms keep their tables, now titled with its name.
    assert _row(_table(html, "parameters-accel"), "b_x")[1:3] == list(_shown(cal.accel, "b_x"))
    assert "<h2>reference: Gyroscope</h2>" in html
    assert 'id="judged"' not in html  # not judged: nothing to say about the limits


def test_the_limits_judge_every_imu_and_say_so(calibrated, tmp_path):
    cal, folder = calibrated
    (tmp_path / "p.toml").write_text(LIMITS)
    cert = tmp_path / "cert.html"
    proc = run("certificate", folder / "set.cal.json", "--serial", "SET-1", "--limits",
               tmp_path / "p.toml", "-o", cert)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    html = cert.read_text()
    assert "SET-1: pass" in proc.stdout
    assert "the limits judge every IMU's sensors" in html
    limits = _table(html, "limits")
    for sensor in ("accel", "imu1 accel", "imu2 accel"):  # 3 bias checks per IMU
        assert len(re.findall(rf"<td>{sensor}</td><td>bias", limits)) == 3, sensor
    assert _table(html, "parameters-imu2-gyro")


def test_a_unit_fails_when_another_imu_is_outside_the_limits(calibrated, tmp_path):
    """The reference within the limits, another IMU not: the unit fails, naming that IMU's
    figure (here the accelerometer fit's residual RMS, where the parts differ most)."""
    cal, folder = calibrated
    ref = cal.accel.residual_rms
    name, other = max(((k, e.accel.residual_rms) for k, e in cal.imus.items()),
                      key=lambda kv: kv[1])  # fmt: skip
    assert other > 1.2 * ref  # distinct parts (noise 0.5-2 times): a limit falls between
    limits = LIMITS.replace("bias_max = 5.0", f"residual_rms_max = {(ref + other) / 2:.6g}")
    (tmp_path / "p.toml").write_text(limits)
    proc = run("certificate", folder / "set.cal.json", "--serial", "SET-1", "--limits",
               tmp_path / "p.toml", "-o", tmp_path / "cert.html")  # fmt: skip
    assert "SET-1: fail" in proc.stdout, proc.stdout
    bad = re.findall(r'<li class="bad">(.*?)</li>', (tmp_path / "cert.html").read_text())
    assert len(bad) == 1 and bad[0].startswith(f"{name} accel residual rms"), bad


def test_one_imu_has_no_set_section(calibrated, tmp_path):
    """A calibration of one IMU (here imu1's, picked from the set) is certified as before."""
    cal, _ = calibrated
    write_calibration(tmp_path / "imu1.cal.json", pick_imu(cal, "imu1"))
    cert = tmp_path / "cert.html"
    proc = run("certificate", tmp_path / "imu1.cal.json", "--serial", "U1", "-o", cert)
    assert proc.returncode == 0, proc.stderr
    html = cert.read_text()
    assert 'id="imus"' not in html and "<h2>Accelerometer</h2>" in html
    assert _row(_table(html, "parameters-accel"), "b_x")[1:3] == list(
        _shown(cal.imus["imu1"].accel, "b_x"))  # fmt: skip
