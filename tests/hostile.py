"""Hostile inputs for the reliability suite (issue 11.6): malformed sessions, configs and
calibration JSONs, each a named case with what a correct reader must do.

Used by ``tests/test_reliability.py`` (every case, in ``make test``) and ``bench/reliability.py``
(the table).  A case is ``(name, make(folder) -> Path, expect)`` where ``expect`` is
``"error"`` (a one-line ``ImucalError``), ``"ok"`` (reads, and what it reads is right) or
``"either"`` (a byte flip: an error, or the very data of the original).
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BASE_SESSION = ROOT / "sessions" / "six-seed3.h5"

Case = tuple[str, Callable[[Path], Path], str]


# --------------------------------------------------------------------------------------------
# Sessions
# --------------------------------------------------------------------------------------------


def base_session(folder: Path, name: str = "base.h5") -> Path:
    """A valid session (rewritten by this package, so it has checksums and NaN fill)."""
    from imucal_cli.formats.session import read_session, write_session

    path = folder / name
    if not path.exists():
        write_session(path, read_session(BASE_SESSION))
    return path


def _edited(edit: Callable[[h5py.File, Path], None]) -> Callable[[Path], Path]:
    def make(folder: Path) -> Path:
        src = base_session(folder)
        path = folder / f"case-{id(edit)}.h5"
        shutil.copyfile(src, path)
        with h5py.File(path, "r+") as file:
            edit(file, folder)
        return path

    return make


def _bytes(transform: Callable[[bytes], bytes]) -> Callable[[Path], Path]:
    def make(folder: Path) -> Path:
        data = base_session(folder).read_bytes()
        path = folder / f"case-{id(transform)}.h5"
        path.write_bytes(transform(data))
        return path

    return make


def _set_attr(where: str, name: str, value) -> Callable[[h5py.File, Path], None]:
    def edit(file: h5py.File, folder: Path) -> None:
        file[where].attrs[name] = value

    return edit


def _del_attr(where: str, name: str) -> Callable[[h5py.File, Path], None]:
    def edit(file: h5py.File, folder: Path) -> None:
        del file[where].attrs[name]

    return edit


def _replace(name: str, data) -> Callable[[h5py.File, Path], None]:
    def edit(file: h5py.File, folder: Path) -> None:
        if name in file:
            del file[name]
        file[name] = data

    return edit


def _delete(name: str) -> Callable[[h5py.File, Path], None]:
    def edit(file: h5py.File, folder: Path) -> None:
        del file[name]

    return edit


def _external_storage(file: h5py.File, folder: Path) -> None:
    secret = folder / "secret.bin"
    n = file["raw/time"].shape[0]
    secret.write_bytes(np.arange(3 * n, dtype="f8").tobytes())
    del file["raw/accel"]
    file.create_dataset("raw/accel", shape=(n, 3), dtype="f8", external=[(str(secret), 0, 24 * n)])


def _external_link(file: h5py.File, folder: Path) -> None:
    other = folder / "other.h5"
    with h5py.File(other, "w") as f:
        f["time"] = file["raw/time"][()]
    del file["raw/time"]
    file["raw/time"] = h5py.ExternalLink(str(other), "/time")


def _soft_loop(file: h5py.File, folder: Path) -> None:
    del file["raw/time"]
    file["raw/time"] = h5py.SoftLink("/raw/loop")
    file["raw/loop"] = h5py.SoftLink("/raw/time")


def _soft_alias(file: h5py.File, folder: Path) -> None:
    file["raw/accel_copy"] = file["raw/accel"][()]
    del file["raw/accel"]
    file["raw/accel"] = h5py.SoftLink("/raw/accel_copy")


def _virtual(missing: bool) -> Callable[[h5py.File, Path], None]:
    def edit(file: h5py.File, folder: Path) -> None:
        source = folder / "vsource.h5"
        accel = file["raw/accel"][()]
        if not missing:
            with h5py.File(source, "w") as f:
                f["a"] = accel
        layout = h5py.VirtualLayout(shape=accel.shape, dtype="f8")
        layout[:] = h5py.VirtualSource(str(source), "a", shape=accel.shape)
        del file["raw/accel"]
        file["raw"].create_virtual_dataset("accel", layout, fillvalue=0.0)

    return edit


def _huge(file: h5py.File, folder: Path) -> None:
    for name in ("time", "accel", "gyro"):
        if name in file["raw"]:
            del file["raw"][name]
    file["raw"].create_dataset("time", shape=(2_000_000_000,), chunks=(1024,), dtype="f8")
    file["raw"].create_dataset("accel", shape=(2_000_000_000, 3), chunks=(1024, 3), dtype="f8")


def _unwritten_chunks(file: h5py.File, folder: Path) -> None:
    accel = file["raw/accel"][()]
    del file["raw/accel"]
    ds = file["raw"].create_dataset("accel", shape=accel.shape, chunks=(64, 3), dtype="f8")
    ds[:64] = accel[:64]  # the rest would read as zeros


def _log_garbage(rows: list[bytes]) -> Callable[[h5py.File, Path], None]:
    def edit(file: h5py.File, folder: Path) -> None:
        del file["segments"]
        file.create_group("segments")
        file["capture_log/segments"] = np.array(rows, dtype="S64")

    return edit


def _nan_in_segment(file: h5py.File, folder: Path) -> None:
    accel = file["raw/accel"][()]
    start = int(file["segments/0000"].attrs["start"])
    accel[start + 3, 1] = np.nan
    del file["raw/accel"]
    file["raw/accel"] = accel


def _time_edit(fn: Callable[[np.ndarray], np.ndarray]) -> Callable[[h5py.File, Path], None]:
    def edit(file: h5py.File, folder: Path) -> None:
        t = fn(file["raw/time"][()].copy())
        del file["raw/time"]
        file["raw/time"] = t

    return edit


def _byte_cases() -> list[Case]:
    """Cut, zeroed and overwritten files."""
    cases: list[Case] = []
    for size in (0, 7, 8, 16, 40, 47, 48, 100, 512, 1000, 4096, 20000, 100000):
        cases.append((f"truncated to {size} bytes", _bytes(lambda d, s=size: d[:s]), "error"))
    cases.append(("truncated by one byte", _bytes(lambda d: d[:-1]), "error"))
    cases.append(("half the file", _bytes(lambda d: d[: len(d) // 2]), "error"))
    cases.append(("zeros", _bytes(lambda d: bytes(len(d))), "error"))
    cases.append(("text file named .h5", _bytes(lambda d: b"t,ax,ay,az\n0,1,2,3\n"), "error"))
    rng = np.random.default_rng(11)
    for k in range(30):
        offset = int(rng.integers(0, 225_000))
        span = int(rng.integers(1, 65))

        def flip(d: bytes, o=offset, n=span, seed=k) -> bytes:
            noise = np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()
            o = min(o, len(d) - n)
            flipped = bytes(a ^ b | 1 for a, b in zip(d[o : o + n], noise, strict=True))
            return d[:o] + flipped + d[o + n :]

        cases.append((f"{span} bytes overwritten at {offset}", _bytes(flip), "either"))
    return cases


def session_cases() -> list[Case]:
    """Every malformed-session case (more than 100), deterministic."""
    cases: list[Case] = [("valid session", base_session, "ok"), *_byte_cases()]

    def add(name: str, edit, expect: str = "error") -> None:
        cases.append((name, _edited(edit), expect))

    for name, value in [
        ("format", "imucal-calibration"), ("format", 7), ("format", b"\xff\xfe"),
        ("format_version", 2), ("format_version", "1"), ("format_version", 1.5),
        ("format_version", np.array([1, 1])), ("format_version", np.nan),
        ("created", 20260101), ("sensor", 5),
        ("source", np.zeros(3)), ("sample_rate_hz", -100.0), ("sample_rate_hz", 0.0),
        ("sample_rate_hz", np.nan), ("sample_rate_hz", np.inf), ("sample_rate_hz", "fast"),
        ("gravity", -9.8), ("gravity", np.inf), ("gravity", 1e308), ("gravity", 0.5),
        ("accel_units", 3),
    ]:  # fmt: skip
        add(f"root {name} = {value!r}", _set_attr("/", name, value))
    add("root sensor with ANSI escapes", _set_attr("/", "sensor", "\x1b[2J\x1b[31mred"), "ok")
    add("root sensor not UTF-8", _set_attr("/", "sensor", b"\xff\xfe bad utf-8"), "ok")
    for name in ("format", "format_version", "created"):
        add(f"root {name} missing", _del_attr("/", name))
    n = 6  # segments in six-seed3
    raw_cases = {
        "time missing": _delete("raw/time"),
        "raw missing": _delete("raw"),
        "raw is a dataset": _replace("raw", np.zeros(3)),
        "time 2-D": _time_edit(lambda t: t.reshape(-1, 1)),
        "time as text": _replace("raw/time", np.array([b"a", b"b"])),
        "time NaN": _time_edit(lambda t: np.where(np.arange(t.size) == 10, np.nan, t)),
        "time infinite": _time_edit(lambda t: np.where(np.arange(t.size) == 10, np.inf, t)),
        "time decreasing": _time_edit(lambda t: t[::-1]),
        "time repeated": _time_edit(lambda t: np.where(np.arange(t.size) == 5, t[4], t)),
        # stamps 1e10 s apart (another unit): noise gave 1e8 ug/sqrt(Hz), exit 0 (audit)
        "time in 1e10 s steps": _time_edit(lambda t: t * 1e12),
        "time shorter": _time_edit(lambda t: t[:-7]),
        "time longer": _time_edit(lambda t: np.concatenate([t, t[-1] + 1 + np.arange(3.0)])),
        "accel 1-D": _replace("raw/accel", np.zeros(10)),
        "accel 2 channels": _replace("raw/accel", np.zeros((10, 2))),
        "accel complex": _replace("raw/accel", np.zeros((10, 3), complex)),
        "gyro as a group": lambda f, d: (f.__delitem__("raw/gyro"), f.create_group("raw/gyro")),
        "temperature 2-D": _replace("raw/temperature", np.zeros((3, 3))),
        "external storage (another file's bytes)": _external_storage,
        "external link to another file": _external_link,
        "soft-link loop": _soft_loop,
        "soft link inside the file": _soft_alias,
        "virtual dataset": _virtual(missing=False),
        "virtual dataset, source missing": _virtual(missing=True),
        "2e9 samples declared in a small file": _huge,
        "chunks never written (would read zeros)": _unwritten_chunks,
        "NaN accel inside a segment": _nan_in_segment,
        # 1e300 readings: an OverflowError traceback in calibrate, numpy's warnings (audit)
        "accel of 1e300": lambda f, d: f["raw/accel"].__setitem__(
            slice(None), f["raw/accel"][()] * 1e300),
    }
    for name, edit in raw_cases.items():
        add(name, edit)
    seg = "segments/0000"
    for name, value in [
        ("kind", "wobble"), ("kind", 3), ("start", -1), ("start", 10**9), ("stop", 0),
        ("start", 2.5), ("start", "zero"), ("stop", np.nan), ("up", [0.0, 0.0]),
        ("up", [0.0, 0.0, 0.0]), ("up", [np.nan, 0.0, 1.0]), ("up", "up"), ("label", 7),
        ("axis", [1.0, 0.0, 0.0]), ("angle_deg", 90.0),
    ]:  # fmt: skip
        expect = "ok" if name in ("axis", "angle_deg") else "error"  # extra attributes of a static
        add(f"segment {name} = {value!r}", _set_attr(seg, name, value), expect)
    for name in ("kind", "start", "stop"):
        add(f"segment {name} missing", _del_attr(seg, name))
    add("segment label with a bidi override", _set_attr(seg, "label", "evil\u202etxt"), "ok")
    # a known turn of 1e300 deg overflowed the known-angle fit: a traceback (audit)
    add("rotation angle_deg = 1e300", _set_attr("segments/0001", "angle_deg", 1e300))
    add("segment is a dataset", lambda f, d: (f.__delitem__(seg), f.__setitem__(seg, 1)), "ok")
    add("no segments group", _delete("segments"), "ok")
    add("capture log with garbage", _log_garbage([b"{", b"not json"]))
    add("capture log row without a name", _log_garbage([b'{"kind": "static"}']))
    add("calibrations is a dataset", _replace("calibrations", np.zeros(2)), "ok")
    assert len(cases) > 100, len(cases)
    assert n == 6
    return cases


# --------------------------------------------------------------------------------------------
# Configs (TOML)
# --------------------------------------------------------------------------------------------


def config_cases() -> list[tuple[str, bytes, str]]:
    """(name, file content, expect) for the calibrate config: more than 100 cases."""
    cases: list[tuple[str, bytes, str]] = [
        ("empty", b"", "ok"),
        ("defaults", b"gravity = 9.81\n", "ok"),
    ]
    bad_numbers = ["nan", "inf", "-inf", "0", "-1", "1e400", '"1"', "true", "[1]", "{a = 1}"]
    keys = {
        "": ["gravity"],
        "accel": ["nominal_sensitivity", "max_scale_error", "min_separation_deg"],
        "accel.gravity": ["max_iterations"],
        "accel.factorization": ["max_iterations", "fixture_tolerance_deg"],
        "gyro": ["nominal_sensitivity", "max_scale_error"],
        "gyro.rotations": ["max_gap_s", "min_tilt_deg"],
        "gyro.full": ["max_iterations"],
        "gyro.factorization": ["samples_per_segment", "max_iterations"],
    }
    for table, names in keys.items():
        for key in names:
            for value in bad_numbers:
                head = f"[{table}]\n" if table else ""
                zero_ok = value == "0" and key in ("fixture_tolerance_deg", "min_tilt_deg")
                text = f"{head}{key} = {value}\n".encode()
                cases.append((f"[{table}] {key} = {value}", text, "ok" if zero_ok else "error"))
    for value in ("9223372036854775807", "2147483648", "-5"):
        cases.append(
            (
                f"max_iterations = {value}",
                f"[accel.gravity]\nmax_iterations = {value}\n".encode(),
                "error",
            )
        )
    for text in [
        "[accel]\nnominal_bias = [1, 2]\n", "[accel]\nnominal_bias = [nan, 0, 0]\n",
        "[accel]\nnominal_bias = \"zero\"\n", "[accel]\nrange = [1]\n",
        "[accel]\nrange = [5, 1]\n", "[accel]\nrange = [nan, 1]\n",
        "[accel]\nrange = [-inf, inf]\n", "[accel]\nsolver = \"magic\"\n",
        "[accel.gravity]\nmodel = \"10\"\n", "[accel.gravity]\ninit = 3\n",
        "[gyro]\nsolver = [\"static\"]\n", "[accel]\nunknown_key = 1\n", "[nope]\n",
        "accel = 3\n", "gravity = 9.81\ngravity = 9.8\n", "this is not toml\n",
        "[accel]\nmax_scale_error = 1.5\n", "[gyro.rotations]\nmin_tilt_deg = 95\n",
    ]:  # fmt: skip
        cases.append((text.strip().replace("\n", " "), text.encode(), "error"))
    cases.append(("nominal_bias of 3", b"[accel]\nnominal_bias = [1.0, 2.0, 3.0]\n", "ok"))
    cases.append(("not UTF-8", b"gravity = 9.81 # \xff\xfe\n", "error"))
    cases.append(("NUL byte", b"gravity = 9.81\x00\n", "error"))
    cases.append(("deep nesting", b"a = " + b"[" * 5000 + b"]" * 5000 + b"\n", "error"))
    cases.append(
        ("huge integer", b"[accel.gravity]\nmax_iterations = " + b"9" * 400 + b"\n", "error")
    )
    cases.append(  # past Python's 4300-digit limit of int() (issue 26)
        ("20,000-digit integer", b"[accel.gravity]\nmax_iterations = " + b"9" * 20_000 + b"\n",
         "error")
    )
    assert len(cases) > 100, len(cases)
    return cases


# --------------------------------------------------------------------------------------------
# Calibration JSON
# --------------------------------------------------------------------------------------------


def calibration_cases(valid: str) -> list[tuple[str, bytes, str]]:
    """(name, file content, expect) for calibration JSONs, from a valid document's text."""
    import json

    doc = json.loads(valid)
    cases: list[tuple[str, bytes, str]] = [("valid", valid.encode(), "ok")]

    def with_(path: str, value, expect: str = "error") -> None:
        d = json.loads(valid)
        node = d
        keys = path.split(".")
        for key in keys[:-1]:
            node = node[int(key)] if isinstance(node, list) else node[key]
        last = keys[-1]
        if value is _DELETE:
            del node[last]
        elif isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
        cases.append((f"{path} = {str(value)[:30]}", json.dumps(d).encode(), expect))

    for section in [name for name in ("accel", "gyro") if name in doc]:
        for field, values in {
            "bias": [[0, 0], [0, "1", 0], [None, 0, 0], "x", [], [[0, 0, 0]], [10**400, 0, 0],
                     [True, 0, 0], {"x": 0}],
            "matrix": [[[1, 0, 0]], [[1, 0], [0, 1], [0, 0]], "I", [[1, 0, 0]] * 4, None,
                       [[1, 0, 0], [0, 1, 0], [0, 0, "1"]], [[1, 0, 0], [0, 1, 0], [0, 0, 10**400]],
                       [[1, 0, 0], [0, 1, 0], None], [],
                       # no sensor's: apply wrote zeros, or 1e30 m/s^2, exit 0 (audit)
                       [[0, 0, 0]] * 3, [[1e30, 0, 0], [0, 1e30, 0], [0, 0, 1e30]],
                       [[1e-300, 0, 0], [0, 1e-300, 0], [0, 0, 1e-300]],
                       [[1, 2, 3], [2, 4, 6], [1, 1, 1]]],
            "units": ["g", 3, None], "solver": [None, 5],
            "residual_rms": ["small", [1], {"a": 1}],
        }.items():  # fmt: skip
            for value in values:
                with_(f"{section}.{field}", value)
        with_(f"{section}.bias", _DELETE)
        with_(f"{section}.matrix", _DELETE)
    for value in ["imucal-session", None, 1]:
        with_("format", value)
    for value in [2, "1", 1.5, None, True]:
        with_("format_version", value)
    with_("created", 5)
    with_("created", _DELETE)
    with_("session", ["x"])
    with_("accel", "none")
    with_("accel", _DELETE, "ok" if "gyro" in doc else "error")
    with_("accel", [1, 2])
    with_("gyro", 3)
    with_("accel.bias", [1e200, 0.0, 0.0])  # no sensor has it (issue 26)
    with_("sample_clock_scale", 1.0001)  # the spec: only in the gyro section
    with_("accel.sample_clock_scale", 1.0001)
    if "gyro" in doc:
        with_("gyro.g_sensitivity", [[0.1, 0.0]] * 3)
    with_("sensor", "\x1b[31mred\x1b[0m", "ok")
    with_("accel.solver", "gravity\u202e", "ok")
    with_("accel.warnings", ["line\nbreak", "\x07bell"], "ok")
    if isinstance(doc["accel"].get("parameters"), list) and doc["accel"]["parameters"]:
        for value in (-1.0, 1e308, 0.0, "x", None, [1]):
            with_("accel.parameters.0.std", value, "ok")
        for value in ("x", None, 1e308, -1e308):
            with_("accel.parameters.0.value", value, "ok")
    for key, value in [
        ("parameters", "x"), ("parameters", [1, 2]), ("parameters", [{"name": 5}]),
        ("parameters", [{}]), ("poses", "x"), ("poses", [{"label": 3}]), ("poses", [1]),
        ("coverage", []), ("coverage", {"fraction": "x"}), ("misalignment_deg", "x"),
        ("misalignment_deg", {"xy": "a"}), ("sensitivity", "x"), ("sensitivity", [None]),
        ("warnings", "x"), ("warnings", [1, None]), ("rotations", "x"), ("rotations", [{}]),
        ("units_in", 5), ("variant", []), ("gravity", "g"), ("gravity", -9.8),
    ]:  # fmt: skip
        with_(f"accel.{key}", value, "ok")
    for key in ("rms_before", "rms_after", "rms_loo", "noise_scale", "iterations"):
        if key in doc["accel"]:
            for value in (-1, "x", None, [1, 2], {"a": 1}, 1e308):
                with_(f"accel.{key}", value, "ok")
    for name, content in _text_cases(valid).items():
        cases.append((name, content, "ok" if name == "BOM" else "error"))
    return cases


