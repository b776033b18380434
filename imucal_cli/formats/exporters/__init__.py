"""Exporters: a calibration written in another tool's format, one module per format.

Each exporter is a function of a :class:`~imucal_cli.model.calibration.Calibration` (and,
for the noise formats, :class:`~imucal_cli.formats.noise.NoiseFigures`) returning text;
:mod:`imucal_cli.use.export` chooses one.  This module holds what they share:

- :class:`ExportOptions`: the options a format may take (noise figures, rate, topic, the
  driver's scale from raw units to SI, a device id).
- :func:`published`: a sensor's calibration rewritten for the SI values a driver publishes
  (ROS ``sensor_msgs/Imu``, PX4 ``sensor_accel``, ArduPilot): ``p = factor * raw``, so
  ``calibrated = (matrix / factor) @ (p - factor * bias)``.
- :func:`kalibr_frame`: the calibration in Kalibr's scale-misalignment layout (lower-triangular
  ``M``, a rotation ``C_gyro_i``, g-sensitivity ``A``), which OpenVINS and Basalt share.
- :func:`diagonal_fit`: offset and per-axis scale only (PX4, ArduPilot) and what that loses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from imucal_cli import __version__
from imucal_cli.errors import InputError
from imucal_cli.estimators.thermal.temperature import reexpand
from imucal_cli.formats.noise import NoiseFigures
from imucal_cli.formats.text import clean_text
from imucal_cli.model.calibration import (
    MIN_GAIN,
    MODEL_EQUATION,
    OFFSET_LIMIT,
    Calibration,
    SensorCalibration,
)
from imucal_cli.model.session import RAW_UNITS

SENSORS = ("accel", "gyro")
STANDARD_GRAVITY = 9.80665
"""m/s^2 per g (standard gravity), the factor for raw data in g."""

SI_UNITS = {"accel": "m/s^2", "gyro": "rad/s"}
_NOMINAL = {"accel": {"m/s^2": 1.0, "g": STANDARD_GRAVITY},
            "gyro": {"rad/s": 1.0, "deg/s": math.pi / 180.0}}  # fmt: skip

#: An example of ``--accel-scale`` / ``--gyro-scale`` for a common part, per sensor.
_SCALE_EXAMPLE = {
    "accel": "9.80665/16384 for a 16-bit +-2 g part",
    "gyro": "0.0174533/131 for a 16-bit +-250 deg/s part",
}


@dataclass
class ExportOptions:
    """Options of ``imucal export``; each format uses the ones it needs.

    Attributes
    ----------
    noise : NoiseFigures or None
        From ``imucal noise --json`` (Kalibr, OpenVINS, ROS covariance).
    rate_hz : float or None
        The rate the target runs at, Hz; default the noise recording's rate.
    topic : str
        The ROS topic of the IMU messages (Kalibr, OpenVINS).
    scale : dict
        ``{"accel": f, "gyro": f}``: SI units per raw unit as the target's driver publishes
        them, for raw data in counts or V (PX4, ArduPilot, Kalibr, OpenVINS, Basalt);
        ``"mag"``: uT per raw unit (PX4, ArduPilot).
    device_id : int or None
        PX4's ``CAL_ACC0_ID``/``CAL_GYRO0_ID``, ArduPilot's ``INS_ACC_ID``/``INS_GYR_ID``.
    device_ids : dict of str to int
        Several IMUs exported whole (PX4, ArduPilot): each IMU's device id by its name in the
        set (``--device-id NAME=N``), written at that IMU's instance (``CAL_ACC1_ID``, ...).
    prefix : str or None
        Name prefix of C identifiers (c-header, fusion).
    fusion_version : str
        The Fusion release whose ``FusionMatrix`` layout to write: "1.3" (flat) or "1.2".
    drop : frozenset of str
        Terms the user accepts to lose in a format that cannot hold them (``"g-sensitivity"``):
        without it such a calibration is refused, never silently cut.
    """

    noise: NoiseFigures | None = None
    rate_hz: float | None = None
    topic: str = "/imu0"
    scale: dict[str, float] = field(default_factory=dict)
    device_id: int | None = None
    device_ids: dict[str, int] = field(default_factory=dict)
    prefix: str | None = None
    fusion_version: str = "1.3"
    drop: frozenset[str] = frozenset()


def sections(cal: Calibration) -> list[tuple[str, SensorCalibration]]:
    """The accelerometer and gyroscope sections present (the inertial sensors)."""
    return [(name, getattr(cal, name)) for name in SENSORS if getattr(cal, name) is not None]


def all_sections(cal: Calibration) -> list[tuple[str, SensorCalibration]]:
    """Every sensor section present, the magnetometer too, in file order."""
    return list(cal.sections().items())


UNSTATED_UNITS = ("raw units", "unknown")
"""What a calibration's ``units_in`` says when the session did not state its raw units."""


