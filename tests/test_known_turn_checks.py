"""Issue 24.5: turns of a known angle are checked like every other fit.

A turn is integrated from rest to rest (a capture's segments cut a smooth turn's slow start
and end); the turns between still periods are weighed with the scatter they show, and left
out where they do not match the model; the known turns are judged against the rest of the
fit; a known turn whose axis no accelerometer frame holds never crashes the step."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bench.captured import FERRARIS_TOML, as_captured, ferraris_plan
from imucal_cli.calibrate.gyro.turn_windows import settle_turns
from imucal_cli.calibrate.session import calibrate_session, suspect_error
from imucal_cli.errors import DesignError
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.formats.session import read_session
from imucal_cli.simulate.play import simulate_plan
from tests.cli_helpers import run

CREATED = "2026-01-01T00:00:00Z"
FERRARIS = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "imucal_ferraris"
G_LEVEL = 5e-4  # rad/s per m/s^2, the g-sensitivity


@pytest.fixture(scope="module")
def plan(tmp_path_factory) -> str:
    return str(ferraris_plan(tmp_path_factory.mktemp("plan")))


def _captured(plan: str, seed: int, **options):
    session, truth = simulate_plan(plan, seed=seed, created=CREATED, **options)
    return as_captured(session, plan), truth


def _turn_integrals(session, truth, turns) -> tuple[np.ndarray, np.ndarray]:
    """Each turn's true rotation angle over its segment (rad: the norm of the true rate's
    integral, a full turn about any fixed axis is 2 pi) and that integral's noise std
    (the still periods' true-rate noise, integrated over the segment's samples)."""
    w = truth.gyro.apply(session.gyro)
    still = np.concatenate([w[s.start : s.stop] for s in session.static_segments()])
    sigma = float(np.sqrt(np.mean(np.var(still, axis=0))))
    dt = float(np.mean(np.diff(session.time)))
    angles = np.array([np.linalg.norm(np.trapezoid(w[r.start : r.stop], dx=dt, axis=0))
                       for r in turns])  # fmt: skip
    noise = np.array([sigma * dt * np.sqrt(r.stop - r.start) for r in turns])
    return angles, noise


def _cut_late(session, samples: int):
    """The session with each known turn started ``samples`` late and ended as many early, the
    still periods beside it stretched to meet it (a segmentation that takes a smooth turn's
    gentle ends for still, as the variance alone did before issue 27)."""
    segs = sorted(session.segments, key=lambda s: s.start)
    out = list(segs)
    for k, turn in enumerate(segs):
        if turn.kind != "rotation" or turn.angle_deg is None:
            continue
        out[k] = replace(turn, start=turn.start + samples, stop=turn.stop - samples)
        if k > 0 and out[k - 1].kind == "static" and out[k - 1].stop == turn.start:
            out[k - 1] = replace(out[k - 1], stop=turn.start + samples)
        if k + 1 < len(segs) and segs[k + 1].kind == "static" and segs[k + 1].start == turn.stop:
            out[k + 1] = replace(segs[k + 1], start=turn.stop - samples)
    return replace(session, segments=out)


def test_a_turn_is_integrated_from_rest_to_rest(plan):
    """The capture's segments integrate each smooth full turn within its noise (4 std, plus the
    gyro's quantisation; issue 27: the still periods no longer take its gentle ends). Segments
    that start it 0.2 s late and end it as early read short; given back the edges of the still
    periods that already move, each integrates to a full turn within its noise."""
    captured, truth = _captured(plan, seed=4)
    known = [s for s in captured.rotation_segments() if s.angle_deg is not None]
    assert len(known) == 3
    quantum = 4 * float(np.max(np.abs(truth.gyro.matrix)))  # 4 counts' worth of rate x 1 s
    angles, noise = _turn_integrals(captured, truth, known)
    assert np.all(np.abs(angles - 2 * np.pi) < 4 * noise + quantum), np.degrees(angles)
    session = _cut_late(captured, 20)
    known = [s for s in session.rotation_segments() if s.angle_deg is not None]
    cut, noise = _turn_integrals(session, truth, known)
    settled, note = settle_turns(session)
    assert note is not None and "integrated with the turn" in note
    whole, noise2 = _turn_integrals(
        session, truth, [s for s in settled.rotation_segments() if s.angle_deg is not None])
    assert np.all(np.abs(whole - 2 * np.pi) < 4 * noise2 + quantum), np.degrees(whole)
    assert np.any(np.abs(cut - 2 * np.pi) > 4 * noise + quantum), np.degrees(cut)


@pytest.mark.parametrize("seed", [1, 2])
def test_a_captured_ferraris_session_calibrates_within_its_std(plan, seed):
    """A g-sensitive part through the Ferraris protocol, segmented as a capture segments it:
    every fitted term within 4.5 std of the truth (21 terms, two sessions: a false alarm
    about 1e-4), the known turns within 3 of their stated std of 360 degrees, saved."""
    from bench.trust_gyro import _truth_x

    session, truth = _captured(plan, seed, g_sensitivity=G_LEVEL)
    cal = calibrate_session(session, Config())
    assert suspect_error(cal) is None, cal.gyro.warnings
    g = cal.gyro
    assert g.solver == "gyro-known" and g.g_sensitivity is not None
    est = np.array([p.value for p in g.parameters])
    std = np.array([p.std for p in g.parameters])
    x = _truth_x(cal, truth, np.asarray(truth.gyro.g_sensitivity))
    assert np.all(np.abs(est - x) < 4.5 * std), (est - x) / std
    for r in (r for r in g.rotations if r.known_angle_deg is not None):
        assert abs(r.angle_error_deg) < 3 * r.noise_deg, r


def _mislabelled(plan_text: str, folder: Path, true_deg: float, seed: int):
    """The Ferraris protocol with the turn about +Y really ``true_deg``, labelled 360."""
    path = folder / "turned.toml"
    path.write_text(plan_text.replace('label = "360 about +Y"\naxis = [0, 1, 0]\nangle_deg = 360',
                                      'label = "360 about +Y"\naxis = [0, 1, 0]\n'
                                      f"angle_deg = {true_deg:g}"))  # fmt: skip
    session, truth = _captured(str(path), seed)
    segs = [replace(s, angle_deg=360.0) if s.label == "360 about +Y" else s
            for s in session.segments]  # fmt: skip
    return replace(session, segments=segs)


def test_a_known_angle_off_by_degrees_is_stated(tmp_path):
    """A turn of 352 degrees labelled 360: 8 of its 1-degree std. The turns between the faces
    measure the y gain too, so the known turn disagrees with the rest and is said (a
    warning), not silently absorbed into the gains."""
    session = _mislabelled(FERRARIS_TOML, tmp_path, 352.0, seed=3)
    g = calibrate_session(session, Config()).gyro
    said = [w for w in g.warnings if "turns of known angle disagree" in w]
    assert said and "360 about +Y" in said[0], g.warnings
    assert g.known_turn_check.known_p_value < 1e-3


def test_a_known_angle_far_off_is_refused(tmp_path):
    """A turn of 340 degrees labelled 360: 20 std off, beyond [gyro] max_residual_ratio: not
    saved without --force."""
    session = _mislabelled(FERRARIS_TOML, tmp_path, 340.0, seed=3)
    cal = calibrate_session(session, Config())
    problem = suspect_error(cal)
    assert problem is not None and "turns of known angle disagree" in str(problem)


def test_turns_of_a_known_90_degrees_never_crash(tmp_path):
    """Issue 24.5: turns about x and y with +Z up labelled 90 degrees (qureshi-axes) while the
    accelerometer is calibrated by the gravity-magnitude solver, whose frame holds no label:
    every such turn is left out (a 60-degree turn about x is no longer taken for one about
    the vertical), and the gyro is calibrated by the turns between still periods, or refused
    in one line; never a traceback."""
    session, _ = simulate_plan("qureshi-axes:6", seed=1, created=CREATED)
    segs = [replace(s, angle_deg=90.0) if s.kind == "rotation" and s.axis is not None
            and abs(s.axis[2]) < 0.5 else s for s in session.segments]  # fmt: skip
    session = replace(session, segments=segs)
    for solver in ("auto", "known"):
        cfg = config_from_dict({"gyro": {"solver": solver}})
        try:
            cal = calibrate_session(session, cfg)
        except DesignError as exc:
            assert "\n" not in str(exc)
            continue
        notes = cal.gyro.notes
        assert any("neither about the vertical" in n for n in notes), notes
        assert cal.gyro.solver == "gyro-full"


def test_known_90_degree_turns_about_labelled_axes_calibrate(tmp_path):
    """Turns of a known 90 degrees about labelled axes, with an accelerometer from labelled
    poses (its frame is the labels'): used, each within 3 std of its angle."""
    steps = ['[[step]]\nkind = "static"\nlabel = "face +Z up"\nup = [0, 0, 1]']
    for axis, after in (("[1, 0, 0]", "[0, -1, 0]"), ("[0, 1, 0]", "[1, 0, 0]")):
        for _ in range(2):
            steps += [f'[[step]]\nkind = "rotation"\nlabel = "+90 about {axis}"\naxis = {axis}\n'
                      'angle_deg = 90', f'[[step]]\nkind = "static"\nlabel = "after"\nup = {after}',
                      f'[[step]]\nkind = "rotation"\nlabel = "-90 about {axis}"\naxis = {axis}\n'
                      'angle_deg = -90',
                      '[[step]]\nkind = "static"\nlabel = "face +Z up"\nup = [0, 0, 1]']
    steps += ['[[step]]\nkind = "rotation"\nlabel = "-90 about y"\naxis = [0, 1, 0]\n'
              'angle_deg = -90', '[[step]]\nkind = "static"\nlabel = "face -X up"\nup = [-1, 0, 0]']
    steps += ['[[step]]\nkind = "rotation"\nlabel = "+90 about z"\naxis = [0, 0, 1]\n'
              'angle_deg = 90', '[[step]]\nkind = "static"\nlabel = "face -X up"\nup = [-1, 0, 0]']
    path = tmp_path / "q90.toml"
    path.write_text("\n".join(steps) + "\n")
    session, _ = simulate_plan(str(path), seed=2, created=CREATED)
    g = calibrate_session(session, Config()).gyro
    known = [r for r in g.rotations if r.known_angle_deg is not None]
    assert g.solver == "gyro-known" and len(known) == 10
    assert all(abs(r.angle_error_deg) < 3 * r.noise_deg for r in known), known


@pytest.mark.skipif(not FERRARIS.is_dir(), reason="../shared/data/imucal_ferraris absent")
def test_mad_lab_session_labelled_by_hand_keeps_its_known_angles(tmp_path):
    """MaD Lab's session (A) imported without its section list and labelled with ``imucal
    label`` (faces, and each 360-degree turn's angle and axis): the 9 face-to-face moves miss
    the model by several times their noise with no pattern, and weighed in they moved the y
    gain 1.05 % off the known y turn (+3.8 degrees). They are said and left out: each known
    turn integrates to its angle within 2 of its std (1 degree)."""
    h5 = tmp_path / "a.h5"
    csv = FERRARIS / "example_ferraris_session.csv"
    proc = run("import", csv, "--rate", "102.4", "--accel-units", "m/s^2", "--gyro-units",
               "deg/s", "-o", h5)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert run("label", h5, "--faces").returncode == 0
    session = read_session(h5)
    full = [s for s in session.rotation_segments()
            if s.stop - s.start > 3 * 102.4]  # the three 360-degree turns last 3.4-3.6 s
    assert len(full) == 3
    for seg, axis in zip(full, ("1,0,0", "0,1,0", "0,0,1"), strict=True):
        proc = run("label", h5, "--segment", seg.name, "--angle", "-360", "--axis", axis)
        assert proc.returncode == 0, proc.stderr
    out = tmp_path / "a.cal.json"
    proc = run("calibrate", h5, "-o", out, "--no-store")
    assert proc.returncode == 0, proc.stderr
    from imucal_cli.formats.calibration import read_calibration

    g = read_calibration(out).gyro
    known = [r for r in g.rotations if r.known_angle_deg is not None]
    assert len(known) == 3
    assert all(abs(r.angle_error_deg) < 2 * r.noise_deg for r in known), known
    assert g.known_turn_check.turns_between_still_periods == "left out"
    assert any("left out" in w and "turns between still periods" in w
               for w in g.warnings)  # fmt: skip


def test_an_excess_only_where_the_turns_scatter_beyond_their_noise():
    """The turns between still periods get an excess only where their chi^2 is above its
    upper 1 % quantile: a positive-part estimate from a few turns is above zero half the time
    when there is none (captured Ferraris sessions: 97.5 % of the 95 % intervals held the
    truth with it)."""
    from types import SimpleNamespace

    from imucal_cli.calibrate.gyro.known_checks import significant_excess

    def own(chi2_total):
        return SimpleNamespace(tau=1e-3, gravity_redundancy=8.0,
                               gravity_chi2_stated=np.full(10, chi2_total / 10))  # fmt: skip

    assert significant_excess(own(12.0)) == 0.0  # within the noise (upper 1 %: 20.1)
    assert significant_excess(own(30.0)) == 1e-3  # beyond it: kept


def test_clean_captured_ferraris_turns_get_no_excess(plan):
    """No excess simulated: where the turns between still periods scatter as their stated
    noise says (level 0.8-1.0 in the accelerometer's frame), none is applied; seed 301's
    scatter 2.1 times the noise (the capture's cut of a turn) keeps one. Seed 306 keeps a
    small one (level 1.2; it was 1.4 while its accelerometer's placement came to 1.1 deg
    against the 2.0 placed: the holds either side of each turn on the table, one placement,
    counted as two agreeing repeats; now 1.8 deg, asserted below; the rule itself: the test
    above)."""
    for seed in (302, 303, 304, 305, 307, 308):
        session, _ = _captured(plan, seed)
        check = calibrate_session(session, Config()).gyro.known_turn_check
        assert check.turns_between_still_periods == "used"
        assert check.their_excess_deg == 0.0, (seed, check)
    cal = calibrate_session(_captured(plan, 306)[0], Config())
    assert 1.5 < cal.accel.placement.rms_deg < 2.5, cal.accel.placement
    check = calibrate_session(_captured(plan, 301)[0], Config()).gyro.known_turn_check
    assert check.their_level > 1.5 and check.their_excess_deg > 0.1, check
