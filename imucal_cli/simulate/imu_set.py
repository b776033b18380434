"""Several IMUs on one rigid body (``imucal simulate --imus N``, issue 28): a flight
controller's two or three IMUs, a robot's, an IMU array.

The body goes through a pose plan (six, qureshi18, random:N) as :mod:`.triad` plays it: a
lead, then per pose a hold of ``hold_s`` and a lifted smootherstep move of ``move_s`` to the
next pose.  The motion is evaluated in closed form at any time (:class:`SetMotion`), so every
IMU samples it exactly at its own times: no IMU's samples are interpolated.

The IMUs (the reference first, named ``reference``; the others ``imu1``, ``imu2``, ...):

- each a part of its own (:func:`~.sensor.random_imu`): the reference the part of ``seed``
  (:func:`~.sensor.draw_part`, the same part as a single-IMU simulation of that seed), the
  others drawn from a fourth generator of the seed;
- each mounted rotated from the reference by a random rotation of ``0..max_rotation_deg``
  (uniform angle, random axis): IMU k reads ``x_k = R_k^T x`` of the body's (the reference's
  nominal frame) specific force and rate ``x``;
- each with its own rate (the reference ``rate_hz``, the others ``rate_hz`` times one of
  :data:`RATE_FACTORS`), its own white noise (``accel_noise``, ``gyro_noise`` times a factor in
  :data:`NOISE_RANGE`), a random start phase and a time offset uniform in
  ``+-max_offset_s``: its sample stamped ``tau`` (on the reference's clock, which is true
  time) was taken at ``tau + time_offset_s`` (the spec's meaning: the time to add to its stamps).

Lever arms are left out (every IMU at one point: they differ only while the body moves, where
the set's estimates use no accelerometer).

The truth (:func:`set_truth`): the reference's true calibration at the top level, as a single
IMU's (matrix ``inv(S)``: raw to its nominal frame), and ``imus``: each other IMU's true
``accel`` and ``gyro`` (raw to its own nominal frame), ``rotation_to_reference`` (``R_k``: its
nominal frame into the reference's) and ``time_offset_s``.  A calibration's frames are its
solver's (the gravity solver: upper triangular, :func:`gauge_rotation` gives the truth in it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.session import ImuStream, Segment, Session, utc_now_iso
from imucal_cli.model.calibration import Calibration, ImuEntry
from imucal_cli.plans import plan_poses
from imucal_cli.simulate.motion import (
    EZ,
    check_int,
    check_positive,
    check_samples,
    check_seed,
    hold_samples,
    placed,
    placement_tilts,
    unit,
)
from imucal_cli.simulate.sensor import G0, Imu, check_units, draw_part, floats, random_imu
from imucal_cli.simulate.triad import random_separation_deg, sensor_name, spread_directions

__all__ = ["MAX_IMUS", "SetMotion", "gauge_rotation", "set_truth", "simulate_set", "true_motion"]

MAX_IMUS = 64
"""The most IMUs ``--imus`` simulates."""

RATE_FACTORS = (1.0, 1.25, 1.5, 2.0)
"""An IMU other than the reference samples at ``rate_hz`` times one of these."""

NOISE_RANGE = (0.5, 2.0)
"""An IMU other than the reference has its noise times a factor uniform in this range."""


def imu_name(k: int) -> str:
    """``reference`` for k = 0, else ``imu<k>``."""
    return "reference" if k == 0 else f"imu{k}"


# --------------------------------------------------------------------------------------------
# The motion, in closed form at any time
# --------------------------------------------------------------------------------------------


@dataclass
class _Piece:
    t0: float
    t1: float
    att: Rotation  # attitude (body -> world) at t0
    rotvec: np.ndarray | None  # a move: body rotation vector from t0 to t1; a hold: None


class SetMotion:
    """The body's true specific force and rate at any time: holds and smootherstep moves.

    Parameters
    ----------
    gravity : float
        Local gravity, m/s^2.
    lift_m : float
        Height the body is lifted during each move (a vertical acceleration), m.
    """

    def __init__(self, gravity: float, lift_m: float) -> None:
        self.gravity, self.lift_m = gravity, lift_m
        self.pieces: list[_Piece] = []
        self.end = 0.0

    def hold(self, att: Rotation, seconds: float) -> tuple[float, float]:
        """Held still at ``att`` for ``seconds``; returns the interval (s)."""
        self.pieces.append(_Piece(self.end, self.end + seconds, att, None))
        self.end += seconds
        return self.pieces[-1].t0, self.end

    def move(self, att: Rotation, target: Rotation, seconds: float) -> tuple[float, float]:
        """A smootherstep slerp from ``att`` to ``target`` over ``seconds`` (zero rate and
        angular acceleration at both ends, as :meth:`.motion.Timeline.move`)."""
        rv = (att.inv() * target).as_rotvec()
        self.pieces.append(_Piece(self.end, self.end + seconds, att, rv))
        self.end += seconds
        return self.pieces[-1].t0, self.end

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Specific force (m/s^2) and rate (rad/s), (N, 3) each in the body frame, at the true
        times ``t`` (s; clipped to the motion's span: still at both ends)."""
        t = np.clip(np.asarray(t, float), 0.0, self.end)
        force, rate = np.empty((len(t), 3)), np.zeros((len(t), 3))
        starts = np.array([p.t0 for p in self.pieces])
        which = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.pieces) - 1)
        for i, p in enumerate(self.pieces):
            rows = np.flatnonzero(which == i)
            if rows.size == 0:
                continue
            if p.rotvec is None:
                force[rows] = p.att.inv().apply(self.gravity * EZ)
                continue
            dur = p.t1 - p.t0
            tau = np.clip((t[rows] - p.t0) / dur, 0.0, 1.0)
            s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
            ds = 30.0 * tau**2 * (1.0 - tau) ** 2 / dur
            path = p.att * Rotation.from_rotvec(s[:, None] * p.rotvec)
            x = np.pi * tau
            lift = self.lift_m * (np.pi / dur) ** 2 * (12.0 * np.sin(x) ** 2 * np.cos(x) ** 2
                                                       - 4.0 * np.sin(x) ** 4)  # fmt: skip
            world = np.zeros((rows.size, 3))
            world[:, 2] = self.gravity + lift
            force[rows] = path.inv().apply(world)
            rate[rows] = ds[:, None] * p.rotvec
        return force, rate


