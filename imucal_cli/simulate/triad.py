"""The virtual IMU: a cheap 16-bit MEMS accelerometer + gyroscope with known truth.

The simulator plays the experiment of Qureshi & Golnaraghi (section III-A, IV-B): the unit is
placed by hand in a list of poses (the 6 faces and 12 45-degree edges of a cube, or any other
plan), held still in each for ``hold_s`` seconds, and turned smoothly from one pose to the
next.  It returns the session exactly as a recorder would have written it, plus a truth
:class:`~imucal_cli.model.calibration.Calibration` that maps the raw channels back to the specific
force and angular rate in the fixture frame.

The part and its sensor model are :mod:`imucal_cli.simulate.sensor` (per sample, fixture
frame, SI input, raw output: ``raw = S @ (x + n) + b``, rounded and clipped to 16 bits for
``units="counts"``; the truth calibration ``matrix = inv(S)``, ``bias = b``); the motion is
built with :class:`imucal_cli.simulate.motion.Timeline`.

Timeline (:func:`simulate_stream`): ``lead_s`` still in the first pose (unlabelled), then for
every pose a static segment of ``hold_s`` and, between poses, a rotation segment of about
``move_s``: a slerp from one true orientation to the next with a smootherstep profile (zero rate
and angular acceleration at both ends) while the unit is lifted by ``lift_m`` and put down
again.

The directions of ``random:N`` are uniform on the sphere, each at least
:func:`random_separation_deg` from the ones before (drawn again when closer): a person asked
for poses in new directions spreads them, and the guided capture refuses a pose within 15 deg of
one taken, so that N poses give N distinct directions (9 of them the 9 parameters of the
gravity-magnitude model).

Each pose's true orientation is the labelled one tilted by a random horizontal rotation vector
(2 components iid normal, std ``jitter_deg / sqrt(2)``, so the RMS angle between the true and
the labelled up is ``jitter_deg``) and turned to a uniform random heading about the vertical.
A still accelerometer reads ``+gravity * up`` (specific force points away from the earth).  The
gyro reads the body angular rate; the earth rate (7e-5 rad/s, buried in the noise) is left out.

Randomness: three generators spawned from ``numpy.random.SeedSequence(seed)``: the sensor
truth, the poses (random directions, headings, placement tilt) and the noise.  The truth is
drawn in relative terms (scale errors, angles, bias in g and deg/s) and the noise in SI, so one
seed describes the same physical experiment whatever the raw ``units``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.formats.session import Segment, Session, utc_now_iso
from imucal_cli.model.calibration import Calibration
from imucal_cli.model.codec import build
from imucal_cli.plans import plan_poses
from imucal_cli.simulate.clock import clocked
from imucal_cli.simulate.motion import (
    EZ,
    Timeline,
    check_jitter,
    check_positive,
    check_samples,
    check_seed,
    hold_samples,
    move_samples,
    placed,
    placement_tilts,
    samples,
    unit,
)
from imucal_cli.simulate.sensor import (  # noqa: F401 (the part's figures, re-exported)
    ACCEL_LSB_PER_G,
    G0,
    GYRO_LSB_PER_DPS,
    RAW_MAX,
    RAW_MIN,
    UNITS,
    Imu,
    check_units,
    draw_part,
    floats,
    random_imu,
    spawn,
)
from imucal_cli.simulate.temperature import Ramp, ramp_part

__all__ = ["SimulatedStream", "random_imu", "sensor_name", "simulate", "simulate_stream",
           "stream_session", "truth_calibration"]  # fmt: skip


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
    segments : list of Segment
        Static holds and the rotations between them, in time order.
    true_up : ndarray, shape (K, 3)
        True up direction (unit, fixture frame) of each of the K static poses.
    labelled_up : list of (ndarray (3,) or None)
        Nominal up of each pose (None for random plans).
    tilt_deg : ndarray, shape (K,)
        Angle between the true and the nominal up (placement error), degrees.
    rotvec : ndarray, shape (K-1, 3)
        True rotation of each move (body frame rotation vector, rad): the integral of ``rate``.
    attitudes : Rotation
        True attitude (body -> world, world z up) of every sample, N rotations.
    truth : Imu
    options : dict
        The generation options (JSON-ready).
    """

    time: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    specific_force: np.ndarray
    rate: np.ndarray
    segments: list[Segment]
    true_up: np.ndarray
    labelled_up: list[np.ndarray | None]
    tilt_deg: np.ndarray
    rotvec: np.ndarray
    truth: Imu
    options: dict
    attitudes: Rotation | None = None
    temperature: np.ndarray | None = None
    true_temperature: np.ndarray | None = None


