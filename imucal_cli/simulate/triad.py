"""The virtual IMU: a cheap 16-bit MEMS accelerometer + gyroscope with known truth.

The simulator plays the experiment of Qureshi & Golnaraghi (section III-A, IV-B): the unit is
placed by hand in a list of poses (the 6 faces and 12 45-degree edges of a cube, or any other
plan), held still in each for ``hold_s`` seconds, and turned smoothly from one pose to the
next.  It returns the session exactly as a recorder would have written it, plus a truth
:class:`~imucal_cli.formats.calibration.Calibration` that maps the raw channels back to the specific
force and angular rate in the fixture frame.

Sensor model (per sample, body = fixture frame, SI input, raw output)::

    raw_accel = S_a @ (f + n_a) + b_a        f: specific force, m/s^2;  n_a ~ N(0, sigma_a^2 I)
    raw_gyro  = S_g @ (w + n_g) + b_g        w: angular rate,  rad/s;   n_g ~ N(0, sigma_g^2 I)

then rounded to integers and clipped to the signed 16-bit range for ``units="counts"``.
The noise is input-referred, so the truth calibration ``matrix = inv(S)``, ``bias = b`` turns a
raw sample into ``f + n`` (plus quantisation).  ``S`` is a general 3 x 3 matrix: per-axis scale
errors, sensitivity axes that are not orthogonal, and a small rotation of the chip relative to
the fixture (shared by both sensors, which sit in one package).

Randomness: three generators spawned from ``numpy.random.SeedSequence(seed)``: the sensor
truth, the poses (random directions, headings, placement tilt) and the noise.  The truth is
drawn in relative terms (scale errors, angles, bias in g and deg/s) and the noise in SI, so one
seed describes the same physical experiment whatever the raw ``units``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration, SensorCalibration
from imucal_cli.formats.session import Segment, Session, utc_now_iso
from imucal_cli.plans import plan_poses

__all__ = [
    "G0",
    "ImuTruth",
    "SimulatedStream",
    "StreamSegment",
    "UNITS",
    "random_imu",
    "sensor_name",
    "simulate",
    "simulate_stream",
    "truth_calibration",
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


@dataclass
class ImuTruth:
    """The true sensor: ``raw = S @ (x + noise) + b``, then quantised and clipped.

    ``x`` is the specific force (m/s^2) or angular rate (rad/s) in the fixture (body) frame.

    Attributes
    ----------
    accel_S : ndarray, shape (3, 3)
        Accelerometer sensitivity, raw units per m/s^2.  Row i is sensitivity axis i (a unit
        vector in the fixture frame) times that axis' gain.
    accel_b : ndarray, shape (3,)
        Accelerometer bias, raw units.
    accel_noise : ndarray, shape (3,)
        White Gaussian noise per axis per sample, m/s^2 (input-referred).
    gyro_S : ndarray, shape (3, 3)
        Gyroscope sensitivity, raw units per rad/s.
    gyro_b : ndarray, shape (3,)
        Gyroscope bias, raw units.
    gyro_noise : ndarray, shape (3,)
        White Gaussian noise per axis per sample, rad/s.
    accel_units, gyro_units : str
        Raw units: ``counts``/``counts`` or ``m/s^2``/``rad/s``.
    accel_nominal, gyro_nominal : float
        Nominal gain, raw units per m/s^2 and per rad/s (835.4 and 939.6 counts, or 1).
    quantise : bool
        Round raw samples to integers (``counts``).
    accel_limits, gyro_limits : tuple of float
        Output range (low, high) in raw units; readings beyond it saturate.
    accel_scale_error, gyro_scale_error : ndarray, shape (3,)
        Relative gain error of each axis (dimensionless, gain = nominal * (1 + error)).
    accel_bias_g : ndarray, shape (3,)
        Accelerometer bias in g (standard gravity).
    gyro_bias_dps : ndarray, shape (3,)
        Gyroscope bias, deg/s.
    mount_rotvec : ndarray, shape (3,)
        Rotation of the chip relative to the fixture (rotation vector, rad).
    """

    accel_S: np.ndarray
    accel_b: np.ndarray
    accel_noise: np.ndarray
    gyro_S: np.ndarray
    gyro_b: np.ndarray
    gyro_noise: np.ndarray
    accel_units: str = "counts"
    gyro_units: str = "counts"
    accel_nominal: float = ACCEL_LSB_PER_G / G0
    gyro_nominal: float = GYRO_LSB_PER_DPS * 180.0 / np.pi
    quantise: bool = True
    accel_limits: tuple[float, float] = (RAW_MIN, RAW_MAX)
    gyro_limits: tuple[float, float] = (RAW_MIN, RAW_MAX)
    accel_scale_error: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_scale_error: np.ndarray = field(default_factory=lambda: np.zeros(3))
    accel_bias_g: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_bias_dps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    mount_rotvec: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def accel_raw(self, specific_force: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """Raw accelerometer samples.

        Parameters
        ----------
        specific_force : ndarray, shape (N, 3)
            True specific force in the fixture frame, m/s^2.
        noise : ndarray, shape (N, 3)
            Noise already scaled to m/s^2.

        Returns
        -------
        ndarray, shape (N, 3), float64
            Raw samples in ``accel_units``.
        """
        return self._raw(specific_force + noise, self.accel_S, self.accel_b, self.accel_limits)

    def gyro_raw(self, rate: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """Raw gyroscope samples from the true rate (N, 3) rad/s and noise (N, 3) rad/s."""
        return self._raw(rate + noise, self.gyro_S, self.gyro_b, self.gyro_limits)

    def _raw(self, x, S, b, limits) -> np.ndarray:
        raw = x @ S.T + b
        if self.quantise:
            raw = np.rint(raw)
        return np.clip(raw, limits[0], limits[1])


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _tilted_axes(rng: np.random.Generator, max_deg: float) -> np.ndarray:
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


def random_imu(
    rng: np.random.Generator,
    units: str = "counts",
    accel_noise: float = 0.01,
    gyro_noise: float = 0.005,
) -> ImuTruth:
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
        White noise per axis per sample, m/s^2.
    gyro_noise : float
        White noise per axis per sample, rad/s.

    Returns
    -------
    ImuTruth
    """
    if units not in UNITS:
        raise InputError(f"units {units!r} are not supported: use counts or m/s^2")
    # Every draw happens, in this order, whatever the units.
    a_scale = rng.uniform(-ACCEL_SCALE_ERROR_MAX, ACCEL_SCALE_ERROR_MAX, 3)
    a_axes = _tilted_axes(rng, AXIS_TILT_MAX_DEG)
    a_bias_g = rng.uniform(-ACCEL_BIAS_MAX_G, ACCEL_BIAS_MAX_G, 3)
    g_scale = rng.uniform(*GYRO_SCALE_ERROR_RANGE, 3) * rng.choice([-1.0, 1.0], 3)
    g_axes = _tilted_axes(rng, AXIS_TILT_MAX_DEG)
    g_bias_dps = rng.uniform(-GYRO_BIAS_MAX_DPS, GYRO_BIAS_MAX_DPS, 3)
    mount_axis = _unit(rng.standard_normal(3))
    mount_angle = np.radians(rng.uniform(0.0, MOUNT_MAX_DEG))
    mount_rotvec = mount_axis * mount_angle
    chip_to_fixture_T = Rotation.from_rotvec(mount_rotvec).as_matrix().T

    a_counts = ACCEL_LSB_PER_G / G0  # counts per m/s^2
    g_counts = GYRO_LSB_PER_DPS * 180.0 / np.pi  # counts per rad/s
    if units == "counts":
        a_nom, g_nom, quantise = a_counts, g_counts, True
        a_bias = a_bias_g * ACCEL_LSB_PER_G
        g_bias = g_bias_dps * GYRO_LSB_PER_DPS
        a_units, g_units = "counts", "counts"
    else:
        a_nom, g_nom, quantise = 1.0, 1.0, False
        a_bias = a_bias_g * G0
        g_bias = np.radians(g_bias_dps)
        a_units, g_units = "m/s^2", "rad/s"
    # Saturation at the same physical input in either unit system.
    a_lim = (RAW_MIN * a_nom / a_counts, RAW_MAX * a_nom / a_counts)
    g_lim = (RAW_MIN * g_nom / g_counts, RAW_MAX * g_nom / g_counts)
    return ImuTruth(
        accel_S=a_nom * np.diag(1.0 + a_scale) @ a_axes @ chip_to_fixture_T,
        accel_b=a_bias,
        accel_noise=np.full(3, float(accel_noise)),
        gyro_S=g_nom * np.diag(1.0 + g_scale) @ g_axes @ chip_to_fixture_T,
        gyro_b=g_bias,
        gyro_noise=np.full(3, float(gyro_noise)),
        accel_units=a_units,
        gyro_units=g_units,
        accel_nominal=a_nom,
        gyro_nominal=g_nom,
        quantise=quantise,
        accel_limits=a_lim,
        gyro_limits=g_lim,
        accel_scale_error=a_scale,
        gyro_scale_error=g_scale,
        accel_bias_g=a_bias_g,
        gyro_bias_dps=g_bias_dps,
        mount_rotvec=mount_rotvec,
    )


