"""Issue 17.1: a temperature-dependent bias read, applied and exported (C header, PX4 TC_*,
ArduPilot INS_TCAL*); formats that cannot hold it refuse it."""

import copy
import json
import math
import re
import shutil
import subprocess

import numpy as np
import pytest

from imucal_cli.errors import CalibrationFileError, InputError
from imucal_cli.formats.calibration import calibration_to_json
from imucal_cli.formats.exporters import ExportOptions
from imucal_cli.formats.exporters.c_header import export_c_header
from imucal_cli.formats.session import write_session
from imucal_cli.model.calibration import Calibration
from imucal_cli.simulate.temperature import Ramp
from imucal_cli.simulate.triad import simulate
from imucal_cli.use.apply import apply_calibration
from imucal_cli.use.export import export

from .cli_helpers import assert_one_line_error, run

G0 = 9.80665
GCC = shutil.which("gcc")
SCALE = {"accel": G0 / 16384.0, "gyro": math.radians(1.0) / 131.0}


@pytest.fixture(scope="module")
def warm():
    """A six-pose session through a 5 -> 40 C ramp and its truth (with temperature terms)."""
    session, truth = simulate(seed=21, plan="six", temperature=Ramp(5.0, 40.0, "linear"),
                              created="2026-01-01T00:00:00Z")  # fmt: skip
    for name in ("accel", "gyro"):
        getattr(truth, name).temperature_range_c = [5.0, 40.0]
    return session, truth


def _static_magnitudes(session, values):
    return np.concatenate([np.linalg.norm(values[s.start : s.stop], axis=1)
                           for s in session.static_segments()])  # fmt: skip


def test_apply_uses_the_temperature_and_needs_it(warm):
    session, truth = warm
    with_t = truth.accel.apply(session.accel, temperature=session.temperature)
    without = truth.accel.apply(session.accel, temperature=np.full(len(session.time), 25.0))
    err_with = np.abs(_static_magnitudes(session, with_t) - G0).mean()
    err_without = np.abs(_static_magnitudes(session, without) - G0).mean()
    assert err_with < 0.01 and err_without > 3 * err_with
    # the bias at the reference temperature is the plain bias
    np.testing.assert_allclose(truth.accel.bias_at(25.0)[0], truth.accel.bias)
    with pytest.raises(CalibrationFileError, match="needs the temperature"):
        truth.accel.apply(session.accel)


@pytest.mark.parametrize("change,match", [
    ({"bias_tempco": None}, "temperature_ref without bias_tempco"),
    ({"temperature_ref": None}, "bias_tempco without temperature_ref"),
    ({"bias_tempco": [[1.0, 2.0]]}, "bias_tempco must be a list of vectors of 3"),
    ({"temperature_ref": "hot"}, "temperature_ref must be a finite number"),
    ({"sample_clock_scale": 0.0}, "sample_clock_scale must be"),
])  # fmt: skip
def test_malformed_terms_are_refused_on_reading(warm, change, match):
    doc = json.loads(calibration_to_json(warm[1]))
    for key, value in change.items():
        if value is None:
            doc["accel"].pop(key)
        else:
            doc["accel"][key] = value
    with pytest.raises(CalibrationFileError, match=match):
        Calibration.from_dict(doc, "x.json")


def test_apply_command_compensates_and_refuses_a_session_without_temperature(warm, tmp_path):
    session, truth = warm
    (tmp_path / "cal.json").write_text(calibration_to_json(truth))
    write_session(tmp_path / "warm.h5", session)
    out = tmp_path / "out.csv"
    proc = run("apply", tmp_path / "cal.json", tmp_path / "warm.h5", "-o", out)
    assert proc.returncode == 0, proc.stderr
    rows = np.loadtxt(out, delimiter=",", comments="#", skiprows=1)
    np.testing.assert_allclose(
        rows[:, 1:4], truth.accel.apply(session.accel, temperature=session.temperature),
        rtol=1e-8, atol=1e-8)  # fmt: skip
    cold = copy.deepcopy(session)
    cold.temperature = None
    write_session(tmp_path / "cold.h5", cold)
    assert_one_line_error(run("apply", tmp_path / "cal.json", tmp_path / "cold.h5", "-o",
                              tmp_path / "o2.csv"), "no temperature", "bias_tempco")  # fmt: skip


def test_apply_corrects_times_by_the_sample_clock(warm, tmp_path):
    session, truth = warm
    cal = copy.deepcopy(truth)
    for name in ("accel", "gyro"):
        getattr(cal, name).sample_clock_scale = 1.005
    write_session(tmp_path / "s.h5", session)
    summary = apply_calibration(cal, tmp_path / "s.h5", tmp_path / "o.csv")
    assert summary.clock_scale == 1.005
    t = np.loadtxt(tmp_path / "o.csv", delimiter=",", comments="#", skiprows=1)[:, 0]
    np.testing.assert_allclose(t - t[0], (session.time - session.time[0]) / 1.005, atol=1e-9)


def _c_apply_program(tmp_path, header, n_rows):
    (tmp_path / "cal.h").write_text(header)
    src = tmp_path / "main.c"
    src.write_text(
        '#include <stdio.h>\n#include "cal.h"\nint main(void)\n{\n'
        "    float raw[3], t, out[3];\n"
        '    while (scanf("%f %f %f %f", &raw[0], &raw[1], &raw[2], &t) == 4) {\n'
        "        imucal_accel_apply(raw, t, out);\n"
        '        printf("%.9g %.9g %.9g\\n", (double)out[0], (double)out[1], (double)out[2]);\n'
        "    }\n    return 0;\n}\n"
    )
    exe = tmp_path / "main"
    proc = subprocess.run([GCC, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-o",
                           str(exe), str(src)], capture_output=True, text=True)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return exe