def _stream_options(plan, seed, rate_hz, hold_s, accel_noise, jitter_deg, units, gravity,
                    gyro_noise, move_s, lead_s, lift_m, tumble_s) -> dict:  # fmt: skip
    """The options of :func:`simulate_stream`, checked, as a JSON-ready dict."""
    check_units(units)
    opt = {
        "plan": plan.strip().lower(),
        "seed": check_seed(seed),
        "rate_hz": check_positive("rate", rate_hz, "Hz"),
        "hold_s": check_positive("hold", hold_s, "s"),
        "accel_noise": check_positive("accel noise", accel_noise, "m/s^2", allow_zero=True),
        "gyro_noise": check_positive("gyro noise", gyro_noise, "rad/s", allow_zero=True),
        "jitter_deg": check_positive("jitter", jitter_deg, "deg", allow_zero=True),
        "units": units,
        "gravity": check_positive("gravity", gravity, "m/s^2"),
        "move_s": check_positive("move time", move_s, "s"),
        "lead_s": check_positive("lead time", lead_s, "s", allow_zero=True),
        "lift_m": check_positive("lift", lift_m, "m", allow_zero=True),
        "tumble_s": check_positive("tumble", tumble_s, "s", allow_zero=True),
    }
    check_jitter(opt)
    return opt


def _stream_samples(opt: dict, k_poses: int) -> int:
    """Samples of the session: lead, ``k_poses`` holds (at least 10 samples each), the moves
    and tumbles between them; refused beyond :data:`~imucal_cli.simulate.motion.MAX_SAMPLES`."""
    rate_hz = opt["rate_hz"]
    n_hold = hold_samples(opt["hold_s"], rate_hz)
    n_way, n_step = _tumble_steps(opt)
    n_total = (
        samples(opt["lead_s"], rate_hz)
        + k_poses * n_hold
        + (k_poses - 1) * (move_samples(opt["move_s"], rate_hz) + n_way * n_step)
    )
    check_samples(n_total, "lower the rate, the hold or the number of poses")
    return n_total


def random_separation_deg(k: int) -> float:
    """The least angle between two of ``k`` random pose directions, degrees: 25 (the guided
    capture's 15 plus placement errors), less for many poses (100 / sqrt(k): a fifth of the
    density at which random sequential placement on the sphere jams)."""
    return float(min(25.0, 100.0 / np.sqrt(max(k, 1))))


def spread_directions(rng: np.random.Generator, k: int, min_deg: float) -> np.ndarray:
    """``k`` unit vectors (k, 3), each uniform on the sphere and at least ``min_deg`` from
    every one before it (random sequential placement: a closer draw is drawn again)."""
    cos_min = np.cos(np.radians(min_deg))
    out = np.empty((k, 3))
    n = 0
    while n < k:
        v = unit(rng.standard_normal(3))
        if n == 0 or np.max(out[:n] @ v) < cos_min:
            out[n] = v
            n += 1
    return out


def _orientations(
    rng: np.random.Generator, nominal: list, jitter_deg: float
) -> tuple[np.ndarray, list[Rotation], np.ndarray, np.ndarray]:
    """Nominal up (K, 3), true attitudes, true up (K, 3) and tilt vectors (K, 3) of the poses.

    Draws, in order: random directions (unlabelled plans only), headings, placement tilts.
    """
    k_poses = len(nominal)
    if nominal[0] is None:
        nominal_up = spread_directions(rng, k_poses, random_separation_deg(k_poses))
    else:
        nominal_up = np.array(nominal)
    heading = rng.uniform(0.0, 2.0 * np.pi, k_poses)
    tilt_vec = placement_tilts(rng, jitter_deg, k_poses)
    orient = [  # body -> world
        placed(nominal_up[k], Rotation.from_rotvec([0.0, 0.0, heading[k]]), tilt_vec[k])
        for k in range(k_poses)
    ]
    true_up = unit(np.array([r.inv().apply(EZ) for r in orient]))
    return nominal_up, orient, true_up, tilt_vec


TUMBLE_STEP_S = 1.0
"""A tumble passes through one random attitude per this many seconds."""


def _tumble_steps(opt: dict) -> tuple[int, int]:
    """Random waypoints per tumble and samples per waypoint move (0, 0: no tumble)."""
    if opt["tumble_s"] <= 0:
        return 0, 0
    n_way = max(1, int(round(opt["tumble_s"] / TUMBLE_STEP_S)))
    return n_way, max(2, int(round(opt["tumble_s"] * opt["rate_hz"] / n_way)))