def _text_cases(valid: str) -> dict[str, bytes]:
    """Calibration files broken as text: NaN/Infinity, huge integers, nesting, encodings."""
    import json

    doc = json.loads(valid)
    raw = valid.encode()
    compact = json.dumps(doc).encode()

    def dumped(edit) -> bytes:
        d = json.loads(valid)
        edit(d)
        return json.dumps(d).encode()  # NaN and Infinity as Python writes them

    nan, inf = float("nan"), float("inf")
    nest = b'{"format": "imucal-calibration", "x": '
    text_cases = {
        "NaN in bias": dumped(lambda d: d["accel"]["bias"].__setitem__(0, nan)),
        "Infinity in matrix": dumped(lambda d: d["accel"]["matrix"][1].__setitem__(1, inf)),
        "-Infinity residual": dumped(lambda d: d["accel"].__setitem__("residual_rms", -inf)),
        "Infinity in an extra field": dumped(lambda d: d["accel"].__setitem__("chi2", inf)),
        "400-digit integer": compact.replace(b'"bias": [', b'"bias": [' + b"9" * 400 + b", ", 1),
        "5000-digit integer": compact.replace(b'"bias": [', b'"bias": [' + b"9" * 5000 + b", ", 1),
        "400-digit extra": compact.replace(b'"solver"', b'"big": ' + b"9" * 400 + b', "solver"', 1),
        "deep nesting": nest + b"[" * 100_000 + b"]" * 100_000 + b"}",
        "nested 100 levels": nest + b"[" * 100 + b"]" * 100 + b"}",
        "not UTF-8": raw.replace(b'"format"', b'"\xff\xfeformat"', 1),
        "empty": b"",
        "a list": b"[]",
        "a number": b"3",
        "truncated": raw[: len(raw) // 2],
        "NUL bytes": raw.replace(b"{", b"{\x00", 1),
        "BOM": b"\xef\xbb\xbf" + raw,
    }  # fmt: skip
    return text_cases


class _Delete:
    def __repr__(self) -> str:
        return "<deleted>"


_DELETE = _Delete()
