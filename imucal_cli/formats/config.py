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
    outliers = "exclude"         # poses that disagree with the rest (a bump, motion during the
                                 # hold, a wrong label): "exclude", "downweight" or "keep"

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
                                 # parameters), "known" (turns of a known angle, with
                                 # the others), or "factorization" (Hwangbo & Kanade)
    # nominal_sensitivity = 938.7  # raw units per rad/s (datasheet); default from the units
    # range = [-32768, 32767]      # raw output range: turns reaching it are clipped and left
                                   # out; default: the ADC word of counts data, else none
    max_scale_error = 0.20
    max_residual_ratio = 10.0    # refuse when turns' residuals exceed this many times the
                                 # noise (and the other turns' level); --force saves anyway
    max_rate_std = 0.05          # refuse (auto: leave the gyro out) when the turns determine
                                 # its rates only to this fraction (1 std, worst direction,
                                 # the accelerometer calibration's uncertainty included)

    [gyro.rotations]             # static, dynamic and full
    max_gap_s = 2.0              # still data must end/start this close to a rotation
    min_tilt_deg = 30.0          # static/dynamic: skip turns about an axis this near vertical

    [gyro.full]
    max_iterations = 100
    g_sensitivity = "auto"       # "auto" (kept when significant and determined), "on", "off"

    [gyro.known]                 # turns of a known angle (angle_deg on the rotation segments)
    angle_std_deg = 1.0          # how well each known angle is met (a hand turn back onto the
                                 # same face: about a degree; a turntable: far better)

    [gyro.factorization]
    samples_per_segment = 40     # samples of each rotation used in the constraints
    refine = true
    # fixture_tolerance_deg = 0.0  # how square the turns are; default: from the data
    max_iterations = 200

    [mag]                        # runs whenever the session has /raw/mag
    solver = "magnitude"         # "magnitude" (ML on |B| and the dip), "ellipsoid", "none"
    # field_uT = 48.9            # local field, uT; default the session's magnetic_field_uT,
                                 # else unknown: the output is in units of the local field
    align = true                 # rotate onto the accelerometer frame (the dip angle)
    # range = [-32760, 32760]    # raw output range: readings reaching it are saturated
    min_coverage = 0.5           # refuse below this fraction of the sphere covered
    max_field_change_pct = 3.0   # flag |B| off by more than this % of |B| beyond the noise
                                 # (overall, over any 1 s of motion, or in a hold)
    max_dip_error_deg = 2.0      # flag a hold whose gravity-field angle is this far off
    max_saturated_pct = 5.0      # refuse when more readings than this are saturated
    max_iterations = 100

    [mag.quality]                # pass or recapture (MotionCal's goals)
    max_gaps_pct = 15.0
    max_variance_pct = 4.5
    max_wobble_pct = 4.0
    max_fit_error_pct = 5.0

    [temperature]                # each channel's bias a polynomial in temperature (issue 17.1)
    model = "auto"               # "auto": when the still periods span min_span_c or more;
                                 # "on": always (refused when the data cannot give it); "off"
    max_degree = 3               # highest degree tried; the data choose (F-tests)
    min_span_c = 10.0            # narrowest temperature span fitted, C (at least 10)

    [clock]                      # the device's sample clock against the host's (issue 17.2)
    model = "auto"               # "auto": estimated and corrected when the session records host
                                 # arrival times (/raw/host_time); "off"

    [targets.accel]              # imucal capture --config: capture until each std is below
    # gain_pct = 0.05            # (1 std, worst axis; unset: no target); --until overrides
    # bias_mg = 0.5
    # misalignment_deg = 0.05

    [targets.gyro]
    # gain_pct = 0.05
    # bias_dps = 0.01
    # misalignment_deg = 0.05

Unknown keys and wrong types are errors (a typo must not silently fall back to a default).
Every value is checked against the rule of its key (:func:`setting`: finite, within bounds, one
of the choices, the right length) and a mistake is one line naming the key.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any

from imucal_cli.errors import ConfigError
from imucal_cli.formats.inputs import read_text_input

#: Local gravity a config or a session (its ``gravity`` attribute) may state, m/s^2, exclusive:
#: 9.78 at the equator to 9.83 at the poles, with room for altitude and a rounded value.
GRAVITY_RANGE = (9.0, 10.5)

