"""Issue 26: the Fusion export compiled with gcc against Fusion's own sources, 1.3.2 (the C
library PyPI ``imufusion`` 1.3 wraps: ``FusionMatrix`` a flat array of 9, ``FusionModelInertial``)
by default and 1.2.9 (``float array[3][3]``, ``FusionCalibrationInertial``) with
``--fusion-version 1.2``; the compiled program calibrates a session's raw samples and its output
is compared with ``imucal apply`` on the same session.  Skipped when gcc or the sources in
``../shared/third_party`` are absent."""

from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.session import read_session, write_session
from imucal_cli.simulate.magnetometer import simulate_mag

from .cli_helpers import assert_one_line_error, run

GCC = shutil.which("gcc")
THIRD_PARTY = Path(__file__).resolve().parents[2] / "shared" / "third_party"
SOURCES = {"1.3": THIRD_PARTY / "fusion-1.3.2" / "Fusion",
           "1.2": THIRD_PARTY / "fusion-1.2.9" / "Fusion"}  # fmt: skip
MODELS = {"1.3": ("FusionModelInertial", "FusionModelMagnetic"),
          "1.2": ("FusionCalibrationInertial", "FusionCalibrationMagnetic")}  # fmt: skip
SESSION = Path(__file__).resolve().parents[1] / "sessions" / "qureshi18-seed1.h5"
G0 = 9.80665
EPS32 = 2.0**-24  # float32 unit roundoff

pytestmark = pytest.mark.skipif(
    GCC is None or not all((d / "Fusion.h").is_file() for d in SOURCES.values()),
    reason="gcc or the Fusion sources in ../shared/third_party are absent",
)


def compile_program(tmp_path: Path, version: str, header: str, body: str, std="c11") -> Path:
    """``main.c`` including the export ``cal.h``, compiled against Fusion ``version``'s own
    headers with every warning an error; the path of the program."""
    (tmp_path / "cal.h").write_text(header)
    (tmp_path / "main.c").write_text('#include <stdio.h>\n#include "cal.h"\n' + body)
    exe = tmp_path / f"main{version}"
    cmd = [GCC, f"-std={std}", "-Wall", "-Wextra", "-Werror", "-pedantic", "-I",
           str(SOURCES[version]), "-o", str(exe), "main.c", "-lm"]  # fmt: skip
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return exe


def inertial_body(version: str) -> str:
    model = MODELS[version][0]
    return (
        "int main(void) {\n  FusionVector a, g, ca, cg;\n"
        '  while (scanf("%f %f %f %f %f %f", &a.array[0], &a.array[1], &a.array[2], '
        "&g.array[0], &g.array[1], &g.array[2]) == 6) {\n"
        f"    ca = {model}(a, accelerometerMisalignment, accelerometerSensitivity, "
        "accelerometerOffset);\n"
        f"    cg = {model}(g, gyroscopeMisalignment, gyroscopeSensitivity, gyroscopeOffset);\n"
        '    printf("%.9g %.9g %.9g %.9g %.9g %.9g\\n", (double)ca.array[0], (double)ca.array[1],'
        " (double)ca.array[2], (double)cg.array[0], (double)cg.array[1], (double)cg.array[2]);\n"
        "  }\n  return 0;\n}\n"
    )


def feed(exe: Path, rows: np.ndarray) -> np.ndarray:
    stdin = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in rows) + "\n"
    out = subprocess.run([str(exe)], input=stdin, capture_output=True, text=True, check=True)
    return np.loadtxt(out.stdout.splitlines(), ndmin=2)


