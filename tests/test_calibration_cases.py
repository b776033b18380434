"""Issue 25.2: the calibration JSON stays as it was through the typed calibration model and
the solver registry: every plan's simulated session calibrates to the document recorded in
``tests/data/calibrations/`` (:mod:`tests.calibration_cases`: every member (a JSON object's
have no order), every text and integer, numbers within what another CPU's arithmetic moves
them, the solver's path (iterations, stop message, start) aside), and every stored
calibration reads and writes back unchanged.

The documents are compared as the fixture writer (``python -m tests.calibration_cases``)
writes them, into a temporary folder: a regeneration reproduces every committed fixture (no
fixture is out of step with its writer, as hand-edited ones were), and every committed file
is in the writer's form (sorted members, no volatile member), so that on the recording
machine's arithmetic a regeneration changes no file."""

from __future__ import annotations

import json
import shutil

import pytest

from tests.calibration_cases import (
    CASES,
    FIXTURES,
    VOLATILE,
    compare,
    differences,
    fixture_text,
    main,
    stored,
    write_case,
    write_stored,
)


def _fixture(name: str) -> dict:
    return json.loads((FIXTURES / f"{name}.json").read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_plan_calibrates_to_its_recorded_document(name, tmp_path):
    out = tmp_path / "fixtures"
    out.mkdir()
    written = write_case(name, tmp_path, out)
    assert [p.name for p in written] == [f"{name}.cal.json", f"{name}.truth.json"]
    assert compare(written) == []


def test_every_stored_calibration_reads_and_writes_back_unchanged(tmp_path):
    written = write_stored(tmp_path)
    assert len(written) >= 5  # four truths and a session's stored calibration
    assert compare(written) == []


def test_the_committed_fixtures_are_the_files_the_writer_writes():
    """Each case's two files and each stored calibration's, no other; each in the writer's
    form (a hand edit that reorders, reindents or keeps a volatile member is seen)."""
    names = {f"{c}.{k}.json" for c in CASES for k in ("cal", "truth")}
    names |= {f"{n}.json" for n in stored()}
    assert {p.name for p in FIXTURES.glob("*")} == names
    for path in sorted(FIXTURES.glob("*.json")):
        text = path.read_text(encoding="utf-8")
        doc = json.loads(text)
        assert not set(VOLATILE) & set(doc), path.name
        assert text == fixture_text(doc), f"{path.name}: not in the writer's form"


def test_the_check_sees_a_fixture_out_of_step(tmp_path, monkeypatch, capsys):
    """``--check`` writes nothing and passes on the committed fixtures; a number moved beyond
    the tolerance in a committed fixture fails it, and it says where."""
    import tests.calibration_cases as cases

    copy = tmp_path / "committed"
    shutil.copytree(FIXTURES, copy)
    monkeypatch.setattr(cases, "FIXTURES", copy)
    before = {p.name: p.read_bytes() for p in copy.iterdir()}
    assert main(["six", "--check"]) == 0
    assert capsys.readouterr().out == "the fixtures agree within the tolerance\n"
    assert {p.name: p.read_bytes() for p in copy.iterdir()} == before
    doc = json.loads((copy / "six.cal.json").read_text(encoding="utf-8"))
    doc["accel"]["matrix"][0][0] *= 1.05
    (copy / "six.cal.json").write_text(fixture_text(doc), encoding="utf-8")
    assert main(["six", "--check"]) == 1
    found = capsys.readouterr().out.splitlines()
    assert found and all(f.startswith("six.cal.json: .accel.matrix[0][0]") for f in found), found


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
