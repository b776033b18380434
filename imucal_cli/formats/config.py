"""The calibrate configuration: a TOML file (or flags) choosing solvers and their options.

Example (every key optional; these are the defaults)::

    gravity = 9.80665            # m/s^2; default: the session's `gravity` attribute

    [accel]
    solver = "auto"              # "auto" (the most accurate the session supports), "gravity"
                                 # (Qureshi & Golnaraghi III-A), "labelled" (labelled poses,
                                 # full matrix), "factorization" (Hwangbo & Kanade), "none"
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

    [accel.labelled]             # poses with `up` labels, each direction a nuisance parameter
    # placement_deg = 2.0        # RMS angle between the true and the labelled up; default:
                                 # estimated from the data (2 deg when too few poses)
    max_iterations = 200

    [accel.factorization]        # Hwangbo & Kanade
    use = "means"                # constraints over per-pose "means" or individual "samples"
    linear = "subspace"          # redundant units: "subspace" or "paper" (eqs. 16-26)
    refine = true                # nonlinear refinement (section IV-C)
    # fixture_tolerance_deg = 0.0  # how square the block is placed; default: from the data
    max_iterations = 200

    [gyro]
    solver = "auto"              # "auto": the most accurate solver the session supports
                                 # (none when it has no gyro or no rotations); "none";
                                 # "static", "dynamic" (Qureshi III-B), "full" (12 or 21
                                 # parameters), or "factorization" (Hwangbo & Kanade)
    # nominal_sensitivity = 938.7  # raw units per rad/s (datasheet); default from the units
    # range = [-32768, 32767]      # raw output range: turns reaching it are clipped and left
                                   # out; default: the ADC word of counts data, else none
    max_scale_error = 0.20
    max_residual_ratio = 10.0    # refuse when turns' residuals exceed this many times the
                                 # noise (and the other turns' level); --force saves anyway

    [gyro.rotations]             # static, dynamic and full
    max_gap_s = 2.0              # still data must end/start this close to a rotation
    min_tilt_deg = 30.0          # static/dynamic: skip turns about an axis this near vertical

    [gyro.full]
    max_iterations = 100
    g_sensitivity = "auto"       # "auto" (kept when significant and determined), "on", "off"

    [gyro.factorization]
    samples_per_segment = 40     # samples of each rotation used in the constraints
    refine = true
    # fixture_tolerance_deg = 0.0  # how square the turns are; default: from the data
    max_iterations = 200

Unknown keys and wrong types are errors (a typo must not silently fall back to a default).
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

from imucal_cli.errors import ConfigError

ACCEL_SOLVERS = ("auto", "gravity", "labelled", "factorization", "none")
GYRO_SOLVERS = ("auto", "none", "static", "dynamic", "full", "factorization")


@dataclass
class GravityOptions:
    """Options of the gravity-magnitude solver (``[accel.gravity]``)."""

    model: str = "9"
    init: str = "auto"
    weighting: str = "noise"
    max_iterations: int = 200
    leave_one_out: bool = True


@dataclass
class LabelledOptions:
    """Options of the labelled-pose solver (``[accel.labelled]``)."""

    placement_deg: float | None = None
    max_iterations: int = 200


@dataclass
class AccelFactorizationOptions:
    """Options of the factorization solver for accelerometers (``[accel.factorization]``)."""

    use: str = "means"
    linear: str = "subspace"
    refine: bool = True
    fixture_tolerance_deg: float | None = None
    max_iterations: int = 200


@dataclass
class GyroFactorizationOptions:
    """Options of the factorization solver for gyroscopes (``[gyro.factorization]``)."""

    samples_per_segment: int = 40
    linear: str = "subspace"
    refine: bool = True
    fixture_tolerance_deg: float | None = None
    max_iterations: int = 200


@dataclass
class AccelConfig:
    """``[accel]``: which solver, and what is nominal for the physical-sense checks."""

    solver: str = "auto"
    nominal_sensitivity: float | None = None
    nominal_bias: float | list[float] | None = None
    range: list[float] | None = None
    max_scale_error: float = 0.20
    min_separation_deg: float = 10.0
    gravity: GravityOptions = field(default_factory=GravityOptions)
    labelled: LabelledOptions = field(default_factory=LabelledOptions)
    factorization: AccelFactorizationOptions = field(default_factory=AccelFactorizationOptions)


@dataclass
class GyroRotationOptions:
    """How rotations are used (``[gyro.rotations]``), for the static/dynamic/full solvers."""

    max_gap_s: float = 2.0
    min_tilt_deg: float = 30.0


@dataclass
class GyroFullOptions:
    """Options of the 12-parameter gyro model (``[gyro.full]``)."""

    max_iterations: int = 100
    g_sensitivity: str = "auto"


@dataclass
class GyroConfig:
    """``[gyro]``: which solver (``"auto"``: the most accurate the session supports;
    ``"none"``: the gyroscope is not calibrated)."""

    solver: str = "auto"
    nominal_sensitivity: float | None = None
    range: list[float] | None = None
    max_scale_error: float = 0.20
    max_residual_ratio: float = 10.0
    factorization: GyroFactorizationOptions = field(default_factory=GyroFactorizationOptions)
    rotations: GyroRotationOptions = field(default_factory=GyroRotationOptions)
    full: GyroFullOptions = field(default_factory=GyroFullOptions)


@dataclass
class Config:
    """The whole configuration."""

    gravity: float | None = None
    accel: AccelConfig = field(default_factory=AccelConfig)
    gyro: GyroConfig = field(default_factory=GyroConfig)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for recording in the calibration JSON); None values dropped."""
        return _drop_none(asdict(self))


