"""Issue 25.2: the calibration JSON stays as it was through the typed calibration model and
the solver registry: every plan's simulated session calibrates to the document recorded in
``tests/data/calibrations/`` (:mod:`tests.calibration_cases`: every member (a JSON object's
have no order), every text and integer, numbers within what another CPU's arithmetic moves
them, the solver's path (iterations, stop message, start) aside), and every stored
calibration reads and writes back unchanged."""

from __future__ import annotations

import json

import pytest

from tests.calibration_cases import CASES, FIXTURES, differences, simulated, stored, strip


def _fixture(name: str) -> dict:
    return json.loads((FIXTURES / f"{name}.json").read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_plan_calibrates_to_its_recorded_document(name, tmp_path):
    cal, truth = simulated(name, tmp_path)
    assert differences(strip(cal), _fixture(f"{name}.cal")) == []
    assert differences(strip(truth), _fixture(f"{name}.truth")) == []


def test_every_stored_calibration_reads_and_writes_back_unchanged():
    docs = stored()
    assert len(docs) >= 5  # four truths and a session's stored calibration
    for name, doc in docs.items():
        assert differences(strip(doc), _fixture(name)) == [], name


def test_the_comparison_sees_a_changed_value_key_or_word():
    doc = _fixture("six.cal")
    assert differences(doc, json.loads(json.dumps(doc))) == []
    changed = json.loads(json.dumps(doc))
    changed["accel"]["matrix"][0][0] *= 1.05
    assert differences(doc, changed)[0].startswith(".accel.matrix[0][0]")
    changed = json.loads(json.dumps(doc))
    changed["accel"]["iterations"] += 1  # the solver's path, not its result
    assert differences(doc, changed) == []
    changed = json.loads(json.dumps(doc))
    changed["accel"]["moved"] = changed["accel"].pop("solver")
    assert "keys" in differences(doc, changed)[0]
    assert differences({"a": "left out 5 poses"}, {"a": "left out 6 poses"})
    assert differences({"a": "within 5.6 deg"}, {"a": "within 5.7 deg"}) == []
    assert differences({"a": "within 5.6 deg"}, {"a": "within 5.8 deg"})
    assert differences({"a": 1}, {"a": 1.0})
