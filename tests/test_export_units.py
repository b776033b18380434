"""`imucal export`: a calibration's raw units (``units_in``) are ones imucal knows, or refused.

Audit: a calibration JSON whose ``units_in`` was a string imucal does not know ("furlongs",
"rpm", "milligauss") was exported to the C header and to Fusion with the string as the raw
units, unconverted, exit 0 (``json`` dropped it silently; the SI targets asked for a
``--accel-scale`` without saying the unit is unknown).  The raw units are those of the session
format (accel counts, V, g, m/s^2; gyro counts, V, rad/s, deg/s; mag counts, uT, nT, gauss), or
not stated ("raw units", "unknown", absent): anything else is refused in one line naming the
unit and the known ones, for every target, before anything is written.
"""

from __future__ import annotations

import json

import pytest

from imucal_cli.use.export import EXPORT_FORMATS, FORMATS

from .cli_helpers import assert_one_line_error, run

CALIBRATION_FORMATS = [f for f in EXPORT_FORMATS if FORMATS[f].needs_calibration]


@pytest.fixture(scope="module")
def truths(tmp_path_factory):
    """The simulator's truth of a triad, of a triad with a magnetometer, and of two IMUs."""
    folder = tmp_path_factory.mktemp("units")
    out = {}
    for name, extra in (("triad", []), ("mag", ["--mag"]), ("set", ["--imus", "2"])):
        h5 = folder / f"{name}.h5"
        proc = run("simulate", "--plan", "six", *extra, "-o", h5)
        assert proc.returncode == 0, proc.stderr
        out[name] = json.loads((folder / f"{name}.truth.json").read_text())
    return out


def _with(tmp_path, doc: dict, change) -> str:
    doc = json.loads(json.dumps(doc))
    change(doc)
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("fmt", CALIBRATION_FORMATS)
def test_an_unknown_accel_unit_is_refused_by_every_target(truths, tmp_path, fmt):
    cal = _with(tmp_path, truths["triad"],
                lambda d: d["accel"].__setitem__("units_in", "furlongs"))  # fmt: skip
    out = tmp_path / "out.txt"
    proc = run("export", cal, "-f", fmt, "--accel-scale", "0.001", "--gyro-scale", "0.001",
               "-o", out)  # fmt: skip
    assert_one_line_error(proc, "accel", "'furlongs'", "counts, V, g, m/s^2")
    assert not out.exists()


@pytest.mark.parametrize(
    ("doc", "path", "unit", "known"),
    [
        ("triad", ("gyro",), "rpm", "counts, V, rad/s, deg/s"),
        ("mag", ("mag",), "milligauss", "counts, uT, nT, gauss"),
        ("set", ("imus", "imu1", "accel"), "mg", "counts, V, g, m/s^2"),
    ],
)
def test_an_unknown_unit_of_any_section_is_refused(truths, tmp_path, doc, path, unit, known):
    def change(d):
        for key in path:
            d = d[key]
        d["units_in"] = unit

    cal = _with(tmp_path, truths[doc], change)
    for fmt in ("c-header", "px4"):
        assert_one_line_error(run("export", cal, "-f", fmt), f"{unit!r}", known, path[-1])


@pytest.mark.parametrize("unit", ["g", "m/s^2", "counts", "V", "raw units", "unknown", None])
def test_known_or_unstated_units_export(truths, tmp_path, unit):
    def change(d):
        if unit is None:
            del d["accel"]["units_in"]
        else:
            d["accel"]["units_in"] = unit

    cal = _with(tmp_path, truths["triad"], change)
    proc = run("export", cal, "-f", "c-header")
    assert proc.returncode == 0, proc.stderr
    shown = unit if unit not in (None, "unknown") else "raw units"
    assert f"/* accel: 3 raw channels ({shown}) -> m/s^2 */" in proc.stdout


def test_a_known_unit_is_converted_for_an_si_target(truths, tmp_path):
    """Raw data in g exports to PX4 without --accel-scale: 9.80665 m/s^2 per g."""
    cal = _with(tmp_path, truths["triad"], lambda d: (d["accel"].__setitem__("units_in", "g"),
                                                      d.pop("gyro")))  # fmt: skip
    proc = run("export", cal, "-f", "px4")
    assert proc.returncode == 0, proc.stderr
    assert "9.80665" in proc.stdout


@pytest.mark.parametrize(("attr", "unit", "known"), [("accel_units", "furlongs", "counts, V, g"),
                                                     ("gyro_units", "rpm", "rad/s, deg/s")])
def test_a_session_of_unknown_units_is_not_calibrated(tmp_path, attr, unit, known):
    """The unit came from the session: ``calibrate`` wrote a calibration with units_in
    'furlongs' (exit 0) from a session whose accel_units were 'furlongs'. Refused in one line
    that says how to state them; ``imucal label`` states them and the session calibrates."""
    import h5py

    h5 = tmp_path / "s.h5"
    assert run("simulate", "--plan", "six", "-o", h5).returncode == 0
    with h5py.File(h5, "r+") as f:
        f.attrs[attr] = unit
    out = tmp_path / "cal.json"
    assert_one_line_error(run("calibrate", h5, "--no-store", "-o", out),
                          f"{attr} is {unit!r}", known, "imucal label")  # fmt: skip
    assert not out.exists()
    sensor = attr.split("_")[0]
    assert run("label", h5, f"--{sensor}-units", "counts").returncode == 0
    proc = run("calibrate", h5, "--no-store", "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(out.read_text())["accel"]["units_in"] == "counts"
