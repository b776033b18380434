"""Issue 9.3: turns of a known angle calibrate the gyro, including turns about the vertical that
gravity cannot see (the Ferraris 360-degree turns)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.errors import DesignError
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import Segment, Session, read_session
from tests.cli_helpers import run

FERRARIS = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "imucal_ferraris"
RATE = 100.0
FACES = [np.array(v, float) for v in ([1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1],
                                      [0, 0, -1])]  # fmt: skip


def _ferraris_like(seed: int, gyro_noise: float = 0.005):
    """Six faces held 3 s, then a turn of -360 deg about each of +X, +Y, +Z (flat on a table,
    the face up), raw counts; returns the session and the true (bias, matrix) of the gyro."""
    rng = np.random.default_rng(seed)
    M_a = np.eye(3) / 835.0 + rng.normal(0, 2e-6, (3, 3))
    b_a = rng.normal(0, 100, 3)
    M_g = np.eye(3) / 939.0 + rng.normal(0, 5e-6, (3, 3))
    b_g = rng.normal(0, 20, 3)
    blocks, segments, n0 = [], [], 0

    def add(kind, up, w, label, axis=None, angle=None):
        nonlocal n0
        n = len(w)
        f = np.tile(9.80665 * up, (n, 1)) + rng.normal(0, 0.01, (n, 3))
        acc = f @ np.linalg.inv(M_a).T + b_a
        gyr = (w + rng.normal(0, gyro_noise, (n, 3))) @ np.linalg.inv(M_g).T + b_g
        blocks.append((acc, gyr))
        segments.append(Segment(f"{len(segments):04d}", kind, n0, n0 + n, label=label,
                                up=up if kind == "static" else None, axis=axis,
                                angle_deg=angle))  # fmt: skip
        n0 += n

    for k, up in enumerate(FACES):
        add("static", up, np.zeros((int(3 * RATE), 3)), f"face {k}")
    for k in range(3):
        T = 3.0
        s = np.linspace(0, 1, int(T * RATE))
        rate = -2 * np.pi / T * 30 * s**2 * (1 - s) ** 2  # smootherstep's derivative
        add("rotation", FACES[2 * k], rate[:, None] * FACES[2 * k], f"turn {k}", FACES[2 * k],
            -360.0)  # fmt: skip
        add("static", FACES[2 * k], np.zeros((int(2 * RATE), 3)), f"after {k}")
    acc = np.vstack([b[0] for b in blocks])
    gyr = np.vstack([b[1] for b in blocks])
    session = Session(time=np.arange(len(acc)) / RATE, accel=acc, gyro=gyr, temperature=None,
                      segments=segments, created="2026-01-01T00:00:00Z", sample_rate_hz=RATE,
                      accel_units="counts", gyro_units="counts")  # fmt: skip
    return session, b_g, M_g


@pytest.mark.parametrize("seed", [1, 2])
def test_known_turns_calibrate_the_gyro_by_default_within_their_std(seed):
    session, b_true, M_true = _ferraris_like(seed)
    gyro = calibrate_session(session, Config()).gyro
    assert gyro is not None and gyro.solver == "gyro-known"
    assert gyro.choice.solver == "known" and gyro.warnings == []
    x = np.array([p.value for p in gyro.parameters[:12]])
    std = np.array([p.std for p in gyro.parameters[:12]])
    z = (x - np.r_[b_true, M_true.ravel()]) / std
    assert np.all(np.abs(z) < 4.5), z
    gains = np.linalg.norm(np.linalg.inv(M_true), axis=1)
    assert np.allclose(gyro.sensitivity, gains, rtol=5e-3)
    assert all(r.known_angle_deg == -360.0 for r in gyro.rotations)


def test_two_known_turns_cannot_determine_the_matrix():
    session, _, _ = _ferraris_like(3)
    turns = [s for s in session.segments if s.kind == "rotation"]
    session = replace(session, segments=[s for s in session.segments if s is not turns[-1]])
    cfg = Config()
    with pytest.raises(DesignError, match="three different axes"):
        calibrate_session(session, replace(cfg, gyro=replace(cfg.gyro, solver="known")))


def test_a_turn_about_the_vertical_without_a_labelled_axis_is_measured():
    """The accelerometer reads gravity along a turn about the vertical: its axis is measured."""
    session, b_true, M_true = _ferraris_like(4)
    segs = [replace(s, axis=None) if s.kind == "rotation" else s for s in session.segments]
    gyro = calibrate_session(replace(session, segments=segs), Config()).gyro
    assert any("measured vertical" in n for n in gyro.notes)
    gains = np.linalg.norm(np.linalg.inv(M_true), axis=1)
    assert np.allclose(gyro.sensitivity, gains, rtol=2e-2)


@pytest.mark.skipif(not FERRARIS.is_dir(), reason="../shared/data/imucal_ferraris absent")
def test_mad_lab_ferraris_session_calibrates_as_well_as_mad(tmp_path):
    """MaD Lab's example session (A): imported with its section list, calibrated with no
    config; on its five face-to-face moves (held out) the gravity direction the gyro predicts
    is as good as with MaD's own calibration (0.728 deg RMS, bench mad)."""
    from bench.mad import held_out
    from imucal_cli.formats.calibration import read_calibration

    h5 = tmp_path / "a.h5"
    proc = run("import", FERRARIS / "example_ferraris_session.csv", "--sections",
               FERRARIS / "example_ferraris_session_list.json", "--rate", "102.4",
               "--turn-angle", "-360", "-o", h5)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "a.cal.json"
    proc = run("calibrate", h5, "-o", out, "--no-store")
    assert proc.returncode == 0, proc.stderr
    cal = read_calibration(out)
    assert cal.gyro.solver == "gyro-known"
    err = held_out(read_session(h5), cal.accel.apply, lambda z, a: cal.gyro.apply(z, accel=a))
    assert len(err) == 5 and np.sqrt(np.mean(err**2)) < 0.75, err


