"""`imucal report`: the report dict, its rendering, loading from JSON or session, CLI errors.

The gravity-solver calibrations here are written by hand following DEVELOPERS.md (its accel
section) and the spec's minimal example, so the report is tested on what files carry, not on a
solve.  The factorization sections come from the real pipeline on the Hwangbo-Kanade
simulations (redundant accelerometer unit, gyroscope procedure).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from rich.console import Console

from imucal_cli.cli import main
from imucal_cli.formats.calibration import calibration_from_json, calibration_to_json
from imucal_cli.use.report.build import STANDARD_GRAVITY, add_table, build_report
from imucal_cli.use.report.coverage_map import coverage_map
from imucal_cli.use.report.load import load_for_report
from imucal_cli.use.report.render import render_report

G = STANDARD_GRAVITY
UPS = [
    [0, 0, 1],
    [0, 0, -1],
    [1, 0, 0],
    [-1, 0, 0],
    [0, 1, 0],
    [0, -1, 0],
    [0.7071, 0, 0.7071],
    [0, 0.7071, -0.7071],
]


def _poses() -> list[dict]:
    poses = []
    for i, up in enumerate(UPS):
        tilted = np.asarray(up, dtype=float) + [0.01, -0.02, 0.005]
        poses.append(
            {
                "segment": f"{i:04d}",
                "label": f"pose {i} [tilt]",
                "up": up,
                "samples": 200 + i,
                "magnitude_before": 9.9 + 0.01 * i,
                "magnitude_after": G + 0.0004 * (i - 3),
                "residual": 0.0004 * (i - 3),
                "residual_loo": 0.0006 * (i - 3),
                "angle_to_up_deg": 1.9 + 0.1 * i,
                "direction": (tilted / np.linalg.norm(tilted)).tolist(),
            }
        )
    return poses


def full_calibration() -> dict:
    """A calibration as the gravity solver writes it (DEVELOPERS.md schema)."""
    return {
        "format": "imucal-calibration",
        "format_version": 1,
        "session": "bench3-unit17.h5",
        "created": "2026-11-21T10:00:00Z",
        "sensor": "BNO055 #17",
        "toolkit_version": "0.1.0",
        "config": {"variant": "9-parameter", "init": "updown"},
        "accel": {
            "solver": "gravity",
            "units": "m/s^2",
            "bias": [12.3, -4.5, 7.8],
            "matrix": [[0.0011975, -1.2e-5, 1.9e-5], [0.0, 0.0012045, 5e-7], [0.0, 0.0, 0.001189]],
            "residual_rms": 0.0021,
            "model": "calibrated = matrix @ (raw - bias)",
            "units_in": "counts",
            "variant": "9-parameter",
            "gauge": "upper-triangular matrix",
            "gravity": G,
            "parameters": [
                {"name": "b_x", "value": 12.3, "std": 0.4, "unit": "counts"},
                {"name": "s_x", "value": 835.1234, "std": 0.04, "unit": "counts per m/s^2"},
                {"name": "k_x", "value": 0.00118295, "std": 4e-8, "unit": "m/s^2 per counts"},
            ],
            "misalignment_deg": {"xy": 0.12, "xz": -0.3, "yz": 0.05},
            "misalignment_std_deg": {"xy": 0.01, "xz": 0.02, "yz": 0.015},
            "sensitivity": [835.1, 830.2, 841.0],
            "sensitivity_std": [0.04, 0.05, 0.06],
            "sensitivity_unit": "counts per m/s^2",
            "init": "updown",
            "iterations": 7,
            "converged": True,
            "message": "step below tolerance",
            "noise_scale": 1.0,
            "chi2": 8.7,
            "dof": 7,
            "rms_before": 0.12,
            "rms_after": 0.002,
            "rms_loo": 0.0025,
            "loo_method": "refit without each pose",
            "before_basis": "nominal sensitivity 835.0 counts per m/s^2, zero bias",
            "coverage": {"fraction": 0.83, "largest_gap_deg": 41.0, "n_poses": 8, "n_distinct": 8},
            "poses": _poses(),
            "warnings": ["pose 0003 sits 3 sigma off"],
        },
    }


def minimal_calibration() -> dict:
    """The spec's example: only the standard fields, as another tool would write it."""
    return {
        "format": "imucal-calibration",
        "format_version": 1,
        "session": "bench3-unit17.h5",
        "created": "2026-11-21T10:00:00Z",
        "accel": {
            "solver": "gravity",
            "units": "m/s^2",
            "bias": [0.012, -0.031, 0.004],
            "matrix": [[1.006, -0.012, 0.019], [0.0, 1.007, 0.0005], [0.0, 0.0, 0.983]],
            "residual_rms": 0.0138,
        },
        "gyro": {
            "solver": "gyro-dynamic",
            "units": "rad/s",
            "bias": [0.0008, -0.0011, 0.0009],
            "matrix": [[0.9754, 0, 0], [0, 0.983, 0], [0, 0, 0.9747]],
            "residual_rms": 0.002,
        },
    }


def write_json(path: Path, document: dict) -> Path:
    path.write_text(json.dumps(document, indent=2))
    return path


def write_session(path: Path, calibrations: list[dict]) -> Path:
    """A minimal valid session with the given calibrations under /calibrations/0000, 0001, ..."""
    n = 100
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "imucal-session"
        f.attrs["format_version"] = 1
        f.attrs["created"] = "2026-11-21T10:00:00Z"
        f.attrs["accel_units"] = "counts"
        f.create_dataset("raw/time", data=np.arange(n) / 100.0)
        f.create_dataset("raw/accel", data=np.tile([0.0, 0.0, 835.0], (n, 1)))
        segment = f.create_group("segments/0000")
        segment.attrs["kind"] = "static"
        segment.attrs["start"] = 0
        segment.attrs["stop"] = n
        segment.attrs["up"] = [0.0, 0.0, 1.0]
        group = f.create_group("calibrations")
        for i, document in enumerate(calibrations):
            group.create_group(f"{i:04d}").attrs["json"] = json.dumps(document)
    return path