def float32_bound(matrix: np.ndarray, raw: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """A bound on float32's error in ``matrix @ (raw - bias)``: each of the subtraction, the
    product by the sensitivity, three products and two sums rounds once (relative EPS32 of its
    magnitude), and the constants themselves are rounded to float32 (EPS32 each)."""
    terms = np.abs(raw - bias) + np.abs(raw) + np.abs(bias)
    return 8 * EPS32 * terms @ np.abs(matrix).T


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """``imucal calibrate`` of a shipped session (18 poses, hand turns), ``imucal apply`` of it."""
    folder = tmp_path_factory.mktemp("fusion")
    session = folder / "q18.h5"
    shutil.copy(SESSION, session)
    cal = folder / "cal.json"
    proc = run("calibrate", session, "-o", cal, "--no-store")
    assert proc.returncode == 0, proc.stderr
    out = folder / "applied.csv"
    proc = run("apply", cal, session, "-o", out)
    assert proc.returncode == 0, proc.stderr
    return session, cal, np.loadtxt(out, delimiter=",", skiprows=2)


@pytest.mark.parametrize("version", ["1.3", "1.2"])
def test_compiled_against_fusion_gives_what_imucal_apply_gives(tmp_path, calibrated, version):
    session, cal_path, applied = calibrated
    args = ["export", cal_path, "--format", "fusion"]
    if version != "1.3":
        args += ["--fusion-version", version]
    proc = run(*args)
    assert proc.returncode == 0, proc.stderr
    header = proc.stdout
    assert f"For Fusion {version}" in header and MODELS[version][0] in header
    exe = compile_program(tmp_path, version, header, inertial_body(version))
    s = read_session(session)
    raw = np.hstack([s.accel, s.gyro]).astype(np.float32)  # counts: exact in float32
    out = feed(exe, raw)
    cal = read_calibration(cal_path)
    # Fusion's units: g and deg/s
    want_a, want_g = applied[:, 1:4] / G0, np.degrees(applied[:, 4:7])
    tol_a = float32_bound(cal.accel.matrix / G0, s.accel, cal.accel.bias)
    tol_g = float32_bound(np.degrees(cal.gyro.matrix), s.gyro, cal.gyro.bias)
    assert np.all(np.abs(out[:, :3] - want_a) <= tol_a + 1e-9 * np.abs(want_a))
    assert np.all(np.abs(out[:, 3:] - want_g) <= tol_g + 1e-9 * np.abs(want_g))
    # the signal itself: a wrong layout was off by the whole of it (10.1 m/s^2, 5.4 rad/s)
    assert np.abs(want_a).max() > 0.9 and np.abs(want_g).max() > 10.0


@pytest.mark.parametrize("written, compiled", [("1.2", "1.3"), ("1.3", "1.2")])
def test_a_file_for_the_other_layout_does_not_compile(tmp_path, calibrated, written, compiled):
    _, cal_path, _ = calibrated
    header = run("export", cal_path, "--format", "fusion", "--fusion-version", written).stdout
    (tmp_path / "cal.h").write_text(header)
    (tmp_path / "main.c").write_text('#include "cal.h"\nint main(void) { return 0; }\n')
    proc = subprocess.run([GCC, "-std=c11", "-I", str(SOURCES[compiled]), "-c", "main.c"],
                          cwd=tmp_path, capture_output=True, text=True)  # fmt: skip
    assert proc.returncode != 0
    assert f"imucal export --fusion-version {compiled}" in proc.stderr


def test_magnetometer_compiled_against_fusion_gives_what_imucal_apply_gives(tmp_path):
    session, truth = simulate_mag("random:10", 1, hold_s=1.0, tumble_s=2.0)
    path = tmp_path / "mag.h5"
    write_session(path, session)
    cal = tmp_path / "cal.json"
    cal.write_text(__import__("imucal_cli.formats.calibration", fromlist=["x"])
                   .calibration_to_json(truth))  # fmt: skip
    out = tmp_path / "applied.csv"
    proc = run("apply", cal, path, "-o", out)
    assert proc.returncode == 0, proc.stderr
    applied = np.loadtxt(out, delimiter=",", skiprows=2)
    columns = open(out).readline().strip().split(",")
    want = applied[:, [columns.index(c) for c in ("mx", "my", "mz")]]
    for version in ("1.3", "1.2"):
        args = ["export", cal, "--format", "fusion", "--fusion-version", version]
        header = run(*args).stdout
        body = (
            "int main(void) {\n  FusionVector m, c;\n"
            '  while (scanf("%f %f %f", &m.array[0], &m.array[1], &m.array[2]) == 3) {\n'
            f"    c = {MODELS[version][1]}(m, softIronMatrix, hardIronOffset);\n"
            '    printf("%.9g %.9g %.9g\\n", (double)c.array[0], (double)c.array[1], '
            "(double)c.array[2]);\n  }\n  return 0;\n}\n"
        )
        exe = compile_program(tmp_path, version, header, body)
        raw = session.mag.astype(np.float32)
        got = feed(exe, raw)
        tol = float32_bound(truth.mag.matrix, raw.astype(float), truth.mag.bias)
        tol += EPS32 * np.abs(truth.mag.matrix @ (session.mag - truth.mag.bias).T).T  # f32 input
        assert np.all(np.abs(got - want) <= tol + 1e-9 * np.abs(want)), version


def test_g_sensitivity_is_refused_or_dropped_knowingly(tmp_path, calibrated):
    import json

    from imucal_cli.errors import InputError
    from imucal_cli.formats.exporters import ExportOptions
    from imucal_cli.use.export import export

    _, cal_path, _ = calibrated
    doc = json.loads(Path(cal_path).read_text())
    doc["gyro"]["g_sensitivity"] = [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.5]]
    gs = tmp_path / "gs.json"
    gs.write_text(json.dumps(doc))
    assert_one_line_error(run("export", gs, "--format", "fusion"), "--drop g-sensitivity")
    cal = read_calibration(gs)
    text = export(cal, "fusion", options=ExportOptions(drop=frozenset({"g-sensitivity"})))
    assert "g-sensitivity dropped" in text
    worst = float(text.split("up to ")[1].split(" rad/s")[0])
    assert worst == pytest.approx(np.linalg.norm(cal.gyro.matrix @ cal.gyro.g_sensitivity, 2)
                                  * G0, rel=1e-3)  # fmt: skip
    assert math.isfinite(worst)
    assert_one_line_error(run("export", gs, "--format", "fusion", "--drop", "bias"), "--drop")
    with pytest.raises(InputError, match="1.3 or 1.2"):
        export(read_calibration(cal_path), "fusion", options=ExportOptions(fusion_version="1.1"))