@pytest.mark.skipif(not FERRARIS.is_dir(), reason="../shared/data/imucal_ferraris absent")
def test_annotated_session_agrees_with_mad_snapshot(tmp_path):
    """Session (B) with its ``part`` column: the gyro gains agree with MaD's stored result
    (``imucal_snapshot_example_cal.json``) within our stated std."""
    import json

    from imucal_cli.formats.calibration import read_calibration

    h5 = tmp_path / "b.h5"
    proc = run("import", FERRARIS / "annotated_session.csv", "--sections", "part", "--rate",
               "204.8", "--turn-angle", "-360", "-o", h5)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "b.cal.json"
    assert run("calibrate", h5, "-o", out, "--no-store").returncode == 0
    gyro = read_calibration(out).gyro
    snap = json.loads((FERRARIS / "imucal_snapshot_example_cal.json").read_text())
    mad = np.linalg.norm(np.asarray(snap["K_g"]) @ np.asarray(snap["R_g"]), axis=1)  # per deg/s
    ours = np.asarray(gyro.sensitivity) * np.pi / 180
    std = np.asarray(gyro.sensitivity_std) * np.pi / 180
    assert np.all(np.abs(ours - mad) < 3 * std), (ours, mad, std)


def test_gyro_refusals_name_what_the_session_already_has():
    """Issue 9.6 (gyro): the full model cannot use 360-degree turns without still data around
    them; its refusal names the known-angle solver for those turns, and where the angles are
    not stated, the labelling step that states them."""
    session, _, _ = _ferraris_like(5)
    cfg = Config()
    full = replace(cfg, gyro=replace(cfg.gyro, solver="full"))
    # without the still periods after the turns, none has still data before and after it
    moved = [s for s in session.segments if not s.label.startswith("after")]
    with pytest.raises(DesignError, match='solver = "known"'):
        calibrate_session(replace(session, segments=moved), full)
    unknown = [replace(s, angle_deg=None) for s in moved]
    with pytest.raises(DesignError, match="imucal label .* --angle DEG"):
        calibrate_session(replace(session, segments=unknown), full)
