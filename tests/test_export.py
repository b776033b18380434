"""`imucal export`: the C header compiles (gcc, strict C99) and applies the calibration as
numpy does in float32; imu_calib YAML; compact JSON; the CLI."""

from __future__ import annotations

import copy
import json
import math
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import calibration_from_json, write_calibration
from imucal_cli.formats.exporters import ExportOptions
from imucal_cli.formats.session import write_session
from imucal_cli.model.accel import AccelCalibration
from imucal_cli.model.calibration import Calibration, SensorCalibration
from imucal_cli.simulate.redundant import simulate_redundant_accel
from imucal_cli.simulate.triad import simulate
from imucal_cli.use.export import export, export_c_header, export_json, export_yaml
from tests.cli_helpers import IMUCAL, assert_one_line_error, run  # noqa: F401

GCC = shutil.which("gcc")
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wshadow", "-Wconversion",
          "-Wdouble-promotion"]  # fmt: skip
needs_gcc = pytest.mark.skipif(GCC is None, reason="gcc not installed")


@pytest.fixture(scope="module")
def sim():
    return simulate(seed=5, created="2026-01-01T00:00:00Z")


@pytest.fixture(scope="module")
def redundant():
    return simulate_redundant_accel(seed=3, created="2026-01-01T00:00:00Z")


def apply_float32(sec: SensorCalibration, raw: np.ndarray) -> np.ndarray:
    """What the header's function computes, in numpy float32: d = raw - b; sum M[i][j] d[j]."""
    m = sec.matrix.astype(np.float32)
    b = sec.bias.astype(np.float32)
    d = raw.astype(np.float32) - b
    out = np.empty((len(raw), 3), np.float32)
    for i in range(3):
        total = np.zeros(len(raw), np.float32)
        for j in range(b.shape[0]):
            total = total + m[i, j] * d[:, j]
        out[:, i] = total
    return out