def _pose_motion(opt: dict, rng: np.random.Generator) -> tuple[SetMotion, list, np.ndarray]:
    """The plan's motion (lead, holds, moves), the ``(kind, t0, t1, label, up)`` of each step
    and the true up of each pose (K, 3), body frame."""
    poses = plan_poses(opt["plan"])
    nominal = [up for _, up in poses]
    if nominal[0] is None:
        nominal_up = spread_directions(rng, len(poses), random_separation_deg(len(poses)))
    else:
        nominal_up = np.array(nominal)
    headings = rng.uniform(0.0, 2.0 * np.pi, len(poses))
    tilts = placement_tilts(rng, opt["jitter_deg"], len(poses))
    orient = [placed(nominal_up[k], Rotation.from_rotvec([0.0, 0.0, headings[k]]), tilts[k])
              for k in range(len(poses))]  # fmt: skip
    motion = SetMotion(opt["gravity"], opt["lift_m"])
    motion.hold(orient[0], opt["lead_s"])
    steps = []
    for k, (label, up) in enumerate(poses):
        t0, t1 = motion.hold(orient[k], opt["hold_s"])
        steps.append(("static", t0, t1, label, None if up is None else nominal_up[k].copy()))
        if k + 1 < len(poses):
            t0, t1 = motion.move(orient[k], orient[k + 1], opt["move_s"])
            steps.append(("rotation", t0, t1, f"turn to {poses[k + 1][0]}", None))
    true_up = unit(np.array([r.inv().apply(EZ) for r in orient]))
    return motion, steps, true_up


def _segments(steps: list, time: np.ndarray) -> list[Segment]:
    """The reference's segments: a hold's samples (its whole interval), a move's interior."""
    out = []
    for kind, t0, t1, label, up in steps:
        if kind == "static":
            start, stop = np.searchsorted(time, t0, "left"), np.searchsorted(time, t1, "right")
        else:
            start, stop = np.searchsorted(time, t0, "right"), np.searchsorted(time, t1, "left")
        if stop - start >= 2:
            out.append(Segment(f"{len(out):04d}", kind, int(start), int(stop), label,
                               up=up if kind == "static" else None))  # fmt: skip
    return out


# --------------------------------------------------------------------------------------------
# The set
# --------------------------------------------------------------------------------------------


@dataclass
class _Member:
    """One IMU of the set: its part, mounting, rate, offset, stamps and noise seed."""

    name: str
    part: Imu
    rotation: Rotation  # its frame into the body's (the reference's nominal frame)
    rate_hz: float
    offset_s: float
    stamps: np.ndarray
    noise_seed: np.random.SeedSequence
    noise_factor: float