ACCEL_SOLVERS = ("auto", "gravity", "labelled", "factorization", "partial", "none")
GYRO_SOLVERS = ("auto", "none", "static", "dynamic", "full", "known", "factorization")
MAG_SOLVERS = ("magnitude", "ellipsoid", "none")

#: Largest whole number a count (iterations, samples) may take.
MAX_COUNT = 1_000_000


# --------------------------------------------------------------------------------------------
# Rules: every key is checked against the rule of its field (declared with `setting`)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Rule:
    """What one config value may be.

    Attributes
    ----------
    kind : str
        ``"number"`` (a finite float), ``"count"`` (a whole number), ``"bool"``, ``"text"``,
        ``"range"`` (``[min, max]``, two finite numbers, min < max) or ``"numbers"`` (a finite
        number, or a list of them: one per channel).
    gt, ge, lt, le : float, optional
        Bounds: greater than, at least, less than, at most.
    choices : tuple of str, optional
        The values a text may take.
    min_len : int
        ``numbers``: the fewest values a list may hold (3: a sensor has at least 3 channels).
    unit : str
        Printed after the bounds in messages (``"m/s^2"``).
    """

    kind: str
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple[str, ...] | None = None
    unit: str = ""
    min_len: int = 1

    def bounds(self) -> str:
        parts = []
        for op, bound in ((">", self.gt), (">=", self.ge), ("<", self.lt), ("<=", self.le)):
            if bound is not None:
                parts.append(f"{op} {bound:g}")
        text = " and ".join(parts)
        return f"{text} {self.unit}".rstrip() if text else ""

    def within(self, x: float) -> bool:
        return not (
            (self.gt is not None and not x > self.gt)
            or (self.ge is not None and not x >= self.ge)
            or (self.lt is not None and not x < self.lt)
            or (self.le is not None and not x <= self.le)
        )


def setting(default: Any, kind: str, **rule: Any) -> Any:
    """A config field with its rule: ``max_iterations: int = setting(200, "count", ge=1)``.

    Every field of the config dataclasses should be declared this way; a field declared
    without one still gets a rule inferred from its type (a finite number, a whole number in
    ``[0, MAX_COUNT]``, a bool, a string), so a key added without a rule is never unchecked.
    """
    return field(default=default, metadata={"rule": Rule(kind, **rule)})


_KIND_FROM_TYPE = (
    ("list[float]", "numbers"), ("bool", "bool"), ("int", "count"), ("float", "number"),
    ("str", "text"),
)  # fmt: skip


def rule_of(f) -> Rule:
    """The rule of a dataclass field: declared with :func:`setting`, else from its type."""
    rule = f.metadata.get("rule")
    if rule is not None:
        return rule
    annotation = str(f.type)
    for token, kind in _KIND_FROM_TYPE:
        if token in annotation:
            return Rule(kind, ge=0, le=MAX_COUNT) if kind == "count" else Rule(kind)
    raise TypeError(f"config field {f.name!r} has no rule and an unknown type {annotation!r}")


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _finite(value: Any) -> bool:
    try:
        return _is_number(value) and math.isfinite(value)
    except OverflowError:  # an integer past the float range
        return False