# --------------------------------------------------------------------------------------------
# Plans
# --------------------------------------------------------------------------------------------

# --------------------------------------------------------------------------------------------
# The stream
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StreamSegment:
    """A segment of the simulated stream (mirrors the session format's ``/segments``).

    ``start``/``stop`` are sample indices, half-open; ``up`` (3,) for labelled static poses.
    """

    name: str
    kind: str
    start: int
    stop: int
    label: str | None = None
    up: np.ndarray | None = None


@dataclass
class SimulatedStream:
    """Everything :func:`simulate_stream` generated, as arrays.

    Attributes
    ----------
    time : ndarray, shape (N,)
        Seconds from the first sample, ``arange(N) / rate_hz``.
    accel, gyro : ndarray, shape (N, 3)
        Raw samples in ``truth.accel_units`` / ``truth.gyro_units``.
    specific_force : ndarray, shape (N, 3)
        True specific force in the fixture frame, m/s^2, without noise.
    rate : ndarray, shape (N,3)
        True angular rate in the fixture frame, rad/s, without noise.
    segments : list of StreamSegment
        Static holds and the rotations between them, in time order.
    true_up : ndarray, shape (K, 3)
        True up direction (unit, fixture frame) of each of the K static poses.
    labelled_up : list of (ndarray (3,) or None)
        Nominal up of each pose (None for random plans).
    tilt_deg : ndarray, shape (K,)
        Angle between the true and the nominal up (placement error), degrees.
    rotvec : ndarray, shape (K-1, 3)
        True rotation of each move (body frame rotation vector, rad): the integral of ``rate``.
    truth : ImuTruth
    options : dict
        The generation options (JSON-ready).
    """

    time: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    specific_force: np.ndarray
    rate: np.ndarray
    segments: list[StreamSegment]
    true_up: np.ndarray
    labelled_up: list[np.ndarray | None]
    tilt_deg: np.ndarray
    rotvec: np.ndarray
    truth: ImuTruth
    options: dict