def _pose_timeline(opt: dict, poses: list, nominal_up, orient, true_up) -> Timeline:
    """Lead, then per pose a labelled hold and a lifted move to the next pose (through random
    attitudes first when ``tumble_s`` > 0: the motion then sweeps the sphere)."""
    rate_hz, g = opt["rate_hz"], opt["gravity"]
    n_hold = samples(opt["hold_s"], rate_hz)
    n_move = move_samples(opt["move_s"], rate_hz)
    n_way, n_step = _tumble_steps(opt)
    tumble_rng = np.random.default_rng(np.random.SeedSequence(opt["seed"]).spawn(5)[4])
    tl = Timeline(rate_hz, g, orient[0])
    tl.hold(samples(opt["lead_s"], rate_hz), g * true_up[0])
    for k, (label, up) in enumerate(poses):
        span = tl.hold(n_hold, g * true_up[k])
        tl.segment("static", span, label, up=None if up is None else nominal_up[k].copy())
        if k + 1 < len(poses):
            start = tl.n
            for waypoint in Rotation.random(n_way, random_state=tumble_rng) if n_way else []:
                tl.move(waypoint, n_step)
            span = tl.move(orient[k + 1], n_move, lift_m=opt["lift_m"])
            tl.segment("rotation", (start, span[1]), f"turn to {poses[k + 1][0]}")
    return tl


def simulate_stream(
    plan: str = "qureshi18", seed: int = 0, rate_hz: float = 100.0, hold_s: float = 2.0,
    accel_noise: float = 0.01, jitter_deg: float = 2.0, units: str = "counts",
    gravity: float = G0, gyro_noise: float = 0.005, move_s: float = 1.5, lead_s: float = 1.0,
    lift_m: float = 0.03, tumble_s: float = 0.0, temperature: Ramp | None = None,
) -> SimulatedStream:  # fmt: skip
    """Generate the raw stream of a calibration session and its truth, as arrays.

    The motion is the module's timeline: a lead, a hold per pose, a lifted move between poses.

    Parameters
    ----------
    plan : str
        ``six``, ``qureshi18`` or ``random:N`` (see :func:`plan_poses`).
    seed : int
        Non-negative seed; the same seed and options give the same arrays bit for bit.
    rate_hz, hold_s : float
        Sample rate, Hz; hold per pose, s (at least 10 samples).
    accel_noise, gyro_noise : float
        White noise per axis per sample: accelerometer m/s^2, gyroscope rad/s.
    jitter_deg : float
        RMS placement error of the up direction, degrees.
    units : {"counts", "m/s^2"}
        Raw units of the simulated part (see :func:`random_imu`).
    gravity : float
        Local gravity, m/s^2.
    move_s, lead_s, lift_m : float
        Duration of each move between poses, s; still time before the first hold, s; height
        the unit is lifted during each move, m (a vertical linear acceleration).
    tumble_s : float
        Before each move, the unit tumbles this long through random attitudes (one per
        second, drawn from a fifth generator of the seed), s; 0: none.
    temperature : Ramp, optional
        The part's temperature through the session: its biases follow it and the reading is
        recorded (:func:`~imucal_cli.simulate.temperature.ramp_part`).

    Returns
    -------
    SimulatedStream

    Raises
    ------
    InputError
        A bad plan, unit or value.
    """
    poses = plan_poses(plan)
    opt = _stream_options(plan, seed, rate_hz, hold_s, accel_noise, jitter_deg, units, gravity,
                          gyro_noise, move_s, lead_s, lift_m, tumble_s)  # fmt: skip
    n_total = _stream_samples(opt, len(poses))
    truth, pose_ss, noise_ss = draw_part(opt["seed"], units, opt["accel_noise"],
                                         opt["gyro_noise"])  # fmt: skip
    nominal = [up for _, up in poses]
    nominal_up, orient, true_up, tilt_vec = _orientations(
        np.random.default_rng(pose_ss), nominal, opt["jitter_deg"]
    )
    tl = _pose_timeline(opt, poses, nominal_up, orient, true_up)
    force, rate = tl.arrays()
    assert len(force) == n_total
    time = np.arange(n_total) / opt["rate_hz"]
    truth, thermal = ramp_part(truth, temperature, time, opt)
    true_c, reading_c = (None, None) if thermal is None else thermal
    raw = truth.sample({"accel": force, "gyro": rate}, np.random.default_rng(noise_ss),
                       temperature=true_c)  # fmt: skip
    return SimulatedStream(
        time=time, accel=raw["accel"], gyro=raw["gyro"], specific_force=force, rate=rate,
        segments=tl.segments, true_up=true_up,
        labelled_up=[None if u is None else np.asarray(u, float).copy() for u in nominal],
        tilt_deg=np.degrees(np.linalg.norm(tilt_vec, axis=1)), rotvec=_move_rotvecs(orient),
        truth=truth, options=opt, attitudes=tl.attitudes(), temperature=reading_c,
        true_temperature=true_c,
    )  # fmt: skip