def check_value(rule: Rule, value: Any, key: str, where: str) -> Any:
    """Check and convert one value; raise :class:`ConfigError` naming ``key``."""

    def fail(what: str) -> ConfigError:
        return ConfigError(f"{where}: `{key}` must be {what}, not {value!r}")

    kind = rule.kind
    bounds = rule.bounds()
    number = "a finite number" + (f" {bounds}" if bounds else "")
    if kind == "number":
        if not _finite(value) or not rule.within(value):
            raise fail(number)
        return float(value)
    if kind == "count":
        if isinstance(value, bool) or not isinstance(value, int) or not rule.within(value):
            raise fail("a whole number" + (f" {bounds}" if bounds else ""))
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise fail("true or false")
        return value
    if kind == "text":
        if _is_number(value) and isinstance(value, int):
            value = str(value)  # model = 9 is as good as model = "9"
        if not isinstance(value, str):
            raise fail("a string" + (f" ({', '.join(rule.choices)})" if rule.choices else ""))
        if rule.choices is not None and value not in rule.choices:
            raise ConfigError(
                f"{where}: `{key}` = {value!r} is not known (choose: {', '.join(rule.choices)})"
            )
        return value
    if kind == "range":
        if not (isinstance(value, list) and len(value) == 2 and all(map(_finite, value))):
            raise fail("[min, max] in raw units, two finite numbers")
        if not value[0] < value[1]:
            raise ConfigError(f"{where}: `{key}` minimum must be below its maximum, not {value!r}")
        return [float(v) for v in value]
    if kind == "numbers":
        if isinstance(value, list):
            if len(value) < rule.min_len or not all(map(_finite, value)):
                raise fail(
                    f"a finite number or a list of at least {rule.min_len} finite numbers "
                    "(one per channel)"
                )
            return [float(v) for v in value]
        if not _finite(value):
            raise fail("a finite number or a list of finite numbers (one per channel)")
        return float(value)
    raise TypeError(f"unknown rule kind {kind!r}")


def per_channel(value: float | list[float] | None, n: int, key: str) -> list[float] | None:
    """A ``numbers`` value (one, or one per channel) as ``n`` values; None stays None.

    Raises
    ------
    ConfigError
        A list whose length is not ``n`` (the message names the key and both lengths).
    """
    if value is None:
        return None
    if isinstance(value, list):
        if len(value) != n:
            raise ConfigError(
                f"config: `{key}` has {len(value)} values but the session has {n} channels "
                "(give one value, or one per channel)"
            )
        return [float(v) for v in value]
    return [float(value)] * n


# --------------------------------------------------------------------------------------------
# The configuration
# --------------------------------------------------------------------------------------------

_ITERATIONS = {"ge": 1, "le": MAX_COUNT}
_DEG = "deg"


@dataclass
class GravityOptions:
    """Options of the gravity-magnitude solver (``[accel.gravity]``)."""

    model: str = setting("9", "text", choices=("9", "12"))
    init: str = setting("auto", "text", choices=("auto", "updown", "ellipsoid"))
    weighting: str = setting("noise", "text", choices=("noise", "equal"))
    max_iterations: int = setting(200, "count", **_ITERATIONS)
    leave_one_out: bool = setting(True, "bool")


@dataclass
class LabelledOptions:
    """Options of the labelled-pose solver (``[accel.labelled]``)."""

    placement_deg: float | None = setting(None, "number", gt=0, le=45, unit=_DEG)
    max_iterations: int = setting(200, "count", **_ITERATIONS)


@dataclass
class AccelFactorizationOptions:
    """Options of the factorization solver for accelerometers (``[accel.factorization]``)."""

    use: str = setting("means", "text", choices=("means", "samples"))
    linear: str = setting("subspace", "text", choices=("subspace", "paper"))
    refine: bool = setting(True, "bool")
    fixture_tolerance_deg: float | None = setting(None, "number", ge=0, lt=45, unit=_DEG)
    max_iterations: int = setting(200, "count", **_ITERATIONS)


@dataclass
class GyroFactorizationOptions:
    """Options of the factorization solver for gyroscopes (``[gyro.factorization]``)."""

    samples_per_segment: int = setting(40, "count", ge=3, le=MAX_COUNT)
    linear: str = setting("subspace", "text", choices=("subspace", "paper"))
    refine: bool = setting(True, "bool")
    fixture_tolerance_deg: float | None = setting(None, "number", ge=0, lt=45, unit=_DEG)
    max_iterations: int = setting(200, "count", **_ITERATIONS)


@dataclass
class AccelConfig:
    """``[accel]``: which solver, and what is nominal for the physical-sense checks."""

    solver: str = setting("auto", "text", choices=ACCEL_SOLVERS)
    nominal_sensitivity: float | None = setting(None, "number", gt=0)
    nominal_bias: float | list[float] | None = setting(None, "numbers", min_len=3)
    range: list[float] | None = setting(None, "range")
    max_scale_error: float = setting(0.20, "number", gt=0, lt=1)
    min_separation_deg: float = setting(10.0, "number", gt=0, lt=90, unit=_DEG)
    outliers: str = setting("exclude", "text", choices=("exclude", "downweight", "keep"))
    gravity: GravityOptions = field(default_factory=GravityOptions)
    labelled: LabelledOptions = field(default_factory=LabelledOptions)
    factorization: AccelFactorizationOptions = field(default_factory=AccelFactorizationOptions)


