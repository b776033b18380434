"""The virtual IMU's sensor model, shared by every simulator and the pty device.

A simulated part is an :class:`Imu`: one :class:`ChannelGroup` per sensor (``accel``, ``gyro``;
a magnetometer or a temperature-dependent term is one more group or one more field), each
mapping a physical 3-vector ``x`` (fixture frame, in the group's ``input_unit``) to its raw
channels::

    raw = clip(quantise(S @ (x + n_in) + b + sum_k c_k (T - T_ref)^k + n_out), low, high)

``S`` (n x 3) is the sensitivity (row i = channel i's sensitivity axis times its gain, raw units
per input unit), ``b`` (n,) the bias in raw units, ``n_in`` white input-referred noise (input
units, per axis) and ``n_out`` white output-referred noise (raw units, per channel, e.g. an
ADC's).  A group declares which noise it has; each declared noise is drawn, in group order, from
one generator (:meth:`Imu.sample`), so the same generator state gives the same samples.
The bias follows the part's temperature ``T`` where the group has ``tempco`` (``c_k``, raw units
per C^k about ``temperature_ref``; :mod:`imucal_cli.simulate.temperature` draws them and the
temperature ramp); the truth then holds ``temperature_ref`` and ``bias_tempco``.

The truth calibration of a group is ``matrix = to_si * S^-1`` (pseudo-inverse for a redundant
unit), ``bias = b``: ``matrix @ (raw - bias)`` gives ``x`` in SI units up to noise and
quantisation (:meth:`ChannelGroup.truth`).

:func:`random_imu` draws a cheap 16-bit 6-axis part from a generator; every simulator draws it
from the first of the three generators spawned from ``numpy.random.SeedSequence(seed)`` (truth,
poses, noise), so one seed is one physical part in every plan.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Segment, Session, utc_now_iso
from imucal_cli.model.calibration import Calibration, SensorCalibration, section_class
from imucal_cli.model.codec import build
from imucal_cli.simulate.motion import unit

__all__ = [
    "ACCEL_LSB_PER_G",
    "G0",
    "GYRO_LSB_PER_DPS",
    "RAW_MAX",
    "RAW_MIN",
    "UNITS",
    "ChannelGroup",
    "Imu",
    "check_units",
    "draw_part",
    "floats",
    "random_imu",
    "spawn",
]

G0 = 9.80665
"""Standard gravity, m/s^2: the "g" of LSB/g and milli-g figures (not the local gravity)."""

RAW_MIN, RAW_MAX = -32768, 32767
"""Signed 16-bit output range, counts."""

ACCEL_LSB_PER_G = 8192.0
"""+-4 g full scale on 16 bits: 8192 LSB/g, i.e. about 835.4 counts per m/s^2."""

GYRO_LSB_PER_DPS = 16.4
"""+-2000 deg/s full scale on 16 bits: 16.4 LSB per deg/s, about 939.6 counts per rad/s."""

# Spread of the manufacturing errors of the simulated part (uniform draws, see random_imu).
ACCEL_SCALE_ERROR_MAX = 0.03  # |relative scale error| <= 3 %
ACCEL_BIAS_MAX_G = 0.050  # |zero-g offset| <= 50 mg
GYRO_SCALE_ERROR_RANGE = (0.01, 0.03)  # 1 % .. 3 %, random sign
GYRO_BIAS_MAX_DPS = 3.0  # |zero-rate offset| <= 3 deg/s
AXIS_TILT_MAX_DEG = 0.5  # each sensitivity axis leans <= 0.5 deg: pairs <= 1 deg off 90
MOUNT_MAX_DEG = 1.0  # chip rotated <= 1 deg relative to the fixture

UNITS = {"counts": "rad/s", "m/s^2": "rad/s"}
"""Accepted accelerometer raw units (keys); the gyro reads ``counts`` or ``rad/s`` to match."""

_SI = {"m/s^2": ("m/s^2", 1.0), "g": ("m/s^2", G0), "rad/s": ("rad/s", 1.0), "uT": ("uT", 1.0)}
"""Input unit -> (SI unit of the calibrated output, factor from the input unit to SI)."""


def spawn(seed: int) -> tuple[np.random.SeedSequence, ...]:
    """The three seed sequences of a simulation: the part, the poses (motion), the noise."""
    return tuple(np.random.SeedSequence(int(seed)).spawn(3))


def floats(a) -> list:
    """``a`` as a (nested) list of floats, for a JSON truth record."""
    return np.asarray(a, dtype=float).tolist()


def misalignment_deg(S: np.ndarray) -> dict[str, float]:
    """Angles between the sensitivity axes (rows of a (3, 3) ``S``) minus 90 degrees."""
    n = S / np.linalg.norm(S, axis=-1, keepdims=True)
    out = {}
    for (i, j), key in zip(((0, 1), (0, 2), (1, 2)), ("xy", "xz", "yz"), strict=True):
        out[key] = float(np.degrees(np.arccos(np.clip(n[i] @ n[j], -1.0, 1.0))) - 90.0)
    return out


@dataclass
class ChannelGroup:
    """One sensor of the virtual IMU: ``n`` raw channels measuring a physical 3-vector.

    Attributes
    ----------
    name : str
        ``"accel"``, ``"gyro"`` (the session dataset and calibration section it fills).
    input_unit : str
        Unit of the physical input ``x``: ``"m/s^2"``, ``"g"`` or ``"rad/s"``.
    units : str
        Raw units (``counts``, ``m/s^2``, ``rad/s``).
    S : ndarray, shape (n, 3)
        Sensitivity, raw units per input unit; row i = channel i's axis (unit vector, fixture
        frame) times its gain.
    b : ndarray, shape (n,)
        Bias, raw units.
    noise_in : ndarray, shape (3,), or None
        Input-referred white noise per axis per sample, input units; None: none declared.
    noise_out : float or None
        Output-referred white noise per channel per sample, raw units (before rounding).
    nominal : float
        Nominal gain, raw units per input unit (the datasheet's).
    quantise : bool
        Round raw samples to integers.
    limits : tuple of float
        Output range (low, high), raw units; readings beyond it saturate.
    scale_error : ndarray, shape (n,)
        Relative gain error of each channel (gain = nominal * (1 + error)).
    datasheet : dict
        The part in datasheet terms for the truth record, e.g. ``{"bias_g": ...}`` (also
        readable as attributes of the :class:`Imu`: ``imu.accel_bias_g``).
    """

    name: str
    input_unit: str
    units: str
    S: np.ndarray
    b: np.ndarray
    noise_in: np.ndarray | None = None
    noise_out: float | None = None
    nominal: float = 1.0
    quantise: bool = False
    limits: tuple[float, float] = (-np.inf, np.inf)
    scale_error: np.ndarray = field(default_factory=lambda: np.zeros(3))
    datasheet: dict[str, Any] = field(default_factory=dict)
    tempco: np.ndarray | None = None
    temperature_ref: float = 25.0

    @property
    def channels(self) -> int:
        """Number of raw channels ``n``."""
        return self.S.shape[0]

    def raw(
        self, x: np.ndarray, noise_in: np.ndarray | None = None,
        noise_out: np.ndarray | None = None, temperature: np.ndarray | None = None,
    ) -> np.ndarray:  # fmt: skip
        """Raw samples (N, n) from the true input ``x`` (N, 3) and drawn noise.

        ``noise_in`` (N, 3) is in input units, ``noise_out`` (N, n) in raw units; either may be
        None (no noise of that kind). ``temperature`` (N,), degrees C: the part's true
        temperature, which moves the bias by ``tempco`` (ignored without it).
        """
        if noise_in is not None:
            x = x + noise_in
        raw = x @ self.S.T + self.b
        if temperature is not None and self.tempco is not None:
            dt = np.asarray(temperature, float) - self.temperature_ref
            raw = raw + (dt[:, None] ** np.arange(1, len(self.tempco) + 1)) @ self.tempco
        if noise_out is not None:
            raw = raw + noise_out
        if self.quantise:
            raw = np.rint(raw)
        return np.clip(raw, self.limits[0], self.limits[1])

    def draw_noise(
        self, rng: np.random.Generator, n: int
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The declared noise of ``n`` samples: input-referred (n, 3), then output (n, ch)."""
        n_in = None if self.noise_in is None else rng.standard_normal((n, 3)) * self.noise_in
        n_out = (
            None
            if self.noise_out is None
            else rng.standard_normal((n, self.channels)) * self.noise_out
        )
        return n_in, n_out

    @property
    def si_unit(self) -> str:
        """Unit of the calibrated output (``m/s^2``, ``rad/s``)."""
        return _SI[self.input_unit][0]

    def truth(self, extra: dict) -> SensorCalibration:
        """The true calibration: ``matrix @ (raw - bias)`` is ``x`` in SI units."""
        to_si = _SI[self.input_unit][1]
        inverse = np.linalg.inv if self.S.shape == (3, 3) else np.linalg.pinv
        if self.tempco is not None:
            extra = {"temperature_ref": float(self.temperature_ref),
                     "bias_tempco": floats(self.tempco), **extra}  # fmt: skip
        return build(section_class(self.name, "truth"), solver="truth", units=self.si_unit,
                     bias=np.array(self.b, dtype=float), matrix=to_si * inverse(self.S),
                     **extra)  # fmt: skip

    def describe(self) -> dict[str, Any]:
        """The part in the truth record's terms (a triad: misalignment and datasheet figures)."""
        noise = None if self.noise_in is None else np.asarray(self.noise_in, float)
        out: dict[str, Any] = {"units_in": self.units}
        if noise is not None:
            out["noise"] = float(noise[0]) if np.all(noise == noise[0]) else floats(noise)
            out["noise_unit"] = f"{self.input_unit} per axis per sample (white, input-referred)"
        out["sensitivity"] = floats(np.linalg.norm(self.S, axis=1))
        out["sensitivity_unit"] = f"{self.units} per {self.input_unit}"
        out["nominal_sensitivity"] = float(self.nominal)
        out["scale_error"] = floats(self.scale_error)
        if self.S.shape == (3, 3):
            out["misalignment_deg"] = misalignment_deg(self.S)
        for key, value in self.datasheet.items():
            if key == "bias_g":
                out["bias_mg"] = floats(1000.0 * np.asarray(value))
            else:
                out[key] = floats(value)
        out["S"] = floats(self.S)
        return out


@dataclass
class Imu:
    """A simulated part: its channel groups, in noise-drawing order, and its mounting.

    Attributes
    ----------
    groups : tuple of ChannelGroup
    mount_rotvec : ndarray, shape (3,)
        Rotation of the chip relative to the fixture (rotation vector, rad), shared by the
        groups of one package.

    ``imu.accel`` is the group named ``accel``; ``imu.accel_S``, ``imu.gyro_b``,
    ``imu.accel_bias_g``, ... read a group's field (or datasheet entry), and
    ``imu.accel_raw(x, noise)`` is ``imu.accel.raw(x, noise)``.
    """

    groups: tuple[ChannelGroup, ...]
    mount_rotvec: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def group(self, name: str) -> ChannelGroup:
        """The group named ``name`` (KeyError when the part has none)."""
        for g in self.groups:
            if g.name == name:
                return g
        raise KeyError(name)

    def __getattr__(self, attr: str):
        if attr.startswith("_") or attr in ("groups", "mount_rotvec"):
            raise AttributeError(attr)
        prefix, _, rest = attr.partition("_")
        try:
            g = self.group(prefix)
        except KeyError:
            raise AttributeError(attr) from None
        if not rest:
            return g
        if rest in g.datasheet:
            return g.datasheet[rest]
        short = {"noise": "noise_in"}.get(rest, rest)
        if hasattr(g, short):
            return getattr(g, short)
        raise AttributeError(attr)

    @property
    def quantise(self) -> bool:
        """Every group rounds to integers."""
        return all(g.quantise for g in self.groups)

    def sample(
        self, inputs: dict[str, np.ndarray], rng: np.random.Generator,
        temperature: np.ndarray | None = None,
    ) -> dict:  # fmt: skip
        """Raw samples of every group from its true input (N, 3); noise drawn in group order;
        ``temperature`` (N,), degrees C, moves the biases of groups with a ``tempco``."""
        out = {}
        for g in self.groups:
            x = inputs[g.name]
            out[g.name] = g.raw(x, *g.draw_noise(rng, len(x)), temperature=temperature)
        return out

    def record(
        self, inputs: dict[str, np.ndarray], segments: list[Segment], *,
        noise_seed: np.random.SeedSequence, rate_hz: float, gravity: float, sensor: str,
        created: str | None = None, time: np.ndarray | None = None,
        temperature: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> Session:  # fmt: skip
        """A session of the part going through a motion: the true inputs (fixture frame, (N,
        3) each) through the sensor model with noise from one generator (``noise_seed``).
        ``temperature``: the part's true temperature and the reading recorded, (N,) each."""
        true_c, reading_c = (None, None) if temperature is None else temperature
        raw = self.sample(inputs, np.random.default_rng(noise_seed), temperature=true_c)
        n = len(next(iter(inputs.values())))
        channels: dict = {"accel": None, "gyro": None, "accel_units": None, "gyro_units": None}
        for g in self.groups:  # each group fills its dataset and units (mag: mag, mag_units)
            channels[g.name], channels[f"{g.name}_units"] = raw[g.name], g.units
        return Session(
            time=np.arange(n) / rate_hz if time is None else time,
            temperature=reading_c,
            segments=segments,
            created=created or utc_now_iso(),
            sensor=sensor,
            source="simulator",
            sample_rate_hz=rate_hz,
            gravity=gravity,
            **channels,
        )

    def truth_sections(self, extras: dict[str, dict]) -> dict[str, SensorCalibration]:
        """Each group's truth, its ``describe()`` record updated with ``extras[name]``."""
        out = {}
        for g in self.groups:
            common = {"model": "calibrated = matrix @ (raw - bias)", "quantised": g.quantise}
            out[g.name] = g.truth({**common, **g.describe(), **extras.get(g.name, {})})
        return out

    def session_and_truth(
        self, inputs: dict[str, np.ndarray], segments: list[Segment], *,
        noise_seed: np.random.SeedSequence, options: dict, sensor: str, extras: dict,
        created: str | None = None, time: np.ndarray | None = None, root: dict | None = None,
        temperature: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[Session, Calibration]:  # fmt: skip
        """What a simulator returns: the recorded session (:meth:`record`) and its truth.

        ``options`` are the simulator's (JSON-ready; ``seed``, ``plan``, ``rate_hz`` and
        ``gravity`` are used), ``extras`` each group's truth record (:meth:`truth_sections`),
        ``root`` more root fields of the truth (before ``simulator``, the options),
        ``temperature`` the true and recorded temperature (:meth:`record`).
        """
        created = created or utc_now_iso()
        session = self.record(
            inputs, segments, noise_seed=noise_seed, rate_hz=options["rate_hz"],
            gravity=options["gravity"], sensor=sensor, created=created, time=time,
            temperature=temperature,
        )  # fmt: skip
        sections = self.truth_sections(extras)  # one calibration section per group
        head = {"sensor": sensor, "seed": options["seed"], "plan": options["plan"]}
        extra = {**head, **(root or {}), "simulator": options}
        return session, build(Calibration, **sections, **extra, created=created)


def tilted_axes(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    """Three sensitivity axes, each leaning from its chip axis by up to ``max_deg``.

    Returns rows n_i (3, 3), unit vectors in the chip frame.  Draws 6 numbers.
    """
    tilt = np.radians(rng.uniform(0.0, max_deg, 3))
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    eye = np.eye(3)
    rows = []
    for i in range(3):
        p, q = eye[(i + 1) % 3], eye[(i + 2) % 3]
        lean = np.cos(phase[i]) * p + np.sin(phase[i]) * q
        rows.append(np.cos(tilt[i]) * eye[i] + np.sin(tilt[i]) * lean)
    return np.array(rows)


def check_units(units: str) -> str:
    """The raw ``units`` of a simulated part (a key of :data:`UNITS`), else a one-line error."""
    if units not in UNITS:
        raise InputError(f"units {units!r} are not supported: use counts or m/s^2")
    return units


def _manufacturing_errors(rng: np.random.Generator) -> dict[str, Any]:
    """The part's errors in relative terms, drawn in this order whatever the units: accel
    scale, axes, bias (g); gyro scale, axes, bias (deg/s); the chip's mounting rotation."""
    out = {
        "a_scale": rng.uniform(-ACCEL_SCALE_ERROR_MAX, ACCEL_SCALE_ERROR_MAX, 3),
        "a_axes": tilted_axes(rng, AXIS_TILT_MAX_DEG),
        "a_bias_g": rng.uniform(-ACCEL_BIAS_MAX_G, ACCEL_BIAS_MAX_G, 3),
        "g_scale": rng.uniform(*GYRO_SCALE_ERROR_RANGE, 3) * rng.choice([-1.0, 1.0], 3),
        "g_axes": tilted_axes(rng, AXIS_TILT_MAX_DEG),
        "g_bias_dps": rng.uniform(-GYRO_BIAS_MAX_DPS, GYRO_BIAS_MAX_DPS, 3),
    }
    mount_axis = unit(rng.standard_normal(3))
    out["mount_rotvec"] = mount_axis * np.radians(rng.uniform(0.0, MOUNT_MAX_DEG))
    return out


def random_imu(
    rng: np.random.Generator,
    units: str = "counts",
    accel_noise: float = 0.01,
    gyro_noise: float = 0.005,
) -> Imu:
    """Draw a cheap 16-bit MEMS part (+-4 g accelerometer, +-2000 deg/s gyroscope).

    Accelerometer: gain 8192 LSB/g (835.4 counts per m/s^2) with per-axis errors uniform in
    +-3 %, each sensitivity axis leaning up to 0.5 deg from its chip axis (so pairs of axes are
    up to 1 deg from orthogonal), bias uniform in +-50 mg.  Gyroscope: 16.4 LSB per deg/s with
    scale errors of 1-3 % (random sign), axes leaning up to 0.5 deg, bias uniform in
    +-3 deg/s.  The chip sits rotated up to 1 deg (random axis) in the fixture; both sensors
    share that rotation.  These are typical datasheet figures for consumer 6-axis parts.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of all draws.  The same number of draws is made for every ``units``, so the
        same generator state gives the same physical part.
    units : {"counts", "m/s^2"}
        Raw units.  ``counts``: integer output, gyro in counts.  ``m/s^2``: a part whose
        nominal gain is 1 (same relative errors, bias in m/s^2 and rad/s, no quantisation,
        same saturation point); gyro in rad/s.
    accel_noise : float
        White noise per axis per sample, m/s^2 (input-referred).
    gyro_noise : float
        White noise per axis per sample, rad/s (input-referred).

    Returns
    -------
    Imu
        Groups ``accel`` (datasheet ``bias_g``) and ``gyro`` (datasheet ``bias_dps``).
    """
    check_units(units)
    e = _manufacturing_errors(rng)
    chip_to_fixture_T = Rotation.from_rotvec(e["mount_rotvec"]).as_matrix().T
    a_counts = ACCEL_LSB_PER_G / G0  # counts per m/s^2
    g_counts = GYRO_LSB_PER_DPS * 180.0 / np.pi  # counts per rad/s
    if units == "counts":
        a_nom, g_nom, quantise = a_counts, g_counts, True
        a_bias = e["a_bias_g"] * ACCEL_LSB_PER_G
        g_bias = e["g_bias_dps"] * GYRO_LSB_PER_DPS
        a_units, g_units = "counts", "counts"
    else:
        a_nom, g_nom, quantise = 1.0, 1.0, False
        a_bias = e["a_bias_g"] * G0
        g_bias = np.radians(e["g_bias_dps"])
        a_units, g_units = "m/s^2", "rad/s"

    specs = (  # name, input unit, nominal, scale error, axes, bias, units, noise, per SI, sheet
        ("accel", "m/s^2", a_nom, e["a_scale"], e["a_axes"], a_bias, a_units, accel_noise,
         a_counts, {"bias_g": e["a_bias_g"]}),
        ("gyro", "rad/s", g_nom, e["g_scale"], e["g_axes"], g_bias, g_units, gyro_noise,
         g_counts, {"bias_dps": e["g_bias_dps"]}),
    )  # fmt: skip
    groups = tuple(
        ChannelGroup(
            name=name,
            input_unit=input_unit,
            units=raw_units,
            S=nom * np.diag(1.0 + scale) @ axes @ chip_to_fixture_T,
            b=bias,
            noise_in=np.full(3, float(noise)),
            nominal=nom,
            quantise=quantise,
            # saturation at the same physical input in either unit system
            limits=(RAW_MIN * nom / per_si, RAW_MAX * nom / per_si),
            scale_error=scale,
            datasheet=sheet,
        )
        for name, input_unit, nom, scale, axes, bias, raw_units, noise, per_si, sheet in specs
    )
    return Imu(groups=groups, mount_rotvec=e["mount_rotvec"])


def draw_part(
    seed: int, units: str, accel_noise: float, gyro_noise: float
) -> tuple[Imu, np.random.SeedSequence, np.random.SeedSequence]:
    """The part of a simulation and the seeds of the rest: :func:`random_imu` from the first
    of the three generators of ``seed`` (:func:`spawn`), then the pose and noise seeds."""
    truth_ss, pose_ss, noise_ss = spawn(seed)
    imu = random_imu(np.random.default_rng(truth_ss), units, accel_noise=accel_noise,
                     gyro_noise=gyro_noise)  # fmt: skip
    return imu, pose_ss, noise_ss