def _members(opt: dict, span_s: float) -> tuple[list[_Member], np.random.SeedSequence]:
    """The reference (the part of ``seed``) and the others (a fourth generator of the seed:
    per IMU its part, then rotation, rate, noise factor, offset and phase); the pose seed."""
    part, pose_ss, noise_ss = draw_part(opt["seed"], opt["units"], opt["accel_noise"],
                                        opt["gyro_noise"])  # fmt: skip
    rate = opt["rate_hz"]
    ref_stamps = np.arange(int(np.floor(span_s * rate)) + 1) / rate
    members = [_Member("reference", part, Rotation.identity(), rate, 0.0, ref_stamps,
                       noise_ss, 1.0)]  # fmt: skip
    others = np.random.SeedSequence(opt["seed"]).spawn(4)[3].spawn(max(opt["imus"] - 1, 0))
    for k, ss in enumerate(others, start=1):
        part_ss, geo_ss, n_ss = ss.spawn(3)
        geo = np.random.default_rng(geo_ss)
        axis = unit(geo.standard_normal(3))
        rotation = Rotation.from_rotvec(axis * np.radians(geo.uniform(0, opt["max_rotation_deg"])))
        rate_k = rate * float(geo.choice(RATE_FACTORS))
        factor = float(geo.uniform(*NOISE_RANGE))
        offset = float(geo.uniform(-opt["max_offset_s"], opt["max_offset_s"]))
        phase = float(geo.uniform(0.0, 1.0 / rate_k))
        if opt["synchronous"]:  # one device samples every IMU at the reference's ticks
            rate_k, phase = rate, 0.0
        stamps = phase + np.arange(int(np.floor((span_s - phase) * rate_k)) + 1) / rate_k
        imu = random_imu(np.random.default_rng(part_ss), opt["units"],
                         accel_noise=opt["accel_noise"] * factor,
                         gyro_noise=opt["gyro_noise"] * factor)  # fmt: skip
        members.append(_Member(imu_name(k), imu, rotation, rate_k, offset, stamps, n_ss, factor))
    return members, pose_ss


def _options(n_imus, plan, seed, rate_hz, hold_s, accel_noise, gyro_noise, jitter_deg, units,
             gravity, move_s, lead_s, lift_m, max_rotation_deg, max_offset_s,
             synchronous) -> dict:  # fmt: skip
    check_units(units)
    opt = {
        "imus": check_int("--imus", n_imus, 1, MAX_IMUS), "plan": plan.strip().lower(),
        "seed": check_seed(seed), "rate_hz": check_positive("rate", rate_hz, "Hz"),
        "hold_s": check_positive("hold", hold_s, "s"),
        "accel_noise": check_positive("accel noise", accel_noise, "m/s^2", allow_zero=True),
        "gyro_noise": check_positive("gyro noise", gyro_noise, "rad/s", allow_zero=True),
        "jitter_deg": check_positive("jitter", jitter_deg, "deg", allow_zero=True),
        "units": units, "gravity": check_positive("gravity", gravity, "m/s^2"),
        "move_s": check_positive("move time", move_s, "s"),
        "lead_s": check_positive("lead time", lead_s, "s", allow_zero=True),
        "lift_m": check_positive("lift", lift_m, "m", allow_zero=True),
        "max_rotation_deg": check_positive("rotation", max_rotation_deg, "deg", allow_zero=True),
        "max_offset_s": check_positive("time offset", max_offset_s, "s", allow_zero=True),
        "synchronous": bool(synchronous),
    }  # fmt: skip
    if opt["max_rotation_deg"] > 180 or opt["max_offset_s"] > 1.0:
        raise InputError("the IMUs' rotations are at most 180 deg and their offsets 1 s")
    hold_samples(opt["hold_s"], opt["rate_hz"])
    return opt