@dataclass
class GyroRotationOptions:
    """How rotations are used (``[gyro.rotations]``), for the static/dynamic/full solvers."""

    max_gap_s: float = setting(2.0, "number", gt=0, le=3600, unit="s")
    min_tilt_deg: float = setting(30.0, "number", ge=0, lt=90, unit=_DEG)


@dataclass
class GyroFullOptions:
    """Options of the 12-parameter gyro model (``[gyro.full]``)."""

    max_iterations: int = setting(100, "count", **_ITERATIONS)
    g_sensitivity: str = setting("auto", "text", choices=("auto", "on", "off"))


@dataclass
class GyroKnownOptions:
    """Turns of a known angle (``[gyro.known]``), for the known and auto solvers."""

    angle_std_deg: float = setting(1.0, "number", gt=0, le=90)


@dataclass
class GyroConfig:
    """``[gyro]``: which solver (``"auto"``: the most accurate the session supports;
    ``"none"``: the gyroscope is not calibrated)."""

    solver: str = setting("auto", "text", choices=GYRO_SOLVERS)
    nominal_sensitivity: float | None = setting(None, "number", gt=0)
    range: list[float] | None = setting(None, "range")
    max_scale_error: float = setting(0.20, "number", gt=0, lt=1)
    max_residual_ratio: float = setting(10.0, "number", gt=1)
    max_rate_std: float = setting(0.05, "number", gt=0, le=1)
    factorization: GyroFactorizationOptions = field(default_factory=GyroFactorizationOptions)
    rotations: GyroRotationOptions = field(default_factory=GyroRotationOptions)
    full: GyroFullOptions = field(default_factory=GyroFullOptions)
    known: GyroKnownOptions = field(default_factory=GyroKnownOptions)


@dataclass
class MagQualityOptions:
    """``[mag.quality]``: the figures a calibration must meet to pass (else: recapture)."""

    max_gaps_pct: float = setting(15.0, "number", gt=0, le=100, unit="%")
    max_variance_pct: float = setting(4.5, "number", gt=0, unit="%")
    max_wobble_pct: float = setting(4.0, "number", gt=0, unit="%")
    max_fit_error_pct: float = setting(5.0, "number", gt=0, unit="%")


@dataclass
class MagConfig:
    """``[mag]``: the magnetometer solver (runs whenever the session has ``/raw/mag``)."""

    solver: str = setting("magnitude", "text", choices=MAG_SOLVERS)
    field_uT: float | None = setting(None, "number", gt=0, lt=1e4, unit="uT (Earth: 20 to 70)")
    align: bool = setting(True, "bool")
    range: list[float] | None = setting(None, "range")
    min_coverage: float = setting(0.5, "number", gt=0, le=1, unit="(fraction of the sphere)")
    max_field_change_pct: float = setting(3.0, "number", gt=0, unit="%")
    max_dip_error_deg: float = setting(2.0, "number", gt=0, unit=_DEG)
    max_saturated_pct: float = setting(5.0, "number", gt=0, le=100, unit="%")
    max_iterations: int = setting(100, "count", **_ITERATIONS)
    quality: MagQualityOptions = field(default_factory=MagQualityOptions)


@dataclass
class TemperatureConfig:
    """``[temperature]``: the bias temperature model (issue 17.1)."""

    model: str = setting("auto", "text", choices=("auto", "on", "off"))
    max_degree: int = setting(3, "count", ge=1, le=3)
    min_span_c: float = setting(10.0, "number", ge=10.0, le=200.0, unit="C")
    accel_tempco_mg_per_c: float = setting(0.5, "number", gt=0.0, le=100.0, unit="mg/C")


@dataclass
class ClockConfig:
    """``[clock]``: the device's sample clock against the host's (issue 17.2)."""

    model: str = setting("auto", "text", choices=("auto", "off"))