def check_raw_units(cal: Calibration) -> None:
    """Refuse a section (the reference's, or an IMU's of ``imus``) whose raw units
    (``units_in``) are none of the session format's for that sensor (:data:`RAW_UNITS`) nor
    unstated: an export states them as the raw units its numbers take, and converts by them.

    Raises
    ------
    InputError
        The first such section, its unit and the known ones named.
    """
    places = [("", cal.sections())]
    places += [(f"imus.{name}.", entry.sections()) for name, entry in (cal.imus or {}).items()]
    for where, secs in places:
        for name, sec in secs.items():
            unit = sec.units_in
            if unit is None or unit in UNSTATED_UNITS or unit in RAW_UNITS[name]:
                continue
            raise InputError(f"{where}{name}.units_in is {unit!r}, raw units imucal does not "
                             f"know: the {name}'s are {', '.join(RAW_UNITS[name])} (or unstated: "
                             "\"raw units\"); correct the calibration, or the session's "
                             f"{name}_units and calibrate again")  # fmt: skip


def units_in(sec: SensorCalibration) -> str:
    unit = sec.units_in
    return unit if isinstance(unit, str) and unit not in UNSTATED_UNITS else "raw units"


def one_line(text: object) -> str:
    """Free text (a sensor name, a solver) for a comment in an export: one printable line,
    control characters written as escapes (see :mod:`imucal_cli.formats.text`)."""
    return " ".join(clean_text(str(text)).split())


def check_finite(name: str, what: str, values: np.ndarray) -> np.ndarray:
    """Refuse NaN or infinite numbers (a matrix of 1e200 times a bias overflows to inf): an
    export must never carry a number the target would read as inf or nan."""
    values = np.asarray(values, dtype=np.float64)
    bad = values[~np.isfinite(values)]
    if bad.size:
        raise InputError(
            f"the {name} {what} has a value that is not a finite number ({bad[0]!r}); "
            "refusing to export it"
        )
    return values


def fmt(value: float) -> str:
    """Shortest round-trip repr of a float that YAML 1.1, JSON and C parsers read as a float.

    Raises
    ------
    InputError
        NaN or infinite (a calibration of 1e200 overflows): never exported as ``inf``.
    """
    if not math.isfinite(value):
        raise InputError(
            f"refusing to export {float(value)!r}: a number of the calibration, or one derived "
            "from it, is not finite (values too large?)"
        )
    text = repr(float(value) + 0.0)  # + 0.0: no "-0.0"
    mantissa, e, exponent = text.partition("e")
    if e and "." not in mantissa:
        text = f"{mantissa}.0e{exponent}"
    return text


def provenance(cal: Calibration | None, target: str) -> list[str]:
    """Comment lines (without the comment marker) naming the source and the toolkit."""
    lines = [f"{target}, written by imucal {__version__} (imucal export)."]
    if cal is not None:
        sensor = cal.sensor
        lines.append(
            f"sensor: {one_line(sensor) if sensor else 'not stated'}; session: "
            f"{one_line(cal.session) if cal.session else 'not stated'}; calibration created "
            f"{one_line(cal.created)}"
        )
    return lines


