"""Issue 25.2: the typed calibration model. Every member of every calibration this toolkit
writes is a typed field (nothing is left over in ``unknown``); a file is read forgivingly
beyond the spec's fields (a member this version does not know, or of the wrong type, is kept
and written back unchanged; a ``null`` stays ``null``); producers cannot add a member the
model does not have; the several-IMU ``imus`` of the spec reads and writes."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from imucal_cli.errors import CalibrationFileError
from imucal_cli.formats.calibration import calibration_from_json, calibration_to_json
from imucal_cli.model.accel import AccelCalibration, Coverage, PoseRow
from imucal_cli.model.calibration import Calibration, ImuEntry
from imucal_cli.model.codec import Record, build, encode, jsonable
from imucal_cli.model.gyro import GyroCalibration
from imucal_cli.model.parts import By, Choice
from imucal_cli.model.truth import AccelTruth
from tests.calibration_cases import FIXTURES, differences

CREATED = "2026-01-01T00:00:00Z"


def _unknown(obj, path: str, out: list[str]) -> None:
    """Paths of every member left in a record's ``unknown``."""
    if isinstance(obj, Record):
        out += [f"{path}.{k}" for k in obj.unknown]
        for f in dataclasses.fields(obj):
            if f.name not in ("unknown", "nulls"):
                _unknown(getattr(obj, f.name), f"{path}.{f.name}", out)
    elif isinstance(obj, list | tuple):
        for i, x in enumerate(obj):
            _unknown(x, f"{path}[{i}]", out)
    elif isinstance(obj, dict):
        for k, x in obj.items():
            _unknown(x, f"{path}.{k}", out)


@pytest.mark.parametrize("path", sorted(FIXTURES.glob("*.json")), ids=lambda p: p.stem)
def test_every_recorded_calibration_is_typed_through_and_writes_back(path):
    doc = json.loads(path.read_text(encoding="utf-8"))
    if "exit" in doc:
        pytest.skip("a case that saves nothing")
    doc.setdefault("created", CREATED)  # the fixtures leave out what changes from run to run
    cal = Calibration.from_dict(doc, path.name)
    left: list[str] = []
    _unknown(cal, "cal", left)
    assert left == []
    assert differences(jsonable(cal.to_dict()), doc, rel=0.0) == []


def test_sections_are_typed_by_sensor_and_solver():
    doc = json.loads((FIXTURES / "qureshi18.cal.json").read_text())
    doc["created"] = CREATED
    cal = Calibration.from_dict(doc)
    assert isinstance(cal.accel, AccelCalibration) and isinstance(cal.gyro, GyroCalibration)
    assert isinstance(cal.accel.coverage, Coverage) and cal.accel.coverage.n_distinct == 18
    assert isinstance(cal.accel.poses[0], PoseRow) and cal.accel.fit.converged is True
    assert cal.accel.choice == Choice("gravity", By.AUTO, cal.accel.choice.reason)
    truth = json.loads((FIXTURES / "qureshi18.truth.json").read_text())
    truth["created"] = CREATED
    assert isinstance(Calibration.from_dict(truth).accel, AccelTruth)


def _minimal(**accel) -> dict:
    return {"format": "imucal-calibration", "format_version": 1, "created": CREATED,
            "accel": {"solver": "gravity", "units": "m/s^2", "bias": [0.0, 0.0, 0.0],
                      "matrix": np.eye(3).tolist(), "residual_rms": None, **accel}}  # fmt: skip


def test_unknown_and_malformed_members_are_kept_and_written_back():
    doc = _minimal(later_version={"a": [1, 2]}, rms_after="not a number",
                   coverage={"fraction": 0.5, "n_poses": "six", "new": 1},
                   poses=[{"segment": "0001", "residual": 0.1, "why": "x"}], rms_loo=None)
    doc["root_later"] = True
    cal = Calibration.from_dict(doc)
    sec = cal.accel
    assert sec.rms_after is None and sec.unknown["rms_after"] == "not a number"
    assert sec.coverage.fraction == 0.5 and sec.coverage.n_poses is None
    assert sec.coverage.unknown == {"n_poses": "six", "new": 1}
    assert sec.poses[0].residual == 0.1 and sec.poses[0].unknown == {"why": "x"}
    assert sec.rms_loo is None and "rms_loo" in sec.nulls  # a null stays null
    back = jsonable(cal.to_dict())
    assert back["root_later"] is True
    a = back["accel"]
    assert a["later_version"] == {"a": [1, 2]} and a["rms_after"] == "not a number"
    assert a["rms_loo"] is None and a["coverage"] == {"fraction": 0.5, "n_poses": "six",
                                                      "new": 1}  # fmt: skip
    # a table's columns are written whether the row has them or not
    assert a["poses"][0]["residual"] == 0.1 and a["poses"][0]["why"] == "x"
    assert "rms_before" not in a  # absent stays absent


def test_the_spec_fields_stay_strict():
    with pytest.raises(CalibrationFileError, match="accel.bias must be a list"):
        Calibration.from_dict(_minimal(bias=[0, "x", 0]))
    with pytest.raises(CalibrationFileError, match="bias_tempco without temperature_ref"):
        Calibration.from_dict(_minimal(bias_tempco=[[0.0, 0.0, 0.0]]))
    with pytest.raises(CalibrationFileError, match="g_sensitivity in the accel section"):
        Calibration.from_dict(_minimal(g_sensitivity=np.eye(3).tolist()))


def test_build_takes_members_as_the_json_names_them_and_refuses_others():
    sec = build(AccelCalibration, solver="gravity", units="m/s^2", bias=np.zeros(3),
                matrix=np.eye(3), residual_rms=0.1, iterations=4, configuration="triad",
                rms_loo=None)  # fmt: skip
    assert sec.fit.iterations == 4 and sec.factorization.configuration == "triad"
    out = encode(sec)
    assert out["iterations"] == 4 and out["configuration"] == "triad" and out["rms_loo"] is None
    assert "rms_before" not in out and "fit" not in out and "factorization" not in out
    with pytest.raises(TypeError, match="no member 'rms_held_out'"):
        build(AccelCalibration, rms_held_out=0.1)  # the magnetometer's, not the accel's


def test_several_imus_read_and_write():
    doc = _minimal()
    other = {k: v for k, v in doc["accel"].items()}
    doc["imus"] = {"imu1": {"accel": other, "rotation_to_reference": np.eye(3).tolist(),
                            "rotation_std_deg": [0.01, 0.01, 0.02], "time_offset_s": 0.0031,
                            "time_offset_std_s": 0.0002}}  # fmt: skip
    cal = calibration_from_json(json.dumps(doc))
    imu = cal.imus["imu1"]
    assert isinstance(imu, ImuEntry) and isinstance(imu.accel, AccelCalibration)
    assert imu.time_offset_s == 0.0031 and imu.rotation_std_deg == [0.01, 0.01, 0.02]
    back = json.loads(calibration_to_json(cal))
    assert differences(back["imus"], doc["imus"], rel=0.0) == []
    doc["imus"]["imu1"]["accel"]["matrix"] = [[1.0]]
    with pytest.raises(CalibrationFileError, match=r"imus\.imu1\.accel\.matrix must be 3 rows"):
        calibration_from_json(json.dumps(doc))
