"""Issue 15: MotionCal ``Raw:`` and i2cdevlib ``a/g:`` lines captured live, with the importer's
own line parser: told apart from lines of numbers by the first lines, the same values live as
from a file, counts as the session's units."""

from __future__ import annotations

import numpy as np
import pytest

from imucal_cli.capture.recorder import Recorder
from imucal_cli.capture.stream import AutoLineProtocol, PrefixedLineProtocol
from imucal_cli.formats.columns import ColumnSpec
from imucal_cli.formats.importers.serial_lines import read_serial_lines
from imucal_cli.formats.session import read_session

from .test_capture import ScriptedSource

SPEC = ColumnSpec.parse("t,ax,ay,az,gx,gy,gz")


def counts(n: int, seed: int, width: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(-20000, 20000, (n, width))


def motioncal_text(rows: np.ndarray) -> bytes:
    return "".join("Raw:" + ",".join(map(str, r)) + "\r\n" for r in rows).encode()


def i2cdevlib_text(rows: np.ndarray, prefix: str = "a/g:") -> bytes:
    return "".join(prefix + "\t" + "\t".join(map(str, r)) + "\n" for r in rows).encode()


def feed_in_pieces(protocol, data: bytes, size: int = 7) -> list:
    blocks = [protocol.feed(data[i : i + size], 0.01 * i) for i in range(0, len(data), size)]
    return [b for b in blocks if len(b)]


def stacked(blocks, name):
    return np.concatenate([getattr(b, name) for b in blocks])


def test_live_lines_mean_what_the_file_means(tmp_path):
    """One MotionCal stream with the lines a sketch also prints (Uni:, a banner), a cut line and
    a line with a control character: the live protocol keeps what the importer keeps."""
    rows = counts(40, 1, 9)
    data = (b"MotionCal sketch ready\n" + motioncal_text(rows[:10]) + b"Uni:0.1,0.2,9.8,0,0,0\n"
            + b"Raw:1,2,3\n" + b"Raw:1,2\x0b3,4,5,6,7,8,9\n" + motioncal_text(rows[10:]))
    path = tmp_path / "mc.txt"
    path.write_bytes(data)
    from_file = read_serial_lines(path, 100.0)
    live = PrefixedLineProtocol()
    blocks = feed_in_pieces(live, data)
    np.testing.assert_array_equal(stacked(blocks, "accel"), from_file.accel)
    np.testing.assert_array_equal(stacked(blocks, "gyro"), from_file.gyro)
    np.testing.assert_array_equal(stacked(blocks, "mag"), from_file.mag)
    np.testing.assert_array_equal(stacked(blocks, "accel"), rows[:, :3])
    assert live.fmt == "motioncal" and live.units["mag_units"] == "counts"
    assert live.stats["malformed"] == from_file.malformed == 2
    assert live.stats["comments"] == from_file.skipped == 2
    assert live.stats["samples"] == 40 and np.all(np.diff(stacked(blocks, "time")) > 0)


@pytest.mark.parametrize(
    ("data", "kind"),
    [(b"Initializing I2C devices...\nTesting device connections...\nMPU6050 connection "
      b"successful\n" + i2cdevlib_text(counts(30, 2, 6)), "i2cdevlib"),
     (b"-371,88\n" + motioncal_text(counts(30, 3, 9)), "motioncal"),  # opened mid-line
     (i2cdevlib_text(counts(30, 4, 9), "a/g/m:"), "i2cdevlib-mag"),
     (b"# banner\n2,3\n" + "".join(f"{k * 0.01:.2f},{k},2,3,4,5,6\n" for k in range(30))
      .encode(), "numbers")],
)  # fmt: skip
def test_the_first_lines_tell_which_lines(data, kind):
    said = []
    protocol = AutoLineProtocol(SPEC, on_choice=said.append)
    blocks = feed_in_pieces(protocol, data, 11)
    assert sum(len(b) for b in blocks) == 30
    assert protocol.stats["bytes"] == len(data)
    if kind == "numbers":
        assert protocol.columns is SPEC and not said and protocol.units == {}
        np.testing.assert_allclose(stacked(blocks, "time")[:2], [0.0, 0.01])
        assert protocol.stats["malformed"] == 1  # the cut first line "2,3"
    else:
        assert protocol.columns is None and len(said) == 1 and "recognised" in said[0]
        assert protocol.units["accel_units"] == "counts"
        assert (blocks[0].mag is None) == (kind == "i2cdevlib")


def test_garbage_is_read_as_lines_of_numbers_that_do_not_parse():
    """No prefix and no number: after DECIDE_LINES lines the --columns reader counts them
    malformed (so capture can say 'wrong baud rate?')."""
    protocol = AutoLineProtocol(SPEC)
    junk = bytes(np.random.default_rng(5).integers(128, 256, 3000, dtype=np.uint8))
    data = b"\n".join(junk[i : i + 100] for i in range(0, 3000, 100)) + b"\n"
    assert not feed_in_pieces(protocol, data, 64)
    assert protocol.columns is SPEC and protocol.stats["malformed"] == 30
    assert protocol.stats["samples"] == 0


def test_a_capture_of_motioncal_lines_stores_counts_and_the_magnetometer(tmp_path):
    rows = counts(120, 6, 9)
    data = motioncal_text(rows)
    chunks = [data[i : i + 97] for i in range(0, len(data), 97)]
    rec = Recorder(tmp_path / "mc.h5", ScriptedSource(chunks), AutoLineProtocol(SPEC))
    got = sum(len(b) for b in rec.blocks())
    rec.close()
    s = read_session(tmp_path / "mc.h5")
    assert got == len(s.time) == 120
    np.testing.assert_array_equal(s.accel, rows[:, 0:3])
    np.testing.assert_array_equal(s.gyro, rows[:, 3:6])
    np.testing.assert_array_equal(s.mag, rows[:, 6:9])
    assert (s.accel_units, s.gyro_units, s.mag_units) == ("counts", "counts", "counts")


def test_capture_protocol_choices_refuse_what_does_not_fit(tmp_path):
    from .cli_helpers import assert_one_line_error, run

    assert_one_line_error(run("capture", "--port", "/dev/null", "--protocol", "motioncal",
                              "--plan", "warmup:5", "--no-prompt", "-o", tmp_path / "w.h5"),
                          "warm-up: motioncal lines carry none")  # fmt: skip
    assert_one_line_error(run("simulate", "--protocol", "motioncal", "-o", tmp_path / "x.h5"),
                          "--protocol is what --serve prints")  # fmt: skip
    from imucal_cli.cli import completion
    from imucal_cli.simulate.device import SERVE_PROTOCOLS

    assert completion.SERVE_PROTOCOLS == SERVE_PROTOCOLS


def test_an_axis_that_is_never_a_number_is_named(tmp_path):
    """Issue 24.6: a sketch that prints ``nan`` for an axis it cannot read (a disconnected
    sensor) was told "no valid line (60 malformed, 7 fields per line expected): wrong baud
    rate?", every line having its 7 fields.  The field is named instead."""
    data = "".join(f"{0.01 * i:.2f},nan,{i},8192,1,2,3\r\n" for i in range(60)).encode()
    chunks = [data[i : i + 97] for i in range(0, len(data), 97)]
    rec = Recorder(tmp_path / "nan.h5", ScriptedSource(chunks), AutoLineProtocol(SPEC))
    assert sum(len(b) for b in rec.blocks()) == 0
    rec.close()
    note = rec.received_note()
    assert "field(s) ax (nan or inf in 60 lines) not a number" in note, note
    assert "baud rate?" not in note, note
