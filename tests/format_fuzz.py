"""Damaged files of every importer, and the oracle that judges what a reader made of one (issue
26.1): shared by ``bench/reliability.py`` (hundreds of files per format) and the fast suite
(``tests/test_format_fuzz.py``, a few per format).

Each format's base file is written by the library that writes it in the field (rosbags, mcap,
mcap-ros1-support, pymavlink, the ULog specification read back by pyulog, the sketches' and
devices' own line and frame layouts), with random values.  A mutation changes bytes in place
(a flipped bit, a byte set, a length-like field set to 0x7fffffff, 64 bytes zeroed, a block
copied over another) or cuts the file.  The reader must then give a one-line ImucalError (exit
2), or samples that are the file's own:

- every row whose values are a written sample's must have that sample's time (formats with a
  time of their own);
- a row whose values (or time) no written sample has is *silently wrong*, unless the format has
  no checksum over it and the mutation hit that sample's own bytes (no reader can tell a flipped
  bit in a float from a value): those are counted apart, as "read as damaged".
"""

from __future__ import annotations

import array
import shutil
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

N = 240  # samples per base file
RATE = 200.0


@dataclass
class Base:
    """A format's undamaged file and what it holds."""

    name: str
    fmt: str
    paths: list[Path]
    target: Path  # the file mutated (one of paths, or inside a folder of paths)
    time: np.ndarray  # (N,) s, as the reader must give them
    values: np.ndarray  # (N, 6) accel then gyro (or (N, 3): accel only)
    timed: bool  # the format has its own time (else time = sample / rate)
    checked: bool  # a checksum covers every sample's bytes
    anchors: list[list[int]] = field(default_factory=list)  # per sample: byte offsets in target
    window: tuple[int, int] = (-64, 64)  # bytes around an anchor that belong to the sample
    options: dict = field(default_factory=dict)  # read_recording keyword arguments

    def hit(self, j: int, ranges: list[tuple[int, int]]) -> bool:
        """Whether a mutated byte range lies within sample ``j``'s bytes."""
        if not self.anchors:
            return True
        lo, hi = self.window
        return any(a + lo < stop and start < a + hi for a in self.anchors[j]
                   for start, stop in ranges)  # fmt: skip


def _signals(seed: int):
    rng = np.random.default_rng(seed)
    t = 1000.0 + np.arange(N) / RATE
    return t, rng.normal(0, 3, (N, 3)) + [0, 0, 9.8], rng.normal(0, 0.5, (N, 3)), rng


def _anchors(data: bytes, signatures: list[list[bytes]]) -> list[list[int]]:
    out = []
    for sigs in signatures:
        found = [data.find(s) for s in sigs]
        out.append([f for f in found if f >= 0])
    return out


# --------------------------------------------------------------------------------------------
# Base files
# --------------------------------------------------------------------------------------------


def _ros(folder: Path, kind: str) -> Base:
    from tests.test_import_formats import write_bag

    t, a, w, _ = _signals(11)
    path = folder / ("bag.bag" if kind == "ros1" else f"bag_{kind}")
    write_bag(path, {"ros2-mcap": "mcap"}.get(kind, kind), mag=False, temp=False, data=(t, a, w))
    target = path if path.is_file() else next(p for p in path.iterdir()
                                              if p.suffix in (".db3", ".mcap"))  # fmt: skip
    data = target.read_bytes()
    sigs = [[struct.pack("<3d", *w[i]), struct.pack("<3d", *a[i])] for i in range(N)]
    return Base(f"ROS {kind} bag (rosbags)", "ros", [path], target, t, np.hstack([a, w]), True,
                False, _anchors(data, sigs), (-160, 120))  # fmt: skip


def _mcap(folder: Path, kind: str) -> Base:
    from tests.ros_fixture import write_mcap_ros1, write_mcap_ros2

    t, a, w, _ = _signals(12)
    path = folder / f"{kind}.mcap"
    if kind == "mcap-ros1":
        write_mcap_ros1(path, (t, a, w), mag=False, temp=False)
    else:
        write_mcap_ros2(path, (t, a, w), summary=kind == "mcap-ros2")
    return Base(f"MCAP {kind[5:]} (mcap writers)", "ros", [path], path, t, np.hstack([a, w]),
                True, True)  # fmt: skip