def rendered(document: dict) -> str:
    cal = calibration_from_json(json.dumps(document), "test.json")
    console = Console(record=True, width=100)
    render_report(build_report(cal), console)
    return console.export_text()


def terminal_width(report: dict) -> int:
    """Widest line of the report drawn in a 100-column terminal (panels, wrapped prose)."""
    console = Console(record=True, width=100, force_terminal=True)
    render_report(report, console)
    return max(len(line) for line in console.export_text().splitlines())


def run_imucal(args: list[str], capsys, monkeypatch) -> tuple[int, str, str]:
    """Run the console entry point in-process; returns (exit code, stdout, stderr)."""
    monkeypatch.setattr(sys, "argv", ["imucal", *args])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    out, err = capsys.readouterr()
    return code, out, err


# ---------------------------------------------------------------------------------------------
# The report dict / --json


def test_json_output_carries_the_stored_values(tmp_path, capsys, monkeypatch):
    path = write_json(tmp_path / "cal.json", full_calibration())
    code, out, err = run_imucal(["report", str(path), "--json"], capsys, monkeypatch)
    assert code == 0, err
    assert err == ""
    report = json.loads(out)  # stdout is the JSON and nothing else
    accel = report["sensors"]["accel"]
    assert list(report["sensors"]) == ["accel"]
    assert report["sensor"] == "BNO055 #17"
    assert accel["variant"] == "9-parameter"
    assert (accel["units_in"], accel["units_out"]) == ("counts", "m/s^2")
    assert accel["parameters"][1] == {
        "name": "s_x",
        "value": 835.1234,
        "std": 0.04,
        "unit": "counts per m/s^2",
    }
    assert accel["misalignment_deg"][1] == {"axes": "xz", "angle": -0.3, "std": 0.02}
    rms = accel["rms"]
    assert (rms["before"], rms["after"], rms["held_out"]) == (0.12, 0.002, 0.0025)
    assert rms["after_mg"] == pytest.approx(0.002 / G * 1000)
    assert rms["held_out_mg"] == pytest.approx(0.0025 / G * 1000)
    assert rms["improvement"] == pytest.approx(60.0)
    assert rms["improvement_held_out"] == pytest.approx(48.0)
    fit = accel["fit"]
    assert (fit["init"], fit["iterations"], fit["converged"]) == ("updown", 7, True)
    assert (fit["noise_scale"], fit["chi2"], fit["dof"]) == (1.0, 8.7, 7)
    assert accel["coverage"]["largest_gap_deg"] == 41.0
    assert len(accel["poses"]) == len(UPS)
    assert accel["poses"][0]["residual_mg"] == pytest.approx(-0.0012 / G * 1000)
    assert accel["warnings"] == ["pose 0003 sits 3 sigma off"]
    assert accel["unavailable"] == []
    assert report["reference"] is None  # the user's own sensor: no paper figures (issue 12)
    simulated = build_report(
        calibration_from_json(json.dumps({**full_calibration(), "source": "simulator"}), "s.json")
    )
    assert simulated["reference"]["rms_before_g"] == 0.0129
    assert simulated["reference"]["rms_after_g"] == 0.0014


def test_mg_figures_use_the_calibrations_gravity():
    document = full_calibration()
    document["accel"]["gravity"] = 9.81
    cal = calibration_from_json(json.dumps(document), "test.json")
    rms = build_report(cal)["sensors"]["accel"]["rms"]
    assert rms["before_mg"] == pytest.approx(0.12 / 9.81 * 1000)


# ---------------------------------------------------------------------------------------------
# Rendering


def test_render_shows_values_with_units_and_std():
    text = rendered(full_calibration())
    assert "835.12 ± 0.04 counts per m/s^2" in text
    assert "12.3 ± 0.4 counts" in text
    assert "(1.18295 ± 0.00004)e-3 m/s^2 per counts" in text  # small values: common exponent
    assert "-0.30 ± 0.02 deg" in text
    assert "830.20 ± 0.05 counts per m/s^2" in text  # sensitivity with its std
    assert "matrix [m/s^2 per counts] and bias [counts]" in text
    assert "raw counts -> calibrated m/s^2" in text
    assert "7 iterations; converged" in text
    assert "pose 0003 sits 3 sigma off" in text
    assert (
        terminal_width(build_report(calibration_from_json(json.dumps(full_calibration()), "x")))
        <= 100
    )


def test_render_rms_before_after_held_out_with_improvement():
    lines = rendered(full_calibration()).splitlines()

    def line_with(start: str) -> str:
        return next(line for line in lines if line.strip().startswith(start))

    assert "0.12 m/s^2" in line_with("before calibration")
    assert "12.2 mg" in line_with("before calibration")
    after = line_with("after calibration")
    assert "0.002 m/s^2" in after and "0.204 mg" in after and "60.0 ×" in after
    held_out = line_with("held out")
    assert "0.0025 m/s^2" in held_out and "0.255 mg" in held_out and "48.0 ×" in held_out
    assert not any("Qureshi" in line for line in lines)  # the user's own sensor
    lines = rendered({**full_calibration(), "source": "simulator"}).splitlines()
    paper = line_with("paper: Qureshi & Golnaraghi")
    assert "0.0129 -> 0.0014 g" in paper and "12.9 -> 1.4 mg" in paper


def test_render_has_one_row_per_pose():
    lines = rendered(full_calibration()).splitlines()
    for i, pose in enumerate(_poses()):
        row = next(line for line in lines if line.strip().startswith(pose["segment"]))
        assert f"pose {i} [tilt]" in row  # markup-like labels are shown verbatim
        assert str(pose["samples"]) in row
        assert f"{pose['magnitude_before']:.4f}" in row
        assert f"{pose['magnitude_after']:.4f}" in row
        assert f"{pose['residual'] / G * 1000:+.3f}" in row
        assert f"{pose['residual_loo'] / G * 1000:+.3f}" in row
        assert f"{pose['angle_to_up_deg']:.2f}" in row
    assert "+X+Z" in next(line for line in lines if line.strip().startswith("0006"))
    assert "+Y-Z" in next(line for line in lines if line.strip().startswith("0007"))