def _up_to_vertical(u: np.ndarray) -> Rotation:
    """Smallest rotation (body -> world) that takes body vector ``u`` onto world +Z."""
    ez = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, ez)
    s, c = np.linalg.norm(axis), float(u @ ez)
    if s < 1e-12:
        return Rotation.identity() if c > 0 else Rotation.from_rotvec([np.pi, 0.0, 0.0])
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c))


def _check_positive(name: str, value: float, unit: str, allow_zero: bool = False) -> float:
    value = float(value)
    ok = np.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"{name} must be a finite number {bound} {unit}, got {value:g}")
    return value


MAX_SAMPLES = 20_000_000


def simulate_stream(
    plan: str = "qureshi18",
    seed: int = 0,
    rate_hz: float = 100.0,
    hold_s: float = 2.0,
    accel_noise: float = 0.01,
    jitter_deg: float = 2.0,
    units: str = "counts",
    gravity: float = G0,
    gyro_noise: float = 0.005,
    move_s: float = 1.5,
    lead_s: float = 1.0,
    lift_m: float = 0.03,
) -> SimulatedStream:
    """Generate the raw stream of a calibration session and its truth, as arrays.

    Timeline: ``lead_s`` still in the first pose (unlabelled), then for every pose a static
    segment of ``hold_s`` and, between poses, a rotation segment of about ``move_s``: a slerp
    from one true orientation to the next with a smootherstep profile (zero rate and angular
    acceleration at both ends) while the unit is lifted by ``lift_m`` and put down again.

    Each pose's true orientation is the labelled one tilted by a random horizontal rotation
    vector (2 components iid normal, std ``jitter_deg / sqrt(2)``, so the RMS angle between the
    true and the labelled up is ``jitter_deg``) and turned to a uniform random heading about
    the vertical.  A still accelerometer reads ``+gravity * up`` (specific force points away
    from the earth).  The gyro reads the body angular rate; the earth rate (7e-5 rad/s,
    buried in the noise) is left out.

    Parameters
    ----------
    plan : str
        ``six``, ``qureshi18`` or ``random:N`` (see :func:`plan_poses`).
    seed : int
        Non-negative seed; the same seed and options give the same arrays bit for bit.
    rate_hz : float
        Sample rate, Hz.
    hold_s : float
        Hold per pose, s; must give at least 10 samples.
    accel_noise : float
        Accelerometer white noise per axis per sample, m/s^2.
    jitter_deg : float
        RMS placement error of the up direction, degrees.
    units : {"counts", "m/s^2"}
        Raw units of the simulated part (see :func:`random_imu`).
    gravity : float
        Local gravity, m/s^2.
    gyro_noise : float
        Gyroscope white noise per axis per sample, rad/s.
    move_s : float
        Duration of each move between poses, s.
    lead_s : float
        Still time before the first hold, s.
    lift_m : float
        Height the unit is lifted during each move, m (vertical linear acceleration).

    Returns
    -------
    SimulatedStream

    Raises
    ------
    InputError
        A bad plan, unit or value.
    """
    poses = plan_poses(plan)
    if units not in UNITS:
        raise InputError(f"units {units!r} are not supported: use counts or m/s^2")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    rate_hz = _check_positive("rate", rate_hz, "Hz")
    hold_s = _check_positive("hold", hold_s, "s")
    accel_noise = _check_positive("accel noise", accel_noise, "m/s^2", allow_zero=True)
    gyro_noise = _check_positive("gyro noise", gyro_noise, "rad/s", allow_zero=True)
    jitter_deg = _check_positive("jitter", jitter_deg, "deg", allow_zero=True)
    gravity = _check_positive("gravity", gravity, "m/s^2")
    move_s = _check_positive("move time", move_s, "s")
    lead_s = _check_positive("lead time", lead_s, "s", allow_zero=True)
    lift_m = _check_positive("lift", lift_m, "m", allow_zero=True)
    if jitter_deg > 45.0:
        raise InputError(f"jitter must be at most 45 deg, got {jitter_deg:g}")

    n_hold = int(round(hold_s * rate_hz))
    if n_hold < 10:
        raise InputError(
            f"hold {hold_s:g} s at {rate_hz:g} Hz gives {n_hold} samples per pose; "
            "at least 10 are needed"
        )
    n_move = max(2, int(round(move_s * rate_hz)))
    n_lead = int(round(lead_s * rate_hz))
    k_poses = len(poses)
    n_total = n_lead + k_poses * n_hold + (k_poses - 1) * n_move
    if n_total > MAX_SAMPLES:
        raise InputError(
            f"the session would have {n_total} samples (more than {MAX_SAMPLES}): "
            "lower the rate, the hold or the number of poses"
        )

    truth_ss, pose_ss, noise_ss = np.random.SeedSequence(int(seed)).spawn(3)
    truth = random_imu(
        np.random.default_rng(truth_ss), units, accel_noise=accel_noise, gyro_noise=gyro_noise
    )

    # Poses: nominal up, then heading and placement tilt (pose generator, fixed order).
    rng = np.random.default_rng(pose_ss)
    nominal = [up for _, up in poses]
    if nominal[0] is None:
        nominal_up = _unit(rng.standard_normal((k_poses, 3)))
    else:
        nominal_up = np.array(nominal)
    heading = rng.uniform(0.0, 2.0 * np.pi, k_poses)
    tilt_vec = np.zeros((k_poses, 3))
    tilt_vec[:, :2] = rng.standard_normal((k_poses, 2)) * np.radians(jitter_deg) / np.sqrt(2.0)
    orient = []  # body -> world
    for k in range(k_poses):
        r = (
            Rotation.from_rotvec(tilt_vec[k])
            * Rotation.from_rotvec([0.0, 0.0, heading[k]])
            * _up_to_vertical(nominal_up[k])
        )
        orient.append(r)
    ez = np.array([0.0, 0.0, 1.0])
    true_up = np.array([r.inv().apply(ez) for r in orient])
    true_up = _unit(true_up)

    force = np.empty((n_total, 3))
    rate = np.zeros((n_total, 3))
    segments: list[StreamSegment] = []
    rotvecs = np.zeros((max(k_poses - 1, 0), 3))
    labels = [label for label, _ in poses]

    force[:n_lead] = gravity * true_up[0]
    i = n_lead
    for k in range(k_poses):
        force[i : i + n_hold] = gravity * true_up[k]
        segments.append(
            StreamSegment(
                name=f"{len(segments):04d}",
                kind="static",
                start=i,
                stop=i + n_hold,
                label=labels[k],
                up=None if nominal[k] is None else nominal_up[k].copy(),
            )
        )
        i += n_hold
        if k == k_poses - 1:
            break
        # Move k -> k+1: R(tau) = R_k * Exp(s(tau) r), body rate = s'(t) r.
        rv = (orient[k].inv() * orient[k + 1]).as_rotvec()
        rotvecs[k] = rv
        dur = (n_move + 1) / rate_hz  # the neighbouring still samples sit at tau = 0 and 1
        tau = np.arange(1, n_move + 1) / (n_move + 1)
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        ds = 30.0 * tau**2 * (1.0 - tau) ** 2 / dur
        att = orient[k] * Rotation.from_rotvec(s[:, None] * rv)
        x = np.pi * tau
        # height lift_m * sin^4(pi tau): zero velocity and acceleration at both ends
        sx, cx = np.sin(x), np.cos(x)
        lift_acc = lift_m * (np.pi / dur) ** 2 * (12.0 * sx**2 * cx**2 - 4.0 * sx**4)
        world = np.zeros((n_move, 3))
        world[:, 2] = gravity + lift_acc
        force[i : i + n_move] = att.inv().apply(world)
        rate[i : i + n_move] = ds[:, None] * rv
        segments.append(
            StreamSegment(
                name=f"{len(segments):04d}",
                kind="rotation",
                start=i,
                stop=i + n_move,
                label=f"turn to {labels[k + 1]}",
            )
        )
        i += n_move
    assert i == n_total

    # Noise in SI (noise generator: accel then gyro, standard normals scaled).
    nrng = np.random.default_rng(noise_ss)
    accel_n = nrng.standard_normal((n_total, 3)) * truth.accel_noise
    gyro_n = nrng.standard_normal((n_total, 3)) * truth.gyro_noise

    tilt_deg = np.degrees(np.linalg.norm(tilt_vec, axis=1))
    options = {
        "plan": plan.strip().lower(),
        "seed": int(seed),
        "rate_hz": rate_hz,
        "hold_s": hold_s,
        "accel_noise": accel_noise,
        "gyro_noise": gyro_noise,
        "jitter_deg": jitter_deg,
        "units": units,
        "gravity": gravity,
        "move_s": move_s,
        "lead_s": lead_s,
        "lift_m": lift_m,
    }
    return SimulatedStream(
        time=np.arange(n_total) / rate_hz,
        accel=truth.accel_raw(force, accel_n),
        gyro=truth.gyro_raw(rate, gyro_n),
        specific_force=force,
        rate=rate,
        segments=segments,
        true_up=true_up,
        labelled_up=[None if u is None else np.asarray(u, float).copy() for u in nominal],
        tilt_deg=tilt_deg,
        rotvec=rotvecs,
        truth=truth,
        options=options,
    )


