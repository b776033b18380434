"""The certificate (issue 29.3): opened in a real headless browser (Debian's chromium; skipped,
saying so, where it is absent: .ci/run installs it), and as PDF rendered by WeasyPrint, both
read back as the text a reader sees (pypdf)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import h5py
import numpy as np
import pytest

from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.session.digest import session_digest

from .cli_helpers import assert_one_line_error, run
from .registry_helpers import SESSION

LIMITS = """
[product]
name = "SIM-16"
[limits.accel]
bias_max = 0.8
residual_rms_max = 0.0001
[limits.gyro]
bias_max = 0.1
"""

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def unit(tmp_path_factory):
    """A unit calibrated, judged (rejected: its accel residual above 0.0001 m/s^2) and
    recorded."""
    folder = tmp_path_factory.mktemp("cert")
    session = folder / "unit.h5"
    shutil.copy(SESSION, session)
    (folder / "p.toml").write_text(LIMITS)
    db = folder / "reg.db"
    proc = run("calibrate", session, "-o", folder / "unit.cal.json", "--limits",
               folder / "p.toml", "--registry", db, "--lot", "L1",
               "--station", "bench-3")  # fmt: skip
    assert proc.returncode == 4, proc.stderr
    return {"folder": folder, "session": session, "db": db,
            "cal": read_calibration(folder / "unit.cal.json")}  # fmt: skip


def _shown_parameter(cal) -> tuple[str, str]:
    """b_x of the accelerometer as the certificate prints it: value and '± std'."""
    p = next(p for p in cal.accel.to_dict()["parameters"] if p["name"] == "b_x")
    return f"{p['value']:.6g}", f"± {p['std']:.6g}"


def _pdf_text(path) -> str:
    from pypdf import PdfReader

    return "\n".join(page.extract_text() for page in PdfReader(path).pages)


def _chromium(*args) -> subprocess.CompletedProcess:
    return subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
                           "--disable-background-networking", "--disable-component-update",
                           "--disable-sync", "--no-first-run", *args],
                          capture_output=True, text=True, timeout=180, check=False)  # fmt: skip


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (Debian: apt-get install "
                    "chromium; .ci/run installs it)")  # fmt: skip
def test_the_certificate_in_a_headless_browser(unit, tmp_path):
    cert = tmp_path / "cert.html"
    proc = run("certificate", "sim-16bit seed 1", "--registry", unit["db"], "-o", cert)
    assert proc.returncode == 0, proc.stderr
    assert "sim-16bit seed 1: fail" in proc.stdout
    profile = tmp_path / "profile"
    # What a reader sees: the page printed by the browser, its text read back.
    printed = tmp_path / "printed.pdf"
    shown = _chromium(f"--user-data-dir={profile}", f"--print-to-pdf={printed}",
                      "--no-pdf-header-footer", cert.as_uri())  # fmt: skip
    assert printed.is_file(), shown.stderr[-2000:]
    text = " ".join(_pdf_text(printed).split())
    assert "sim-16bit seed 1" in text and "FAIL" in text and "bench-3" in text
    assert "accel residual rms" in text and "0.0001" in text
    value, std = _shown_parameter(unit["cal"])
    assert f"b_x {value} {std} counts" in text, text[:3000]
    assert session_digest(unit["session"]) in text.replace(" ", "")
    # The DOM the browser built: the verdict element and the inline plots.
    dom = _chromium(f"--user-data-dir={profile}", "--dump-dom", cert.as_uri()).stdout
    assert 'id="verdict" class="verdict fail">FAIL<' in dom
    assert dom.count('src="data:image/png;base64,') == 2


@pytest.mark.slow  # WeasyPrint's rendering: make test-all
def test_a_pdf_certificate_from_a_calibration_file(unit, tmp_path):
    pytest.importorskip("weasyprint", reason="WeasyPrint not installed (the pdf extra)")
    (tmp_path / "loose.toml").write_text(LIMITS.replace("0.0001", "0.01"))
    cert = tmp_path / "cert.pdf"
    proc = run("certificate", unit["folder"] / "unit.cal.json", "--limits",
               tmp_path / "loose.toml", "--lot", "L1", "-o", cert)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert cert.read_bytes()[:5] == b"%PDF-"
    text = " ".join(_pdf_text(cert).split())
    assert "sim-16bit seed 1" in text and "PASS" in text and "FAIL" not in text
    value, std = _shown_parameter(unit["cal"])
    assert f"b_x {value} {std} counts" in text
    # the session is beside the calibration: its content hash is computed and shown
    assert session_digest(unit["session"]) in text.replace(" ", "")


def test_without_weasyprint_a_pdf_is_one_line_naming_the_extra(unit, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "weasyprint", None)  # import weasyprint -> ImportError
    proc = run("certificate", unit["folder"] / "unit.cal.json", "-o", tmp_path / "c.pdf")
    assert_one_line_error(proc, "WeasyPrint", "imucal-cli[pdf]")
    assert not (tmp_path / "c.pdf").exists()


def test_certificate_refusals(unit, tmp_path):
    assert_one_line_error(run("certificate", "nobody", "--registry", unit["db"], "-o",
                              tmp_path / "c.html"), "no unit 'nobody'")  # fmt: skip
    assert_one_line_error(run("certificate", "nobody", "-o", tmp_path / "c.html"),
                          "no such file", "--registry")  # fmt: skip
    (tmp_path / "c.html").write_text("x")
    assert_one_line_error(run("certificate", "sim-16bit seed 1", "--registry", unit["db"], "-o",
                              tmp_path / "c.html"), "exists")  # fmt: skip
    doc = json.loads((unit["folder"] / "unit.cal.json").read_text())
    del doc["sensor"]
    (tmp_path / "anon.json").write_text(json.dumps(doc))
    assert_one_line_error(run("certificate", tmp_path / "anon.json", "-o", tmp_path / "d.html"),
                          "names no sensor", "--serial")  # fmt: skip


def test_the_session_hash_follows_the_samples_not_the_file(tmp_path):
    session = tmp_path / "s.h5"
    shutil.copy(SESSION, session)
    before = session_digest(session)
    assert run("calibrate", session, "-o", tmp_path / "s.json").returncode == 0
    assert session_digest(session) == before  # a calibration stored in it changes no sample
    with h5py.File(session, "r+") as f:
        accel = f["raw/accel"]
        accel[0, 0] = np.nextafter(accel[0, 0], np.inf)  # one sample, one ulp
    assert session_digest(session) != before