def test_render_coverage_figure():
    text = rendered(full_calibration())
    assert "+Z side" in text and "-Z side" in text
    assert "covered: 83 % of the sphere" in text
    assert "largest gap: 41.0 deg" in text


def test_coverage_map_marks_each_pose_in_its_hemisphere():
    lines = coverage_map([[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 0.7071, -0.7071]])
    rows = lines[1:-1]
    width = 23
    left = [row[:width] for row in rows]
    right = [row[width + 4 :] for row in rows]
    centre = len(rows) // 2
    assert left[centre][width // 2] == "o"  # +Z at the +Z pole
    assert left[centre][-1] == "o"  # +X on the equator, right edge
    assert right[centre][width // 2] == "o"  # -Z at the -Z pole
    # (0, 0.71, -0.71): 45 deg from the -Z pole, above the centre on the -Z side
    assert sum(row.count("o") for row in right[:centre]) == 1
    assert sum(row.count("o") for row in rows) == 4


# ---------------------------------------------------------------------------------------------
# Calibrations with only the standard fields, and malformed optional fields


def test_minimal_calibration_renders_and_says_what_is_unavailable():
    text = rendered(minimal_calibration())
    assert "1.006" in text and "0.983" in text  # the matrix
    assert "0.0138 m/s^2" in text  # residual_rms
    assert "raw units (not stated)" in text and "raw raw" not in text
    assert "Not in this calibration" in text
    assert "named parameters with standard deviations" in text
    assert "per-pose residuals" in text
    assert "gyro: gyro-dynamic solver" in text

    cal = calibration_from_json(json.dumps(minimal_calibration()), "minimal.json")
    report = build_report(cal)
    accel = report["sensors"]["accel"]
    assert accel["rms"]["before"] is None and accel["rms"]["improvement"] is None
    assert "leave-one-pose-out (held-out) RMS" in accel["unavailable"]
    assert accel["matrix"][0] == [1.006, -0.012, 0.019]
    assert report["sensors"]["gyro"]["rms"]["after_mg"] is None  # no mg for rad/s
    json.dumps(report)


def test_malformed_optional_fields_read_as_missing():
    document = full_calibration()
    accel = document["accel"]
    accel["parameters"] = "see lab book"
    accel["poses"] = [1, {"segment": "0000", "up": "up"}]
    accel["coverage"] = None
    accel["iterations"] = "seven"
    text = rendered(document)
    assert "named parameters with standard deviations" in text
    assert "pose coverage (fraction, largest gap)" in text


def test_undetermined_values_are_null_in_json_and_n_a_in_text():
    document = full_calibration()
    document["accel"]["parameters"][0]["std"] = float("nan")
    document["accel"]["rms_loo"] = float("nan")
    cal = calibration_from_json(json.dumps(document), "test.json")
    report = build_report(cal)
    json.dumps(report, allow_nan=False)  # strict JSON
    accel = report["sensors"]["accel"]
    assert accel["parameters"][0]["std"] is None
    assert accel["rms"]["held_out"] is None
    assert "12.3 ± n/a counts" in rendered(document)


# ---------------------------------------------------------------------------------------------
# Sessions


def test_session_reports_its_last_stored_calibration(tmp_path, capsys, monkeypatch):
    older = minimal_calibration()
    newer = full_calibration()
    path = write_session(tmp_path / "s.h5", [older, newer])
    cal = load_for_report(path)
    assert cal.accel.rms_after == 0.002

    code, out, err = run_imucal(["report", str(path), "--json"], capsys, monkeypatch)
    assert code == 0, err
    assert json.loads(out)["sensors"]["accel"]["rms"]["after"] == 0.002

    code, out, err = run_imucal(["report", str(path)], capsys, monkeypatch)
    assert code == 0, err
    assert "835.12 ± 0.04 counts per m/s^2" in out


# ---------------------------------------------------------------------------------------------
# Bad input: exit 2, one line on stderr, no traceback


def _assert_one_line_error(code: int, out: str, err: str, fragment: str) -> None:
    assert code == 2
    assert out == ""
    assert err.startswith("imucal: error: ")
    assert err.count("\n") == 1
    assert "Traceback" not in err
    assert fragment in err


def test_session_without_calibration(tmp_path, capsys, monkeypatch):
    path = write_session(tmp_path / "s.h5", [])
    code, out, err = run_imucal(["report", str(path)], capsys, monkeypatch)
    _assert_one_line_error(
        code, out, err, "session has no stored calibration; run `imucal calibrate"
    )


def test_missing_file(tmp_path, capsys, monkeypatch):
    path = tmp_path / "nope.json"
    code, out, err = run_imucal(["report", str(path), "--json"], capsys, monkeypatch)
    _assert_one_line_error(code, out, err, str(path))


@pytest.mark.parametrize(
    "content",
    [b'{"format": "imucal-calibration", "accel": ', b"\xff\xfe\x00binary", b"[1, 2, 3]"],
    ids=["truncated-json", "binary", "not-a-calibration"],
)
def test_invalid_calibration_file(tmp_path, capsys, monkeypatch, content):
    path = tmp_path / "bad.json"
    path.write_bytes(content)
    code, out, err = run_imucal(["report", str(path)], capsys, monkeypatch)
    _assert_one_line_error(code, out, err, str(path))


def test_installed_entry_point_missing_file(tmp_path):
    imucal = Path(sys.executable).with_name("imucal")
    if not imucal.exists():
        pytest.skip("imucal console script not installed next to this interpreter")
    path = tmp_path / "missing.json"
    result = subprocess.run(
        [str(imucal), "report", str(path)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"imucal: error: {path}: no such file"
    assert result.stdout == ""


def test_help_explains_the_command(capsys, monkeypatch):
    code, out, _ = run_imucal(["report", "--help"], capsys, monkeypatch)
    assert code == 0
    assert "--json" in out
    assert "session" in out and "re-solved" in out


# ---------------------------------------------------------------------------------------------
# End to end: what `imucal calibrate` writes, the report shows in full


def test_report_of_a_real_calibrate_run_misses_nothing(tmp_path, capsys, monkeypatch):
    session = tmp_path / "sim.h5"
    output = tmp_path / "sim.cal.json"
    code, _, err = run_imucal(["simulate", "--seed", "3", "-o", str(session)], capsys, monkeypatch)
    assert code == 0, err
    code, _, err = run_imucal(
        ["calibrate", str(session), "--output", str(output)], capsys, monkeypatch
    )
    assert code == 0, err
    for path in (output, session):  # the JSON and the copy stored in the session
        code, out, err = run_imucal(["report", str(path), "--json"], capsys, monkeypatch)
        assert code == 0, err
        accel = json.loads(out)["sensors"]["accel"]
        assert accel["unavailable"] == []
        assert len(accel["poses"]) == accel["coverage"]["n_poses"]
        assert accel["rms"]["after"] < accel["rms"]["before"]


def test_data_added_in_build_is_drawn_without_new_render_code():
    """Other report content (outliers, g-sensitivity, ...) is added to the dict as warnings,
    parameters or tables; the renderer draws it generically."""
    cal = calibration_from_json(json.dumps(full_calibration()), "test.json")
    report = build_report(cal)
    section = report["sensors"]["accel"]
    section["warnings"].append("pose 0003 looks bumped: left out")
    section["parameters"].append({"name": "k_t", "value": 1.25e-3, "std": 2e-5, "unit": "1/K"})
    add_table(
        section,
        "outliers (studentized residual)",
        ["seg", "label", "t [1]"],
        [["0003", "pose 3", 7.25], ["0005", "pose 5", None]],
        caption="left out when |t| > 4",
    )
    json.dumps(report)  # still JSON-ready
    console = Console(record=True, width=100)
    render_report(report, console)
    text = console.export_text()
    assert "pose 0003 looks bumped: left out" in text
    assert "k_t" in text and "1/K" in text
    assert "outliers (studentized residual)" in text and "left out when |t| > 4" in text
    row = next(line for line in text.splitlines() if "0003" in line and "7.25" in line)
    assert "pose 3" in row
    assert any("0005" in line and "—" in line for line in text.splitlines())
    with pytest.raises(ValueError, match="3 cells"):
        add_table(section, "bad", ["a", "b", "c"], [[1, 2]])


def test_values_without_any_std_are_shown_plain():
    document = minimal_calibration()
    document["accel"]["residual_rms"] = None
    document["accel"]["misalignment_deg"] = {"xy": 0.12, "xz": -0.3, "yz": 0.05}
    text = rendered(document)
    assert "0.12 deg" in text and "n/a" not in text
    assert "RMS gravity-magnitude error" not in text  # no table of dashes
    assert "solver residual RMS" in text  # listed as not in this calibration


# ---------------------------------------------------------------------------------------------
# Factorization sections (Hwangbo & Kanade), from the real pipeline on simulated sessions

TABLE_I_ANGLES = ["s1s2", "s1s3", "s1s4", "s2s3", "s2s4", "s3s4"]


def _calibrated(session, config: dict):
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import config_from_dict

    return calibrate_session(session, config_from_dict(config))


@pytest.fixture(scope="module")
def redundant_accel_cal():
    """Section V's unit (two dual-axis parts, n = 4), unlabelled orientations."""
    from imucal_cli.simulate.redundant import simulate_redundant_accel

    session, _truth = simulate_redundant_accel(seed=1)
    return _calibrated(session, {"accel": {"solver": "factorization"}})


@pytest.fixture(scope="module")
def gyro_cal():
    """Section IV-B: turns on three orthogonal faces in two mountings, one ruler 90-degree turn."""
    from imucal_cli.simulate.redundant import simulate_hk_gyro

    session, _truth = simulate_hk_gyro(seed=1)
    return _calibrated(session, {"accel": {"solver": "none"}, "gyro": {"solver": "factorization"}})


def _render_cal(cal) -> str:
    console = Console(record=True, width=100)
    render_report(build_report(cal), console)
    return console.export_text()


def _line(text: str, start: str) -> str:
    return next(line for line in text.splitlines() if line.strip().startswith(start))


def test_factorization_redundant_accel_table_one(redundant_accel_cal):
    extra = redundant_accel_cal.accel
    report = build_report(redundant_accel_cal)
    json.dumps(report, allow_nan=False)
    accel = report["sensors"]["accel"]
    fz = accel["factorization"]
    assert (fz["configuration"], fz["case"], fz["elements"]) == ("redundant", "magnitude-only", 4)
    assert fz["refined"] is True
    names = [row["name"] for row in fz["rows"]]
    assert names == ["b1", "b2", "b3", "b4", "|s1|", "|s2|", "|s3|", "|s4|", *TABLE_I_ANGLES]
    rows = {row["name"]: row for row in fz["rows"]}
    # refined = the section's final values, linear = the stored linear solution
    assert rows["b3"]["refined"] == pytest.approx(redundant_accel_cal.accel.bias[2])
    assert rows["b3"]["linear"] == pytest.approx(extra.factorization.linear.bias[2])
    assert rows["|s4|"]["refined"] == pytest.approx(extra.sensitivity[3])
    assert rows["|s4|"]["refined_std"] == pytest.approx(extra.sensitivity_std[3])
    assert rows["|s4|"]["unit"] == "counts per m/s^2"
    assert rows["s1s4"]["refined"] == pytest.approx(extra.factorization.angles_deg[0][3])
    assert rows["s1s4"]["refined_std"] == pytest.approx(extra.factorization.angles_std_deg[0][3])
    assert rows["s3s4"]["linear"] == pytest.approx(extra.factorization.linear.angles_deg[2][3])
    assert all(row["refined_std"] is not None and row["refined_std"] > 0 for row in fz["rows"])
    assert rows["s1s4"]["refined"] == pytest.approx(45.0, abs=0.5)  # Table I's 45-degree pair
    assert rows["s1s2"]["refined"] == pytest.approx(90.0, abs=0.5)
    crms = fz["constraint_rms"]
    assert crms["linear"] == extra.factorization.linear.constraint_rms
    assert crms["refined"] == extra.factorization.constraint_rms
    assert accel["rotation"] == extra.factorization.rotation
    assert "canonical frame" in accel["rotation"]  # no labels: the frame the solver chose
    assert accel["rms"]["quantity"] == "gravity-magnitude error"
    # angles replace the gravity solver's misalignment field
    assert "misalignment angles" not in accel["unavailable"]
    assert "angles between sensitivity axes" not in accel["unavailable"]


def test_factorization_redundant_accel_renders_table_one(redundant_accel_cal):
    text = _render_cal(redundant_accel_cal)
    report = build_report(redundant_accel_cal)["sensors"]["accel"]
    rows = {row["name"]: row for row in report["factorization"]["rows"]}
    assert "accel: factorization solver, redundant (n = 4), magnitude-only constraints" in text
    assert "layout of Hwangbo & Kanade, Table I" in text
    header = _line(text, "linear (subspace)")
    assert "refined ± std" in header
    assert "bias [counts]" in _line(text, "bias [counts]") and "b1" in _line(text, "bias [")
    for name in TABLE_I_ANGLES:
        line = _line(text, "angle [deg]" if name == "s1s2" else name)
        row = rows[name]
        assert name in line
        assert f"{row['linear']:.2f}" in line  # std ~0.03 deg: two decimals
        assert f"{row['refined']:.2f} ± {row['refined_std']:.2f}" in line
    gain = _line(text, "gain [counts per m/s^2]")
    s1 = rows["|s1|"]
    decimals = 3 if f"{s1['refined_std']:.1e}"[0] == "1" else 2  # 2 digits of a std 1.x, else 1
    assert "|s1|" in gain and f"{s1['refined']:.{decimals}f} ± " in gain
    assert "C_err RMS [g^2]" in text
    frame = _line(text, "matrix frame")
    assert "no labels: canonical frame" in frame
    assert "redundant unit, 4 elements; magnitude-only constraints: 20" in text
    for channel in ("ch1", "ch2", "ch3", "ch4"):
        assert channel in _line(text, "ch1")
    assert "paper: Qureshi & Golnaraghi" not in text  # that figure is the gravity solver's
    assert "linear solution in the subspace of the sensitivity axes" in text  # notes
    assert terminal_width(build_report(redundant_accel_cal)) <= 100


def test_factorization_triad_accel_with_labels_states_the_aligned_frame():
    from imucal_cli.simulate.triad import simulate

    session, _truth = simulate(plan="qureshi18", seed=1)
    cal = _calibrated(session, {"accel": {"solver": "factorization"}})
    accel = build_report(cal)["sensors"]["accel"]
    names = [row["name"] for row in accel["factorization"]["rows"]]
    assert names == ["bx", "by", "bz", "|sx|", "|sy|", "|sz|", "sxsy", "sxsz", "sysz"]
    assert "labelled up directions" in accel["rotation"]
    text = _render_cal(cal)
    assert "labelled up directions" in _line(text, "matrix frame")
    assert "triad unit, 3 elements" in text
    assert "misalignment angles" not in accel["unavailable"]
    assert not any("frame" in item for item in accel["unavailable"])


def test_factorization_without_refinement_shows_the_linear_column_only(tmp_path):
    from imucal_cli.simulate.redundant import simulate_redundant_accel

    session, _truth = simulate_redundant_accel(seed=2)
    config = {"accel": {"solver": "factorization", "factorization": {"refine": False}}}
    cal = _calibrated(session, config)
    fz = build_report(cal)["sensors"]["accel"]["factorization"]
    assert fz["refined"] is False
    assert all(row["refined"] is None and row["linear"] is not None for row in fz["rows"])
    assert fz["constraint_rms"]["refined"] is None
    text = _render_cal(cal)
    assert "linear solution, not refined" in text
    assert "refined ± std" not in text


def test_factorization_gyro_turns_gains_and_frame(gyro_cal):
    extra = gyro_cal.gyro
    report = build_report(gyro_cal)
    assert list(report["sensors"]) == ["gyro"]  # accel solver "none": no accel section
    gyro = report["sensors"]["gyro"]
    fz = gyro["factorization"]
    assert (fz["configuration"], fz["case"]) == ("triad", "orthogonal-only")
    rows = {row["name"]: row for row in fz["rows"]}
    assert list(rows) == ["bx", "by", "bz", "|sx|", "|sy|", "|sz|", "sxsy", "sxsz", "sysz"]
    assert rows["|sy|"]["unit"] == "counts per rad/s"
    assert fz["constraint_rms"]["unit"] == "(rad/s)^2"
    turn = gyro["rotations"][0]
    stored = extra.rotations[0]
    assert turn["known_angle_deg"] == 90.0
    assert turn["measured_angle_deg"] == stored.measured_angle_deg
    assert turn["angle_error_deg"] == stored.angle_error_deg
    assert "known-angle turn" in gyro["rotation"]
    assert gyro["unavailable"] == []

    text = _render_cal(gyro_cal)
    assert "gyro: factorization solver, triad (n = 3), " in text  # "factorization" once
    assert "known-angle turn along its labelled axis" in _line(text, "matrix frame")
    line = _line(text, turn["segment"])
    assert "ruler-guided" in line
    assert "90.000" in line and f"{turn['measured_angle_deg']:.4f}" in line
    assert f"{turn['angle_error_deg']:+.3g}" in line
    gain = _line(text, "gain [counts per rad/s]")
    assert f"{rows['|sx|']['refined']:.1f} ± " in gain
    assert "sysz" in text and "C_err RMS [(rad/s)^2]" in text
    assert "before calibration" not in text  # no gravity-pose RMS rows for a gyroscope
    assert terminal_width(report) <= 100


def test_factorization_reports_through_the_cli(tmp_path, capsys, monkeypatch, gyro_cal):
    from imucal_cli.formats.calibration import write_calibration

    path = tmp_path / "gyro.cal.json"
    write_calibration(path, gyro_cal)
    code, out, err = run_imucal(["report", str(path), "--json"], capsys, monkeypatch)
    assert code == 0, err
    gyro = json.loads(out)["sensors"]["gyro"]
    assert [r["name"] for r in gyro["factorization"]["rows"]][-3:] == ["sxsy", "sxsz", "sysz"]
    assert gyro["rotations"][0]["known_angle_deg"] == 90.0
    code, out, err = run_imucal(["report", str(path)], capsys, monkeypatch)
    assert code == 0, err
    assert "gyro angle - reference angle" in out and "Table I" in out


def test_minimal_factorization_sections_render_with_what_they_lack():
    document = minimal_calibration()
    document["accel"] = {
        "solver": "factorization",
        "units": "m/s^2",
        "bias": [1.0, 2.0, 3.0, 4.0],
        "matrix": [[0.02, 0, 0, 0.01], [0, 0.02, 0, 0], [0, 0, 0.02, 0.01]],
        "residual_rms": 0.005,
    }
    document["gyro"]["solver"] = "factorization"
    report = build_report(calibration_from_json(json.dumps(document), "minimal.json"))
    json.dumps(report, allow_nan=False)
    accel, gyro = report["sensors"]["accel"], report["sensors"]["gyro"]
    assert [r["name"] for r in accel["factorization"]["rows"]][-6:] == TABLE_I_ANGLES
    assert "angles between sensitivity axes" in accel["unavailable"]
    assert "the frame of the matrix (how the free rotation was resolved)" in accel["unavailable"]
    assert "known-angle turns (measured vs known angle)" in gyro["unavailable"]
    assert "per-pose residuals" not in gyro["unavailable"]  # an accelerometer figure
    text = rendered(document)
    assert "not stated" in _line(text, "matrix frame")
    assert "0.9754" in text and "gyro: factorization solver" in text


def test_minimal_gyro_section_lists_only_gyro_items():
    gyro = build_report(calibration_from_json(json.dumps(minimal_calibration()), "m.json"))[
        "sensors"
    ]["gyro"]
    assert gyro["factorization"] is None and gyro["rotations"] == []
    assert "per-pose residuals" not in gyro["unavailable"]
    assert "RMS before calibration" not in gyro["unavailable"]
    assert "named parameters with standard deviations" in gyro["unavailable"]
    text = rendered(minimal_calibration())
    assert "0.002 rad/s" in text


# ---------------------------------------------------------------------------------------------
# History: several calibrations of one sensor


@pytest.fixture(scope="module")
def two_calibrations(tmp_path_factory):
    """The same simulated part (same seed: same truth) calibrated twice, the second session
    recorded with twice the accelerometer noise and a day later."""
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.calibration import write_calibration
    from imucal_cli.formats.config import config_from_dict
    from imucal_cli.simulate.triad import simulate

    folder = tmp_path_factory.mktemp("history")
    paths = []
    for i, noise in enumerate((0.01, 0.02)):
        session, _truth = simulate(seed=4, accel_noise=noise, created=f"2026-11-2{i}T10:00:00Z")
        cal = calibrate_session(session, config_from_dict({}), name=f"run{i}.h5")
        cal.created = f"2026-11-2{i}T10:05:00Z"
        paths.append(folder / f"run{i}.cal.json")
        write_calibration(paths[-1], cal)
    return paths


def test_history_of_two_calibrations_without_false_drift(two_calibrations, capsys, monkeypatch):
    first, second = two_calibrations
    # Given newest first: ordered by their created date all the same.
    code, out, err = run_imucal(["report", str(second), str(first), "--json"], capsys, monkeypatch)
    assert code == 0, err
    history = json.loads(out)
    assert history["format"] == "imucal-history" and history["drift_sigmas"] == 3.0
    (entry,) = history["sensors"]
    assert entry["sensor"] == "sim-16bit seed 4"
    assert [c["session"] for c in entry["calibrations"]] == ["run0.h5", "run1.h5"]
    rows = {r["name"]: r for r in entry["sections"]["accel"]["rows"]}
    assert {"b_x", "k_x", "k_xy", "sensitivity x", "misalignment xy"} <= set(rows)
    for row in rows.values():
        assert len(row["values"]) == 2 and all(v is not None for v in row["values"])
        assert row["change"][0] == 0 and row["change"][1] == pytest.approx(
            row["values"][1] - row["values"][0]
        )
        assert row["z"][1] is not None and abs(row["z"][1]) <= 3.0, row
        assert row["drifted"] == [False, False]
    assert entry["drifted"] == []
    code, text, err = run_imucal(["report", str(first), str(second)], capsys, monkeypatch)
    assert code == 0, err
    assert "history of sim-16bit seed 4: 2 calibrations" in text
    assert "run0.h5" in text and "run1.h5" in text and "change (z)" in text
    assert "no parameter changed by more than 3 combined std" in text
    assert "drifted" not in text.replace("drifted when", "")


def test_injected_drift_is_flagged(two_calibrations, tmp_path, capsys, monkeypatch):
    first, second = two_calibrations
    document = json.loads(second.read_text())
    b_x = next(p for p in document["accel"]["parameters"] if p["name"] == "b_x")
    shift = 10 * b_x["std"]
    b_x["value"] += shift
    document["accel"]["bias"][0] += shift
    document["created"] = "2026-12-01T10:00:00Z"
    drifted = write_json(tmp_path / "drifted.cal.json", document)
    code, out, err = run_imucal(
        ["report", str(first), str(second), str(drifted), "--json"], capsys, monkeypatch
    )
    assert code == 0, err
    (entry,) = json.loads(out)["sensors"]
    assert entry["drifted"] == ["accel b_x"]
    row = next(r for r in entry["sections"]["accel"]["rows"] if r["name"] == "b_x")
    assert row["drifted"] == [False, False, True] and row["z"][2] > 3.0
    code, text, err = run_imucal(["report", str(first), str(drifted)], capsys, monkeypatch)
    assert code == 0, err
    assert "drifted" in _line(text, "b_x") and "Drifted beyond the uncertainty" in text


def test_history_from_a_session_with_several_stored_calibrations(
    two_calibrations, tmp_path, capsys, monkeypatch
):
    documents = [json.loads(p.read_text()) for p in two_calibrations]
    session = write_session(tmp_path / "s.h5", documents)
    # One path without --history: today's report of the last calibration.
    code, out, _ = run_imucal(["report", str(session), "--json"], capsys, monkeypatch)
    assert code == 0 and json.loads(out)["format"] == "imucal-report"
    code, out, err = run_imucal(
        ["report", str(session), "--history", "--json"], capsys, monkeypatch
    )
    assert code == 0, err
    (entry,) = json.loads(out)["sensors"]
    assert len(entry["calibrations"]) == 2 and entry["drifted"] == []


def test_history_groups_by_sensor_and_says_what_it_leaves_out(two_calibrations, tmp_path):
    from imucal_cli.use.report.history import build_history
    from imucal_cli.use.report.load import load_all_for_history

    other = json.loads(two_calibrations[0].read_text())
    other["sensor"] = "another part"
    unnamed = minimal_calibration()
    paths = [*two_calibrations, write_json(tmp_path / "o.json", other),
             write_json(tmp_path / "u.json", unnamed)]  # fmt: skip
    history = build_history(load_all_for_history(paths))
    assert [e["sensor"] for e in history["sensors"]] == ["sim-16bit seed 4"]
    assert history["single"] == ["another part"] and history["without_sensor"] == 1
    console = Console(record=True, width=100)
    from imucal_cli.use.report.history import render_history

    render_history(history, console)
    text = console.export_text()
    assert "one calibration only (no history): another part" in text
    assert "1 calibration(s) name no sensor" in text


def test_history_refuses_plot_with_one_line(two_calibrations, tmp_path, capsys, monkeypatch):
    code, out, err = run_imucal(
        ["report", *map(str, two_calibrations), "--plot", str(tmp_path / "x.png")],
        capsys, monkeypatch,
    )  # fmt: skip
    _assert_one_line_error(code, out, err, "--plot draws one calibration")


def test_history_compares_a_section_from_its_first_appearance():
    """The first calibration of a sensor may lack the gyro: later gyro runs are still compared
    with each other (the first one that has it is the reference)."""
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import config_from_dict
    from imucal_cli.simulate.rotations import simulate_gyro_rotations
    from imucal_cli.use.report.history import build_history

    session, _ = simulate_gyro_rotations(plan="qureshi-axes", seed=5, rotations_per_axis=6,
                                         created="2026-01-01T00:00:00Z")  # fmt: skip
    accel_only = calibrate_session(session, config_from_dict({"gyro": {"solver": "none"}}))
    with_gyro = [calibrate_session(session, config_from_dict({"gyro": {"solver": "full"}}))
                 for _ in range(2)]  # fmt: skip
    accel_only.created, with_gyro[0].created, with_gyro[1].created = (
        "2026-01-01T00:00:00Z",
        "2026-01-02T00:00:00Z",
        "2026-01-03T00:00:00Z",
    )
    history = build_history([accel_only, *with_gyro])
    gyro_rows = history["sensors"][0]["sections"]["gyro"]["rows"]
    assert gyro_rows and all(row["reference"] == 1 for row in gyro_rows)
    assert all(row["change"][2] == pytest.approx(0.0, abs=1e-12) for row in gyro_rows)
    assert history["sensors"][0]["drifted"] == []


# ---------------------------------------------------------------------------------------------
# History compares like with like (issue 10.8)


@pytest.fixture(scope="module")
def one_session_three_ways():
    """One simulated session calibrated with standard gravity, with g = 9.81 and with the
    factorization solver: the sensor did not change between them."""
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import config_from_dict
    from imucal_cli.simulate.triad import simulate

    session, _ = simulate(seed=4, created="2026-11-20T10:00:00Z")
    configs = ({}, {"gravity": 9.81}, {"accel": {"solver": "factorization"}})
    cals = []
    for i, config in enumerate(configs):
        cal = calibrate_session(session, config_from_dict(config), name=f"run{i}.h5")
        cal.created = f"2026-11-2{i}T10:05:00Z"
        cals.append(cal)
    return cals


def test_history_does_not_report_another_gravity_as_drift(one_session_three_ways):
    from imucal_cli.use.report.history import build_history

    standard, g981, _ = one_session_three_ways
    history = build_history([standard, g981])
    (entry,) = history["sensors"]
    section = entry["sections"]["accel"]
    assert entry["drifted"] == []
    assert section["bases"][0] != section["bases"][1] and "9.81" in section["bases"][1]
    assert len(section["not_compared"]) == 1 and "run1.h5" in section["not_compared"][0]
    sens = next(r for r in section["rows"] if r["name"] == "sensitivity x")
    assert sens["compared_with"] == [0, 1] and sens["change"] == [0.0, 0.0]
    # The same change within one basis is drift: the check above is not blind.
    relabelled = calibration_from_json(
        json.dumps({**json.loads(calibration_to_json(g981)),
                    "accel": {**json.loads(calibration_to_json(g981))["accel"],
                              "gravity": standard.accel.gravity}}), "x.json",
    )  # fmt: skip
    drift = build_history([standard, relabelled])["sensors"][0]
    assert "accel sensitivity x" in drift["drifted"]


def test_history_does_not_compare_solvers_and_names_quantities_alike(one_session_three_ways):
    from imucal_cli.use.report.history import build_history, render_history

    standard, _, factorization = one_session_three_ways
    history = build_history([standard, factorization])
    (entry,) = history["sensors"]
    rows = {r["name"]: r for r in entry["sections"]["accel"]["rows"]}
    # one name per quantity: gain_x is the sensitivity, angles_deg give the misalignment
    assert not any(name.startswith("gain_") for name in rows)
    for name in ("b_x", "sensitivity x", "misalignment xy"):
        assert all(v is not None for v in rows[name]["values"]), name
        assert rows[name]["compared_with"] == [0, 1]
    # the two solvers agree on the physical quantities to within their uncertainty
    sens = rows["sensitivity x"]
    assert abs(sens["values"][1] - sens["values"][0]) < 5 * max(sens["std"])
    assert entry["drifted"] == []
    console = Console(record=True, width=100)
    render_history(history, console)
    text = console.export_text()
    assert "different basis" in text and "factorization" in text
    assert "Drifted" not in text


# ---------------------------------------------------------------------------------------------
# No noise a user cannot act on (issue 12.1)


def test_report_shows_only_the_options_of_the_solvers_that_ran():
    config = {
        "accel": {"solver": "gravity", "max_scale_error": 0.2,
                  "gravity": {"model": "9", "init": "auto"},
                  "factorization": {"use": "means", "refine": True}},
        "gyro": {"solver": "none", "rotations": {"max_gap_s": 2.0}, "full": {"max_iterations": 9}},
    }  # fmt: skip
    document = {**full_calibration(), "config": config}
    report = build_report(calibration_from_json(json.dumps(document), "x.json"))
    assert report["config"] == {
        "accel": {"solver": "gravity", "max_scale_error": 0.2,
                  "gravity": {"model": "9", "init": "auto"}},
    }  # fmt: skip
    text = rendered(document)
    options = _line(text, "options")
    assert "accel.gravity.model=9" in options
    assert "factorization" not in options and "gyro" not in options and "refine" not in options


def test_gyro_options_are_those_of_its_solver(gyro_cal):
    report = build_report(gyro_cal)
    gyro = report["config"]["gyro"]
    assert gyro["solver"] == "factorization" and "factorization" in gyro
    assert "rotations" not in gyro and "full" not in gyro
    assert "accel" not in report["config"]  # the accelerometer was not calibrated


def test_optimiser_message_only_when_it_did_not_converge():
    text = rendered(full_calibration())
    assert "step below tolerance" not in text
    assert "step below tolerance" in json.dumps(
        build_report(calibration_from_json(json.dumps(full_calibration()), "x"))
    )  # still in the JSON, for the record
    document = full_calibration()
    document["accel"] = {**document["accel"], "converged": False,
                         "message": "maximum number of function evaluations"}  # fmt: skip
    fit = _line(rendered(document), "solver:")
    assert "NOT converged" in fit and "maximum number of function evaluations" in fit


def test_imported_calibration_says_where_from_and_shows_its_g_sensitivity(tmp_path):
    """Another tool's calibration (MaD Lab's Turntable JSON): the report names the format and
    the file, what its date is, and the gyro's g-sensitivity with its unit and in its model."""
    from imucal_cli.formats.calibration import read_calibration

    doc = {"acc_unit": "g", "gyr_unit": "deg/s", "from_acc_unit": "a.u.",
           "from_gyr_unit": "a.u.", "K_a": np.diag([2048.0, 2050.0, 2046.0]).tolist(),
           "R_a": np.eye(3).tolist(), "b_a": [1.0, 2.0, 3.0],
           "K_g": np.diag([16.4, 16.4, 16.4]).tolist(), "R_g": np.eye(3).tolist(),
           "K_ga": [[0.5, 0, 0], [0, 0.25, 0], [0, 0, -0.125]], "b_g": [0.0, 0.0, 0.0],
           "cal_type": "Turntable", "_format_version": "2.0"}  # fmt: skip
    path = tmp_path / "madlab.json"
    path.write_text(json.dumps(doc))
    report = build_report(read_calibration(path))
    assert report["imported_from"]["file"] == str(path) and report["imported_from"]["format"]
    assert "modification time" in report["created_basis"]
    gyro = report["sensors"]["gyro"]
    assert gyro["model"] == "calibrated = matrix @ (raw - bias - g_sensitivity @ a)"
    # K_ga acts on the acceleration in g: per m/s^2 it is K_ga / g
    np.testing.assert_allclose(np.diag(gyro["g_sensitivity"]["matrix"]),
                               np.array([0.5, 0.25, -0.125]) / G)  # fmt: skip
    assert gyro["g_sensitivity"]["unit"] == "counts per m/s^2"
    assert report["sensors"]["accel"]["g_sensitivity"] is None
    json.dumps(report, allow_nan=False)
    text = _render_cal(read_calibration(path))
    assert _line(text, "imported from:").endswith(f"file {path}")
    assert "modification time" in _line(text, "created:")
    assert "g-sensitivity [counts per m/s^2]" in text
    assert f"{-0.125 / G:.5g}" in text.split("g-sensitivity")[1]


def test_native_g_sensitivity_is_not_drawn_twice(gyro_cal):
    """The full model lists g_xx among its parameters (with std): no second table."""
    document = json.loads(calibration_to_json(gyro_cal))
    gyro = document["gyro"]
    gyro["g_sensitivity"] = np.eye(3).tolist()
    gyro["parameters"] = [*gyro.get("parameters", []),
                          {"name": "g_xx", "value": 1.0, "std": 0.1, "unit": "counts per m/s^2"}]
    report = build_report(calibration_from_json(json.dumps(document), "x"))
    section = report["sensors"]["gyro"]
    assert section["g_sensitivity"] is not None
    assert not any(t["title"].startswith("g-sensitivity") for t in section["tables"])