# --------------------------------------------------------------------------------------------
# Session and truth objects
# --------------------------------------------------------------------------------------------


def _misalignment_deg(S: np.ndarray) -> dict[str, float]:
    """Angles between the sensitivity axes (rows of S) minus 90 degrees."""
    n = _unit(S)
    out = {}
    for (i, j), key in zip(((0, 1), (0, 2), (1, 2)), ("xy", "xz", "yz"), strict=True):
        out[key] = float(np.degrees(np.arccos(np.clip(n[i] @ n[j], -1.0, 1.0))) - 90.0)
    return out


def _floats(a) -> list:
    return np.asarray(a, dtype=float).tolist()


def sensor_name(seed: int) -> str:
    """The ``sensor`` attribute of a simulated session: ``"sim-16bit seed 1"``."""
    return f"sim-16bit seed {int(seed)}"


def truth_calibration(stream: SimulatedStream, created: str | None = None) -> Calibration:
    """The truth of a simulated stream as a :class:`~imucal_cli.formats.calibration.Calibration`.

    ``matrix = inv(S)`` and ``bias = b`` in raw units, so ``matrix @ (raw - bias)`` gives the
    specific force (m/s^2) and angular rate (rad/s) in the fixture frame, up to noise and
    quantisation.  Extras record the generation: noise, seed, plan, jitter, the true up of
    each static pose (``accel.extra["true_up"]``, in segment order) and the true rotation of
    each move (``gyro.extra["true_rotvec"]``, rad).
    """
    t, opt = stream.truth, stream.options
    static = [s for s in stream.segments if s.kind == "static"]
    moves = [s for s in stream.segments if s.kind == "rotation"]
    common = {"model": "calibrated = matrix @ (raw - bias)", "quantised": bool(t.quantise)}
    accel_extra = {
        **common,
        "units_in": t.accel_units,
        "noise": float(opt["accel_noise"]),
        "noise_unit": "m/s^2 per axis per sample (white, input-referred)",
        "gravity": float(opt["gravity"]),
        "sensitivity": _floats(np.linalg.norm(t.accel_S, axis=1)),
        "sensitivity_unit": f"{t.accel_units} per m/s^2",
        "nominal_sensitivity": float(t.accel_nominal),
        "scale_error": _floats(t.accel_scale_error),
        "misalignment_deg": _misalignment_deg(t.accel_S),
        "mount_rotvec_deg": _floats(np.degrees(t.mount_rotvec)),
        "bias_mg": _floats(1000.0 * t.accel_bias_g),
        "S": _floats(t.accel_S),
        "jitter_deg": float(opt["jitter_deg"]),
        "segments": [s.name for s in static],
        "labels": [s.label for s in static],
        "true_up": _floats(stream.true_up),
        "labelled_up": [None if u is None else _floats(u) for u in stream.labelled_up],
        "tilt_deg": _floats(stream.tilt_deg),
    }
    gyro_extra = {
        **common,
        "units_in": t.gyro_units,
        "noise": float(opt["gyro_noise"]),
        "noise_unit": "rad/s per axis per sample (white, input-referred)",
        "sensitivity": _floats(np.linalg.norm(t.gyro_S, axis=1)),
        "sensitivity_unit": f"{t.gyro_units} per rad/s",
        "nominal_sensitivity": float(t.gyro_nominal),
        "scale_error": _floats(t.gyro_scale_error),
        "misalignment_deg": _misalignment_deg(t.gyro_S),
        "bias_dps": _floats(t.gyro_bias_dps),
        "S": _floats(t.gyro_S),
        "segments": [s.name for s in moves],
        "true_rotvec": _floats(stream.rotvec),
        "true_rotvec_unit": "rad, body (fixture) frame",
    }
    accel, gyro = truth_sections(t, accel_extra, gyro_extra)
    root_extra = {
        "sensor": sensor_name(opt["seed"]),
        "seed": int(opt["seed"]),
        "plan": opt["plan"],
        "jitter_deg": float(opt["jitter_deg"]),
        "simulator": dict(opt),
    }
    kwargs = {} if created is None else {"created": created}
    return Calibration(accel=accel, gyro=gyro, extra=root_extra, **kwargs)


