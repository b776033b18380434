"""Issue 24.6: a dead, stuck, saturated or disconnected axis of any sensor is named in one
line with exit status 2, before any solver runs (a dead accelerometer axis was a LinAlgError
traceback from the labelled solver; a dead gyro axis a fit that "did not converge")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.design.channel_faults import channel_faults
from imucal_cli.errors import InputError
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.formats.session import write_session
from imucal_cli.simulate.play import simulate_plan
from tests.cli_helpers import assert_one_line_error, run

CREATED = "2026-01-01T00:00:00Z"
FAULTS = {  # what the channel reads, and the word the message uses
    "dead": (lambda x: np.zeros_like(x), "dead"),
    "stuck": (lambda x: np.full_like(x, x[0]), "stuck"),
    "saturated": (lambda x: np.full_like(x, 32767.0), "saturated"),
    "disconnected": (lambda x: np.full_like(x, -1.0), "disconnected"),
}
NAMES = {"accel": "accelerometer", "gyro": "gyroscope", "mag": "magnetometer"}


@pytest.fixture(scope="module")
def sessions():
    six, _ = simulate_plan("six", seed=1, created=CREATED)
    turns, _ = simulate_plan("free:10", seed=2, created=CREATED)
    from imucal_cli.simulate.magnetometer import simulate_mag

    mag, _ = simulate_mag("six", 3, tumble_s=1.0)
    return {"six": six, "free:10": turns, "six+mag": mag}


@pytest.mark.parametrize("fault", list(FAULTS))
@pytest.mark.parametrize("plan,sensor", [("six", "accel"), ("free:10", "accel"),
                                         ("six", "gyro"), ("free:10", "gyro"),
                                         ("six+mag", "mag")])  # fmt: skip
def test_a_faulty_axis_is_named(sessions, plan, sensor, fault):
    make, word = FAULTS[fault]
    session = sessions[plan]
    x = np.array(getattr(session, sensor), float)
    x[:, 1] = make(x[:, 1])
    with pytest.raises(InputError) as info:
        calibrate_session(replace(session, **{sensor: x}), Config())
    msg = str(info.value)
    assert f"the {NAMES[sensor]}'s y axis is {word}" in msg and "\n" not in msg, msg
    assert info.value.exit_code == 2


def test_a_sensor_left_out_is_not_judged(sessions):
    """``[gyro] solver = "none"``: a dead gyro does not stop the accelerometer."""
    session = sessions["six"]
    gyro = np.array(session.gyro, float)
    gyro[:, 0] = 0.0
    cal = calibrate_session(replace(session, gyro=gyro),
                            config_from_dict({"gyro": {"solver": "none"}}))  # fmt: skip
    assert cal.accel is not None and cal.gyro is None


def test_dead_accelerometer_axis_through_the_command_line(tmp_path, sessions):
    """The issue's case: a dead (all-zero) accelerometer axis of six labelled faces was a
    numpy LinAlgError traceback; now one line, exit 2, nothing written."""
    session = sessions["six"]
    accel = np.array(session.accel, float)
    accel[:, 2] = 0.0
    h5 = tmp_path / "dead.h5"
    write_session(h5, replace(session, accel=accel))
    out = tmp_path / "dead.cal.json"
    proc = run("calibrate", h5, "-o", out, "--no-store")
    assert_one_line_error(proc, "accelerometer's z axis is dead")
    assert not out.exists()


def test_a_working_channel_is_never_a_fault():
    """Noise of a fraction of a count, rounded: some codes differ, so nothing is named; and
    readings that touch a rail now and then are not saturated."""
    rng = np.random.default_rng(0)
    quiet = np.rint(100 + rng.normal(0, 0.6, (5000, 3)))
    assert channel_faults(quiet, counts=True, limits=(-32768, 32767)) == []
    touching = np.clip(rng.normal(30000, 3000, (5000, 3)), -32768, 32767)
    assert channel_faults(touching, counts=True, limits=(-32768, 32767)) == []


def test_an_axis_nan_in_every_sample_is_named(tmp_path):
    """A session whose accelerometer y is NaN throughout (a sketch printing nan for an axis
    it cannot read, imported or captured before 24.6's line check): the one-line error named
    only 'NaN or inf at sample 0'; it names the dead axis."""
    import h5py

    session, _ = simulate_plan("six", seed=2)
    path = tmp_path / "dead.h5"
    write_session(path, session)
    with h5py.File(path, "r+") as f:
        a = f["raw/accel"][...]
        a[:, 1] = np.nan
        f["raw/accel"][...] = a
    proc = run("calibrate", path, "--no-store")
    assert_one_line_error(proc, "axis y is NaN or inf in every sample")
