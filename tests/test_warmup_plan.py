"""Issue 17.3: the warm-up capture plan (still, temperature logged) and its use."""

import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.session import read_session
from imucal_cli.plans import BUILTIN_PLANS, load_plan, needs_temperature

from .cli_helpers import assert_one_line_error, run


def test_warmup_plan_is_one_long_still_step():
    assert "warmup:MINUTES" in BUILTIN_PLANS
    plan = load_plan("warmup:30")
    assert plan.name == "warmup:30" and needs_temperature(plan)
    (step,) = plan.steps
    assert step.kind == "static" and step.hold_s == 1800.0
    assert "temperature" in step.label
    assert not needs_temperature(load_plan("still:30"))


@pytest.mark.parametrize("text", ["warmup:0", "warmup:-3", "warmup:abc", "warmup:inf"])
def test_warmup_minutes_must_be_positive(text):
    with pytest.raises(InputError, match="MINUTES must be a positive number"):
        load_plan(text)


def test_capture_of_a_warmup_needs_the_temperature_column(tmp_path):
    proc = run("capture", "--port", tmp_path / "nope", "--plan", "warmup:10", "--no-prompt",
               "--columns", "t,ax,ay,az,gx,gy,gz", "-o", tmp_path / "w.h5")  # fmt: skip
    assert_one_line_error(proc, "warmup:10", "add temp to --columns")
    assert not (tmp_path / "w.h5").exists()


def test_simulated_warmup_gives_calibrate_its_curve(tmp_path):
    proc = run("simulate", "--plan", "warmup:4", "--ramp", "8:40", "--seed", "2", "-o",
               tmp_path / "w.h5")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    warm = read_session(tmp_path / "w.h5")
    assert len(warm.static_segments()) == 1 and warm.time[-1] >= 240.0
    assert warm.temperature.max() - warm.temperature.min() > 30
    proc = run("simulate", "--plan", "qureshi18", "--ramp", "24:26:linear", "--seed", "2", "-o",
               tmp_path / "c.h5")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", tmp_path / "c.h5", "--warmup", tmp_path / "w.h5", "--no-store")
    assert proc.returncode == 0, proc.stderr
    cal = read_calibration(tmp_path / "c.cal.json")
    for sec in (cal.accel, cal.gyro):
        assert sec.temperature_terms is not None
        assert "warm-up" in sec.temperature_model.source
