"""Issue 9.2: `imucal label` sets or corrects labels on an existing session: faces from the
measured direction (within a tolerance of a +-axis), one segment by hand, sensor, units and
gravity; /raw is never rewritten."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from imucal_cli.errors import InputError, SessionError
from imucal_cli.formats.session import Segment, read_session, rewrite_labels
from imucal_cli.use.labels import call_faces
from tests.cli_helpers import assert_one_line_error, run

ROOT = Path(__file__).resolve().parents[1]


def raw_digest(path: Path) -> str:
    h = hashlib.sha256()
    with h5py.File(path, "r") as f:
        for name in ("time", "accel", "gyro"):
            if f"raw/{name}" in f:
                h.update(np.ascontiguousarray(f[f"raw/{name}"][...]).tobytes())
    return h.hexdigest()


@pytest.fixture
def six(tmp_path):
    """The shipped six-face session with its labels removed."""
    path = tmp_path / "six.h5"
    shutil.copy(ROOT / "sessions" / "six-seed3.h5", path)
    s = read_session(path)
    truth = [seg.up for seg in s.static_segments()]
    bare = [Segment(name=g.name, kind=g.kind, start=g.start, stop=g.stop) for g in s.segments]
    rewrite_labels(path, bare)
    assert all(seg.up is None for seg in read_session(path).static_segments())
    return path, truth


def test_faces_from_measured_directions(six):
    path, truth = six
    before = raw_digest(path)
    proc = run("label", path, "--faces")
    assert proc.returncode == 0, proc.stderr
    assert "raw data untouched" in proc.stdout
    s = read_session(path)
    for seg, up in zip(s.static_segments(), truth, strict=True):
        np.testing.assert_array_equal(seg.up, up)
        assert seg.label.startswith("face ")
    assert raw_digest(path) == before


def test_faces_need_directions_that_can_be_told(six):
    path, _ = six
    s = read_session(path)
    s.accel_units = "counts"
    calls, basis = call_faces(s)
    assert "mid-range" in basis and all(c.up is not None for c in calls)
    # a tight tolerance leaves tilted poses unlabelled, never forced onto an axis
    tight, _ = call_faces(s, tolerance_deg=0.01)
    assert all(c.up is None for c in tight if c.off_deg > 0.01)
    with pytest.raises(InputError, match="between 0 and 45"):
        call_faces(s, tolerance_deg=60)


def test_one_segment_by_hand_and_root_labels(six):
    path, _ = six
    before = raw_digest(path)
    s = read_session(path)
    turn = next((g for g in s.segments if g.kind == "rotation"), None)
    args = ["--segment", "0000", "--up", "0,0,2", "--label", "flat", "--sensor", "BNO055 #17"]
    proc = run("label", path, *args, "--gravity", "9.81", "--accel-units", "counts")
    assert proc.returncode == 0, proc.stderr
    s2 = read_session(path)
    first = s2.segments[0]
    assert first.label == "flat" and list(first.up) == [0, 0, 1]
    assert (s2.sensor, s2.gravity, s2.accel_units) == ("BNO055 #17", 9.81, "counts")
    assert [(g.kind, g.start, g.stop) for g in s2.segments] == [
        (g.kind, g.start, g.stop) for g in s.segments
    ]
    assert raw_digest(path) == before
    if turn is not None:
        ok = run("label", path, "--segment", turn.name, "--axis", "1,0,0", "--angle", "-90")
        assert ok.returncode == 0, ok.stderr
        got = read_session(path).segments[int(turn.name)]
        assert got.angle_deg == -90.0 and list(got.axis) == [1, 0, 0]


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (("--segment", "9999", "--label", "x"), ["no segment '9999'"]),
        (("--up", "0,0,1"), ["pass --segment"]),
        (("--segment", "0000", "--up", "0,0"), ["3 numbers"]),
        (("--segment", "0000", "--angle", "90"), ["static", "not an axis or angle"]),
        # a known turn of 1e300 deg was stored, and calibrate's known-angle fit then printed a
        # traceback (audit)
        (("--segment", "0001", "--angle", "1e300"), ["--angle", "within +-3600"]),
        (("--accel-units", "furlongs"), ["counts"]),
        (("--gravity", "98.1"), ["9.78"]),
        ((), ["nothing to change"]),
    ],
)
def test_refusals_one_line(six, args, words):
    path, _ = six
    before = path.read_bytes()
    assert_one_line_error(run("label", path, *args), *words)
    assert path.read_bytes() == before


def test_rewrite_checks_ranges(six):
    path, _ = six
    s = read_session(path)
    bad = [Segment(name="0000", kind="static", start=0, stop=len(s.time) + 1)]
    with pytest.raises(SessionError, match="not within"):
        rewrite_labels(path, bad)
    with pytest.raises(SessionError, match="not a label"):
        rewrite_labels(path, s.segments, {"format": "x"})
    assert read_session(path).segments == s.segments
