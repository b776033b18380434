"""Issue 24.2 and 24.5: a gyro clipped during fast turns.

Turns that reach the gyro's range (the end of its ADC word, or a flat top below it: a part
whose range ends within its word, whatever the word's width) are named as clipped and left
out; the other turns still calibrate it (said, not refused), and where none is left the gyro
is left out with that reason and the capture that would add it, the accelerometer saved
(exit 0, ``complete`` false)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from imucal_cli.calibrate.common import with_segments
from imucal_cli.calibrate.gyro.rotations import _flat_tops
from imucal_cli.calibrate.session import calibrate_session, suspect_error
from imucal_cli.design.clipping import flat_top_levels
from imucal_cli.formats.config import Config
from imucal_cli.formats.session import write_session
from imucal_cli.simulate.play import simulate_plan

from .cli_helpers import run

CREATED = "2026-01-01T00:00:00Z"
INT16 = (-32768.0, 32767.0)


@pytest.fixture(scope="module")
def q18():
    return simulate_plan("qureshi18", seed=1, created=CREATED)[0]


def _clipped(session, scale: float = 1.0, level: float | None = None, axes=(0, 1, 2)):
    """The session's gyro times ``scale`` (a more sensitive part, turned as fast) in whole
    counts, clipped at the int16 word, and ``axes`` at +-``level`` (a part whose range ends
    within its word)."""
    z = np.clip(np.round(session.gyro * scale), *INT16)
    if level is not None:
        for a in axes:
            z[:, a] = np.clip(z[:, a], -level, level)
    return replace(session, gyro=z)


def _calibrate_cli(tmp_path, session):
    h5, out = tmp_path / "s.h5", tmp_path / "s.cal.json"
    write_session(h5, session)
    proc = run("calibrate", h5, "-o", out, "--no-store")
    return proc, (json.loads(out.read_text()) if out.exists() else None)


def test_turns_clipped_at_the_int16_word_are_left_out_and_the_rest_calibrate(q18, tmp_path):
    """A part 12 times as sensitive turned as fast: 7 of the 17 turns reach +-32767. They are
    named and left out (said, not refused: exit 0); the other 10 calibrate the gyro, within
    1 % of the unclipped session's gains times 12 (it was refused, nothing saved, before)."""
    clean = calibrate_session(q18, Config()).gyro
    session = _clipped(q18, 12.0)
    proc, cal = _calibrate_cli(tmp_path, session)
    assert proc.returncode == 0, proc.stderr
    g = cal["gyro"]
    said = [w for w in g["warnings"] if "reach the end of the gyro's range" in w]
    assert said and "-32768 .. 32767" in said[0] and "more slowly" in said[0], g["warnings"]
    assert len(g["rotations"]) < len(clean.rotations)
    assert np.allclose(g["sensitivity"], 12 * np.asarray(clean.sensitivity), rtol=0.01)
    assert cal["accel"] is not None


def test_every_turn_clipped_leaves_the_gyro_out_and_saves_the_accel(q18, tmp_path):
    """Every turn beyond the int16 word: the accelerometer is saved (exit 0, ``complete``
    false), the gyro left out naming the clipping and what would add it."""
    proc, cal = _calibrate_cli(tmp_path, _clipped(q18, 40.0))
    assert proc.returncode == 0, proc.stderr
    assert cal["complete"] is False and cal.get("gyro") is None and cal["accel"] is not None
    note = cal["left_out"]["gyro"]
    assert "end of the gyro's range" in note and "more slowly" in note, note
    assert "gyro left out" in proc.stdout


def test_an_axis_clipped_within_its_word_is_named_as_clipping(q18):
    """Gyro x clipped at +-1500 counts (a part whose range ends within the 16-bit word): the
    flat tops are found and the turns that reach them left out, named as clipping; the rest
    calibrate the gyro and nothing blames a wrong time base (before: refused with 'gravity
    residuals 108 times ... a wrong time base')."""
    cal = calibrate_session(_clipped(q18, level=1500.0, axes=(0,)), Config())
    assert suspect_error(cal) is None, cal.gyro.warnings
    text = " ".join(cal.gyro.warnings)
    assert "x -1500 .. 1500" in text and "time base" not in text, text


def test_every_axis_clipped_within_its_word_leaves_the_gyro_out_as_clipped(q18):
    """All three axes clipped at +-1500 counts: every turn reaches the range, the gyro is left
    out with that reason (not 'too few or too small turns'), the accelerometer kept."""
    cal = calibrate_session(_clipped(q18, level=1500.0), Config())
    assert cal.gyro is None and cal.accel is not None and cal.complete is False
    note = cal.left_out["gyro"]
    assert "-1500 .. 1500" in note and "more slowly" in note and "too few" not in note, note