def require(cal: Calibration, names: tuple[str, ...], target: str) -> None:
    """Refuse a calibration holding none of ``names``, or a sensor with other than 3 channels."""
    if not any(getattr(cal, n) is not None for n in names):
        raise InputError(
            f"the calibration has no {' or '.join(names)} section: nothing to export to {target}"
        )
    for name, sec in sections(cal):
        n = sec.bias.shape[0]
        if name in names and n != 3:
            raise InputError(
                f"the {name} calibration has {n} raw channels (a redundant unit); {target} holds "
                "a 3-axis sensor only: export it with --format c-header or json"
            )


@dataclass
class TemperatureTerms:
    """A section's ``temperature_ref`` and ``bias_tempco`` (issue 17.1) in the units of the
    exported bias: ``bias(T) = bias + sum_k tempco[k-1] (T - t_ref)^k``.

    Attributes
    ----------
    t_ref : float
        Degrees C.
    tempco : ndarray (K, n)
        Units of the bias per C^k.
    t_min, t_max : float or None
        Range of temperatures the model was fitted over (``temperature_range_c``), degrees C.
    """

    t_ref: float
    tempco: np.ndarray
    t_min: float | None
    t_max: float | None

    def about(self, t_new: float) -> tuple[np.ndarray, np.ndarray]:
        """``(d0, d)``: the same polynomial about ``t_new``, ``d0`` its value there."""
        return reexpand(self.tempco, self.t_ref, t_new)

    def range_text(self) -> str:
        if self.t_min is None or self.t_max is None:
            return "fitted range not stated"
        return f"fitted over {self.t_min:.1f} .. {self.t_max:.1f} C"


def temperature_terms(sec: SensorCalibration, factor: float = 1.0) -> TemperatureTerms | None:
    """The section's temperature model with its coefficients times ``factor`` (SI units per
    raw unit, for a published bias), or None."""
    terms = sec.temperature_terms
    if terms is None:
        return None
    t_ref, tempco = terms
    rng = sec.temperature_range_c
    lo = hi = None
    if isinstance(rng, list) and len(rng) == 2 and all(isinstance(v, int | float) for v in rng):
        lo, hi = float(rng[0]), float(rng[1])
    return TemperatureTerms(t_ref, tempco * factor, lo, hi)


def clock_lines(cal: Calibration) -> list[str]:
    """Comment lines on a ``sample_clock_scale``: already in the gyro matrix; timestamps."""
    for _, sec in sections(cal):
        scale = sec.sample_clock_scale
        if scale is not None:
            return [f"sample clock: the device's clock runs {(scale - 1) * 1e6:+.1f} ppm "
                    "(sample_clock_scale); the gyro values here are per true second already; "
                    "correct device timestamps as t / sample_clock_scale"]  # fmt: skip
    return []


@dataclass
class Published:
    """One sensor's calibration in terms of what a driver publishes, ``p = factor * raw``.

    ``calibrated = matrix @ (p - bias - g_sensitivity @ a)``, everything in SI: ``p``, ``bias``
    in m/s^2 or rad/s, ``g_sensitivity`` in (rad/s) per (m/s^2), ``a`` the calibrated accel.
    """

    name: str
    matrix: np.ndarray
    bias: np.ndarray
    g_sensitivity: np.ndarray | None
    factor: float
    raw_units: str
    basis: str
    temperature: TemperatureTerms | None = None

    @property
    def unit(self) -> str:
        return SI_UNITS[self.name]

    @property
    def sensitivity(self) -> np.ndarray:
        """``S = matrix^-1``: the published value per SI unit, ``p = S @ true + bias``."""
        return np.linalg.inv(self.matrix)