def _ulog(folder: Path, fifo: bool) -> Base:
    from tests.ulog_fixture import FIFO_FIELDS, SENSOR_FIELDS, write_ulog

    t, a, w, rng = _signals(13)
    t_us = np.round((t - t[0]) * 1e6 + 2e6)
    path = folder / ("fifo.ulg" if fifo else "raw.ulg")
    if not fifo:
        a32, w32 = a.astype(np.float32), w.astype(np.float32)

        def cols(xyz, dev):
            return {"timestamp": (t_us + 50).astype(np.uint64), "timestamp_sample":
                    t_us.astype(np.uint64), "device_id": [dev] * N, "x": xyz[:, 0],
                    "y": xyz[:, 1], "z": xyz[:, 2], "temperature": [30.0] * N}  # fmt: skip

        write_ulog(path, [("sensor_accel", 0, SENSOR_FIELDS, cols(a32, 1)),
                          ("sensor_gyro", 0, SENSOR_FIELDS, cols(w32, 2))])  # fmt: skip
        data = path.read_bytes()
        sigs = [[struct.pack("<3f", *a32[i]), struct.pack("<3f", *w32[i])] for i in range(N)]
        return Base("PX4 ULog sensor_accel/gyro", "ulog", [path], path, t_us * 1e-6,
                    np.hstack([a32, w32]).astype(float), True, False, _anchors(data, sigs),
                    (-32, 20))  # fmt: skip
    per = 8  # samples per FIFO message
    n_msg = N // per
    scales = (9.80665 / 2048, 0.0010652644)
    raws = [rng.integers(-20000, 20000, (n_msg, 32, 3)).astype(np.int16) for _ in range(2)]
    ends = t_us[per - 1 :: per][:n_msg]
    topics = []
    for name, raw, scale in zip(("sensor_accel_fifo", "sensor_gyro_fifo"), raws, scales,
                                strict=True):  # fmt: skip
        topics.append((name, 0, FIFO_FIELDS, {
            "timestamp": (ends + 300).astype(np.uint64), "timestamp_sample": ends.astype(np.uint64),
            "device_id": [7] * n_msg, "dt": [5000.0] * n_msg, "scale": [scale] * n_msg,
            "samples": [per] * n_msg, "x": raw[:, :, 0], "y": raw[:, :, 1], "z": raw[:, :, 2]}))
    write_ulog(path, topics)
    data = path.read_bytes()
    values = np.hstack([raws[s][:, :per].reshape(-1, 3).astype(float)  # int16 x the logged
                        * float(np.float32(scales[s])) for s in (0, 1)])  # float32 scale
    sigs = [[struct.pack("<32h", *raws[s][i // per, :, 0]) for s in (0, 1)] for i in range(N)]
    return Base("PX4 ULog FIFO topics", "ulog", [path], path, t_us[: n_msg * per] * 1e-6,
                values.astype(float), True, False, _anchors(data, sigs), (-40, 200))  # fmt: skip


def _tlog(folder: Path) -> Base:
    from tests.mavlink_fixture import EPOCH_US, TlogWriter

    t, a, w, _ = _signals(14)
    writer = TlogWriter()
    t_us = np.round((t - t[0]) * 1e6 + 2e6).astype(np.int64)
    a32, w32 = a.astype(np.float32), w.astype(np.float32)
    for k in range(N):
        writer.add(EPOCH_US + int(t_us[k]) + 2000, "highres_imu", int(t_us[k]), *a32[k], *w32[k],
                   0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 30.0, 0x1FFF, 0)  # fmt: skip
    path = writer.write(folder / "log.tlog")
    return Base("MAVLink telemetry log (pymavlink)", "mavlink", [path], path, t_us * 1e-6,
                np.hstack([a32, w32]).astype(float), True, True)  # fmt: skip


def _dataflash(folder: Path, kind: str) -> Base:
    from tests.mavlink_fixture import DataFlashWriter, imu_row

    t, a, w, rng = _signals(15)
    writer = DataFlashWriter()
    writer.add("MSG", [0, "ArduCopter V4.5.0"])
    t_us = np.round((t - t[0]) * 1e6 + 2e6).astype(np.int64)
    a32, w32 = a.astype(np.float32), w.astype(np.float32)
    sigs: list[list[bytes]] = []
    if kind in ("IMU", "text"):
        for k in range(N):
            writer.add("IMU", imu_row(int(t_us[k]), 0, a32[k], w32[k], 31.5))
            sigs.append([struct.pack("<3f", *w32[k])])
        values, window = np.hstack([a32, w32]).astype(float), (-16, 40)
    elif kind == "ACC":
        for k in range(N):
            writer.add("ACC", [int(t_us[k]) + 300, 0, int(t_us[k]), *map(float, a32[k])])
            writer.add("GYR", [int(t_us[k]) + 300, 0, int(t_us[k]), *map(float, w32[k])])
            sigs.append([struct.pack("<3f", *a32[k]), struct.pack("<3f", *w32[k])])
        values, window = np.hstack([a32, w32]).astype(float), (-24, 16)
    else:  # ISB: one accel and one gyro batch over the same time, 32 samples per ISBD
        raws = [rng.integers(-3000, 3000, (N, 3)) for _ in range(2)]
        logged = int(t_us[0] + N / RATE * 1e6 + 1000)  # the header: logged once complete
        heads = []
        for number, (sensor, raw, mul) in enumerate(((0, raws[0], 208), (1, raws[1], 938))):
            head = [logged, number, sensor, 0, mul, N, int(t_us[0]), RATE]
            writer.add("ISBH", head)
            heads.append(struct.pack("<QHBBHHQf", *head))
            for seqno in range(N // 32 + 1):
                part = np.vstack([raw[32 * seqno : 32 * seqno + 32], np.zeros((32, 3), int)])[:32]
                writer.add("ISBD", [int(t_us[0]) + seqno, number, seqno,
                                    *(array.array("h", map(int, part[:, j])) for j in range(3))])
        values = np.hstack([raws[0] / 208, raws[1] / 938])
        sigs = [[struct.pack("<32h", *np.vstack([raws[s][32 * (i // 32) : 32 * (i // 32) + 32],
                                                 np.zeros((32, 3), int)])[:32, 0])
                 for s in (0, 1)] + heads for i in range(N)]  # fmt: skip
        window = (-16, 200)
        t_us = t_us[0] + np.round(np.arange(N) / RATE * 1e6)
    path = writer.write(folder / f"df_{kind}.bin")
    if kind == "text":
        path = folder / "df.log"
        path.write_text(writer.text())
        data = path.read_bytes()
        lines = [f"IMU, {int(t_us[k])}, 0, ".encode() for k in range(N)]
        return Base("ArduPilot text log (.log)", "mavlink", [path], path, t_us * 1e-6,
                    values, True, False, _anchors(data, [[s] for s in lines]), (0, 160))
    name = {"IMU": "IMU", "ACC": "ACC/GYR", "ISB": "ISBH/ISBD"}[kind]
    return Base(f"ArduPilot DataFlash {name} (pymavlink)", "mavlink", [path], path,
                t_us * 1e-6, values, True, False, _anchors(path.read_bytes(), sigs), window,
                {"topic": "ISB.0"} if kind == "ISB" else {})  # fmt: skip


def _text_lines(folder: Path, kind: str) -> Base:
    t, a, w, rng = _signals(16)
    ra, rw = rng.integers(-16000, 16000, (N, 3)), rng.integers(-16000, 16000, (N, 3))
    if kind == "motioncal":
        lines = ["Raw:" + ",".join(str(v) for v in (*ra[i], *rw[i], 10, 20, 30)) for i in range(N)]
    else:
        lines = ["a/g:\t" + "\t".join(str(v) for v in (*ra[i], *rw[i])) for i in range(N)]
    path = folder / f"{kind}.txt"
    path.write_text("\n".join(lines) + "\n")
    data = path.read_bytes()
    return Base(f"{kind} lines", "lines", [path], path, np.arange(N) / RATE,
                np.hstack([ra, rw]).astype(float), False, False,  # no time of their own
                _anchors(data, [[(ln + "\n").encode()] for ln in lines]), (0, 70),
                {"rate_hz": RATE})  # fmt: skip


def _witmotion(folder: Path) -> Base:
    from tests.test_import_formats import wit_frame

    _, _, _, rng = _signals(17)
    ra, rw = rng.integers(-32000, 32000, (N, 3)), rng.integers(-32000, 32000, (N, 3))
    frames = [wit_frame(0x51, [*ra[i], 2500]) + wit_frame(0x52, [*rw[i], 0]) for i in range(N)]
    path = folder / "wit.bin"
    path.write_bytes(b"".join(frames))
    data = path.read_bytes()
    return Base("WitMotion frames", "witmotion", [path], path, np.arange(N) / RATE,
                np.hstack([ra, rw]).astype(float), False, False,
                _anchors(data, [[f] for f in frames]), (0, 22), {"rate_hz": RATE})  # fmt: skip


def _imu_tk(folder: Path) -> Base:
    t, a, w, _ = _signals(18)
    acc = folder / "acc.txt"
    gyr = folder / "gyr.txt"
    lines = [f"{t[i]:.3f} " + " ".join(repr(float(v)) for v in a[i]) for i in range(N)]
    acc.write_text("\n".join(lines) + "\n")
    gyr.write_text("".join(f"{t[i]:.3f}\t" + "\t".join(repr(float(v)) for v in w[i]) + "\n"
                           for i in range(N)))  # fmt: skip
    data = acc.read_bytes()
    return Base("imu_tk pair", "imu_tk", [acc, gyr], acc, np.round(t, 3), np.hstack([a, w]),
                True, False, _anchors(data, [[(ln + "\n").encode()] for ln in lines]), (0, 90))


def _euroc(folder: Path) -> Base:
    t, a, w, _ = _signals(19)
    ns = (1403636579758555392 + np.arange(N, dtype=np.int64) * 5_000_000)
    head = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
            "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")  # fmt: skip
    lines = [f"{ns[i]}," + ",".join(repr(float(v)) for v in (*w[i], *a[i])) for i in range(N)]
    path = folder / "data.csv"
    path.write_text("\n".join([head, *lines]) + "\n")
    data = path.read_bytes()
    return Base("EuRoC / TUM-VI CSV", "csv", [path], path, ns * 1e-9, np.hstack([a, w]), True,
                False, _anchors(data, [[(ln + "\n").encode()] for ln in lines]), (0, 140))


MAKERS: dict[str, Callable[[Path], Base]] = {
    "ros1": lambda f: _ros(f, "ros1"),
    "ros2-sqlite": lambda f: _ros(f, "ros2"),
    "ros2-mcap": lambda f: _ros(f, "ros2-mcap"),
    "mcap-ros2": lambda f: _mcap(f, "mcap-ros2"),
    "mcap-nosummary": lambda f: _mcap(f, "mcap-nosummary"),
    "mcap-ros1": lambda f: _mcap(f, "mcap-ros1"),
    "ulog": lambda f: _ulog(f, False),
    "ulog-fifo": lambda f: _ulog(f, True),
    "tlog": _tlog,
    "dataflash": lambda f: _dataflash(f, "IMU"),
    "dataflash-acc": lambda f: _dataflash(f, "ACC"),
    "dataflash-isb": lambda f: _dataflash(f, "ISB"),
    "dataflash-text": lambda f: _dataflash(f, "text"),
    "motioncal": lambda f: _text_lines(f, "motioncal"),
    "i2cdevlib": lambda f: _text_lines(f, "i2cdevlib"),
    "witmotion": _witmotion,
    "imu_tk": _imu_tk,
    "euroc": _euroc,
}
"""Every importer's base file (CSV has its own line-level fuzzer in ``bench/reliability.py``)."""


# --------------------------------------------------------------------------------------------
# Mutations and the oracle
# --------------------------------------------------------------------------------------------


def mutate(data: bytes, rng: np.random.Generator) -> tuple[bytes, list[tuple[int, int]], str]:
    """A damaged copy of ``data``, the byte ranges changed (a cut: from it to the end), and
    what was done."""
    out = bytearray(data)
    n = len(out)
    kind = int(rng.integers(6))
    at = int(rng.integers(0, max(n - 72, 1)))
    if kind == 0:
        out[at] ^= 1 << int(rng.integers(8))
        return bytes(out), [(at, at + 1)], "bit flipped"
    if kind == 1:
        out[at] = int(rng.integers(256))
        return bytes(out), [(at, at + 1)], "byte set"
    if kind == 2:
        out[at : at + 4] = b"\xff\xff\xff\x7f"
        return bytes(out), [(at, at + 4)], "0x7fffffff written"
    if kind == 3:
        out[at : at + 64] = bytes(64)
        return bytes(out), [(at, at + 64)], "64 bytes zeroed"
    if kind == 4:
        src = int(rng.integers(0, max(n - 72, 1)))
        out[at : at + 48] = data[src : src + 48]
        return bytes(out), [(at, at + 48)], "48 bytes copied over others"
    cut = int(rng.integers(0, n))
    return bytes(out[:cut]), [(cut, n + 1)], "cut"


def place(base: Base, data: bytes, folder: Path) -> list[Path]:
    """The damaged file(s) in ``folder``, as the reader takes them."""
    case = folder / "case"
    shutil.rmtree(case, ignore_errors=True)
    case.mkdir()
    paths = []
    for p in base.paths:
        if p.is_dir():
            shutil.copytree(p, case / p.name)
            (case / p.name / base.target.name).write_bytes(data)
        else:
            (case / p.name).write_bytes(data if p == base.target else p.read_bytes())
        paths.append(case / p.name)
    return paths


@dataclass
class Judgement:
    verdict: str  # "handled" or "silent wrong"
    wrong: int  # rows silently wrong
    damaged: int  # rows read from bytes the mutation hit, in a format without checksum
    detail: str = ""


def judge(base: Base, rec, ranges: list[tuple[int, int]]) -> Judgement:
    """What a reader that accepted a damaged file gave (``rec``: a Recording), against the
    file's truth (module notes)."""
    accel = rec.accel if rec.accel is not None else np.zeros((len(rec.time), 0))
    got = accel if rec.gyro is None or base.values.shape[1] == 3 else np.hstack([accel, rec.gyro])
    width = got.shape[1]
    truth = base.values[:, :width]
    index = {tuple(row): j for j, row in enumerate(truth)}
    period = float(np.median(np.diff(base.time)))
    hit = [] if base.checked else [i for i in range(len(truth)) if base.hit(i, ranges)]
    wrong = damaged = unattributed = 0
    first = ""
    for k in range(len(rec.time)):
        j = index.get(tuple(got[k]))
        if j is not None and (not base.timed or abs(rec.time[k] - base.time[j]) <= 1e-6):
            continue
        if j is None and base.timed:
            near = int(np.argmin(np.abs(base.time - rec.time[k])))
            j = near if abs(base.time[near] - rec.time[k]) < 0.5 * period else None
        if not base.checked and j is not None and base.hit(j, ranges):
            damaged += 1
            continue
        # Not the sample of its time or values: bytes moved by the mutation (a block copied
        # over a message's header) make another sample's message; at most two rows (accel and
        # gyro messages) per sample whose bytes were hit, in a format without checksum.
        if hit and unattributed < 2 * len(hit):
            unattributed += 1
            damaged += 1
            continue
        wrong += 1
        if not first:
            first = (f"row {k}: t {rec.time[k]:.6f}, values {np.round(got[k], 4).tolist()} "
                     f"(nearest written sample {j})")  # fmt: skip
    return Judgement("silent wrong" if wrong else "handled", wrong, damaged, first)