@pytest.mark.parametrize("plan", ["qureshi18", "qureshi-axes:9", "ferraris", "free:8"])
@pytest.mark.parametrize("units", ["counts", "m/s^2"])
def test_no_flat_top_in_a_gyro_that_did_not_clip(plan, units):
    """Clean simulated sessions (counts, and unquantised rad/s): no channel is taken for
    clipped (a count a quiet gyro repeats at a turn's peak is not a flat top)."""
    for seed in (0, 1):
        session, _ = simulate_plan(plan, seed=seed, created=CREATED, units=units)
        low, high = _flat_tops(with_segments(session)[0])
        assert np.all(np.isinf(low)) and np.all(np.isinf(high)), (seed, low, high)


def test_flat_tops_of_an_unquantised_stream():
    """A rad/s stream of a part clipped at +-2 rad/s in y (float, no counts, no ADC word):
    the flat tops are found at both signs, in y only."""
    t = np.arange(0, 20, 0.01)
    rng = np.random.default_rng(0)
    w = np.zeros((len(t), 3))
    moving = (t % 5) > 2.5
    w[:, 1] = np.where(moving, 3.0 * np.sin(2 * np.pi * (t % 5 - 2.5) / 2.5), 0.0)
    w[:, 0] = np.where(moving, 0.5 * np.sin(2 * np.pi * (t % 5 - 2.5) / 2.5), 0.0)
    w += rng.normal(0, 0.003, w.shape)
    w[:, 1] = np.clip(w[:, 1], -2.0, 2.0)
    low, high = flat_top_levels(w, moving, ~moving)
    assert low[1] == -2.0 and high[1] == 2.0
    assert np.isinf(low[[0, 2]]).all() and np.isinf(high[[0, 2]]).all()


def test_a_clipped_known_turn_is_named_as_the_cause():
    """Plan ferraris with the gyro clipped at +-2000 counts (its full turns reach it): the
    known turns' short integrals make the face-to-face moves disagree with gravity, and the
    clipping is named first as the cause, with what would add the gyro."""
    session, _ = simulate_plan("ferraris", seed=1, created=CREATED)
    cal = calibrate_session(_clipped(session, level=2000.0), Config())
    assert cal.gyro is None and cal.accel is not None
    note = cal.left_out["gyro"]
    assert note.startswith("gyro not calibrated: a turn of known angle reaches the end of the "
                           "gyro's range") and "more slowly" in note, note


def test_flat_tops_of_a_session_read_while_it_is_written():
    """capture --until's refits read the session being written: it held 5 more times than
    gyro samples (2685 against 2680) and the flat-top search failed to broadcast (a
    ValueError out of calibrate); the search runs over the gyro's own rows."""
    from imucal_cli.simulate.play import simulate_plan

    session, _ = simulate_plan("qureshi18", seed=1)
    cut = replace(session, gyro=session.gyro[:-5])
    low, high = _flat_tops(cut)
    assert low.shape == high.shape == (3,)
    assert np.all(np.isinf(low)) and np.all(np.isinf(high))  # an unclipped session


@pytest.mark.parametrize("gyro_noise", [2e-4, 1e-3])  # about 0.1-0.5 and 1 count per sample
def test_a_quiet_1khz_gyro_repeats_no_flat_top_and_shows_a_real_one(gyro_noise):
    """At 1 kHz a turn's peak lasts many readings, and a quiet part (a tenth of a count to a
    count of noise) repeats counts there by the signal, not the noise: no flat top is taken
    in clean turns; clipped at 1500 counts within its word (peaks about 2,000), x's flat
    tops are found at that level."""
    from imucal_cli.simulate.rotations import simulate_gyro_rotations

    for seed in (0, 1):
        session, _ = simulate_gyro_rotations("qureshi-axes", seed=seed, rate_hz=1000.0,
                                             gyro_noise=gyro_noise, rotations_per_axis=4,
                                             created=CREATED)  # fmt: skip
        low, high = _flat_tops(with_segments(session)[0])
        assert np.all(np.isinf(low)) and np.all(np.isinf(high)), (seed, low, high)
        clipped = _clipped(session, level=1500.0, axes=(0,))
        low, high = _flat_tops(with_segments(clipped)[0])
        assert low[0] == -1500.0 and high[0] == 1500.0, (seed, low, high)
        assert np.all(np.isinf(low[1:])) and np.all(np.isinf(high[1:]))
