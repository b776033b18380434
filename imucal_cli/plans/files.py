"""TOML plan files (:func:`imucal_cli.plans.load_plan`; the format in the package notes): read
safely, every step checked, one line naming the file and the step when one is wrong.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from imucal_cli.errors import InputError
from imucal_cli.formats.inputs import read_text_input
from imucal_cli.formats.session import TURN_ANGLE_RULE, as_turn_angle, as_unit_vector
from imucal_cli.plans.model import Plan, Step


def _unit_or_none(v) -> np.ndarray | None:
    if v is None:
        return None

    out = as_unit_vector(v)
    out.flags.writeable = False
    return out


def load_file(path: Path) -> Plan:
    src = str(path)
    if not path.is_file():
        raise InputError(f"{src}: no such plan file")

    text = read_text_input(path, what="plan file", max_bytes=1 << 20)
    try:
        data = tomllib.loads(text)
    except RecursionError:
        raise InputError(f"{src}: not valid TOML (nested too deeply)") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{src}: not valid TOML ({exc})") from None
    unknown = sorted(set(data) - {"name", "step"})
    if unknown:
        raise InputError(f"{src}: unknown key {unknown[0]!r} (expected name and [[step]])")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{src}: name must be a non-empty string")
    raw = data.get("step")
    if not isinstance(raw, list) or not raw:
        raise InputError(f"{src}: no steps (add [[step]] tables with kind = 'static' or ...)")
    steps = tuple(_parse_step(src, i + 1, item) for i, item in enumerate(raw))
    return Plan(name.strip(), steps)


def _parse_step(src: str, number: int, item) -> Step:
    where = f"{src}: step {number}"
    if not isinstance(item, dict):
        raise InputError(f"{where}: must be a table ([[step]])")
    unknown = sorted(set(item) - {"kind", "label", "up", "axis", "angle_deg", "mounting"})
    if unknown:
        raise InputError(
            f"{where}: unknown key {unknown[0]!r} "
            "(expected kind, label, up, axis, angle_deg, mounting)"
        )
    kind = item.get("kind")
    if kind not in ("static", "rotation"):
        raise InputError(f"{where}: kind must be 'static' or 'rotation', got {kind!r}")
    label = item.get("label", f"step {number}")
    if not isinstance(label, str) or not label.strip():
        raise InputError(f"{where}: label must be a non-empty string, got {label!r}")
    wrong = ("axis", "angle_deg") if kind == "static" else ("up",)
    for key in wrong:
        if key in item:
            raise InputError(f"{where}: {key!r} does not apply to a {kind} step")
    vectors = {}
    for key in ("up", "axis"):
        if key in item:
            vectors[key] = _vector(where, key, item[key])
    angle = item.get("angle_deg")
    if angle is not None:
        if as_turn_angle(angle) is None:
            raise InputError(f"{where}: angle_deg must be {TURN_ANGLE_RULE}, got {angle!r}")
        angle = float(angle)
    mounting = item.get("mounting")
    if mounting is not None and (
        isinstance(mounting, bool) or not isinstance(mounting, int) or mounting < 1
    ):
        raise InputError(f"{where}: mounting must be an integer >= 1, got {mounting!r}")
    return Step(kind, label.strip(), up=vectors.get("up"), axis=vectors.get("axis"),
                angle_deg=angle, mounting=mounting)  # fmt: skip


def _vector(where: str, key: str, value) -> np.ndarray:
    ok = isinstance(value, list) and len(value) == 3
    ok = ok and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    if ok:
        if as_unit_vector(value) is not None:
            return _unit_or_none(value)
    raise InputError(f"{where}: {key} must be 3 finite numbers, not all zero, got {value!r}")
