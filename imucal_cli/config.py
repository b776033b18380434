"""The calibrate configuration: a TOML file (or flags) choosing solvers and their options.

Example (every key optional; these are the defaults)::

    gravity = 9.80665            # m/s^2; default: the session's `gravity` attribute

    [accel]
    solver = "gravity"           # gravity-magnitude fit (Qureshi & Golnaraghi III-A)
    # nominal_sensitivity = 835.4  # raw units per m/s^2 (datasheet); default from the units
    # nominal_bias = 0.0           # raw units, scalar or one per channel
    # range = [-32768, 32767]      # raw output range; default inferred from the units/data
    max_scale_error = 0.20       # flag a sensitivity further than this from nominal
    min_separation_deg = 10.0    # poses closer than this count as one direction

    [accel.gravity]
    model = "9"                  # "9": eqs. (3)-(8); "12": full matrix aligned to the labels
    init = "auto"                # "auto", "updown" (eqs. 13-14) or "ellipsoid"
    weighting = "noise"          # "noise": weight poses by their measured noise; "equal"
    max_iterations = 200
    leave_one_out = true         # held-out residual of each pose in the report

Unknown keys and wrong types are errors (a typo must not silently fall back to a default).
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from imucal_cli.errors import ConfigError

ACCEL_SOLVERS = ("gravity",)


@dataclass
class GravityOptions:
    """Options of the gravity-magnitude solver (``[accel.gravity]``)."""

    model: str = "9"
    init: str = "auto"
    weighting: str = "noise"
    max_iterations: int = 200
    leave_one_out: bool = True


@dataclass
class AccelConfig:
    """``[accel]``: which solver, and what is nominal for the physical-sense checks."""

    solver: str = "gravity"
    nominal_sensitivity: float | None = None
    nominal_bias: float | list[float] | None = None
    range: list[float] | None = None
    max_scale_error: float = 0.20
    min_separation_deg: float = 10.0
    gravity: GravityOptions = field(default_factory=GravityOptions)


@dataclass
class Config:
    """The whole configuration."""

    gravity: float | None = None
    accel: AccelConfig = field(default_factory=AccelConfig)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for recording in the calibration JSON); None values dropped."""
        return _drop_none(asdict(self))


def _drop_none(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _drop_none(v) for k, v in d.items() if v is not None}
    return d


def _check_type(where: str, key: str, value: Any, kind: Any) -> Any:
    if kind is float or kind == "float|None":
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: `{key}` must be a number, not {value!r}")
        return float(value)
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: `{key}` must be a whole number, not {value!r}")
        return value
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: `{key}` must be true or false, not {value!r}")
        return value
    if kind is str:
        if isinstance(value, int) and not isinstance(value, bool):
            value = str(value)  # model = 9 is as good as model = "9"
        if not isinstance(value, str):
            raise ConfigError(f"{where}: `{key}` must be a string, not {value!r}")
        return value
    return value


def _fill(obj: Any, table: dict[str, Any], where: str, subtables: dict[str, Any]) -> None:
    known = {f.name: f for f in fields(obj)}
    for key, value in table.items():
        if key in subtables:
            continue
        if key not in known:
            raise ConfigError(f"{where}: unknown key `{key}` (known: {', '.join(sorted(known))})")
        hint = type(getattr(obj, key)) if getattr(obj, key) is not None else None
        if key in ("nominal_sensitivity", "gravity"):
            value = _check_type(where, key, value, float)
        elif key == "nominal_bias":
            if isinstance(value, list):
                value = [_check_type(where, key, v, float) for v in value]
            else:
                value = _check_type(where, key, value, float)
        elif key == "range":
            if not (isinstance(value, list) and len(value) == 2):
                raise ConfigError(
                    f"{where}: `range` must be [min, max] in raw units, not {value!r}"
                )
            value = [_check_type(where, key, v, float) for v in value]
            if value[0] >= value[1]:
                raise ConfigError(f"{where}: `range` minimum must be below its maximum")
        elif hint is not None:
            value = _check_type(where, key, value, hint)
        setattr(obj, key, value)


def validate(cfg: Config, where: str = "<config>") -> None:
    """Check values (after flags have overridden the file); raises :class:`ConfigError`."""
    a = cfg.accel
    if a.solver not in ACCEL_SOLVERS:
        raise ConfigError(
            f"{where}: [accel] solver = {a.solver!r} is not known "
            f"(choose: {', '.join(ACCEL_SOLVERS)})"
        )
    g = a.gravity
    for key, value, allowed in (
        ("model", g.model, ("9", "12")),
        ("init", g.init, ("auto", "updown", "ellipsoid")),
        ("weighting", g.weighting, ("noise", "equal")),
    ):
        if value not in allowed:
            raise ConfigError(
                f"{where}: [accel.gravity] {key} = {value!r} is not one of {', '.join(allowed)}"
            )
    if g.max_iterations < 1:
        raise ConfigError(f"{where}: [accel.gravity] max_iterations must be at least 1")
    if cfg.gravity is not None and not 9.0 < cfg.gravity < 10.5:
        raise ConfigError(f"{where}: gravity = {cfg.gravity} m/s^2 is not a gravity on Earth")
    if a.nominal_sensitivity is not None and a.nominal_sensitivity <= 0:
        raise ConfigError(f"{where}: [accel] nominal_sensitivity must be positive")
    if not 0 < a.max_scale_error < 1:
        raise ConfigError(f"{where}: [accel] max_scale_error must be between 0 and 1")


def config_from_dict(data: dict[str, Any], where: str = "<config>") -> Config:
    """Build and validate a :class:`Config` from a parsed TOML table."""
    cfg = Config()
    accel = data.get("accel", {})
    if not isinstance(accel, dict):
        raise ConfigError(f"{where}: `accel` must be a table ([accel])")
    _fill(cfg, data, where, {"accel": None})
    grav = accel.get("gravity", {})
    if not isinstance(grav, dict):
        raise ConfigError(f"{where}: `accel.gravity` must be a table ([accel.gravity])")
    _fill(cfg.accel, accel, f"{where} [accel]", {"gravity": None})
    _fill(cfg.accel.gravity, grav, f"{where} [accel.gravity]", {})
    validate(cfg, where)
    return cfg


def load_config(path: str | Path | None) -> Config:
    """Read a TOML config; ``None`` gives the defaults.

    Raises
    ------
    ConfigError
        Missing file, TOML syntax error, unknown key or bad value (one line, naming the file).
    """
    if path is None:
        return Config()
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config ({exc.strerror})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    return config_from_dict(data, str(path))