def simulate(
    plan: str = "qureshi18",
    seed: int = 0,
    rate_hz: float = 100.0,
    hold_s: float = 2.0,
    accel_noise: float = 0.01,
    jitter_deg: float = 2.0,
    units: str = "counts",
    gravity: float = G0,
    gyro_noise: float = 0.005,
    move_s: float = 1.5,
    lead_s: float = 1.0,
    lift_m: float = 0.03,
    created: str | None = None,
) -> tuple[Session, Calibration]:
    """Simulate a calibration session and return it with its truth.

    Parameters are those of :func:`simulate_stream`; ``created`` (ISO 8601 UTC) defaults to
    now.  The raw arrays are identical bit for bit for the same seed and options.

    Returns
    -------
    session : imucal_cli.formats.session.Session
        ``source="simulator"``, ``sensor="sim-16bit seed <seed>"``, raw accel and gyro (N, 3)
        in ``accel_units``/``gyro_units``; segments ``0000``, ``0001``, ... alternating static
        holds (label and, except for ``random:N``, ``up``) and rotation segments (label only).
    truth : imucal_cli.formats.calibration.Calibration
        See :func:`truth_calibration`.
    """
    stream = simulate_stream(
        plan=plan,
        seed=seed,
        rate_hz=rate_hz,
        hold_s=hold_s,
        accel_noise=accel_noise,
        jitter_deg=jitter_deg,
        units=units,
        gravity=gravity,
        gyro_noise=gyro_noise,
        move_s=move_s,
        lead_s=lead_s,
        lift_m=lift_m,
    )
    created = created or utc_now_iso()
    segments = [
        Segment(name=s.name, kind=s.kind, start=s.start, stop=s.stop, label=s.label, up=s.up)
        for s in stream.segments
    ]
    session = Session(
        time=stream.time,
        accel=stream.accel,
        gyro=stream.gyro,
        temperature=None,
        segments=segments,
        created=created,
        sensor=sensor_name(seed),
        source="simulator",
        sample_rate_hz=float(stream.options["rate_hz"]),
        gravity=float(stream.options["gravity"]),
        accel_units=stream.truth.accel_units,
        gyro_units=stream.truth.gyro_units,
    )
    return session, truth_calibration(stream, created)


