"""Any plan, step by step: the virtual IMU going through a :class:`~imucal_cli.plans.Plan`.

Plans without a dedicated virtual experiment (``gyro-axes``, ``still:MINUTES``, TOML plan files)
are played here, one segment per step, labelled and attributed as the step says:

static step with ``up``
    The unit is moved (a smootherstep slerp of ``move_s``; from a still period, a rotation
    segment ``turn to LABEL`` as a capture records it; after a turn, unsegmented: it continues
    the turn) to that pose, placed
    with a random heading and a placement error (random horizontal tilt, RMS ``jitter_deg``),
    unless it already stands on that face; then held ``hold_s`` (or the step's own ``hold_s``).
static step without ``up``
    Held where the unit is.
rotation step
    A smootherstep turn by ``angle_deg`` (or, when the plan leaves it free, a random angle of
    45-180 degrees either way) about ``axis`` (or a random axis).  A turn about an axis within
    :data:`TABLE_TURN_DEG` of the vertical is a turn on the table: about the true vertical, so
    the placement error tilts its axis in the body frame as it would on a bench.  Peak rate at
    most :data:`PEAK_RATE_DPS`; a still period follows when the next step is no static one.
``mounting``
    When a step's mounting differs from the last one, the unit is re-mounted in the fixture
    (mounting 1: aligned; others: rotations drawn from the seed far from the fixture's
    symmetries, :func:`imucal_cli.simulate.motion.draw_mountings`) by an unsegmented move.

Randomness as every simulator: the part, the poses and the noise from three generators spawned
from ``numpy.random.SeedSequence(seed)``, so a seed gives the part of ``imucal simulate --plan
six`` with that seed, and the same samples bit for bit.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import Calibration
from imucal_cli.plans import Plan, Step
from imucal_cli.simulate.motion import (
    EZ,
    Timeline,
    check_jitter,
    check_positive,
    check_samples,
    check_seed,
    draw_mountings,
    heading,
    hold_samples,
    move_samples,
    place,
    samples,
    unit,
)
from imucal_cli.simulate.sensor import G0, check_units, draw_part, floats
from imucal_cli.simulate.triad import sensor_name

__all__ = ["PEAK_RATE_DPS", "TABLE_TURN_DEG", "simulate_steps"]

PEAK_RATE_DPS = 150.0
"""Largest peak rate of a turn, deg/s (a hand turn); slower turns last at least ``move_s``."""

TABLE_TURN_DEG = 10.0
"""A turn whose axis is this close to the vertical is a turn on the table (about the vertical)."""

FREE_TURN_DEG = (45.0, 180.0)
"""Magnitude range of a turn whose angle the plan leaves free, degrees."""


def _options(seed, rate_hz, hold_s, move_s, lead_s, units, accel_noise, gyro_noise, jitter_deg,
             gravity) -> dict:  # fmt: skip
    check_units(units)
    opt = {
        "seed": check_seed(seed),
        "rate_hz": check_positive("rate", rate_hz, "Hz"),
        "hold_s": check_positive("hold", hold_s, "s"),
        "move_s": check_positive("move time", move_s, "s"),
        "lead_s": check_positive("lead time", lead_s, "s", allow_zero=True),
        "units": units,
        "accel_noise": check_positive("accel noise", accel_noise, "m/s^2", allow_zero=True),
        "gyro_noise": check_positive("gyro noise", gyro_noise, "rad/s", allow_zero=True),
        "jitter_deg": check_positive("jitter", jitter_deg, "deg", allow_zero=True),
        "gravity": check_positive("gravity", gravity, "m/s^2"),
    }
    check_jitter(opt)
    hold_samples(opt["hold_s"], opt["rate_hz"])
    return opt


class _Player:
    """Plays the steps on a :class:`Timeline`; records the truth of each segment."""

    def __init__(self, opt: dict, prng: np.random.Generator) -> None:
        self.opt, self.prng = opt, prng
        self.n_hold = samples(opt["hold_s"], opt["rate_hz"])
        self.n_move = move_samples(opt["move_s"], opt["rate_hz"])
        self.mounts: list[Rotation] = [Rotation.identity()]
        self.mounting = 1
        self.face: np.ndarray | None = None  # nominal up the unit stands on
        self.tl: Timeline | None = None
        self.true_up: list[np.ndarray] = []
        self.turns: list[dict] = []

    def placement(self, up: np.ndarray) -> Rotation:
        """Fixture attitude on a labelled face: tilt * heading * up-to-vertical (draws 3)."""
        return place(self.prng, unit(up), self.opt["jitter_deg"])

    def start(self, steps: tuple[Step, ...]) -> None:
        count = max((s.mounting or 1) for s in steps)
        if count > 1:  # mountings far from the fixture's symmetries and from each other
            self.mounts = draw_mountings(self.prng, count)
        first = next((s for s in steps if s.kind == "static" and s.up is not None), None)
        if first is None:
            att = heading(self.prng)
        else:
            att, self.face = self.placement(first.up), np.asarray(first.up, float)
        self.tl = Timeline(self.opt["rate_hz"], self.opt["gravity"], att)
        self.tl.hold(samples(self.opt["lead_s"], self.opt["rate_hz"]))

    def remount(self, m: int) -> None:
        """Put the unit in mounting ``m`` of the fixture (an unsegmented move)."""
        fixture = self.tl.att * self.mounts[self.mounting - 1].inv()
        self.tl.move(fixture * self.mounts[m - 1], self.n_move)
        self.mounting = m

    def static(self, step: Step) -> None:
        tl = self.tl
        if step.up is not None and (
            self.face is None or not np.allclose(self.face, step.up, atol=1e-9)
        ):
            span = tl.move(self.placement(step.up) * self.mounts[self.mounting - 1],
                           self.n_move)  # fmt: skip
            if tl.segments and tl.segments[-1].kind == "static":  # a turn between still
                # periods, as a capture records it (after a turn, the move continues it)
                tl.segment("rotation", span, f"turn to {step.label or 'the next face'}")
            self.face = np.asarray(step.up, float)
        n = self.n_hold if not step.hold_s else samples(step.hold_s, self.opt["rate_hz"])
        tl.segment("static", tl.hold(n), **step.segment_attrs())
        self.true_up.append(tl.att.inv().apply(EZ))

    def rotation(self, step: Step) -> None:
        tl, prng = self.tl, self.prng
        if step.angle_deg is None:
            mag = prng.uniform(*FREE_TURN_DEG)
            angle_deg = mag * prng.choice([-1.0, 1.0])
        else:
            angle_deg = float(step.angle_deg)
        if step.axis is None:
            axis = unit(prng.standard_normal(3))
        else:
            axis = self.mounts[self.mounting - 1].inv().apply(np.array(step.axis, float))
        vertical = tl.att.inv().apply(EZ)  # body frame
        if np.degrees(np.arccos(np.clip(abs(axis @ vertical), 0.0, 1.0))) <= TABLE_TURN_DEG:
            axis = vertical * np.sign(axis @ vertical)  # on the table: it stays on its face
        else:
            self.face = None
        dur = max(self.opt["move_s"], 1.875 * abs(angle_deg) / PEAK_RATE_DPS)
        n = max(2, int(round(dur * self.opt["rate_hz"])) - 1)
        angle = np.radians(angle_deg)
        seg = tl.segment("rotation", tl.smooth_turn(axis, angle, n), **step.segment_attrs())
        self.turns.append({"segment": seg.name, "angle": angle, "axis": axis})


def simulate_steps(
    plan: Plan,
    seed: int = 0,
    rate_hz: float = 100.0,
    hold_s: float = 2.0,
    move_s: float = 1.5,
    lead_s: float = 1.0,
    units: str = "counts",
    accel_noise: float = 0.01,
    gyro_noise: float = 0.005,
    jitter_deg: float = 2.0,
    gravity: float = G0,
    created: str | None = None,
) -> tuple[Session, Calibration]:
    """Simulate the virtual IMU going through ``plan`` (see the module notes).

    Parameters
    ----------
    plan : Plan
        The steps (a registry plan or a TOML file).
    seed : int
        Non-negative seed; the same seed, plan and options give the same samples bit for bit.
    rate_hz, hold_s, move_s, lead_s : float
        Sample rate (Hz), hold per static step (s, at least 10 samples; a step's own
        ``hold_s`` wins), duration of each move (s), still time before the first step (s).
    units : {"counts", "m/s^2"}
        Raw units of the part (:func:`imucal_cli.simulate.sensor.random_imu`).
    accel_noise, gyro_noise : float
        White noise per axis per sample, m/s^2 and rad/s.
    jitter_deg : float
        RMS placement error of each labelled pose, degrees (<= 45).
    gravity : float
        Local gravity, m/s^2.
    created : str, optional
        ISO 8601 UTC creation time; default now.

    Returns
    -------
    session : Session
        One segment per step (label, ``up``/``axis``/``angle_deg`` and ``mounting`` as the
        step says).
    truth : Calibration
        ``matrix = inv(S)``, ``bias = b`` per sensor; ``accel``: ``segments``,
        ``true_up`` (unit, body frame) per static step, ``labelled_up``; ``gyro``:
        ``turn_segments``, ``true_angle_deg``, ``true_axis`` (body frame), ``true_rotvec``,
        ``mounting_rotvec_deg`` (sensor -> fixture, per mounting).
    """
    opt = _options(seed, rate_hz, hold_s, move_s, lead_s, units, accel_noise, gyro_noise,
                   jitter_deg, gravity)  # fmt: skip
    opt["plan"] = plan.name
    n_est = sum(
        samples(s.hold_s or opt["hold_s"] if s.kind == "static" else 4.0, opt["rate_hz"])
        + samples(opt["move_s"], opt["rate_hz"])
        for s in plan.steps
    )
    check_samples(n_est, "lower the rate, the hold or the number of steps")
    imu, pose_ss, noise_ss = draw_part(opt["seed"], units, opt["accel_noise"],
                                       opt["gyro_noise"])  # fmt: skip
    player = _Player(opt, np.random.default_rng(pose_ss))
    player.start(plan.steps)
    for i, step in enumerate(plan.steps):
        if step.mounting is not None and step.mounting != player.mounting:
            player.remount(step.mounting)
        if step.kind == "static":
            player.static(step)
        else:
            player.rotation(step)
            if i + 1 == len(plan.steps) or plan.steps[i + 1].kind != "static":
                player.tl.hold(player.n_hold)
    force, rate = player.tl.arrays()
    return imu.session_and_truth(
        {"accel": force, "gyro": rate}, player.tl.segments, noise_seed=noise_ss, options=opt,
        sensor=sensor_name(opt["seed"]), created=created, extras=_extras(player),
    )  # fmt: skip


def _extras(player: _Player) -> dict:
    segs = player.tl.segments
    static = [s for s in segs if s.kind == "static"]
    turns = player.turns
    angles = np.array([t["angle"] for t in turns])
    axes = np.array([t["axis"] for t in turns]).reshape(-1, 3)
    return {
        "accel": {
            "frame": "sensor frame (= the fixture frame in mounting 1)",
            "gravity": player.opt["gravity"],
            "jitter_deg": player.opt["jitter_deg"],
            "segments": [s.name for s in static],
            "labels": [s.label for s in static],
            "true_up": floats(unit(np.array(player.true_up).reshape(-1, 3))),
            "labelled_up": [None if s.up is None else floats(s.up) for s in static],
        },
        "gyro": {
            "frame": "sensor frame (= the fixture frame in mounting 1)",
            "turn_segments": [t["segment"] for t in turns],
            "true_angle_deg": floats(np.degrees(angles)),
            "true_axis": floats(axes),
            "true_rotvec": floats(angles[:, None] * axes),
            "true_rotvec_unit": "rad, sensor frame: R_after = R_before Exp(rotvec)",
            "mounting_rotvec_deg": [floats(np.degrees(r.as_rotvec())) for r in player.mounts],
        },
    }