def published(
    cal: Calibration, name: str, target: str, scale: dict[str, float] | None = None
) -> Published | None:
    """Rewrite ``cal``'s ``name`` section for SI input (what ROS, PX4 and ArduPilot publish).

    Raw data in m/s^2, g, rad/s or deg/s converts exactly; counts or V need the driver's factor
    in ``scale[name]`` (SI units per raw unit).  Returns None when the section is absent.

    Raises
    ------
    InputError
        Raw units that need a factor and none given, a bad factor, or a singular matrix.
    """
    sec = getattr(cal, name)
    if sec is None:
        return None
    require(cal, (name,), target)
    raw_units = units_in(sec)
    given = (scale or {}).get(name)
    if given is not None:
        if not (math.isfinite(given) and given != 0):
            raise InputError(f"--{name}-scale must be a finite non-zero number, got {given!r}")
        factor = float(given)
        basis = f"raw ({raw_units}) x {fmt(given)} {SI_UNITS[name]} per raw unit (--{name}-scale)"
    elif raw_units in _NOMINAL[name]:
        factor = _NOMINAL[name][raw_units]
        basis = (f"raw, already in {raw_units}" if factor == 1.0
                 else f"raw ({raw_units}) x {factor:.9g} {SI_UNITS[name]} per {raw_units}")
    else:
        raw = "units it does not state" if raw_units == "raw units" else raw_units
        raise InputError(
            f"the {name} calibration takes raw {raw}; {target} reads {name} in "
            f"{SI_UNITS[name]} as the driver publishes it: pass --{name}-scale (the driver's "
            f"{SI_UNITS[name]} per raw unit, e.g. {_SCALE_EXAMPLE[name]})"
        )
    if abs(np.linalg.det(sec.matrix)) < 1e-300 or not np.isfinite(np.linalg.cond(sec.matrix)):
        raise InputError(f"the {name} matrix is singular: it cannot be inverted for {target}")
    gs = sec.g_term if name == "gyro" else None
    return Published(
        name=name,
        matrix=sec.matrix / factor,
        bias=sec.bias * factor,
        g_sensitivity=None if gs is None else gs * factor,
        factor=factor,
        raw_units=raw_units,
        basis=basis,
        temperature=temperature_terms(sec, factor),
    )


def parse_scale(text: str, option: str) -> float:
    """A factor given as a number or a ratio (``9.80665/16384``), for ``--accel-scale``."""
    num, slash, den = str(text).partition("/")
    try:
        value = float(num) / (float(den) if slash else 1.0)
    except (ValueError, ZeroDivisionError):
        raise InputError(
            f"{option} {text!r}: give a number or a ratio like 9.80665/16384"
        ) from None
    if not math.isfinite(value) or value <= 0:  # a driver's units per raw unit; -1 would mirror
        raise InputError(f"{option} {text!r}: must be a finite positive number (the driver's "
                         "units per raw unit)")  # fmt: skip
    # 1e300 exported offsets of 1e302 m/s^2 and scales of 0.0, exit 0: bounded as a matrix is
    unit = {"--accel-scale": "m/s^2", "--gyro-scale": "rad/s", "--mag-scale": "uT"}.get(option)
    if unit is not None and not MIN_GAIN <= value <= OFFSET_LIMIT[unit]:
        raise InputError(f"{option} {text!r}: {value:g} {unit} per raw unit is no driver's "
                         f"({MIN_GAIN:g} to {OFFSET_LIMIT[unit]:g})")  # fmt: skip
    return value


# --------------------------------------------------------------------------------------------
# Kalibr's scale-misalignment layout (shared by Kalibr, OpenVINS and Basalt)
# --------------------------------------------------------------------------------------------


def lq(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``S = L @ Q`` with ``L`` lower triangular (positive diagonal where it can be) and ``Q`` a
    proper rotation (det +1).  A mirrored ``S`` (det < 0) gets a negative ``L[2, 2]``."""
    q, r = np.linalg.qr(S.T)
    L, Q = r.T, q.T
    d = np.where(np.diag(L) < 0, -1.0, 1.0)
    L, Q = L * d, d[:, None] * Q
    if np.linalg.det(Q) < 0:
        L[:, 2], Q[2, :] = -L[:, 2], -Q[2, :]
    return np.tril(L), Q


@dataclass
class KalibrFrame:
    """The calibration in Kalibr's scale-misalignment model, published SI units in and out.

    Kalibr (Rehder et al. 2016; ``IccSensors.py``), for the IMU frame ``i``::

        accel:  p_a = M_accel @ a_i + b_accel
        gyro:   p_w = M_gyro @ C_gyro_i @ w_i + A @ C_gyro_i @ a_i + b_gyro

    with ``M_accel``, ``M_gyro`` lower triangular and ``C_gyro_i`` a rotation.  Kalibr's frame
    ``i`` is fixed by the lower-triangular ``M_accel`` (x along the accel's x sensitivity axis,
    y in its x-y plane); imucal's calibrated frame ``b`` is rotated from it: ``a_i = C_i_b @
    a_b``.  OpenVINS's kalibr model uses the same numbers (``Ta = M_accel``, ``Tw = M_gyro``,
    ``R_IMUtoGYRO = C_gyro_i``, ``Tg = A @ C_gyro_i``).
    """

    C_i_b: np.ndarray
    M_accel: np.ndarray
    b_accel: np.ndarray
    M_gyro: np.ndarray
    C_gyro_i: np.ndarray
    A: np.ndarray
    b_gyro: np.ndarray
    has_accel: bool
    has_gyro: bool

    @property
    def Tg(self) -> np.ndarray:
        """OpenVINS's gravity sensitivity, acting on ``a_i`` itself (not rotated)."""
        return self.A @ self.C_gyro_i