@dataclass
class AccelTargets:
    """``[targets.accel]``: the largest std a capture with targets stops at (1 std, the worst
    axis; None: no target), :mod:`imucal_cli.formats.targets`."""

    gain_pct: float | None = setting(None, "number", gt=0, le=100, unit="%")
    bias_mg: float | None = setting(None, "number", gt=0, le=1000, unit="mg")
    misalignment_deg: float | None = setting(None, "number", gt=0, le=45, unit=_DEG)


@dataclass
class GyroTargets:
    """``[targets.gyro]``: as :class:`AccelTargets`, the bias in deg/s."""

    gain_pct: float | None = setting(None, "number", gt=0, le=100, unit="%")
    bias_dps: float | None = setting(None, "number", gt=0, le=100, unit="deg/s")
    misalignment_deg: float | None = setting(None, "number", gt=0, le=45, unit=_DEG)


@dataclass
class TargetsConfig:
    """``[targets]``: what ``imucal capture --config`` captures until (``--until`` overrides
    it term by term)."""

    accel: AccelTargets = field(default_factory=AccelTargets)
    gyro: GyroTargets = field(default_factory=GyroTargets)


@dataclass
class Config:
    """The whole configuration."""

    gravity: float | None = setting(None, "number", gt=GRAVITY_RANGE[0], lt=GRAVITY_RANGE[1],
                                    unit="m/s^2")
    accel: AccelConfig = field(default_factory=AccelConfig)
    gyro: GyroConfig = field(default_factory=GyroConfig)
    mag: MagConfig = field(default_factory=MagConfig)
    temperature: TemperatureConfig = field(default_factory=TemperatureConfig)
    clock: ClockConfig = field(default_factory=ClockConfig)
    targets: TargetsConfig = field(default_factory=TargetsConfig)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for recording in the calibration JSON); None values dropped."""
        return _drop_none(asdict(self))


def _drop_none(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _drop_none(v) for k, v in d.items() if v is not None}
    return d


def _is_table(f) -> bool:
    return (
        f.default is MISSING
        and f.default_factory is not MISSING
        and is_dataclass(f.default_factory)
    )


def _fill(obj: Any, table: dict[str, Any], where: str, path: str = "") -> None:
    """Set the fields of dataclass ``obj`` from a TOML table; nested dataclasses are tables."""
    by_name = {f.name: f for f in fields(obj)}
    for key, value in table.items():
        f = by_name.get(key)
        if f is None:
            raise ConfigError(
                f"{where}: unknown key `{key}` in [{path or 'top level'}] "
                f"(known: {', '.join(sorted(by_name))})"
            )
        if _is_table(f):
            if not isinstance(value, dict):
                raise ConfigError(f"{where}: `{key}` must be a table ([...{key}])")
            _fill(getattr(obj, key), value, where, f"{path}.{key}".lstrip("."))
        else:
            name = f"{path}.{key}".lstrip(".")
            setattr(obj, key, check_value(rule_of(f), value, name, where))


def _check_all(obj: Any, where: str, path: str = "") -> None:
    """Check every value against its rule (after flags have overridden the file)."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        name = f"{path}.{f.name}".lstrip(".")
        if _is_table(f):
            _check_all(value, where, name)
        elif value is not None:
            check_value(rule_of(f), value, name, where)


def validate(cfg: Config, where: str = "<config>") -> None:
    """Check every value (after flags have overridden the file); raises :class:`ConfigError`
    with one line naming the key."""
    _check_all(cfg, where)


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
        Missing file, not a regular file, not UTF-8, TOML syntax error, unknown key or bad
        value (one line, naming the file and the key).
    """
    if path is None:
        return Config()
    path = Path(path)
    text = read_text_input(path, what="config file", max_bytes=1 << 20, error=ConfigError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({' '.join(str(exc).split())})") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML (nested too deeply)") from None
    except ValueError as exc:  # an integer past Python's 4300-digit limit (issue 26)
        said = "an integer of more than 4300 digits" if "digits" in str(exc) else \
            " ".join(str(exc).split())[:120]  # fmt: skip
        raise ConfigError(f"{path}: not a valid config ({said})") from None
    return config_from_dict(data, str(path))