def simulate_set(
    n_imus: int = 3, plan: str = "random:18", seed: int = 0, *, rate_hz: float = 100.0,
    hold_s: float = 2.0, accel_noise: float = 0.01, gyro_noise: float = 0.005,
    jitter_deg: float = 2.0, units: str = "counts", gravity: float = G0, move_s: float = 1.5,
    lead_s: float = 1.0, lift_m: float = 0.03, max_rotation_deg: float = 5.0,
    max_offset_s: float = 0.01, created: str | None = None, synchronous: bool = False,
) -> tuple[Session, Calibration]:  # fmt: skip
    """A session of ``n_imus`` IMUs on one rigid body going through a pose plan, and its truth.

    Parameters
    ----------
    n_imus : int
        IMUs in the set, 1 to :data:`MAX_IMUS` (the reference is one of them).
    plan : str
        ``six``, ``qureshi18`` or ``random:N``.
    seed : int
        The same seed and options give the same samples bit for bit.
    rate_hz, hold_s, accel_noise, gyro_noise, jitter_deg, units, gravity, move_s, lead_s,
    lift_m :
        As :func:`imucal_cli.simulate.triad.simulate_stream` (the reference's rate and noise;
        see the module notes for the others').
    max_rotation_deg : float
        Each other IMU is mounted rotated by up to this angle, degrees.
    max_offset_s : float
        Each other IMU's time offset is uniform in +-this, s.
    created : str, optional
        ISO 8601 UTC; default now.
    synchronous : bool
        Every IMU sampled at the reference's stamps (one device reading them all at each tick,
        as ``--serve`` streams them: several triads per line); each still measures the motion
        at its stamp plus its offset.

    Returns
    -------
    session : Session
        ``/raw`` the reference, ``imus`` the others (their own stamps and rates); segments the
        plan's holds and moves on the reference's samples.
    truth : Calibration
        :func:`set_truth`.

    Raises
    ------
    InputError
        A bad plan or option.
    """
    opt = _options(n_imus, plan, seed, rate_hz, hold_s, accel_noise, gyro_noise, jitter_deg,
                   units, gravity, move_s, lead_s, lift_m, max_rotation_deg,
                   max_offset_s, synchronous)  # fmt: skip
    n_poses = len(plan_poses(opt["plan"]))
    span_s = opt["lead_s"] + n_poses * opt["hold_s"] + (n_poses - 1) * opt["move_s"]
    check_samples(int(span_s * opt["rate_hz"] * max(RATE_FACTORS) * opt["imus"]),
                  "lower the rate, the hold, the number of poses or of IMUs")  # fmt: skip
    members, pose_ss = _members(opt, span_s)
    motion, steps, true_up = _pose_motion(opt, np.random.default_rng(pose_ss))
    created = created or utc_now_iso()
    streams = {}
    for m in members:
        force, rate = motion.at(m.stamps + m.offset_s)
        inv = m.rotation.inv()
        raw = m.part.sample({"accel": inv.apply(force), "gyro": inv.apply(rate)},
                            np.random.default_rng(m.noise_seed))  # fmt: skip
        streams[m.name] = ImuStream(
            time=m.stamps, accel=raw["accel"], gyro=raw["gyro"],
            sensor=f"{sensor_name(opt['seed'])} {m.name}", accel_units=m.part.accel.units,
            gyro_units=m.part.gyro.units, sample_rate_hz=m.rate_hz,
        )  # fmt: skip
    ref = streams.pop("reference")
    session = Session(
        time=ref.time, accel=ref.accel, gyro=ref.gyro, temperature=None,
        segments=_segments(steps, ref.time), created=created, sensor=ref.sensor,
        source="simulator", sample_rate_hz=opt["rate_hz"], gravity=opt["gravity"],
        accel_units=ref.accel_units, gyro_units=ref.gyro_units, imus=streams,
    )  # fmt: skip
    return session, set_truth(members, opt, true_up, session, created)


def true_motion(truth: Calibration) -> SetMotion:
    """The body's motion of a simulated set, from its truth's ``simulator`` options (for the
    bounds, which need the true rate's derivative)."""
    opt = dict(truth.simulator)
    pose_ss = np.random.SeedSequence(opt["seed"]).spawn(3)[1]
    return _pose_motion(opt, np.random.default_rng(pose_ss))[0]


