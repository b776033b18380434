"""Issue 27.1: accuracy targets, ``--until`` text and ``[targets]`` in a config, and each
target's std read from a calibration."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imucal_cli.calibrate.session import calibrate_session
from imucal_cli.errors import ConfigError, InputError
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.config import Config, config_from_dict
from imucal_cli.formats.session import read_session
from imucal_cli.formats.targets import (
    STANDARD_GRAVITY,
    Targets,
    brief,
    measure,
    merged,
    parse_until,
    targets_from_config,
)

from .cli_helpers import assert_one_line_error, run

SESSIONS = __import__("pathlib").Path(__file__).resolve().parents[1] / "sessions"


def values(t: Targets) -> dict[str, float]:
    return {x.key: x.value for x in t}


def test_shorthand_sets_every_term_at_that_size_of_a_reading():
    t = values(parse_until("accel=0.05%,gyro=0.05%"))
    assert t["accel.gain"] == pytest.approx(0.05) and t["gyro.gain"] == pytest.approx(0.05)
    assert t["accel.bias"] == pytest.approx(0.5)  # 0.05 % of 1 g, mg
    assert t["gyro.bias"] == pytest.approx(0.01)  # 0.05 % of 20 deg/s
    assert t["accel.misalignment"] == pytest.approx(math.degrees(5e-4))


def test_terms_in_any_unit_become_the_reports_units():
    t = values(parse_until("accel.bias=500ug, accel.gain=300ppm,gyro.bias=36deg/h,"
                           "gyro.misalignment=1mrad,gyro.gain=0.1%,accel.misalignment=3arcmin"))
    assert t == pytest.approx({"accel.bias": 0.5, "accel.gain": 0.03, "gyro.bias": 0.01,
                               "gyro.misalignment": math.degrees(1e-3), "gyro.gain": 0.1,
                               "accel.misalignment": 0.05})
    assert values(parse_until("accel.bias=0.0049033m/s^2"))["accel.bias"] == pytest.approx(
        0.0049033 / STANDARD_GRAVITY * 1e3)
    # a term named twice keeps the last value, over a shorthand too
    assert values(parse_until("gyro=1%,gyro.bias=0.02deg/s"))["gyro.bias"] == 0.02


@pytest.mark.parametrize("text, words", [
    ("", "give targets"),
    ("mag=1%", "sensors accel and gyro"),
    ("accel=1mg", "accel=X% sets every term"),
    ("accel.bias=1", "give a unit"),
    ("accel.gain=1deg", "accel gain in %, ppm"),
    ("accel.bias=-1mg", "positive"),
    ("gyro.bias=1e999deg/s", "positive"),
    ("accel.offset=1mg", "terms gain, bias, misalignment"),
])  # fmt: skip
def test_bad_targets_are_one_line_errors(text, words):
    with pytest.raises(InputError, match=words):
        parse_until(text)
    proc = run("capture", "--port", "/dev/null/none", "--until", text)
    assert_one_line_error(proc, "--until")


def test_config_targets_and_until_over_them():
    cfg = config_from_dict({"targets": {"accel": {"gain_pct": 0.1, "bias_mg": 1.0},
                                        "gyro": {"bias_dps": 0.02}}})  # fmt: skip
    base = targets_from_config(cfg.targets)
    assert values(base) == {"accel.gain": 0.1, "accel.bias": 1.0, "gyro.bias": 0.02}
    both = merged(base, parse_until("accel.bias=0.5mg,gyro.gain=0.05%"))
    assert values(both) == {"accel.gain": 0.1, "accel.bias": 0.5, "gyro.gain": 0.05,
                            "gyro.bias": 0.02}  # fmt: skip
    assert not targets_from_config(Config().targets)
    with pytest.raises(ConfigError, match="targets.gyro.bias_dps"):
        config_from_dict({"targets": {"gyro": {"bias_dps": -1}}})
    with pytest.raises(ConfigError, match="unknown key `bias_mg`"):
        config_from_dict({"targets": {"gyro": {"bias_mg": 1}}})


def test_a_target_for_a_sensor_the_config_leaves_out_is_refused(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[gyro]\nsolver = "none"\n')
    proc = run("capture", "--port", "/dev/null/none", "--until", "gyro=0.1%", "--config", cfg)
    assert_one_line_error(proc, "gyro", '"none"')


def test_measure_reads_the_std_the_calibration_states():
    """Each term's worst std, converted from the section's own fields."""
    session = read_session(SESSIONS / "qureshi18-seed1.h5")
    cal = calibrate_session(session, Config())
    targets = parse_until("accel=0.05%,gyro=0.05%")
    got = {(s.target.sensor, s.target.term): s for s in measure(cal, targets)}
    for sensor in ("accel", "gyro"):
        sec = getattr(cal, sensor).to_dict()
        s, s_std = np.array(sec["sensitivity"]), np.array(sec["sensitivity_std"])
        assert got[(sensor, "gain")].std == pytest.approx(np.max(100 * s_std / s))
        b_std = np.array([p["std"] for p in sec["parameters"][:3]])
        scale = 1e3 / STANDARD_GRAVITY if sensor == "accel" else 180 / np.pi
        assert got[(sensor, "bias")].std == pytest.approx(np.max(b_std / s * scale))
        assert got[(sensor, "misalignment")].std == pytest.approx(
            max(sec["misalignment_std_deg"].values()))
    # 18 poses, 17 turns meet these; every status says so, in one line per sensor
    assert all(s.met for s in got.values()), brief(list(got.values()))
    assert brief(list(got.values())).count("(met)") == 6


def test_nothing_calibrated_yet_is_undetermined_never_met():
    statuses = measure(None, parse_until("accel.gain=0.05%"), {"accel": "too few poses"})
    assert [s.std for s in statuses] == [None] and not statuses[0].met
    assert statuses[0].ratio == math.inf and "too few poses" in statuses[0].describe()


def test_the_gyro_sections_misalignment_std_follows_its_covariance():
    """The full model's ``misalignment_std_deg`` (delta method) against the angles' scatter
    predicted by its parameters' covariance, by sampling: the same to the sampling error."""
    from imucal_cli.planning.information import axes_std

    cal = read_calibration(SESSIONS / "qureshi18-seed1.truth.json")
    M = cal.gyro.matrix
    rng = np.random.default_rng(3)
    A = rng.standard_normal((9, 9)) * 1e-3 * np.abs(M).max()
    cov = A @ A.T
    draws = M.ravel() + rng.standard_normal((4000, 9)) @ np.linalg.cholesky(cov).T

    def angles(x):
        S = np.linalg.inv(x.reshape(3, 3))
        s = S / np.linalg.norm(S, axis=1, keepdims=True)
        return np.degrees(np.arccos([s[0] @ s[1], s[0] @ s[2], s[1] @ s[2]]))

    spread = np.std([angles(x) for x in draws], axis=0)
    _, _, std = axes_std(M, cov)
    assert std == pytest.approx(spread, rel=4 / np.sqrt(2 * 4000) + 0.02)