def compile_program(tmp_path: Path, headers: dict[str, str], body: str) -> Path:
    """Write the headers and a main() around ``body``, compile with strict flags, return it."""
    includes = "".join(f'#include "{name}"\n' for name in headers)
    for name, text in headers.items():
        (tmp_path / name).write_text(text)
    source = tmp_path / "main.c"
    source.write_text(f"#include <stdio.h>\n{includes}\nint main(void)\n{{\n{body}\n}}\n")
    exe = tmp_path / "main"
    proc = subprocess.run([GCC, *CFLAGS, "-o", str(exe), str(source)], capture_output=True,
                          text=True, cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return exe


def apply_body(sensors: dict[str, int], prefix: str = "imucal") -> str:
    """main(): per line read each sensor's raw channels, print each sensor's 3 outputs."""
    decl, reads, calls, prints = [], [], [], []
    for name, n in sensors.items():
        decl.append(f"    float {name}_raw[{n}], {name}_out[3];")
        reads += [f'scanf("%f", &{name}_raw[{j}]) == 1' for j in range(n)]
        calls.append(f"        {prefix}_{name}_apply({name}_raw, {name}_out);")
        prints.append(
            f'        printf("%.9g %.9g %.9g ", (double){name}_out[0], (double){name}_out[1], '
            f"(double){name}_out[2]);"
        )
    return "\n".join(
        [*decl, "    for (;;) {", f"        if (!({' && '.join(reads)})) break;", *calls,
         *prints, '        printf("\\n");', "    }", "    return 0;"]
    )  # fmt: skip


def run_program(exe: Path, raw: np.ndarray) -> np.ndarray:
    text = "\n".join(" ".join(f"{float(v):.9g}" for v in row) for row in raw.astype(np.float32))
    proc = subprocess.run([str(exe)], input=text + "\n", capture_output=True, text=True,
                          timeout=60)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return np.array([[float(v) for v in line.split()] for line in proc.stdout.splitlines()])


def assert_within_ulps(c_out: np.ndarray, want32: np.ndarray, ulps: int = 4) -> None:
    """C printed ``%.9g`` of each float: read back as float32, it is that float exactly."""
    spacing = np.spacing(np.abs(want32)).astype(np.float64)
    err = np.abs(c_out.astype(np.float32).astype(np.float64) - want32.astype(np.float64))
    assert (err <= ulps * spacing).all(), (err / spacing).max()


def raw_samples(session, rng: np.random.Generator, k: int = 400) -> tuple:
    """Recorded samples plus off-grid values (fractional counts) to exercise rounding."""
    idx = rng.choice(len(session.time), k, replace=False)
    shape = (k, session.accel.shape[1])
    accel = np.vstack([session.accel[idx], session.accel[idx] + rng.uniform(-3, 3, shape)])
    gyro = None
    if session.gyro is not None:
        gyro = np.vstack([session.gyro[idx], session.gyro[idx] + rng.uniform(-3, 3, (k, 3))])
    return accel, gyro


# --------------------------------------------------------------------------------------------
# C header
# --------------------------------------------------------------------------------------------


def test_header_layout(sim):
    _, truth = sim
    text = export_c_header(truth)
    assert "#include" not in text and "malloc" not in text
    assert text.startswith("/*") and "#ifndef IMUCAL_CALIBRATION_H" in text
    assert text.rstrip().endswith("#endif /* IMUCAL_CALIBRATION_H */")
    for word in ("out = M (raw - b)", "m/s^2", "rad/s", "solver truth", "sim-16bit seed 5",
                 "2026-01-01T00:00:00Z", "imucal 0.1.0"):  # fmt: skip
        assert word in text, word
    for name in ("ACCEL", "GYRO"):
        assert f"static const float IMUCAL_{name}_MATRIX[3][IMUCAL_{name}_CHANNELS]" in text
        assert f"static const float IMUCAL_{name}_BIAS[IMUCAL_{name}_CHANNELS]" in text
        lower = name.lower()
        assert (
            f"static inline void imucal_{lower}_apply(const float raw[IMUCAL_{name}_CHANNELS], "
            "float out[3])"
        ) in text


def test_header_floats_round_trip_float32(sim):
    _, truth = sim
    text = export_c_header(truth)
    block = text.split("IMUCAL_ACCEL_BIAS[IMUCAL_ACCEL_CHANNELS] = {")[1].split("}")[0]
    values = [np.float32(v.strip().rstrip("f")) for v in block.split(",")]
    np.testing.assert_array_equal(values, truth.accel.bias.astype(np.float32))


@needs_gcc
def test_header_compiles_and_applies_like_numpy_float32(sim, tmp_path):
    session, truth = sim
    exe = compile_program(tmp_path, {"cal.h": export_c_header(truth)},
                          apply_body({"accel": 3, "gyro": 3}))  # fmt: skip
    accel, gyro = raw_samples(session, np.random.default_rng(0))
    c_out = run_program(exe, np.hstack([accel, gyro]))
    assert c_out.shape == (len(accel), 6)
    for cols, sec, raw in ((slice(0, 3), truth.accel, accel), (slice(3, 6), truth.gyro, gyro)):
        want32 = apply_float32(sec, raw)
        assert_within_ulps(c_out[:, cols], want32)
        # and float32 is close to the float64 model
        want64 = sec.apply(raw.astype(np.float32).astype(np.float64))
        assert np.abs(c_out[:, cols] - want64).max() < 1e-5 * np.abs(want64).max()


@needs_gcc
def test_header_carries_the_gyro_g_sensitivity(sim, tmp_path):
    """Issue 26: the header ignored g_sensitivity (0.0225 rad/s off imucal apply); now the gyro's
    apply takes the calibrated accelerometer vector, and gives what imucal apply gives."""
    session, truth = sim
    truth = copy.deepcopy(truth)
    truth.gyro.g_sensitivity = [[2.0, -0.5, 0.3], [0.4, 1.0, -0.2], [0.1, 0.6, 0.5]]
    header = export_c_header(truth)
    assert "IMUCAL_GYRO_G_SENSITIVITY[IMUCAL_GYRO_CHANNELS][3]" in header
    assert ("imucal_gyro_apply(const float raw[IMUCAL_GYRO_CHANNELS], const float accel[3], "
            "float out[3])") in header  # fmt: skip
    body = (
        "    float a[3], g[3], ca[3], cg[3];\n"
        '    while (scanf("%f %f %f %f %f %f", &a[0], &a[1], &a[2], &g[0], &g[1], &g[2]) == 6) {\n'
        "        imucal_accel_apply(a, ca);\n        imucal_gyro_apply(g, ca, cg);\n"
        '        printf("%.9g %.9g %.9g\\n", (double)cg[0], (double)cg[1], (double)cg[2]);\n'
        "    }\n    return 0;"
    )
    exe = compile_program(tmp_path, {"cal.h": header}, body)
    path, cal = tmp_path / "s.h5", tmp_path / "cal.json"
    write_session(path, session)
    write_calibration(cal, truth)
    out = tmp_path / "applied.csv"
    assert run("apply", cal, path, "-o", out).returncode == 0
    want = np.loadtxt(out, delimiter=",", skiprows=2)[:, 4:7]
    got = run_program(exe, np.hstack([session.accel, session.gyro]))
    without = (session.gyro - truth.gyro.bias) @ truth.gyro.matrix.T
    assert np.abs(want - without).max() > 0.01  # the term matters: over 0.01 rad/s
    # float32: relative 1e-6 of the terms summed (raw counts to 3e4, times 1e-3 rad/s)
    np.testing.assert_allclose(got, want, rtol=0, atol=3e4 * 1.1e-3 * 8 * 2.0**-24 * 4)


@needs_gcc
def test_redundant_four_channel_header(redundant, tmp_path):
    session, truth = redundant
    assert truth.accel.bias.shape == (4,) and truth.gyro is None
    text = export_c_header(truth)
    assert "#define IMUCAL_ACCEL_CHANNELS 4" in text and "GYRO" not in text
    exe = compile_program(tmp_path, {"cal.h": text}, apply_body({"accel": 4}))
    accel, _ = raw_samples(session, np.random.default_rng(1), k=min(200, len(session.time)))
    c_out = run_program(exe, accel)
    assert_within_ulps(c_out, apply_float32(truth.accel, accel))


@needs_gcc
def test_two_prefixes_in_one_program_and_one_sensor_used(sim, redundant, tmp_path):
    """Two units in one firmware: distinct prefixes do not collide; unused functions are fine."""
    headers = {
        "imu0.h": export_c_header(sim[1], prefix="IMU0"),
        "imu1.h": export_c_header(redundant[1], prefix="imu1"),
    }
    assert "IMU1_ACCEL_MATRIX" in headers["imu1.h"] and "imu1_accel_apply" in headers["imu1.h"]
    body = (
        "    float r3[3] = {100.0f, -200.0f, 8000.0f}, r4[4] = {1000.0f, 1000.0f, 900.0f, 1100.0f};"
        "\n    float a[3], b[3];\n    imu0_accel_apply(r3, a);\n    imu1_accel_apply(r4, b);\n"
        '    printf("%.9g %.9g\\n", (double)a[2], (double)b[0]);\n    return 0;'
    )
    exe = compile_program(tmp_path, headers, body)
    got = subprocess.run([str(exe)], capture_output=True, text=True).stdout.split()
    r3 = np.array([[100.0, -200.0, 8000.0]])
    r4 = np.array([[1000.0, 1000.0, 900.0, 1100.0]])
    assert_within_ulps(np.array([float(got[0])]), apply_float32(sim[1].accel, r3)[:, 2])
    assert_within_ulps(np.array([float(got[1])]), apply_float32(redundant[1].accel, r4)[:, 0])


@needs_gcc
def test_integral_and_extreme_values_are_float_literals(tmp_path):
    sec = SensorCalibration(
        "x", "m/s^2", [0.0, 1.0, -2.0], [[1, 0, 0], [0, 2.0, 1e-40], [0, 0, 3e37]]
    )
    text = export_c_header(Calibration(accel=sec))
    assert "{ 0.0f, 1.0f, -2.0f }" in text
    exe = compile_program(tmp_path, {"cal.h": text}, apply_body({"accel": 3}))
    raw = np.array([[1.0, 2.0, 3.0], [-4.0, 5.5, -2.0]])
    assert_within_ulps(run_program(exe, raw), apply_float32(sec, raw))


def test_value_beyond_float32_refused():
    sec = SensorCalibration("x", "m/s^2", [0.0, 0.0, 0.0], [[1e39, 0, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(InputError, match=r"accel.matrix\[0\]\[0\].*float32"):
        export_c_header(Calibration(accel=sec))


@pytest.mark.parametrize("prefix", ["", "9A", "_IMU", "my-imu", "IMU 0", "int", "a$b"])
def test_bad_prefix_refused(sim, prefix):
    with pytest.raises(InputError, match="--prefix"):
        export_c_header(sim[1], prefix=prefix)


def test_comment_text_cannot_end_the_comment(sim):
    _, truth = sim
    cal = Calibration(accel=truth.accel, session="a */ b.h5", created=truth.created,
                      sensor="evil */ int x; /* \n second line")  # fmt: skip
    text = export_c_header(cal)
    comment = text.split("#ifndef")[0]
    assert comment.count("*/") == 1 and comment.rstrip().endswith("*/")


# --------------------------------------------------------------------------------------------
# imu_calib YAML
# --------------------------------------------------------------------------------------------


#: The driver's scales of the simulated 16-bit part (8192 LSB/g, 16.4 LSB per deg/s), SI per count.
SCALES = {"accel": 9.80665 / 8192, "gyro": math.radians(1 / 16.4)}


def test_yaml_imu_calib_layout(sim):
    session, truth = sim
    text = export_yaml(truth, ExportOptions(scale=SCALES))
    doc = yaml.safe_load(text)
    assert set(doc) == {"SM", "bias", "gyro"}
    assert len(doc["SM"]) == 9 and len(doc["bias"]) == 3
    assert all(isinstance(v, float) for v in doc["SM"] + doc["bias"])
    # imu_calib's apply on what the driver publishes, p = scale * counts:
    # corrected = SM * p - bias, which is our model on the counts.
    for name, raw in (("accel", session.accel[:50]), ("gyro", session.gyro[:50])):
        d = doc if name == "accel" else doc["gyro"]
        sm, p = np.reshape(d["SM"], (3, 3)), SCALES[name] * raw
        want = getattr(truth, name).apply(raw, accel=truth.accel.apply(session.accel[:50]))
        np.testing.assert_allclose(p @ sm.T - d["bias"], want, rtol=1e-12,
                                   atol=1e-12 * np.abs(want).max())  # fmt: skip
    assert "calibrated = SM @ raw - bias" in text
    assert "calibrated = matrix @ (raw - bias)" in text
    assert "p = raw (counts) x 0.001197100830078125 m/s^2 per raw unit (--accel-scale)" in text


def test_yaml_honours_the_scale_and_refuses_counts_without_it(sim):
    _, truth = sim  # issue 26: the counts calibration was written as if the driver sent counts
    with pytest.raises(InputError, match="imu_calib reads accel in m/s\\^2.*--accel-scale"):
        export_yaml(truth)
    # the gyro's example is a gyro's, and unstated units are said as such (not "raw raw units")
    accel_only = ExportOptions(scale={"accel": SCALES["accel"]})
    with pytest.raises(InputError, match=r"--gyro-scale .*0\.0174533/131 for a 16-bit \+-250"):
        export_yaml(truth, accel_only)
    unstated = copy.deepcopy(truth)
    unstated.gyro.units_in = None
    with pytest.raises(InputError, match="takes raw units it does not state") as err:
        export_yaml(unstated, accel_only)
    assert "raw raw" not in str(err.value)
    half = yaml.safe_load(export_yaml(truth, ExportOptions(scale={k: v / 2 for k, v in
                                                                  SCALES.items()})))  # fmt: skip
    full = yaml.safe_load(export_yaml(truth, ExportOptions(scale=SCALES)))
    np.testing.assert_allclose(half["SM"], 2 * np.asarray(full["SM"]), rtol=1e-15)
    np.testing.assert_allclose(half["bias"], full["bias"], rtol=1e-12)


def test_yaml_refuses_a_g_sensitivity_it_cannot_hold(sim):
    truth = copy.deepcopy(sim[1])
    truth.gyro.g_sensitivity = [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.5]]
    with pytest.raises(InputError, match="g_sensitivity .* --format yaml cannot hold"):
        export(truth, "yaml", options=ExportOptions(scale=SCALES))
    text = export(truth, "yaml", options=ExportOptions(scale=SCALES,
                                                      drop=frozenset({"g-sensitivity"})))
    assert "gyro g-sensitivity dropped (imu_calib has none" in text


def test_yaml_small_numbers_read_as_floats():
    sec = AccelCalibration("x", "m/s^2", [1e-5, 0.0, 2.0], [[1e-5, 0, 0], [0, 1e20, 0], [0, 0, 1]],
                           units_in="m/s^2")  # fmt: skip
    doc = yaml.safe_load(export_yaml(Calibration(accel=sec)))
    assert all(isinstance(v, float) for v in doc["SM"] + doc["bias"])
    np.testing.assert_array_equal(doc["SM"], sec.matrix.ravel())


def test_yaml_refuses_redundant_unit_and_gyro_only(sim, redundant):
    with pytest.raises(InputError, match="4 raw channels.*3 x 3"):
        export_yaml(redundant[1])
    with pytest.raises(InputError, match="no accelerometer"):
        export_yaml(Calibration(gyro=sim[1].gyro))


# --------------------------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------------------------


def test_json_standard_fields_round_trip(sim):
    _, truth = sim
    truth = replace(truth, session="s.h5")
    truth.accel.residual_rms = 0.0123
    text = export_json(truth)
    assert text.count("\n") == 1 and text.endswith("\n") and ": " not in text
    doc = json.loads(text)
    assert list(doc) == ["format", "format_version", "session", "created", "accel", "gyro"]
    assert list(doc["accel"]) == ["solver", "units", "model", "bias", "matrix", "residual_rms"]
    back = calibration_from_json(text)
    for name in ("accel", "gyro"):
        a, b = getattr(truth, name), getattr(back, name)
        np.testing.assert_array_equal(a.bias, b.bias)
        np.testing.assert_array_equal(a.matrix, b.matrix)
        assert (a.solver, a.units, a.residual_rms) == (b.solver, b.units, b.residual_rms)
        assert set(b.to_dict()) == {"solver", "units", "model", "bias", "matrix",
                                    "residual_rms"}  # fmt: skip
        assert b.model == "calibrated = matrix @ (raw - bias)"
    assert (back.session, back.created) == ("s.h5", truth.created)
    assert set(back.to_dict()) == {"format", "format_version", "session", "created", "accel",
                                   "gyro"}  # fmt: skip
    assert export_json(back) == text  # stable


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def test_cli(sim, redundant, tmp_path):
    _, truth = sim
    cal = tmp_path / "cal.json"
    write_calibration(cal, truth)
    four = tmp_path / "four.json"
    write_calibration(four, redundant[1])

    proc = run("export", cal, "--format", "c-header", "--prefix", "BOARD")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == export(truth, "c-header", prefix="BOARD")

    proc = run("export", cal, "-o", tmp_path / "imu.yaml", "--accel-scale", "9.80665/8192",
               "--gyro-scale", str(SCALES["gyro"]))  # format from the suffix
    assert proc.returncode == 0 and proc.stdout == "", proc.stderr
    assert "wrote" in proc.stderr and "yaml" in proc.stderr
    scales = {"accel": 9.80665 / 8192, "gyro": float(str(SCALES["gyro"]))}
    assert (tmp_path / "imu.yaml").read_text() == export_yaml(truth, ExportOptions(scale=scales))

    proc = run("export", cal, "--format", "json", "-o", tmp_path / "c.txt")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "c.txt").read_text() == export_json(truth)

    assert_one_line_error(run("export", cal, "--format", "c-header", "--prefix", "1x"),
                          "--prefix")  # fmt: skip
    assert_one_line_error(run("export", cal, "--format", "yaml", "--prefix", "X"), "c-header")
    assert_one_line_error(run("export", four, "--format", "yaml"), "4 raw channels")
    # a driver's scale: finite and positive, and a gain some driver has (1e300 exported offsets
    # of 1e302 m/s^2 and scales of 0.0, exit 0, before the audit)
    for bad in ("-1", "0", "1/0", "nan", "1e300", "1e-300"):
        assert_one_line_error(run("export", cal, "-o", tmp_path / "bad.yaml", "--accel-scale",
                                  bad), "--accel-scale")  # fmt: skip
    assert not (tmp_path / "bad.yaml").exists()
    assert_one_line_error(run("export", cal, "--format", "xml"), "xml")
    assert_one_line_error(run("export", cal), "--format")
    assert_one_line_error(run("export", tmp_path / "none.json", "--format", "json"), "none.json")