def kalibr_frame(acc: Published | None, gyro: Published | None) -> KalibrFrame:
    """Decompose published-unit calibrations into :class:`KalibrFrame` (LQ decompositions).

    ``p_a = S_a a_b + b`` with ``S_a = L Q`` gives ``M_accel = L``, ``C_i_b = Q``; the gyro's
    ``S_w C_i_b^T = L' Q'`` gives ``M_gyro = L'``, ``C_gyro_i = Q'``; its g-sensitivity
    ``G a_b = G C_i_b^T a_i = A C_gyro_i a_i`` gives ``A = G C_i_b^T C_gyro_i^T``.  A missing
    sensor is identity with zero bias.
    """
    eye, zero = np.eye(3), np.zeros(3)
    if acc is not None:
        M_accel, C_i_b = lq(acc.sensitivity)
        b_accel = acc.bias
    else:
        M_accel, C_i_b, b_accel = eye, eye, zero
    if gyro is not None:
        M_gyro, C_gyro_i = lq(gyro.sensitivity @ C_i_b.T)
        G = np.zeros((3, 3)) if gyro.g_sensitivity is None else gyro.g_sensitivity
        A = G @ C_i_b.T @ C_gyro_i.T
        b_gyro = gyro.bias
    else:
        M_gyro, C_gyro_i, A, b_gyro = eye, eye, np.zeros((3, 3)), zero
    return KalibrFrame(C_i_b, M_accel, b_accel, M_gyro, C_gyro_i, A, b_gyro,
                       acc is not None, gyro is not None)  # fmt: skip


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix, degrees."""
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))


# --------------------------------------------------------------------------------------------
# Offset and diagonal scale only (PX4, ArduPilot)
# --------------------------------------------------------------------------------------------


def _sphere(n: int = 20000) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (Fibonacci lattice), shape (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


@dataclass
class DiagonalFit:
    """``corrected = (p - offset) * scale`` per axis, and what it loses against the full model.

    Attributes
    ----------
    offset : ndarray (3,)
        Published units (m/s^2 or rad/s): the full calibration's bias, exact.
    scale : ndarray (3,)
        Per-axis factor; 1 where the target has no scale (``with_scale`` False).
    nonorthogonality_deg : dict
        Angle between each pair of sensitivity axes minus 90 degrees (``xy``, ``xz``, ``yz``):
        the misalignment the diagonal model cannot hold, whatever frame it is read in.
    axis_angle_deg : ndarray (3,)
        Angle between each sensitivity axis and the calibrated frame's axis of the same name.
    worst_angle_deg : float
        Largest direction error of the corrected vector, over every input direction.
    worst_error : float
        Largest magnitude of ``corrected - true`` per unit input (a fraction: x 9.81 m/s^2 at
        1 g, x 100 for percent).
    g_sensitivity : float or None
        Largest gyro response to 1 g that the target cannot subtract, rad/s.
    """

    offset: np.ndarray
    scale: np.ndarray
    nonorthogonality_deg: dict[str, float]
    axis_angle_deg: np.ndarray
    worst_angle_deg: float
    worst_error: float
    g_sensitivity: float | None

    def lines(self, pub: Published, target: str) -> list[str]:
        """Plain comment lines: what the target loses."""
        no = ", ".join(f"{k} {v:+.3f}" for k, v in self.nonorthogonality_deg.items())
        axes = ", ".join(f"{a} {v:.3f}" for a, v in zip("xyz", self.axis_angle_deg, strict=True))
        at = f"{self.worst_error * STANDARD_GRAVITY:.4g} m/s^2 at 1 g" if pub.name == "accel" \
            else f"{100 * self.worst_error:.3g} % of the rate"  # fmt: skip
        what, lost = ("offset and per-axis scale", "misalignment") if pub.name == "accel" \
            else ("an offset", "scale and misalignment")  # fmt: skip
        out = [
            f"{pub.name}: {target} holds {what} only; the full calibration's {lost} is lost:",
            f"  angles between sensitivity axes minus 90 deg: {no}",
            f"  each sensitivity axis to the calibrated frame's axis, deg: {axes}",
            f"  worst error over all directions: {self.worst_angle_deg:.3f} deg, {at}",
        ]
        if self.g_sensitivity is not None:
            out.append(
                f"  g-sensitivity dropped: up to {self.g_sensitivity:.4g} rad/s "
                f"({math.degrees(self.g_sensitivity):.4g} deg/s) at 1 g"
            )
        return out


def diagonal_fit(pub: Published, with_scale: bool) -> DiagonalFit:
    """Offset (exact) and per-axis scale of ``pub``, and the loss against the full model.

    The scale of axis i is ``1 / |s_i|``, ``s_i`` the axis's sensitivity vector (row i of
    ``S = matrix^-1``): the corrected axis then reads the projection of the true vector on the
    unit sensitivity axis, so only the directions of the axes are lost (nothing of the gains).
    """
    S = pub.sensitivity
    norms = np.linalg.norm(S, axis=1)
    scale = 1.0 / norms if with_scale else np.ones(3)
    units = S / norms[:, None]
    pairs = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}
    nonorth = {
        k: math.degrees(math.acos(np.clip(units[i] @ units[j], -1, 1))) - 90.0
        for k, (i, j) in pairs.items()
    }
    axis_angle = np.degrees(np.arccos(np.clip(np.diag(units), -1, 1)))
    N = scale[:, None] * S  # corrected = N @ true
    u = _sphere()
    v = u @ N.T
    cos = np.einsum("ij,ij->i", u, v) / np.linalg.norm(v, axis=1)
    worst_angle = float(np.degrees(np.arccos(np.clip(cos, -1, 1))).max())
    worst_error = float(np.linalg.norm(N - np.eye(3), 2))
    gs = None
    if pub.g_sensitivity is not None:
        gs = float(np.linalg.norm(pub.g_sensitivity, 2) * STANDARD_GRAVITY)
    return DiagonalFit(pub.bias.copy(), scale, nonorth, axis_angle, worst_angle, worst_error, gs)


def offset_scale_fits(
    cal: Calibration, target: str, opts: ExportOptions, *, also: tuple[str, ...] = ()
) -> tuple[list[str], list[tuple[str, Published, DiagonalFit]]]:
    """PX4 and ArduPilot: per sensor present, its :func:`diagonal_fit` (the accelerometer with
    a scale, the gyro an offset only), and the comment lines saying what each loses.
    ``also``: further sections the target writes itself (a calibration holding only those is
    not refused)."""
    require(cal, ("accel", "gyro", *also), target)
    comments: list[str] = []
    fits: list[tuple[str, Published, DiagonalFit]] = []
    for name in SENSORS:
        pub = published(cal, name, target, opts.scale)
        if pub is None:
            comments.append(f"{name}: not in the calibration, its parameters are not written")
            continue
        fit = diagonal_fit(pub, with_scale=name == "accel")
        comments += [f"{name}: p = {pub.basis}", *fit.lines(pub, target)]
        fits.append((name, pub, fit))
    return comments, fits


def model_lines() -> list[str]:
    """imucal's own model, for the header of every file."""
    return [f"imucal's model: {MODEL_EQUATION} (raw as the device reports it; bias in raw "
            "units; out in m/s^2, rad/s)"]  # fmt: skip
