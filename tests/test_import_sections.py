"""Issue 9.2: MaD Lab section lists and per-row labels become labelled segments (faces with
`up`, turns with axis and angle); a still period holding two poses is split (automatic) or
refused (labelled), never averaged."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.importers import import_files
from imucal_cli.formats.session import read_session
from tests.cli_helpers import assert_one_line_error, run

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "imucal_ferraris"
RATE = 100.0
G = 9.81


def ferraris_rows(rng, turn_sign=1.0, gap_s=2.0):
    """A synthetic Ferraris session: six faces, then three 360-degree turns, motion between;
    returns rows (t, ax, ay, az, gx, gy, gz) and the section list."""
    faces = {"x_p": (1, 0, 0), "x_a": (-1, 0, 0), "y_p": (0, 1, 0), "y_a": (0, -1, 0),
             "z_p": (0, 0, 1), "z_a": (0, 0, -1)}  # fmt: skip
    rows, sections, t = [], {}, 0.0

    def add(acc, gyr, n, label=None):
        nonlocal t
        start = len(rows)
        for _ in range(n):
            a = np.asarray(acc, float) * G + rng.normal(0, 0.01, 3)
            g = np.asarray(gyr, float) + rng.normal(0, 0.002, 3)
            rows.append([t, *a, *g])
            t += 1 / RATE
        if label:
            sections[label] = {"start": start, "end": len(rows)}

    for label, up in faces.items():
        add(up, (0, 0, 0), int(3 * RATE), label)
        add((0.5, 0.5, 0.7), (0.3, -0.2, 0.1), int(gap_s * RATE))  # moving to the next
    for k, axis in enumerate("xyz"):
        rate = np.zeros(3)
        rate[k] = turn_sign * 2 * np.pi / 4.0  # 360 degrees in 4 s
        up = np.zeros(3)
        up[k] = 1
        add(up, rate, int(4 * RATE), f"{axis}_rot")
        add(up, (0, 0, 0), int(1 * RATE))
    return np.array(rows), sections


def write(tmp_path, rows, header="t,ax,ay,az,gx,gy,gz", labels=None):
    path = tmp_path / "session.csv"
    lines = [header if labels is None else "part," + header]
    for i, r in enumerate(rows):
        body = ",".join(f"{v:.6f}" for v in r)
        lines.append(body if labels is None else f"{labels[i]},{body}")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_section_list_gives_faces_and_turns(tmp_path, sign):
    rows, sections = ferraris_rows(np.random.default_rng(1), turn_sign=sign)
    path = write(tmp_path, rows)
    listing = tmp_path / "list.json"
    listing.write_text(json.dumps(sections))
    session = import_files([path], "csv", sections=listing, accel_units="m/s^2")
    static, turns = session.static_segments(), session.rotation_segments()
    assert [s.label.split()[0] for s in static] == ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a"]
    for s in static:
        mean = session.accel[s.start : s.stop].mean(axis=0) / G
        np.testing.assert_allclose(mean, s.up, atol=0.01)  # up: what the accelerometer reads
        assert (s.start, s.stop) == (sections[s.label.split()[0]]["start"],
                                     sections[s.label.split()[0]]["end"])  # fmt: skip
    for s, axis in zip(turns, np.eye(3), strict=True):
        np.testing.assert_array_equal(s.axis, axis)
        assert s.angle_deg == 360.0 * sign  # the gyro's own sign
    assert len(session.import_notes) == 3
    stated = import_files([path], "csv", sections=listing, turn_angle_deg=-360.0)
    assert [s.angle_deg for s in stated.rotation_segments()] == [-360.0] * 3
    assert not stated.import_notes
    for absurd in (1e300, float("nan")):  # 1e300: calibrate's traceback; nan: the output named
        with pytest.raises(InputError, match="--turn-angle must be .* within"):
            import_files([path], "csv", sections=listing, turn_angle_deg=absurd)


def test_per_row_labels_and_cli(tmp_path):
    rows, sections = ferraris_rows(np.random.default_rng(2))
    labels = [""] * len(rows)
    for label, r in sections.items():
        labels[r["start"] : r["end"]] = [label] * (r["end"] - r["start"])
    keep = [i for i, lab in enumerate(labels) if lab]  # concatenated sections, as MaD Lab's
    path = write(tmp_path, rows[keep][:, 1:], "ax,ay,az,gx,gy,gz", [labels[i] for i in keep])
    out = tmp_path / "s.h5"
    proc = run("import", path, "--rate", RATE, "--sections", "part", "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "sign from the gyro" in proc.stdout
    session = read_session(out)
    assert len(session.static_segments()) == 6 and len(session.rotation_segments()) == 3
    # Without the labels the concatenated faces join with no motion between: split, not merged
    auto = import_files([path], "csv", rate_hz=RATE)
    # six faces; the three turns (each a steady 90 deg/s about the vertical: gravity and the
    # gyro's variance do not change) are no still periods (issue 27: before, they were three)
    turns = sum(r["end"] - r["start"] for k, r in sections.items() if k.endswith("_rot"))
    assert len(auto.static_segments()) == 6
    assert auto.static_segments()[-1].stop <= len(keep) - turns
    for s in auto.static_segments():
        a = auto.accel[s.start : s.stop]
        assert np.ptp(a, axis=0).max() < 1.0  # one pose each: no 9.8 m/s^2 jump inside


def test_a_section_holding_two_poses_is_refused(tmp_path):
    rows, sections = ferraris_rows(np.random.default_rng(3))
    sections["x_p"]["end"] = sections["x_a"]["end"]  # x_p now spans the move and x_a
    del sections["x_a"]
    path = write(tmp_path, rows)
    listing = tmp_path / "list.json"
    listing.write_text(json.dumps(sections))
    with pytest.raises(InputError, match="'x_p' .* holds a step at row"):
        import_files([path], "csv", sections=listing)
    proc = run("import", path, "--sections", listing, "-o", tmp_path / "o.h5")
    assert_one_line_error(proc, "two poses")


@pytest.mark.parametrize(
    ("content", "words"),
    [
        ("{", "not JSON"),
        ('{"x_p": [1, 2]}', "must be"),
        ('{"x_p": {"start": 5, "end": 5}}', "empty"),
        ('{"a": {"start": 0, "end": 50}, "b": {"start": 40, "end": 90}}', "overlap"),
        ('{"x_p": {"start": 0, "end": 99999}}', "go past"),
    ],
)
def test_bad_section_lists(tmp_path, content, words):
    rows, _ = ferraris_rows(np.random.default_rng(4))
    path = write(tmp_path, rows)
    listing = tmp_path / "list.json"
    listing.write_text(content)
    with pytest.raises(InputError, match=words):
        import_files([path], "csv", sections=listing)


def test_unknown_label_column(tmp_path):
    rows, _ = ferraris_rows(np.random.default_rng(5))
    path = write(tmp_path, rows)
    with pytest.raises(InputError, match="no column 'part'"):
        import_files([path], "csv", sections="part")


@pytest.mark.skipif(not DATA.is_dir(), reason="shared data absent")
def test_mad_lab_recordings():
    a = import_files([DATA / "example_ferraris_session.csv"], "csv", rate_hz=102.4,
                     sections=DATA / "example_ferraris_session_list.json")  # fmt: skip
    assert [s.start for s in a.static_segments()] == [540, 1620, 2814, 3740, 4522, 5376]
    assert [s.angle_deg for s in a.rotation_segments()] == [-360.0] * 3  # clockwise, as MaD's
    b = import_files([DATA / "annotated_session.csv"], "csv", rate_hz=204.8, sections="part")
    assert [s.n_samples for s in b.static_segments()] == [1061, 1028, 848, 734, 1044, 881]
    assert [s.angle_deg for s in b.rotation_segments()] == [360.0] * 3  # README: positive
    auto = import_files([DATA / "annotated_session.csv"], "csv", rate_hz=204.8)
    assert len(auto.static_segments()) == 6  # was 3: faces merged in pairs
