"""Issue 26.1, sessions and calibrations: an HDF5 user block, a checksum failure under apply,
the shipped sessions' checksums, and values no sensor can have (gravity 1e308, a 20,000-digit
TOML integer, a bias of 1e200, a sample_clock_scale outside the gyro section, a g_sensitivity
of the wrong shape): each a one-line error with exit 2, or read as the format defines it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from imucal_cli.errors import CalibrationFileError, ConfigError, SessionError
from imucal_cli.formats.calibration import calibration_from_json
from imucal_cli.formats.config import load_config
from imucal_cli.formats.session import read_session

from .cli_helpers import assert_one_line_error, run

SESSIONS = Path(__file__).resolve().parents[1] / "sessions"
SIX = SESSIONS / "six-seed3.h5"


def _stored_calibration(session: Path) -> dict:
    with h5py.File(session, "r") as f:
        return json.loads(f["calibrations/0000"].attrs["json"])


def _copy_with_user_block(src: Path, dst: Path, libver=None, size=1024) -> None:
    """``src`` copied object by object by h5py into a file with a user block of ``size``."""
    with h5py.File(src, "r") as a, h5py.File(dst, "w", userblock_size=size, libver=libver) as b:
        for key, value in a.attrs.items():
            b.attrs[key] = value
        for key in a:
            a.copy(a[key], b, key)


@pytest.mark.parametrize("libver", [None, "latest"])  # superblock versions 0 and 3
def test_user_block_is_read_and_a_truncated_one_refused(tmp_path, libver):
    path = tmp_path / "ub.h5"
    _copy_with_user_block(SIX, path, libver)
    session = read_session(path)
    original = read_session(SIX)
    np.testing.assert_array_equal(session.accel, original.accel)
    assert len(session.segments) == len(original.segments)
    cut = tmp_path / "cut.h5"
    cut.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(SessionError, match="truncated"):
        read_session(cut)
    with pytest.raises(OSError, match="truncated"):  # HDF5 itself agrees on both files
        h5py.File(cut, "r")


def test_apply_on_a_chunk_failing_its_checksum_is_one_line(tmp_path):
    session = tmp_path / "s.h5"
    shutil.copy(SIX, session)
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(_stored_calibration(SIX)))
    with h5py.File(session, "r") as f:
        ds = f["raw/time"]
        assert ds.fletcher32
        offset = ds.id.get_chunk_info(ds.id.get_num_chunks() - 1).byte_offset
    data = bytearray(session.read_bytes())
    data[offset + 10] ^= 0xFF  # the last time chunk: apply reads it first
    session.write_bytes(bytes(data))
    assert_one_line_error(run("apply", cal, session, "-o", tmp_path / "out.csv"), "damaged HDF5")


def test_shipped_sessions_carry_checksums_and_every_flip_is_caught(tmp_path):
    shipped = sorted(SESSIONS.glob("*.h5"))
    assert len(shipped) == 4
    rng = np.random.default_rng(26)
    for path in shipped:
        with h5py.File(path, "r") as f:
            assert all(f["raw"][name].fletcher32 for name in f["raw"]), path.name
            ds = f["raw/accel"]
            spans = [ds.id.get_chunk_info(k) for k in range(ds.id.get_num_chunks())]
        original = read_session(path)
        for _ in range(10):  # a bit flipped anywhere in the raw accelerometer's chunks
            info = spans[int(rng.integers(len(spans)))]
            at = info.byte_offset + int(rng.integers(info.size - 4))  # not the checksum
            data = bytearray(path.read_bytes())
            data[at] ^= 1 << int(rng.integers(8))
            flipped = tmp_path / path.name
            flipped.write_bytes(bytes(data))
            with pytest.raises(SessionError, match="damaged"):
                read_session(flipped)
        assert original.accel.shape[0] > 1000


def test_a_gravity_no_place_has_is_one_line(tmp_path):
    session = tmp_path / "g.h5"
    shutil.copy(SIX, session)
    with h5py.File(session, "r+") as f:
        f.attrs["gravity"] = 1e308
    with pytest.raises(SessionError, match="'gravity' is 1e\\+308 m/s\\^2"):
        read_session(session)
    proc = run("calibrate", session, "-o", tmp_path / "c.json", "--no-store")
    assert_one_line_error(proc, "gravity")


def test_a_20000_digit_toml_integer_is_one_line(tmp_path):
    path = tmp_path / "big.toml"
    path.write_text("[accel.gravity]\nmax_iterations = " + "9" * 20_000 + "\n")
    with pytest.raises(ConfigError, match="more than 4300 digits"):
        load_config(path)
    proc = run("calibrate", SIX, "--config", path, "-o", tmp_path / "c.json", "--no-store")
    assert_one_line_error(proc, "big.toml")


def _doc(**changes) -> dict:
    doc = _stored_calibration(SIX)
    for path, value in changes.items():
        node = doc
        *keys, last = path.split("__")
        for key in keys:
            node = node[key]
        node[last] = value
    return doc


@pytest.mark.parametrize(
    "changes, words",
    [
        ({"accel__bias": [1e200, 0.0, 0.0]}, "offset of 1.2e+197 m/s^2"),
        ({"gyro__bias": [0.0, -1e200, 0.0]}, "beyond any sensor"),
        ({"sample_clock_scale": 1.0001}, "sample_clock_scale in the root"),
        ({"accel__sample_clock_scale": 1.0001}, "sample_clock_scale in the accel section"),
        ({"gyro__g_sensitivity": [[0.1, 0.0], [0.0, 0.1], [0.0, 0.0]]}, "g_sensitivity must be"),
        ({"gyro__g_sensitivity": [[0.1, 0.0, 0.0]] * 4}, "g_sensitivity must be 3 x 3"),
        ({"accel__g_sensitivity": [[0.1, 0.0, 0.0]] * 3}, "g_sensitivity in the accel section"),
    ],
)
def test_terms_no_reader_can_apply_are_refused(tmp_path, changes, words):
    text = json.dumps(_doc(**changes))
    with pytest.raises(CalibrationFileError, match=None) as info:
        calibration_from_json(text, "c.json")
    assert words in str(info.value)
    cal = tmp_path / "c.json"
    cal.write_text(text)
    assert_one_line_error(run("apply", cal, SIX, "-o", tmp_path / "out.csv"), words)


def test_sample_clock_scale_in_the_gyro_section_is_applied(tmp_path):
    cal = tmp_path / "c.json"
    cal.write_text(json.dumps(_doc(gyro__sample_clock_scale=1.001)))
    out = tmp_path / "out.csv"
    proc = run("apply", cal, SIX, "-o", out)
    assert proc.returncode == 0, proc.stderr
    t = np.loadtxt(out, delimiter=",", skiprows=2)[:, 0]
    raw_t = read_session(SIX).time
    np.testing.assert_allclose(t - t[0], (raw_t - raw_t[0]) / 1.001, rtol=0, atol=1e-12)