@pytest.mark.skipif(GCC is None, reason="gcc not installed")
def test_c_header_applies_the_temperature_dependent_bias(warm, tmp_path):
    session, truth = warm
    header = export_c_header(truth)
    assert "IMUCAL_ACCEL_TEMPCO[IMUCAL_ACCEL_TEMPCO_ORDER][IMUCAL_ACCEL_CHANNELS]" in header
    assert "#define IMUCAL_ACCEL_TEMPERATURE_MIN_C 5.0f" in header
    exe = _c_apply_program(tmp_path, header, 200)
    idx = np.linspace(0, len(session.time) - 1, 200).astype(int)
    raw, temp = session.accel[idx], session.temperature[idx]
    rows = np.column_stack([raw, temp])
    text = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in rows)
    proc = subprocess.run([str(exe)], input=text + "\n", capture_output=True, text=True,
                          timeout=60)  # fmt: skip
    out = np.array([[float(v) for v in line.split()] for line in proc.stdout.splitlines()])
    want = truth.accel.apply(raw, temperature=temp)
    np.testing.assert_allclose(out, want, atol=2e-4)  # float32 arithmetic


def _params(text, sep):
    pairs = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        parts = line.split(sep)
        name, value = (parts[2], parts[3]) if sep == "\t" else (parts[0], parts[1])
        pairs[name] = float(value)
    return pairs


def _si_truth(truth, name, raw, temp):
    """What a driver publishing SI (p = factor raw) should see corrected (before the matrix):
    p minus the published bias at each temperature, in SI units."""
    sec = getattr(truth, name)
    return (raw - sec.bias_at(temp)) * SCALE[name]


@pytest.mark.parametrize("name,key", [("accel", "A"), ("gyro", "G")])
def test_px4_thermal_parameters_reproduce_the_bias(warm, name, key):
    session, truth = warm
    text = export(truth, "px4", options=ExportOptions(scale=SCALE, device_id=7))
    p = _params(text, "\t")
    assert p[f"TC_{key}_ENABLE"] == 1 and p[f"TC_{key}0_ID"] == 7
    assert (p[f"TC_{key}0_TMIN"], p[f"TC_{key}0_TMAX"]) == (5.0, 40.0)
    raw = getattr(session, name)[::97]
    temp = session.temperature[::97]
    off_key = "CAL_ACC0" if name == "accel" else "CAL_GYRO0"
    dT = np.clip(temp, p[f"TC_{key}0_TMIN"], p[f"TC_{key}0_TMAX"]) - p[f"TC_{key}0_TREF"]
    corrected = raw * SCALE[name]
    for i, axis in enumerate("XYZ"):  # PX4: p - thermal offset - CAL offset
        thermal = sum(p[f"TC_{key}0_X{k}_{i}"] * dT**k for k in range(4))
        corrected[:, i] -= thermal + p[f"{off_key}_{axis}OFF"]
    np.testing.assert_allclose(corrected, _si_truth(truth, name, raw, temp), atol=1e-9)


@pytest.mark.parametrize("name,key,cal", [("accel", "ACC", "INS_ACC1_CALTEMP"),
                                          ("gyro", "GYR", "INS_GYR1_CALTEMP")])
def test_ardupilot_tcal_parameters_reproduce_the_bias(warm, name, key, cal):
    session, truth = warm
    p = _params(export(truth, "ardupilot", options=ExportOptions(scale=SCALE)), ",")
    assert p["INS_TCAL1_ENABLE"] == 1
    raw = getattr(session, name)[::97]
    temp = session.temperature[::97]
    lo, hi = p["INS_TCAL1_TMIN"], p["INS_TCAL1_TMAX"]

    def poly(x):  # ArduPilot's polynomial_eval, coefficients x 1e6
        c = [np.array([p[f"INS_TCAL1_{key}{k}_{a}"] for a in "XYZ"]) for k in (1, 2, 3)]
        return (c[0] + (c[1] + c[2] * x[:, None]) * x[:, None]) * x[:, None] * 1e-6

    corrected = raw * SCALE[name]
    corrected = corrected - poly(np.clip(temp, lo, hi) - 35.0)
    corrected = corrected + poly(np.clip(np.full(len(temp), p[cal]), lo, hi) - 35.0)
    offs = "INS_ACCOFFS" if name == "accel" else "INS_GYROFFS"
    corrected -= np.array([p[f"{offs}_{a}"] for a in "XYZ"])
    np.testing.assert_allclose(corrected, _si_truth(truth, name, raw, temp), atol=1e-9)


@pytest.mark.parametrize("fmt", ["kalibr", "basalt", "yaml", "fusion"])
def test_formats_that_cannot_hold_the_terms_refuse(warm, fmt):
    with pytest.raises(InputError, match=r"bias_tempco.*c-header"):
        export(warm[1], fmt, options=ExportOptions(scale=SCALE))


def test_json_export_keeps_the_terms(warm):
    doc = json.loads(export(warm[1], "json"))
    assert doc["accel"]["temperature_ref"] == 25.0
    assert len(doc["accel"]["bias_tempco"]) == 3
    assert re.search("bias_tempco", export(warm[1], "json"))