def session_from_motion(
    truth: ImuTruth,
    specific_force: np.ndarray,
    rate: np.ndarray,
    segments: list,
    *,
    noise_seed: np.random.SeedSequence,
    rate_hz: float,
    gravity: float,
    sensor: str,
    created: str | None = None,
):
    """A session of the simulated unit performing a motion: the true specific force and rate
    (fixture frame, (N, 3), m/s^2 and rad/s) through the sensor model with its noise (one
    generator from ``noise_seed``: accelerometer noise first, then gyroscope)."""
    from imucal_cli.formats.session import Session, utc_now_iso

    n = len(specific_force)
    nrng = np.random.default_rng(noise_seed)
    accel_n = nrng.standard_normal((n, 3)) * truth.accel_noise
    gyro_n = nrng.standard_normal((n, 3)) * truth.gyro_noise
    return Session(
        time=np.arange(n) / rate_hz,
        accel=truth.accel_raw(specific_force, accel_n),
        gyro=truth.gyro_raw(rate, gyro_n),
        temperature=None,
        segments=segments,
        created=created or utc_now_iso(),
        sensor=sensor,
        source="simulator",
        sample_rate_hz=rate_hz,
        gravity=gravity,
        accel_units=truth.accel_units,
        gyro_units=truth.gyro_units,
    )


def truth_sections(truth: ImuTruth, accel_extra: dict, gyro_extra: dict):
    """The accel and gyro sections of a truth calibration: ``matrix = inv(S)``, ``bias = b``,
    so that ``matrix @ (raw - bias)`` gives the fixture-frame specific force and rate."""

    accel = SensorCalibration(
        solver="truth",
        units="m/s^2",
        bias=np.array(truth.accel_b, dtype=float),
        matrix=np.linalg.inv(truth.accel_S),
        extra=accel_extra,
    )
    gyro = SensorCalibration(
        solver="truth",
        units="rad/s",
        bias=np.array(truth.gyro_b, dtype=float),
        matrix=np.linalg.inv(truth.gyro_S),
        extra=gyro_extra,
    )
    return accel, gyro
