"""The Hwangbo & Kanade designs: the redundant accelerometer unit and the gyroscope procedure.

Two virtual experiments from Hwangbo & Kanade, "Factorization-based calibration method for
MEMS inertial measurement unit":

* :func:`simulate_redundant_accel` -- section V, Fig. 4, Table I: two dual-axis accelerometers
  (ADXL-203 like, n = 4 channels), the second turned 45 degrees, read by an ADC of 0..2047
  spanning -2.5 g..2.5 g, held still in 20 orientations for 10 samples each.
* :func:`simulate_hk_gyro` -- section IV-B, Fig. 3 (f)-(j), Fig. 5: a gyroscope triad in a
  right-angle iron, swept sinusoidally by hand about the normals of three orthogonal faces,
  in two mountings of the IMU in the iron, then turned 90 degrees along a ruler.

Both return ``(Session, Calibration)`` like :func:`imucal_cli.simulate.triad.simulate`: the session
as a recorder would have written it and the truth in the toolkit's model
``calibrated = matrix @ (raw - bias)``.  Randomness follows the simulator: three generators
spawned from ``numpy.random.SeedSequence(seed)`` for the truth, the poses and the noise, so a
seed reproduces a session bit for bit.

Segments of the gyroscope session carry the IMU mounting as the extra segment attribute
``mounting`` (an integer, 1 = the unit square in the iron) and in their label (``"mounting 2:
sweep about +Y"``); the truth repeats the mapping (``gyro.extra["segment_mounting"]``).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration, SensorCalibration
from imucal_cli.formats.session import Segment, Session, utc_now_iso
from imucal_cli.plans import plan_poses
from imucal_cli.simulate.triad import (
    G0,
    MAX_SAMPLES,
    _check_positive,
    _floats,
    _misalignment_deg,
    _unit,
    _up_to_vertical,
    random_imu,
    session_from_motion,
    truth_sections,
)

__all__ = [
    "ADC_MAX",
    "ADC_VOLTS",
    "COUNTS_PER_VOLT",
    "HK_PLANS",
    "NOMINAL_AXES",
    "QUANTISATION_COUNTS",
    "pairwise_angles_deg",
    "simulate_hk_gyro",
    "simulate_hk_plan",
    "simulate_redundant_accel",
]

HK_PLANS = ("hk-redundant", "hk-gyro")
"""Plan names of ``imucal simulate`` served by this module."""

ADC_MAX = 2047
"""Largest ADC code; codes run 0..2047 (paper, section V)."""

ADC_VOLTS = 5.0
"""The ADC input range is 0..5 V: with 1 V/g and a 2.5 V zero-g output, -2.5 g..2.5 g."""

COUNTS_PER_VOLT = ADC_MAX / ADC_VOLTS
"""409.4 counts per volt: the paper says the codes 0..2047 *correspond to* -2.5 g..2.5 g, i.e.
0 V -> code 0 and 5 V -> code 2047 end to end.  (The usual ADC convention, 2048 codes per 5 V =
409.6 counts/V, would put +2.5 g at code 2048, outside the stated range.)  The zero-g output of
2.5 V is then code 1023.5, exactly mid-range."""

QUANTISATION_COUNTS = 1.0 / np.sqrt(12.0)
"""Standard deviation of the rounding error, counts (uniform on +-0.5)."""

NOMINAL_AXES = np.array(
    [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0 / np.sqrt(2.0), 0.0, 1.0 / np.sqrt(2.0)],
    ]
).T
"""Sensitivity axes of the redundant unit as columns (3, 4): part 1 gives s1 = x and s2 = y;
part 2, turned 45 degrees, gives s3 = z and s4 = (x + z) / sqrt(2).  Pairwise angles (Table I):
s1s2 = 90, s1s3 = 90, s1s4 = 45, s2s3 = 90, s2s4 = 90, s3s4 = 45 degrees."""

NOMINAL_GAIN_V_PER_G = 1.0
NOMINAL_BIAS_V = 2.5

# Spread of the manufacturing errors drawn with perturb=True (uniform draws).
PERTURB_GAIN_MAX = 0.02  # |relative gain error| <= 2 %
PERTURB_BIAS_MAX_V = 0.05  # |zero-g offset error| <= 50 mV (50 mg)
PERTURB_TILT_MAX_DEG = 1.0  # each sensitivity axis leans <= 1 deg

MAX_ORIENTATIONS = 10000
BLOCK_POSES = 18  # 6 faces + 12 edges of the right-angle iron


def _check_int(name: str, value, low: int, high: int) -> int:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | np.integer)
        or not low <= value <= high
    ):
        raise InputError(f"{name} must be an integer from {low} to {high}, got {value!r}")
    return int(value)


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def pairwise_angles_deg(S: np.ndarray) -> dict[str, float]:
    """Angles between the sensitivity axes (columns of ``S``), in Table I's order.

    Parameters
    ----------
    S : ndarray, shape (3, n)
        Sensitivity axes as columns (any gains).

    Returns
    -------
    dict of str to float
        ``{"s1s2": ..., "s1s3": ..., ...}``: every pair i < j, degrees.
    """
    u = _unit(np.asarray(S, dtype=float).T)
    out = {}
    for i, j in itertools.combinations(range(u.shape[0]), 2):
        c = float(np.clip(u[i] @ u[j], -1.0, 1.0))
        out[f"s{i + 1}s{j + 1}"] = float(np.degrees(np.arccos(c)))
    return out


def _lean(rng: np.random.Generator, axes: np.ndarray, max_deg: float) -> np.ndarray:
    """Tilt each column of ``axes`` by up to ``max_deg`` towards a random perpendicular."""
    out = np.empty_like(axes)
    for j in range(axes.shape[1]):
        u = axes[:, j]
        p = _unit(np.cross(u, rng.standard_normal(3)))
        tilt = np.radians(rng.uniform(0.0, max_deg))
        out[:, j] = np.cos(tilt) * u + np.sin(tilt) * p
    return out


# --------------------------------------------------------------------------------------------
# Section V: the redundant accelerometer unit
# --------------------------------------------------------------------------------------------


def simulate_redundant_accel(
    seed: int = 0,
    sigma_counts: float = 0.7,
    orientations: int | None = None,
    samples: int = 10,
    rate_hz: float = 50.0,
    labelled: bool = False,
    gravity: float = G0,
    created: str | None = None,
    perturb: bool = False,
    gap_s: float = 2.0,
) -> tuple[Session, Calibration]:
    """Simulate the redundant accelerometer unit of Hwangbo & Kanade, section V (Table I).

    Sensor model, channel j = 1..4, ``f`` the specific force in g (standard gravity, so a still
    unit reads ``gravity / 9.80665`` g along its up direction)::

        volts_j  = bias_V[j] + gain_V_per_g[j] * (s_j . f)
        counts_j = clip(round(COUNTS_PER_VOLT * volts_j + sigma_counts * n), 0, 2047)

    with ``n`` standard normal per sample and channel and ``COUNTS_PER_VOLT`` = 2047 / 5 =
    409.4 (see :data:`COUNTS_PER_VOLT`).  Nominal part (the paper's ground truth): gains
    1 V/g, biases 2.5 V (code 1023.5), axes :data:`NOMINAL_AXES`.  The noise is ``sigma_counts``
    before rounding; the rounding adds about 1/sqrt(12) = 0.29 counts (both are recorded).

    The unit is held still in each orientation for ``samples`` readings; the recorder pauses
    ``gap_s`` while it is turned to the next one, so ``/raw/time`` jumps between holds.

    Parameters
    ----------
    seed : int
        Non-negative seed; the same seed and options give the same counts bit for bit.
    sigma_counts : float
        Gaussian noise per sample per channel, counts, before quantisation (paper: 0.7, 1.5).
    orientations : int, optional
        Number of orientations.  Default 20 (the paper's) random directions uniform on the
        sphere; with ``labelled`` the first N (default 18, at most 18) poses of the iron.
    samples : int
        Readings per orientation (paper: 10).
    rate_hz : float
        Sample rate, Hz (paper: 50).
    labelled : bool
        Place the block on its 6 faces and 12 edges (``plan_poses("qureshi18")``) and write each
        static segment's ``up`` (exact: the iron is square to 0.002 in per 6 in), instead of
        unlabelled random directions.
    gravity : float
        Local gravity, m/s^2.
    created : str, optional
        ISO 8601 UTC creation time; default now.
    perturb : bool
        Draw a non-nominal part: gains within +-2 %, biases within +-50 mV, each axis leaning
        up to 1 degree.  The default is the nominal part of Table I.
    gap_s : float
        Time between the last sample of a hold and the first of the next, s (>= 0).

    Returns
    -------
    session : imucal_cli.formats.session.Session
        ``accel_units="counts"``, ``/raw/accel`` (N, 4), no gyro; one static segment per
        orientation labelled ``"orientation 7"`` (1-based), or the pose name (``"face +Z up"``)
        with ``up`` when ``labelled``.
    truth : imucal_cli.formats.calibration.Calibration
        Accel section only: ``matrix`` (3, 4) = 9.80665 * pinv(S^T) with ``S`` (3, 4) the
        sensitivity axes in counts per g as columns, ``bias`` (4,) counts; so ``matrix @ (raw
        - bias)`` is the specific force in m/s^2.  Extras: ``S_counts_per_g``,
        ``gains_V_per_g``, ``bias_V``, ``angles_deg`` (Table I order), ``noise_counts``,
        ``quantisation_counts``, ``noise_total_counts``, ``counts_per_volt``, ``true_up``
        (one unit vector per orientation, in segment order), ``segments``, ``labels``.

    Raises
    ------
    InputError
        A bad value, or more than 18 labelled orientations.
    """
    seed = _check_seed(seed)
    sigma_counts = _check_positive("sigma", sigma_counts, "counts", allow_zero=True)
    rate_hz = _check_positive("rate", rate_hz, "Hz")
    gravity = _check_positive("gravity", gravity, "m/s^2")
    gap_s = _check_positive("gap", gap_s, "s", allow_zero=True)
    samples = _check_int("samples per orientation", samples, 1, MAX_SAMPLES)
    if labelled:
        if orientations is None:
            orientations = BLOCK_POSES
        if isinstance(orientations, int | np.integer) and orientations > BLOCK_POSES:
            raise InputError(
                f"{orientations} labelled orientations asked, but the block has "
                f"{BLOCK_POSES} poses (6 faces, 12 edges): use at most {BLOCK_POSES}, or "
                "random orientations"
            )
    elif orientations is None:
        orientations = 20
    k_poses = _check_int("orientations", orientations, 1, MAX_ORIENTATIONS)
    n_total = k_poses * samples
    if n_total > MAX_SAMPLES:
        raise InputError(f"{n_total} samples (more than {MAX_SAMPLES}): fewer samples please")

    truth_ss, pose_ss, noise_ss = np.random.SeedSequence(seed).spawn(3)

    # Truth (truth generator; no draws for the nominal part).
    axes = NOMINAL_AXES.copy()
    gains = np.full(4, NOMINAL_GAIN_V_PER_G)
    bias_v = np.full(4, NOMINAL_BIAS_V)
    if perturb:
        trng = np.random.default_rng(truth_ss)
        gains = gains * (1.0 + trng.uniform(-PERTURB_GAIN_MAX, PERTURB_GAIN_MAX, 4))
        bias_v = bias_v + trng.uniform(-PERTURB_BIAS_MAX_V, PERTURB_BIAS_MAX_V, 4)
        axes = _lean(trng, axes, PERTURB_TILT_MAX_DEG)
    S = COUNTS_PER_VOLT * axes * gains  # (3, 4) counts per g, columns s_j
    bias_counts = COUNTS_PER_VOLT * bias_v

    # Orientations (pose generator).
    if labelled:
        poses = plan_poses("qureshi18")[:k_poses]
        labels = [label for label, _ in poses]
        up = np.array([u for _, u in poses], dtype=float)
    else:
        prng = np.random.default_rng(pose_ss)
        up = _unit(prng.standard_normal((k_poses, 3)))
        labels = [f"orientation {k + 1}" for k in range(k_poses)]

    # Samples (noise generator).
    f_g = np.repeat(up * (gravity / G0), samples, axis=0)  # (N, 3) in g
    nrng = np.random.default_rng(noise_ss)
    noise = nrng.standard_normal((n_total, 4)) * sigma_counts
    raw = np.clip(np.rint(f_g @ S + bias_counts + noise), 0.0, float(ADC_MAX))

    hold_s = samples / rate_hz
    time = (
        np.arange(k_poses)[:, None] * (hold_s + gap_s) + np.arange(samples)[None, :] / rate_hz
    ).ravel()
    segments = [
        Segment(
            name=f"{k:04d}",
            kind="static",
            start=k * samples,
            stop=(k + 1) * samples,
            label=labels[k],
            up=up[k] if labelled else None,
        )
        for k in range(k_poses)
    ]
    created = created or utc_now_iso()
    sensor = f"sim-hk-redundant (2 x dual-axis, 45 deg) seed {seed}"
    session = Session(
        time=time,
        accel=raw,
        gyro=None,
        temperature=None,
        segments=segments,
        created=created,
        sensor=sensor,
        source="simulator",
        sample_rate_hz=rate_hz,
        gravity=gravity,
        accel_units="counts",
        gyro_units=None,
    )

    options = {
        "plan": "hk-redundant",
        "seed": seed,
        "sigma_counts": sigma_counts,
        "orientations": k_poses,
        "samples": samples,
        "rate_hz": rate_hz,
        "labelled": bool(labelled),
        "gravity": gravity,
        "perturb": bool(perturb),
        "gap_s": gap_s,
    }
    extra = {
        "model": "calibrated = matrix @ (raw - bias)",
        "design": "Hwangbo & Kanade section V: two dual-axis accelerometers, n = 4, 45 deg",
        "units_in": "counts",
        "quantised": True,
        "gravity": gravity,
        "g_unit": "standard gravity 9.80665 m/s^2 (of V/g and counts per g)",
        "S_counts_per_g": _floats(S),
        "S_layout": "3 x 4, column j = gain_j * counts_per_volt * unit sensitivity axis s_j",
        "gains_V_per_g": _floats(gains),
        "bias_V": _floats(bias_v),
        "angles_deg": pairwise_angles_deg(S),
        "counts_per_volt": COUNTS_PER_VOLT,
        "adc_range_counts": [0, ADC_MAX],
        "adc_range_V": [0.0, ADC_VOLTS],
        "noise_counts": sigma_counts,
        "quantisation_counts": float(QUANTISATION_COUNTS),
        "noise_total_counts": float(np.hypot(sigma_counts, QUANTISATION_COUNTS)),
        "noise_unit": "counts per channel per sample (Gaussian before rounding; rounding adds "
        "about 1/sqrt(12))",
        "perturbed": bool(perturb),
        "segments": [s.name for s in segments],
        "labels": labels,
        "true_up": _floats(up),
    }
    accel = SensorCalibration(
        solver="truth",
        units="m/s^2",
        bias=bias_counts,
        matrix=G0 * np.linalg.pinv(S.T),
        extra=extra,
    )
    root = {"sensor": sensor, "seed": seed, "plan": "hk-redundant", "simulator": options}
    return session, Calibration(accel=accel, gyro=None, extra=root, created=created)


# --------------------------------------------------------------------------------------------
# Section IV-B: the gyroscope procedure
# --------------------------------------------------------------------------------------------

_FACES = ((2, "+Z"), (0, "+X"), (1, "+Y"))  # swept face normals, in the order visited
_CUBE_GROUP = Rotation.create_group("O")  # the 24 rotations taking the iron onto itself


def _orbit_distance_deg(a: Rotation, b: Rotation) -> np.ndarray:
    """Smallest angle between ``b`` and ``a * G`` over the iron's 24 symmetries ``G``, degrees.

    ``b`` may hold several rotations (one distance each).  Two mountings whose distance is near
    0 put the swept face normals onto the same sensor axes (up to sign and order), so they add
    no new constraints.
    """
    rel = np.atleast_3d((a.inv() * b).as_matrix()).reshape(-1, 3, 3)  # a^T b
    group = _CUBE_GROUP.as_matrix()  # (24, 3, 3)
    # angle of G^T rel: cos = (trace(G^T rel) - 1) / 2, trace(G^T R) = sum(G * R)
    cos = (np.einsum("gij,kij->kg", group, rel) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos.max(axis=1), -1.0, 1.0)))


def _draw_mountings(rng: np.random.Generator, count: int) -> list[Rotation]:
    """Mounting 1 = identity; each further mounting the best of 256 uniform random rotations.

    "Best" maximises the distance (:func:`_orbit_distance_deg`) to every earlier mounting, so
    the swept axes of each mounting point in new directions of the sensor frame.
    """
    out = [Rotation.identity()]
    for _ in range(count - 1):
        cands = Rotation.random(256, random_state=rng)
        scores = np.min([_orbit_distance_deg(m, cands) for m in out], axis=0)
        out.append(cands[int(np.argmax(scores))])
    return out


def _smootherstep(n: int, dur: float) -> tuple[np.ndarray, np.ndarray]:
    """Profile ``s`` and rate ``ds/dt`` at ``n`` interior samples of a move lasting ``dur``."""
    tau = np.arange(1, n + 1) / (n + 1)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2 / dur
    return s, ds


def simulate_hk_gyro(
    seed: int = 0,
    mountings: int = 2,
    rate_hz: float = 100.0,
    sweep_s: float = 6.0,
    peak_rate: float = 2.0,
    still_s: float = 3.0,
    noise: float = 0.005,
    units: str = "counts",
    ruler_angle_deg: float = 90.0,
    created: str | None = None,
    periods: int = 3,
    accel_noise: float = 0.01,
    move_s: float = 1.5,
    turn_s: float = 2.0,
    gravity: float = G0,
) -> tuple[Session, Calibration]:
    """Simulate the gyroscope procedure of Hwangbo & Kanade, section IV-B (Fig. 3 f-j, Fig. 5).

    The part is :func:`imucal_cli.simulate.triad.random_imu` (16.4 LSB per deg/s gyroscope with
    1-3 % scale errors, axes off by up to 1 degree, bias up to 3 deg/s; plus its
    accelerometer), fixed in a right-angle iron.  Frames: the *iron* frame (the fixture frame
    of the session's ``axis``/``up``) and the *sensor* frame, the IMU housing.  Mounting ``m``
    is the rotation ``M_m`` (sensor -> iron); mounting 1 is the identity, so there the two
    frames agree; mounting 2, 3, ... are random rotations drawn from the seed, far from the
    iron's symmetries and from each other.

    Timeline (every event separated by ``still_s`` of stillness, each a static segment):

    1. still, +Z up, mounting 1 (the biases);
    2. for each mounting: for the face normals +Z, +X, +Y in turn, the iron is put on the
       opposite face (a smootherstep move of ``move_s``, unsegmented) and swept by hand about
       the vertical normal: rate ``normal * peak_rate * sin(2 pi t / (sweep_s / periods))``
       for ``sweep_s`` (``periods`` whole periods, so it ends where it started); the IMU is
       re-mounted between mountings (an unsegmented move);
    3. back in mounting 1, +Z up, one ruler-guided turn of ``ruler_angle_deg`` about +Z with a
       smootherstep profile of ``turn_s``.

    The attitude is integrated exactly (fixed-axis motions), so the accelerometer sees gravity
    turn consistently; moves add no linear acceleration.  The earth rate is left out.

    Parameters
    ----------
    seed : int
        Non-negative seed; the same seed and options give the same samples bit for bit.
    mountings : int
        Number of IMU mountings in the iron (1..8; the paper used 2).
    rate_hz : float
        Sample rate, Hz.
    sweep_s : float
        Duration of each sinusoidal sweep, s.
    peak_rate : float
        Peak angular rate of a sweep, rad/s (the swing is +-peak_rate * period / pi rad).
    still_s : float
        Duration of each still period, s (at least 10 samples).
    noise : float
        Gyroscope white noise per axis per sample, rad/s (input-referred).
    units : {"counts", "m/s^2"}
        Raw units of the part (``"rad/s"`` is accepted for ``"m/s^2"``): 16-bit counts, or a
        part of nominal gain 1 reading m/s^2 and rad/s.
    ruler_angle_deg : float
        Signed angle of the ruler-guided turn, degrees (right hand about +Z).
    created : str, optional
        ISO 8601 UTC creation time; default now.
    periods : int
        Whole sine periods per sweep.
    accel_noise : float
        Accelerometer white noise per axis per sample, m/s^2.
    move_s : float
        Duration of each unsegmented move (turning the iron to a face, re-mounting), s.
    turn_s : float
        Duration of the ruler-guided turn, s.
    gravity : float
        Local gravity, m/s^2.

    Returns
    -------
    session : imucal_cli.formats.session.Session
        Raw accel and gyro (N, 3).  Static segments for the still periods, labelled
        ``"mounting 1: still, +Z up"``, with ``up`` (iron frame) in mounting 1 only (in other
        mountings the sensor is not aligned with the iron).  Rotation segments for the sweeps,
        labelled ``"mounting 2: sweep about +Y"``, with ``axis`` = the face normal in the iron
        frame; the ruler turn labelled ``"mounting 1: ruler-guided 90-degree turn about +Z"``
        with ``axis`` and ``angle_deg``.  Orthogonality holds only between sweeps of one
        mounting: every segment has the attribute ``mounting`` (int).
    truth : imucal_cli.formats.calibration.Calibration
        ``gyro``: ``matrix = inv(S_g)``, ``bias = b_g`` with ``S_g`` the sensitivity in the
        sensor frame (= the iron frame of mounting 1).  Extras: ``mounting_rotvec_deg`` (one
        rotation vector per mounting, sensor -> iron, degrees), ``segment_mounting``
        (segment name -> mounting, every segment), ``sweep_axes_sensor`` (sweep segment name
        -> unit axis in the sensor frame), ``ruler`` (segment, axes, angle), ``noise``.
        ``accel``: the accelerometer's truth in the same sensor frame.

    Raises
    ------
    InputError
        A bad value.
    """
    seed = _check_seed(seed)
    if units == "rad/s":
        units = "m/s^2"
    mountings = _check_int("mountings", mountings, 1, 8)
    periods = _check_int("periods per sweep", periods, 1, 1000)
    rate_hz = _check_positive("rate", rate_hz, "Hz")
    sweep_s = _check_positive("sweep time", sweep_s, "s")
    peak_rate = _check_positive("peak rate", peak_rate, "rad/s")
    still_s = _check_positive("still time", still_s, "s")
    noise = _check_positive("gyro noise", noise, "rad/s", allow_zero=True)
    accel_noise = _check_positive("accel noise", accel_noise, "m/s^2", allow_zero=True)
    move_s = _check_positive("move time", move_s, "s")
    turn_s = _check_positive("turn time", turn_s, "s")
    gravity = _check_positive("gravity", gravity, "m/s^2")
    ruler_angle_deg = float(ruler_angle_deg)
    if not np.isfinite(ruler_angle_deg) or ruler_angle_deg == 0.0 or abs(ruler_angle_deg) > 180:
        raise InputError(f"ruler angle must be non-zero, within +-180 deg, got {ruler_angle_deg}")
    n_still = int(round(still_s * rate_hz))
    if n_still < 10:
        raise InputError(f"still {still_s:g} s at {rate_hz:g} Hz gives {n_still} samples: >= 10")
    n_sweep = int(round(sweep_s * rate_hz)) - 1  # interior samples: rate 0 at both ends
    n_move = max(2, int(round(move_s * rate_hz)))
    n_turn = max(2, int(round(turn_s * rate_hz)))
    if n_sweep < 4 * periods:
        raise InputError(
            f"sweep {sweep_s:g} s at {rate_hz:g} Hz is too short for {periods} periods"
        )
    n_total = (
        n_still * (6 * mountings + 2) + n_sweep * 3 * mountings + n_move * (3 * mountings) + n_turn
    )
    if n_total > MAX_SAMPLES:
        raise InputError(f"the session would have {n_total} samples (more than {MAX_SAMPLES})")

    truth_ss, pose_ss, noise_ss = np.random.SeedSequence(seed).spawn(3)
    truth = random_imu(
        np.random.default_rng(truth_ss), units, accel_noise=accel_noise, gyro_noise=noise
    )
    prng = np.random.default_rng(pose_ss)
    mounts = _draw_mountings(prng, mountings)

    eye = np.eye(3)
    ez = eye[2]
    rate = np.zeros((n_total, 3))  # body (sensor) frame, rad/s
    force = np.empty((n_total, 3))  # body frame, m/s^2
    segments: list[Segment] = []
    seg_mount: dict[str, int] = {}
    sweep_axes: dict[str, list[float]] = {}
    state = {"i": 0, "att": None}  # att: body -> world of the current sample

    def iron_pose(face: int) -> Rotation:
        heading = Rotation.from_rotvec([0.0, 0.0, prng.uniform(0.0, 2.0 * np.pi)])
        return heading * _up_to_vertical(eye[face])

    def add_segment(kind, n, label, m, **attrs) -> str:
        name = f"{len(segments):04d}"
        i = state["i"]
        segments.append(
            Segment(
                name=name,
                kind=kind,
                start=i,
                stop=i + n,
                label=label,
                extra={"mounting": m},
                **attrs,
            )
        )
        seg_mount[name] = m
        return name

    def still(label: str, m: int, up: np.ndarray | None) -> None:
        i = state["i"]
        add_segment("static", n_still, label, m, up=up)
        force[i : i + n_still] = state["att"].inv().apply(gravity * ez)
        state["i"] = i + n_still

    def move_to(target: Rotation) -> None:
        """Unsegmented smootherstep move of the body attitude to ``target``."""
        i, att = state["i"], state["att"]
        rv = (att.inv() * target).as_rotvec()
        s, ds = _smootherstep(n_move, (n_move + 1) / rate_hz)
        path = att * Rotation.from_rotvec(s[:, None] * rv)
        force[i : i + n_move] = path.inv().apply(gravity * ez)
        rate[i : i + n_move] = ds[:, None] * rv
        state["i"], state["att"] = i + n_move, target

    def turn(axis_body: np.ndarray, theta: np.ndarray, dtheta: np.ndarray) -> None:
        """Fixed-axis motion: attitude ``att * Exp(theta axis)``, body rate ``dtheta axis``."""
        i, n = state["i"], len(theta)
        path = state["att"] * Rotation.from_rotvec(theta[:, None] * axis_body)
        force[i : i + n] = path.inv().apply(gravity * ez)
        rate[i : i + n] = dtheta[:, None] * axis_body
        state["i"] = i + n

    # 1. initial still, mounting 1, +Z up.
    state["att"] = iron_pose(2) * mounts[0]
    still("mounting 1: still, +Z up (biases)", 1, ez)

    # 2. sweeps about three orthogonal face normals, per mounting.
    omega = 2.0 * np.pi * periods / sweep_s
    t_sweep = np.arange(1, n_sweep + 1) / rate_hz
    theta = peak_rate / omega * (1.0 - np.cos(omega * t_sweep))
    dtheta = peak_rate * np.sin(omega * t_sweep)
    for m, mount in enumerate(mounts, start=1):
        mount_m = mount.as_matrix()
        for k, (face, name) in enumerate(_FACES):
            up = eye[face] if m == 1 else None  # in mounting 1 the sensor is aligned with the iron
            if m > 1 or k > 0:
                move_to(iron_pose(face) * mount)
                still(f"mounting {m}: still, {name} up", m, up)
            axis_sensor = mount_m.T @ eye[face]
            seg = add_segment(
                "rotation", n_sweep, f"mounting {m}: sweep about {name}", m, axis=eye[face]
            )
            sweep_axes[seg] = _floats(axis_sensor)
            turn(axis_sensor, theta, dtheta)
            still(f"mounting {m}: still after the sweep about {name}", m, up)

    # 3. ruler-guided turn in mounting 1, +Z up.
    move_to(iron_pose(2) * mounts[0])
    still("mounting 1: still, +Z up, iron against the ruler", 1, ez)
    angle = np.radians(ruler_angle_deg)
    s, ds = _smootherstep(n_turn, (n_turn + 1) / rate_hz)
    ruler_label = f"mounting 1: ruler-guided {ruler_angle_deg:g}-degree turn about +Z"
    ruler_seg = add_segment("rotation", n_turn, ruler_label, 1, axis=ez, angle_deg=ruler_angle_deg)
    turn(ez, angle * s, angle * ds)
    state["att"] = state["att"] * Rotation.from_rotvec(angle * ez)
    still("mounting 1: still, +Z up, after the ruler turn", 1, ez)
    assert state["i"] == n_total, (state["i"], n_total)

    created = created or utc_now_iso()
    sensor = f"sim-16bit seed {seed} (hk-gyro)"
    session = session_from_motion(
        truth,
        force,
        rate,
        segments,
        noise_seed=noise_ss,
        rate_hz=rate_hz,
        gravity=gravity,
        sensor=sensor,
        created=created,
    )

    options = {
        "plan": "hk-gyro",
        "seed": seed,
        "mountings": mountings,
        "rate_hz": rate_hz,
        "sweep_s": sweep_s,
        "peak_rate": peak_rate,
        "still_s": still_s,
        "noise": noise,
        "units": units,
        "ruler_angle_deg": ruler_angle_deg,
        "periods": periods,
        "accel_noise": accel_noise,
        "move_s": move_s,
        "turn_s": turn_s,
        "gravity": gravity,
    }
    common = {"model": "calibrated = matrix @ (raw - bias)", "quantised": bool(truth.quantise)}
    frame = "sensor frame (= the iron frame in mounting 1)"
    gyro_extra = {
        **common,
        "design": "Hwangbo & Kanade section IV-B: sweeps about 3 orthogonal iron faces per "
        "mounting, one ruler-guided turn",
        "units_in": truth.gyro_units,
        "frame": frame,
        "noise": noise,
        "noise_unit": "rad/s per axis per sample (white, input-referred)",
        "sensitivity": _floats(np.linalg.norm(truth.gyro_S, axis=1)),
        "sensitivity_unit": f"{truth.gyro_units} per rad/s",
        "nominal_sensitivity": float(truth.gyro_nominal),
        "scale_error": _floats(truth.gyro_scale_error),
        "misalignment_deg": _misalignment_deg(truth.gyro_S),
        "bias_dps": _floats(truth.gyro_bias_dps),
        "S": _floats(truth.gyro_S),
        "mounting_rotvec_deg": [_floats(np.degrees(r.as_rotvec())) for r in mounts],
        "mounting_rotvec_note": "rotation vector of each mounting, sensor -> iron frame",
        "segment_mounting": seg_mount,
        "sweep_axes_sensor": sweep_axes,
        "peak_rate": peak_rate,
        "sweep_period_s": sweep_s / periods,
        "ruler": {
            "segment": ruler_seg,
            "axis_iron": [0.0, 0.0, 1.0],
            "axis_sensor": [0.0, 0.0, 1.0],
            "angle_deg": ruler_angle_deg,
        },
    }
    accel_extra = {
        **common,
        "units_in": truth.accel_units,
        "frame": frame,
        "noise": accel_noise,
        "noise_unit": "m/s^2 per axis per sample (white, input-referred)",
        "gravity": gravity,
        "sensitivity": _floats(np.linalg.norm(truth.accel_S, axis=1)),
        "sensitivity_unit": f"{truth.accel_units} per m/s^2",
        "misalignment_deg": _misalignment_deg(truth.accel_S),
        "bias_mg": _floats(1000.0 * truth.accel_bias_g),
        "S": _floats(truth.accel_S),
    }
    accel, gyro = truth_sections(truth, accel_extra, gyro_extra)
    root = {"sensor": sensor, "seed": seed, "plan": "hk-gyro", "simulator": options}
    return session, Calibration(accel=accel, gyro=gyro, extra=root, created=created)


def simulate_hk_plan(
    plan: str,
    seed: int = 0,
    rate_hz: float | None = None,
    units: str = "counts",
    hold_s: float | None = None,
    accel_noise: float = 0.01,
    sigma_counts: float = 0.7,
    orientations: int | None = None,
    samples: int = 10,
    labelled: bool = False,
    mountings: int = 2,
    created: str | None = None,
) -> tuple[Session, Calibration]:
    """Run one of :data:`HK_PLANS` with the options of ``imucal simulate``.

    Parameters
    ----------
    plan : {"hk-redundant", "hk-gyro"}
        The design.
    seed : int
        Non-negative seed.
    rate_hz : float, optional
        Sample rate, Hz (default 50 for hk-redundant, 100 for hk-gyro).
    units : str
        ``counts`` (hk-redundant accepts nothing else); hk-gyro also ``m/s^2``.
    hold_s : float, optional
        hk-gyro: duration of each still period, s (default 3).
    accel_noise : float
        hk-gyro: accelerometer noise, m/s^2 per axis per sample.
    sigma_counts, orientations, samples, labelled
        hk-redundant: see :func:`simulate_redundant_accel`.
    mountings : int
        hk-gyro: number of IMU mountings in the iron.
    created : str, optional
        ISO 8601 UTC creation time; default now.

    Returns
    -------
    (Session, Calibration)

    Raises
    ------
    InputError
        Unknown plan, or a bad value.
    """
    name = plan.strip().lower()
    if name == "hk-redundant":
        if units != "counts":
            raise InputError(
                f"plan hk-redundant records 11-bit ADC codes: units must be counts, not {units!r}"
            )
        return simulate_redundant_accel(
            seed=seed,
            sigma_counts=sigma_counts,
            orientations=orientations,
            samples=samples,
            rate_hz=50.0 if rate_hz is None else rate_hz,
            labelled=labelled,
            created=created,
        )
    if name == "hk-gyro":
        return simulate_hk_gyro(
            seed=seed,
            mountings=mountings,
            rate_hz=100.0 if rate_hz is None else rate_hz,
            still_s=3.0 if hold_s is None else hold_s,
            units=units,
            accel_noise=accel_noise,
            created=created,
        )
    raise InputError(f"plan {plan!r} is not one of {', '.join(HK_PLANS)}")