def _move_rotvecs(orient: list[Rotation]) -> np.ndarray:
    """True rotation of each move between the poses (K-1, 3), body frame rotation vectors."""
    rotvecs = np.zeros((max(len(orient) - 1, 0), 3))
    for k in range(len(orient) - 1):
        rotvecs[k] = (orient[k].inv() * orient[k + 1]).as_rotvec()
    return rotvecs


# --------------------------------------------------------------------------------------------
# Session and truth objects
# --------------------------------------------------------------------------------------------


def sensor_name(seed: int) -> str:
    """The ``sensor`` attribute of a simulated session: ``"sim-16bit seed 1"``."""
    return f"sim-16bit seed {int(seed)}"


def truth_calibration(stream: SimulatedStream, created: str | None = None) -> Calibration:
    """The truth of a simulated stream as a :class:`~imucal_cli.model.calibration.Calibration`.

    ``matrix = inv(S)`` and ``bias = b`` in raw units, so ``matrix @ (raw - bias)`` gives the
    specific force (m/s^2) and angular rate (rad/s) in the fixture frame, up to noise and
    quantisation.  Extras record the generation: noise, seed, plan, jitter, the true up of
    each static pose (``accel.true_up``, in segment order) and the true rotation of
    each move (``gyro.true_rotvec``, rad).
    """
    t, opt = stream.truth, stream.options
    static = [s for s in stream.segments if s.kind == "static"]
    moves = [s for s in stream.segments if s.kind == "rotation"]
    sections = t.truth_sections({
        "accel": {
            "gravity": float(opt["gravity"]),
            "mount_rotvec_deg": floats(np.degrees(t.mount_rotvec)),
            "jitter_deg": float(opt["jitter_deg"]),
            "segments": [s.name for s in static],
            "labels": [s.label for s in static],
            "true_up": floats(stream.true_up),
            "labelled_up": [None if u is None else floats(u) for u in stream.labelled_up],
            "tilt_deg": floats(stream.tilt_deg),
        },
        "gyro": {
            "segments": [s.name for s in moves],
            "true_rotvec": floats(stream.rotvec),
            "true_rotvec_unit": "rad, body (fixture) frame",
        },
    })  # fmt: skip
    root_extra = {
        "sensor": sensor_name(opt["seed"]),
        "seed": int(opt["seed"]),
        "plan": opt["plan"],
        "jitter_deg": float(opt["jitter_deg"]),
        "simulator": dict(opt),
    }
    kwargs = {} if created is None else {"created": created}
    return build(Calibration, accel=sections["accel"], gyro=sections["gyro"], **root_extra,
                 **kwargs)  # fmt: skip


def simulate(
    plan: str = "qureshi18", seed: int = 0, *, created: str | None = None,
    clock_scale: float | None = None, **options,
) -> tuple[Session, Calibration]:  # fmt: skip
    """Simulate a calibration session and return it with its truth.

    Parameters are those of :func:`simulate_stream` (``options``: ``rate_hz``, ``hold_s``,
    ...); ``created`` (ISO 8601 UTC) defaults to now.  The raw arrays are identical bit for
    bit for the same seed and options.  ``clock_scale``: the part's clock runs this many
    device seconds per true second; the session records device times and the host's arrival
    times (:mod:`imucal_cli.simulate.clock`), the truth ``sample_clock_scale``.

    Returns
    -------
    session : imucal_cli.formats.session.Session
        ``source="simulator"``, ``sensor="sim-16bit seed <seed>"``, raw accel and gyro (N, 3)
        in ``accel_units``/``gyro_units``; segments ``0000``, ``0001``, ... alternating static
        holds (label and, except for ``random:N``, ``up``) and rotation segments (label only).
    truth : imucal_cli.model.calibration.Calibration
        See :func:`truth_calibration`.
    """
    stream = simulate_stream(plan=plan, seed=seed, **options)
    created = created or utc_now_iso()
    truth = truth_calibration(stream, created)
    return clocked(stream_session(stream, created), truth, clock_scale, seed), truth


def stream_session(stream: SimulatedStream, created: str) -> Session:
    """The session a recorder would have written of a simulated stream (accel and gyro)."""
    return Session(
        time=stream.time,
        accel=stream.accel,
        gyro=stream.gyro,
        temperature=stream.temperature,
        segments=stream.segments,
        created=created,
        sensor=sensor_name(stream.options["seed"]),
        source="simulator",
        sample_rate_hz=float(stream.options["rate_hz"]),
        gravity=float(stream.options["gravity"]),
        accel_units=stream.truth.accel_units,
        gyro_units=stream.truth.gyro_units,
    )