def set_truth(members: list[_Member], opt: dict, true_up: np.ndarray, session: Session,
              created: str) -> Calibration:  # fmt: skip
    """The truth of a simulated set: the reference's sections at the top level and ``imus``:
    each other IMU's true sections, rotation into the reference's frame and time offset."""

    def sections(m: _Member, extra: dict) -> dict:
        noise = {"noise_factor": m.noise_factor, "sample_rate_hz": m.rate_hz}
        return m.part.truth_sections({"accel": {**noise, **extra}, "gyro": noise})

    ref = sections(members[0], {"gravity": opt["gravity"], "true_up": floats(true_up),
                                "segments": [s.name for s in session.static_segments()]})
    imus = {}
    for m in members[1:]:
        sec = sections(m, {"gravity": opt["gravity"]})
        imus[m.name] = ImuEntry(
            accel=sec["accel"], gyro=sec["gyro"],
            rotation_to_reference=m.rotation.as_matrix().tolist(),
            rotation_deg=float(np.degrees(m.rotation.magnitude())),
            time_offset_s=m.offset_s,
        )  # fmt: skip
    return Calibration(accel=ref["accel"], gyro=ref["gyro"], created=created,
                       sensor=session.sensor, seed=opt["seed"], plan=opt["plan"], imus=imus,
                       simulator={**opt, "experiment": "imu set"})  # fmt: skip


def gauge_rotation(matrix: np.ndarray) -> np.ndarray:
    """The rotation ``Q`` of ``matrix = Q U`` (``U`` upper triangular, positive diagonal): a
    true calibration's frame into the gravity solver's (upper-triangular) one is ``Q^T``."""
    Q, U = np.linalg.qr(np.asarray(matrix, float))
    return Q @ np.diag(np.sign(np.diag(U)))


# --------------------------------------------------------------------------------------------
# The set through the virtual serial port (``simulate --serve --imus N``)
# --------------------------------------------------------------------------------------------

#: The options of :func:`simulate_set` that ``--serve`` passes on (the rest are the plans').
SERVED_OPTIONS = ("seed", "rate_hz", "hold_s", "accel_noise", "jitter_deg", "units", "gravity",
                  "move_s", "max_rotation_deg", "max_offset_s", "created")  # fmt: skip


def served_set(plan: str, imus: int, member: int | None = None,
               **options) -> tuple[Session, Calibration]:  # fmt: skip
    """The set ``--serve --imus N`` streams: every IMU sampled at the reference's ticks
    (``synchronous``: one device reading them all, each line every IMU's triads), each still
    with its own offset.  ``member``: only IMU ``member`` (0 the reference), as a session of
    its own on the reference's segments (one port per IMU)."""
    kept = {k: v for k, v in options.items() if k in SERVED_OPTIONS and v is not None}
    session, truth = simulate_set(imus, plan, synchronous=True, **kept)
    if member is None:
        return session, truth
    if not 0 <= member < imus:
        raise InputError(f"--serve-imu must be from 0 to {imus - 1}, got {member}")
    if member == 0:
        return Session(**{**session.__dict__, "imus": {}}), truth
    imu = session.imus[imu_name(member)]
    return Session(time=imu.time, accel=imu.accel, gyro=imu.gyro, temperature=None,
                   segments=session.segments, created=session.created, sensor=imu.sensor,
                   source="simulator", sample_rate_hz=imu.sample_rate_hz,
                   gravity=session.gravity, accel_units=imu.accel_units,
                   gyro_units=imu.gyro_units), truth  # fmt: skip


def set_columns(session: Session, temperature: bool) -> str:
    """The fields of a served set's line: the reference's ``t,ax,ay,az,gx,gy,gz[,temp]``, then
    each other IMU's ``ax.K,ay.K,az.K,gx.K,gy.K,gz.K``."""
    names = ["t", "ax", "ay", "az", "gx", "gy", "gz"] + (["temp"] if temperature else [])
    for k in range(1, len(session.imus) + 1):
        names += [f"{f}.{k}" for f in ("ax", "ay", "az", "gx", "gy", "gz")]
    return ",".join(names)


def set_lines(session: Session, temperature, counts: bool) -> list[bytes]:
    """The data lines of a served set (:func:`set_columns`); ``temperature`` as the device's
    ``_format`` takes it (False, True or the session's temperatures)."""
    with_temp = temperature is not None and temperature is not False
    columns = [session.time[:, None], session.accel, session.gyro]
    if with_temp:
        own = not isinstance(temperature, bool)
        columns.append((np.asarray(temperature, float) if own
                        else 25.0 + 0.01 * session.time)[:, None])  # fmt: skip
    for imu in session.imus.values():
        columns += [imu.accel, imu.gyro]
    value = "%.0f" if counts else "%.6f"
    n_values = sum(c.shape[1] for c in columns) - 1 - with_temp
    fmt = ",".join(["%.4f"] + [value] * 6 + (["%.2f"] if with_temp else [])
                   + [value] * (n_values - 6))  # fmt: skip
    rows = np.column_stack(columns).tolist()
    return [(fmt % tuple(r) + "\n").encode() for r in rows]
