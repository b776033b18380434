"""Issue 26: ROS recordings as their writers leave them.

- MCAP of ROS 1 messages (what ``mcap-ros1-support`` and ``mcap convert x.bag`` write) is read:
  values, stamps (genpy's ``secs``/``nsecs``), magnetometer and temperature.
- A valid MCAP without a summary section (``mcap``'s writer with no index and no statistics)
  is read, message by message, CRCs checked.
- Damaged ROS 1 bags, ROS 2 bags (sqlite3 and MCAP storage) and MCAP files give one line and
  exit 2, never a traceback; an MCAP whose length field asks for gigabytes is "damaged" (exit
  2), not "not enough memory"; what a damaged file still yields is the file's own values
  (MCAP: every chunk's CRC checked, so a damaged chunk is refused; a bag has no checksum, so a
  value whose own bytes were hit cannot be told, every other value must be right).
"""

from __future__ import annotations

import shutil
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from imucal_cli.errors import InputError
from imucal_cli.formats.importers.ros import read_mcap, read_ros

from .cli_helpers import assert_one_line_error, run
from .ros_fixture import imu_samples, write_mcap_ros1, write_mcap_ros2
from .test_import_formats import write_bag

pytest.importorskip("mcap_ros1")


def test_mcap_of_ros1_messages_is_read(tmp_path):
    path = tmp_path / "ros1.mcap"
    t, a, w = write_mcap_ros1(path)
    ch = read_mcap(path)
    np.testing.assert_allclose(ch.time, t, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(ch.accel, a)
    np.testing.assert_array_equal(ch.gyro, w)
    assert "time from header.stamp" in ch.notes
    np.testing.assert_allclose(ch.mag[5], [20.0, -5.0, 40.0])  # tesla -> uT, held
    np.testing.assert_allclose(ch.temperature[[0, 49, 50, 399]], [25.0, 25.0, 25.5, 28.5])
    out = tmp_path / "s.h5"
    proc = run("import", path, "-o", out, "--sections", _whole(tmp_path, len(t)))
    assert proc.returncode == 0, proc.stderr


def _whole(tmp_path: Path, n: int) -> Path:
    path = tmp_path / "sections.json"
    path.write_text(f'{{"z_p": {{"start": 0, "end": {n}}}}}')
    return path


def test_mcap_without_a_summary_is_read(tmp_path):
    path = tmp_path / "nosummary.mcap"
    t, a, w = write_mcap_ros2(path, summary=False)
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        assert make_reader(f).get_summary() is None  # the file is what the test means
    ch = read_mcap(path)
    np.testing.assert_allclose(ch.time, t, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(ch.accel, a)
    np.testing.assert_array_equal(ch.gyro, w)


def test_an_impossible_length_is_damaged_not_out_of_memory(tmp_path, monkeypatch):
    """A damaged length makes a decoder ask for more memory than there is (an MCAP whose record
    length was flipped did): "damaged", exit 2, not "not enough memory", exit 1."""
    import mcap_ros2.decoder

    path = tmp_path / "bad.mcap"
    write_mcap_ros2(path, imu_samples(50))
    real = mcap_ros2.decoder.DecoderFactory.decoder_for

    def decoder_for(self, encoding, schema):
        real(self, encoding, schema)

        def allocate(data: bytes):
            raise MemoryError  # what a length of 2**46 bytes does

        return allocate

    monkeypatch.setattr(mcap_ros2.decoder.DecoderFactory, "decoder_for", decoder_for)
    with pytest.raises(InputError, match="bad.mcap: damaged .*more memory than there is"):
        read_mcap(path)
    data = bytearray(path.read_bytes())  # and a record length past the file: refused at once
    at = 8
    while data[at] != 0x03:  # the schema record
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    data[at + 1 : at + 9] = struct.pack("<Q", 1 << 46)
    path.write_bytes(bytes(data))
    monkeypatch.undo()
    assert_one_line_error(run("import", path, "-o", tmp_path / "s.h5"), "bad.mcap")


def _samples_intact(data: bytes, a: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Whether each sample's six float64 values are still in ``data`` as they were written
    (ROS 1 and CDR both store them little-endian, three in a row per vector)."""
    return np.array([data.find(struct.pack("<3d", *a[i])) >= 0
                     and data.find(struct.pack("<3d", *w[i])) >= 0 for i in range(len(a))])


def _mutations(original: bytes, rng: np.random.Generator, n: int):
    for k in range(n):
        data = bytearray(original)
        kind = k % 5
        at = int(rng.integers(16, len(data) - 70))
        if kind == 0:
            data[at] ^= 1 << int(rng.integers(8))
        elif kind == 1:
            data = data[: int(rng.integers(len(data)))]
        elif kind == 2:
            data[at : at + 4] = b"\xff\xff\xff\x7f"
        elif kind == 3:
            data[at : at + 64] = bytes(64)
        else:
            data[at] = int(rng.integers(256))
        yield bytes(data)


@pytest.mark.parametrize("kind", ["ros1", "ros2", "mcap-storage", "mcap-ros1", "mcap-nosummary"])
def test_damaged_recordings_give_one_line_or_the_file_own_values(tmp_path, kind):
    data = imu_samples(120, seed=3)
    t, a, w = data
    src = tmp_path / "src"
    if kind in ("ros1", "ros2", "mcap-storage"):
        path = src.with_suffix(".bag") if kind == "ros1" else src
        write_bag(path, {"mcap-storage": "mcap"}.get(kind, kind), data=data, mag=False,
                  temp=False)  # fmt: skip
        target = path if path.is_file() else next(p for p in path.iterdir()
                                                  if p.suffix in (".db3", ".mcap"))  # fmt: skip
    else:
        path = target = src.with_suffix(".mcap")
        (write_mcap_ros1 if kind == "mcap-ros1" else write_mcap_ros2)(
            path, data, **({"summary": False} if kind == "mcap-nosummary" else {}))
    original = target.read_bytes()
    checksummed = kind in ("mcap-ros1", "mcap-nosummary")  # chunk CRCs
    rng = np.random.default_rng(26)
    seen = {"error": 0, "read": 0}
    for mutated in _mutations(original, rng, 40):
        case = tmp_path / "case"
        shutil.rmtree(case, ignore_errors=True)
        if path.is_file():
            case = case.with_suffix(path.suffix)
            case.write_bytes(mutated)
        else:
            shutil.copytree(path, case)
            (case / target.name).write_bytes(mutated)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ch = read_ros(case)
        except InputError as exc:
            assert "\n" not in str(exc)
            seen["error"] += 1
            continue
        seen["read"] += 1
        j = np.searchsorted(t, ch.time - 1e-6)
        intact = _samples_intact(mutated, a, w) if not checksummed else np.ones(len(t), bool)
        for k in range(len(ch.time)):
            if j[k] < len(t) and abs(ch.time[k] - t[j[k]]) < 1e-6 and \
                    np.array_equal(ch.accel[k], a[j[k]]) and np.array_equal(ch.gyro[k], w[j[k]]):
                continue  # fmt: skip
            # wrong: only where the sample's own bytes (or its time's) were hit, no checksum
            assert not checksummed, (kind, k)
            near = min(int(j[k]), len(t) - 1)
            assert not (intact[near] and intact[max(near - 1, 0)]) or \
                abs(ch.time[k] - t[near]) > 1e-6, (kind, k)  # fmt: skip
    assert seen["error"] > 0 and seen["read"] > 0, seen


def test_damaged_bag_through_the_command_is_one_line(tmp_path):
    path = tmp_path / "rec.bag"
    write_bag(path, "ros1", mag=False, temp=False, data=imu_samples(100))
    data = bytearray(path.read_bytes())
    data[len(data) // 2 : len(data) // 2 + 64] = bytes(64)
    path.write_bytes(bytes(data))
    proc = run("import", path, "-o", tmp_path / "s.h5")
    assert proc.returncode in (0, 2), proc.stderr
    if proc.returncode == 2:
        assert_one_line_error(proc, "rec.bag")
