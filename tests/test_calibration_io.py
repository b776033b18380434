"""Calibration JSON: round trips, extra fields, apply(), and validation errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from imucal_cli.errors import CalibrationFileError, InputError
from imucal_cli.formats.calibration import (
    calibration_from_json,
    calibration_to_json,
    read_calibration,
    write_calibration,
)
from imucal_cli.model.accel import AccelCalibration, PoseRow
from imucal_cli.model.calibration import (
    FORMAT,
    FORMAT_VERSION,
    MODEL_EQUATION,
    Calibration,
    SensorCalibration,
)
from imucal_cli.model.codec import build
from imucal_cli.model.gyro import GyroCalibration

SPEC_EXAMPLE = """{
  "format": "imucal-calibration",
  "format_version": 1,
  "session": "bench3-unit17.h5",
  "created": "2026-11-21T10:00:00Z",
  "accel": {
    "solver": "gravity",
    "units": "m/s^2",
    "bias": [0.012, -0.031, 0.004],
    "matrix": [[1.006, -0.012, 0.019], [0.0, 1.007, 0.0005], [0.0, 0.0, 0.983]],
    "residual_rms": 0.0138
  },
  "gyro": {
    "solver": "gyro-dynamic",
    "units": "rad/s",
    "bias": [0.0008, -0.0011, 0.0009],
    "matrix": [[0.9754, 0, 0], [0, 0.983, 0], [0, 0, 0.9747]],
    "residual_rms": 0.002
  }
}"""


def make_calibration() -> Calibration:
    rng = np.random.default_rng(3)
    accel = build(
        AccelCalibration,
        solver="gravity",
        units="m/s^2",
        bias=rng.normal(size=4) * 10,  # a redundant unit: 4 raw channels
        matrix=rng.normal(size=(3, 4)),
        residual_rms=np.float64(0.0021),
        model=MODEL_EQUATION,
        variant="9-parameter",
        iterations=np.int64(7),
        converged=True,
        sensitivity=np.array([835.1, 830.2, 841.0]),
        rms_loo=float("nan"),
        poses=[PoseRow(segment="0000", up=(0, 0, 1), residual=0.0004)],
    )
    gyro = GyroCalibration("gyro-dynamic", "rad/s", [0.1, 0.2, 0.3], np.eye(3) * 0.98)
    return Calibration(
        accel=accel,
        gyro=gyro,
        session="bench3-unit17.h5",
        created="2026-11-21T10:00:00Z",
        sensor="BNO055 #17",
        toolkit_version="0.1.0",
        config={"init": "updown"},
    )


def test_spec_example_reads():
    cal = calibration_from_json(SPEC_EXAMPLE)
    assert cal.session == "bench3-unit17.h5" and cal.created == "2026-11-21T10:00:00Z"
    assert cal.accel.solver == "gravity" and cal.accel.units == "m/s^2"
    np.testing.assert_array_equal(cal.accel.bias, [0.012, -0.031, 0.004])
    assert cal.accel.matrix.shape == (3, 3) and cal.accel.residual_rms == 0.0138
    assert cal.gyro.matrix[1, 1] == 0.983
    standard = {"solver", "units", "bias", "matrix", "residual_rms"}
    assert set(cal.accel.to_dict()) == standard and set(cal.gyro.to_dict()) == standard
    assert set(cal.to_dict()) == {"format", "format_version", "session", "created", "accel",
                                  "gyro"}  # fmt: skip


def test_round_trip_preserves_everything(tmp_path):
    cal = make_calibration()
    path = tmp_path / "c.cal.json"
    write_calibration(path, cal)
    back = read_calibration(path)
    for name in ("accel", "gyro"):
        a, b = getattr(cal, name), getattr(back, name)
        assert (a.solver, a.units, a.residual_rms) == (b.solver, b.units, b.residual_rms)
        np.testing.assert_array_equal(a.bias, b.bias)
        np.testing.assert_array_equal(a.matrix, b.matrix)
    assert back.session == cal.session and back.created == cal.created
    assert (back.sensor, back.toolkit_version, back.config) == (
        cal.sensor, cal.toolkit_version, cal.config)  # fmt: skip
    accel = back.accel.to_dict()
    assert {k: v for k, v in accel.items() if k not in ("bias", "matrix")} == {
        "solver": "gravity",
        "units": "m/s^2",
        "residual_rms": 0.0021,
        "model": MODEL_EQUATION,
        "variant": "9-parameter",
        "iterations": 7,
        "converged": True,
        "sensitivity": [835.1, 830.2, 841.0],
        "rms_loo": None,  # NaN is written as null
        "poses": [{"segment": "0000", "label": None, "up": [0, 0, 1], "magnitude_before": None,
                   "residual": 0.0004, "residual_loo": None,
                   "angle_to_up_deg": None}],  # a table's columns are all written
    }  # fmt: skip
    assert back.accel.rms_loo is None and back.accel.fit.iterations == 7
    assert back.gyro.residual_rms is None
    # Writing what was read gives the same text.
    assert calibration_to_json(back) == calibration_to_json(calibration_from_json(
        calibration_to_json(cal)))  # fmt: skip


def test_json_layout():
    text = calibration_to_json(make_calibration())
    d = json.loads(text)
    assert list(d)[:4] == ["format", "format_version", "session", "created"]
    assert d["format"] == FORMAT and d["format_version"] == FORMAT_VERSION
    assert list(d["accel"])[:5] == ["solver", "units", "bias", "matrix", "residual_rms"]
    assert text.startswith('{\n  "format": "imucal-calibration"')  # indent 2
    assert "NaN" not in text


def test_only_one_sensor_and_no_session():
    cal = Calibration(gyro=SensorCalibration("gyro-dynamic", "rad/s", np.zeros(3), np.eye(3)))
    d = json.loads(calibration_to_json(cal))
    assert "accel" not in d and "session" not in d
    assert d["created"].endswith("Z")
    back = calibration_from_json(calibration_to_json(cal))
    assert back.accel is None and back.session is None


def test_apply_matches_the_model():
    rng = np.random.default_rng(5)
    sensor = make_calibration().accel
    raw = rng.normal(size=(50, 4)) * 1000
    expected = np.array([sensor.matrix @ (r - sensor.bias) for r in raw])
    np.testing.assert_allclose(sensor.apply(raw), expected, rtol=1e-12)
    np.testing.assert_allclose(sensor.apply(raw[7]), expected[7], rtol=1e-12)
    assert sensor.apply(raw).shape == (50, 3) and sensor.apply(raw[0]).shape == (3,)


def test_apply_wrong_channel_count():
    sensor = make_calibration().accel
    with pytest.raises(CalibrationFileError, match=r"4 raw channels .* shape \(10, 3\)"):
        sensor.apply(np.zeros((10, 3)))


def with_changes(change) -> str:
    d = json.loads(SPEC_EXAMPLE)
    change(d)
    return json.dumps(d)


def setter(path: str, value):
    def change(d):
        *parents, last = path.split(".")
        for key in parents:
            d = d[key]
        d[last] = value

    return change


def deleter(path: str):
    def change(d):
        *parents, last = path.split(".")
        for key in parents:
            d = d[key]
        del d[last]

    return change


def both_sections_gone(d):
    del d["accel"]
    d["gyro"] = None


BAD = {
    "invalid json": ('{\n  "format": "imucal-calibration",\n  "bias": [1, 2,]\n}',
                     "invalid JSON at line 3"),
    "not an object": ("[1, 2, 3]", "expected a JSON object, got list"),
    "format wrong": (with_changes(setter("format", "imucal-session")), "not an imucal calibration"),
    "format missing": (with_changes(deleter("format")), "format is None"),
    "version 2": (with_changes(setter("format_version", 2)), "unsupported format_version 2"),
    "version text": (with_changes(setter("format_version", "1")), "unsupported format_version"),
    "version true": (with_changes(setter("format_version", True)), "unsupported format_version"),
    "created missing": (with_changes(deleter("created")), "'created' is missing"),
    "session number": (with_changes(setter("session", 3)), "'session' must be a string"),
    "no sections": (with_changes(both_sections_gone), "no 'accel', 'gyro' or 'mag' calibration"),
    "section list": (with_changes(setter("accel", [1, 2])), "'accel' must be an object"),
    "solver missing": (with_changes(deleter("accel.solver")), "accel.solver is missing"),
    "solver number": (with_changes(setter("gyro.solver", 1)), "gyro.solver must be a string"),
    "units missing": (with_changes(deleter("gyro.units")), "gyro.units is missing"),
    "units wrong": (with_changes(setter("gyro.units", "deg/s")), "gyro.units is 'deg/s'"),
    "bias missing": (with_changes(deleter("accel.bias")), "accel.bias must be a list"),
    "bias short": (with_changes(setter("accel.bias", [0.0, 0.0])), "at least 3 finite numbers"),
    "bias text": (with_changes(setter("accel.bias", [0, "1", 0])), "accel.bias must be a list"),
    "bias null": (with_changes(setter("accel.bias", [0, None, 0])), "accel.bias must be a list"),
    "bias nan": (SPEC_EXAMPLE.replace("0.012, -0.031", "NaN, -0.031"), "accel.bias must be"),
    "matrix missing": (with_changes(deleter("gyro.matrix")), "gyro.matrix must be 3 rows of 3"),
    "matrix 2 rows": (with_changes(setter("accel.matrix", [[1, 0, 0], [0, 1, 0]])),
                      "accel.matrix must be 3 rows"),
    "matrix ragged": (with_changes(setter("accel.matrix", [[1, 0, 0], [0, 1], [0, 0, 1]])),
                      "accel.matrix must be 3 rows"),
    "matrix vs bias": (with_changes(setter("accel.bias", [0, 0, 0, 0])),
                       "accel.matrix must be 3 rows of 4 finite numbers"),
    "matrix infinite": (SPEC_EXAMPLE.replace("0.9754", "Infinity"), "gyro.matrix must be"),
    "rms text": (with_changes(setter("accel.residual_rms", "small")), "accel.residual_rms must"),
    "rms nan": (SPEC_EXAMPLE.replace("0.0138", "NaN"), "accel.residual_rms must be a finite"),
}  # fmt: skip


@pytest.mark.parametrize("text, message", BAD.values(), ids=BAD.keys())
def test_validation_errors(tmp_path, text, message):
    path = tmp_path / "bad.cal.json"
    path.write_text(text)
    with pytest.raises(CalibrationFileError) as info:
        read_calibration(path)
    assert isinstance(info.value, InputError)
    assert str(info.value).startswith(f"{path}: ")
    assert "\n" not in str(info.value)
    assert message in str(info.value)


def test_from_dict_names_its_source():
    with pytest.raises(CalibrationFileError, match="^<dict>: "):
        Calibration.from_dict({})
    with pytest.raises(CalibrationFileError, match="^run3: "):
        calibration_from_json("{", source="run3")


def test_read_errors_for_files(tmp_path):
    (tmp_path / "binary.json").write_bytes(b"\x00\xff\xfe\x89")
    (tmp_path / "session.json").write_bytes(b"\x89HDF\r\n\x1a\n\xff\xfe")
    cases = {
        tmp_path / "missing.json": "no such file",
        tmp_path: "is a directory, not a calibration file",
        tmp_path / "binary.json": "not a text (UTF-8) file",
        tmp_path / "session.json": "an HDF5 file (a session?), not a calibration file",
    }
    for path, message in cases.items():
        with pytest.raises(CalibrationFileError) as info:
            read_calibration(path)
        assert str(info.value) == f"{path}: {message}"


def test_write_refuses_a_calibration_it_could_not_read_back(tmp_path):
    path = tmp_path / "c.json"
    cal = make_calibration()
    cal.accel.bias[0] = np.nan
    with pytest.raises(CalibrationFileError, match=f"^{path}: accel.bias"):
        write_calibration(path, cal)
    assert not path.exists()
    with pytest.raises(InputError, match="missing-dir does not exist"):
        write_calibration(tmp_path / "missing-dir" / "c.json", make_calibration())