def _drop_none(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _drop_none(v) for k, v in d.items() if v is not None}
    return d


#: Keys whose value is a number even though their default is None.
_NUMBER_KEYS = {"gravity", "nominal_sensitivity", "fixture_tolerance_deg", "placement_deg"}


def _number(where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: `{key}` must be a number, not {value!r}")
    return float(value)


def _convert(where: str, key: str, value: Any, default: Any) -> Any:
    """Check ``value`` against the type of the key's default and convert it."""
    if key in _NUMBER_KEYS or isinstance(default, float):
        return _number(where, key, value)
    if key == "nominal_bias":
        if isinstance(value, list):
            return [_number(where, key, v) for v in value]
        return _number(where, key, value)
    if key == "range":
        if not (isinstance(value, list) and len(value) == 2):
            raise ConfigError(f"{where}: `range` must be [min, max] in raw units, not {value!r}")
        value = [_number(where, key, v) for v in value]
        if value[0] >= value[1]:
            raise ConfigError(f"{where}: `range` minimum must be below its maximum")
        return value
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: `{key}` must be true or false, not {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: `{key}` must be a whole number, not {value!r}")
        return value
    if isinstance(default, str):
        if isinstance(value, int) and not isinstance(value, bool):
            value = str(value)  # model = 9 is as good as model = "9"
        if not isinstance(value, str):
            raise ConfigError(f"{where}: `{key}` must be a string, not {value!r}")
        return value
    return value


def _fill(obj: Any, table: dict[str, Any], where: str) -> None:
    """Set the fields of dataclass ``obj`` from a TOML table; nested dataclasses are tables."""
    known = {f.name for f in fields(obj)}
    for key, value in table.items():
        if key not in known:
            raise ConfigError(f"{where}: unknown key `{key}` (known: {', '.join(sorted(known))})")
        default = getattr(obj, key)
        if is_dataclass(default):
            if not isinstance(value, dict):
                raise ConfigError(f"{where}: `{key}` must be a table ([...{key}])")
            _fill(default, value, f"{where} [{key}]")
        else:
            setattr(obj, key, _convert(where, key, value, default))


def _one_of(where: str, table: str, key: str, value: str, allowed: tuple[str, ...]) -> None:
    if value not in allowed:
        raise ConfigError(
            f"{where}: [{table}] {key} = {value!r} is not known (choose: {', '.join(allowed)})"
        )


def validate(cfg: Config, where: str = "<config>") -> None:
    """Check values (after flags have overridden the file); raises :class:`ConfigError`."""
    a = cfg.accel
    _one_of(where, "accel", "solver", a.solver, ACCEL_SOLVERS)
    g = a.gravity
    _one_of(where, "accel.gravity", "model", g.model, ("9", "12"))
    _one_of(where, "accel.gravity", "init", g.init, ("auto", "updown", "ellipsoid"))
    _one_of(where, "accel.gravity", "weighting", g.weighting, ("noise", "equal"))
    f = a.factorization
    _one_of(where, "accel.factorization", "use", f.use, ("means", "samples"))
    _one_of(where, "accel.factorization", "linear", f.linear, ("subspace", "paper"))
    _one_of(where, "gyro", "solver", cfg.gyro.solver, GYRO_SOLVERS)
    _one_of(
        where, "gyro.factorization", "linear", cfg.gyro.factorization.linear, ("subspace", "paper")
    )
    _one_of(where, "gyro.full", "g_sensitivity", cfg.gyro.full.g_sensitivity,
            ("auto", "on", "off"))  # fmt: skip
    if not cfg.gyro.max_residual_ratio > 1:
        raise ConfigError(f"{where}: [gyro] max_residual_ratio must be above 1")
    pl = a.labelled.placement_deg
    if pl is not None and not 0 < pl <= 45:
        raise ConfigError(
            f"{where}: [accel.labelled] placement_deg = {pl:g} must be above 0 and at most 45 "
            "(degrees between the true and the labelled up)"
        )
    for table, n in (
        ("accel.gravity", g.max_iterations),
        ("accel.labelled", a.labelled.max_iterations),
        ("accel.factorization", f.max_iterations),
        ("gyro.factorization", cfg.gyro.factorization.max_iterations),
        ("gyro.full", cfg.gyro.full.max_iterations),
    ):
        if n < 1:
            raise ConfigError(f"{where}: [{table}] max_iterations must be at least 1")
    if cfg.gyro.factorization.samples_per_segment < 3:
        raise ConfigError(f"{where}: [gyro.factorization] samples_per_segment must be at least 3")
    if cfg.gravity is not None and not 9.0 < cfg.gravity < 10.5:
        raise ConfigError(f"{where}: gravity = {cfg.gravity} m/s^2 is not a gravity on Earth")
    for table, sens in (("accel", a.nominal_sensitivity), ("gyro", cfg.gyro.nominal_sensitivity)):
        if sens is not None and sens <= 0:
            raise ConfigError(f"{where}: [{table}] nominal_sensitivity must be positive")
    for table, err in (("accel", a.max_scale_error), ("gyro", cfg.gyro.max_scale_error)):
        if not 0 < err < 1:
            raise ConfigError(f"{where}: [{table}] max_scale_error must be between 0 and 1")


def config_from_dict(data: dict[str, Any], where: str = "<config>") -> Config:
    """Build and validate a :class:`Config` from a parsed TOML table."""
    cfg = Config()
    _fill(cfg, data, where)
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
