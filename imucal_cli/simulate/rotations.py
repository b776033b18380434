"""Hand rotations for gyroscope calibration (Qureshi & Golnaraghi, section III-B, IV-B.2).

The virtual experiment of the paper's gyroscope calibration (Fig. 2): the unit is turned by
hand, smoothly, about each of its sensitive axes in turn, ``rotations_per_axis`` times per axis
(18 in the paper), every turn a different angle within +-180 degrees, with the unit held still
for ``still_s`` (5 s in the paper) before and after each turn.  The accelerometer sees each
turn through gravity only if the turn axis is horizontal, so:

* x and y turns: the unit starts flat, +Z up, and is turned about its x (then y) axis;
* z turns: the unit is first laid on its side, +X up (the paper's "rotate the coordinate axes
  90 degrees around y"), so that z is horizontal, and turned about z.

Plan ``free:N`` instead turns the unit N times about random axes (uniform on the sphere) by
random angles: arbitrary hand rotations for the full 12-parameter gyroscope model.

:func:`simulate_gyro_rotations` returns ``(Session, Calibration)`` like
:func:`imucal_cli.simulate.triad.simulate`.  The part is
:func:`imucal_cli.simulate.triad.random_imu`
drawn from the same spawned generator, so a seed gives the same physical part (accelerometer
and gyroscope, both relative to the fixture frame) as ``imucal simulate --plan qureshi18`` with
that seed: one seed can calibrate the accelerometer from a pose session and then the gyroscope
from a rotation session.

Frames: world (z up), body = fixture frame; the attitude ``R`` maps body to world.  Each turn is
about a fixed axis ``u`` (body frame) with angle profile ``theta(t)``, so the attitude
``R(t) = R0 Exp(theta(t) u)`` and the body rate ``theta'(t) u`` are exact in closed form; the
accelerometer reads ``R(t)^T (0, 0, g)`` (no linear acceleration: the unit turns about its own
centre) and the gyroscope the body rate.  The earth rate is left out.

The turns (:func:`simulate_gyro_rotations`).  Plan ``qureshi-axes`` (Qureshi & Golnaraghi,
Fig. 2; III-B; IV-B.2): for the x, then y axis the unit is placed flat, +Z up, and turned
``rotations_per_axis`` times about that axis; for z it is laid on its side, +X up, and turned
about z.  Each starting pose is the labelled one tilted by a random horizontal rotation vector
(RMS angle ``jitter_deg``) at a random heading; the move that lays the unit on the next starting
face (``MOVE_S``, a smootherstep slerp) is not a segment.  Turn angles are uniform within +-180
degrees, at least 20 degrees in magnitude and at least ~10 degrees from each other on one axis.
The hand turns about the nominal body axis, steered half-way back to level (:data:`LEVELLING`),
tilted by a random error perpendicular to it (RMS angle ``axis_jitter_deg``, fresh for every
turn): the true axis is a few degrees off the body axis (recorded in the truth), and the body
axis stays within about 10 degrees of level.  Plan ``free:N``: the unit starts flat, +Z up
(with placement jitter), then N turns about body axes uniform on the sphere by angles within
+-180 degrees (|angle| >= 20 degrees).

Every turn has a smootherstep angle profile (zero rate and angular acceleration at both ends);
its peak rate is drawn uniformly in 50-100 % of ``peak_rate_dps`` and sets the duration (at
least ``MIN_TURN_S``; the duration is then rounded to whole samples, and the true peak rate is
recomputed and recorded).  ``still_s`` of stillness comes before the first turn, between turns
(the still after one turn is the still before the next) and after the last.

The session: raw accel and gyro (N, 3).  Segments in time order, alternating: a static segment
per still period, labelled ``"still before x turn 3"`` (``"still after x turn 18"`` for the
last of an axis; ``"still before turn 3"`` for free:N), with ``up`` only on the first still of
each starting face (``[0, 0, 1]`` or ``[1, 0, 0]``, labelled ``"still before z turn 1, +X
up"``); and a rotation segment per turn spanning its moving samples, labelled ``"turn 3 about
x"`` with ``axis`` = the nominal body axis (qureshi-axes), or ``"turn 3"`` without ``axis``
(free:N).  No segment has ``angle_deg``: the angle is unknown to the person; the accelerometer
measures it.

The truth: ``accel`` and ``gyro``: ``matrix = inv(S)``, ``bias = b`` (fixture frame), as
:func:`imucal_cli.simulate.triad.truth_calibration`.  ``gyro``
(:class:`~imucal_cli.model.truth.GyroTruth`): per turn, in order, ``turn_segments`` (segment
names), ``turn_labels``, ``turn_axis_names`` (qureshi-axes: x/y/z), ``true_angle_deg``,
``true_axis`` (unit, body frame), ``true_rotvec`` (rad, body frame: ``R_after = R_before
Exp(rotvec)``), ``nominal_axis`` (or None), ``axis_error_deg``, ``peak_rate_dps``,
``duration_s``; ``noise``.  ``accel`` (:class:`~imucal_cli.model.truth.AccelTruth`): per still,
``segments``, ``labels``, ``true_up`` (unit, fixture frame), ``labelled_up`` (or None);
``noise``, ``gravity``.
"""

from __future__ import annotations

import re

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import Calibration
from imucal_cli.plans import load_plan
from imucal_cli.simulate.clock import clocked
from imucal_cli.simulate.motion import (
    EZ,
    Timeline,
    check_jitter,
    check_positive,
    check_samples,
    check_seed,
    move_samples,
    place,
    samples,
    still_samples,
    unit,
)
from imucal_cli.simulate.sensor import G0, check_units, draw_part, floats
from imucal_cli.simulate.temperature import Ramp, ramp_part
from imucal_cli.simulate.triad import sensor_name

__all__ = [
    "LEVELLING",
    "MAX_PEAK_RATE_DPS",
    "MIN_TURN_DEG",
    "SMOOTHERSTEP_PEAK",
    "is_gyro_plan",
    "parse_gyro_plan",
    "simulate_gyro_rotations",
]

SMOOTHERSTEP_PEAK = 1.875
"""Peak of the smootherstep rate ``30 tau^2 (1 - tau)^2``: peak rate = 1.875 angle / duration."""

MIN_TURN_DEG = 20.0
"""Smallest turn magnitude, degrees: smaller turns carry little scale information."""

MIN_SEPARATION_DEG = 10.0
"""Turns about one axis differ by at least this much (fewer if many turns are asked for)."""

MAX_PEAK_RATE_DPS = 1000.0
"""Largest ``peak_rate_dps`` accepted: half the +-2000 deg/s range of the simulated gyro."""

MIN_TURN_S = 0.5
"""Shortest turn, s: a hand does not flick the unit faster, whatever the peak rate allows."""

PEAK_FRACTION = (0.5, 1.0)
"""Each turn's peak rate is uniform in this fraction of ``peak_rate_dps``."""

MOVE_S = 2.0
"""Duration of the unsegmented move that lays the unit on the next starting face, s."""

MAX_TURNS = 1000

LEVELLING = 0.5
"""qureshi-axes: the hand aims each turn at the body axis steered this fraction of the way back
to level (a person keeps the axis roughly horizontal), then misses by ``axis_jitter_deg``.
Without it the axis errors of successive turns would walk the axis up to 30 degrees from level
over 18 turns; with it the axis stays within about 10 degrees."""

_FREE_RE = re.compile(r"free(?::(\d+))?")
_AXIS_NAMES = "xyz"
# (axis index, nominal up of the starting face, its label) for plan qureshi-axes
_QURESHI_AXES = ((0, 2, "+Z"), (1, 2, "+Z"), (2, 0, "+X"))


def is_gyro_plan(plan: str) -> bool:
    """True when ``plan`` names a plan of this module (``qureshi-axes``, ``free``, ``free:N``)."""
    name = plan.strip().lower()
    return name == "qureshi-axes" or _FREE_RE.fullmatch(name) is not None


def parse_gyro_plan(plan: str, count: int | None = None) -> tuple[str, int | None]:
    """Split a plan name into its kind and the number of free rotations.

    Parameters
    ----------
    plan : str
        ``qureshi-axes``, ``free:N``, or ``free`` together with ``count``.
    count : int, optional
        Number of free rotations; must agree with N when both are given.

    Returns
    -------
    kind : {"qureshi-axes", "free"}
    n : int or None
        Number of free rotations (None for qureshi-axes).

    Raises
    ------
    InputError
        Unknown plan, missing or bad N.
    """
    name = plan.strip().lower()
    if name == "qureshi-axes":
        if count is not None:
            raise InputError("plan qureshi-axes takes rotations_per_axis, not count")
        return "qureshi-axes", None
    m = _FREE_RE.fullmatch(name)
    if m is None:
        raise InputError(f"plan {plan!r} is unknown: use qureshi-axes or free:N (N rotations)")
    n = None if m.group(1) is None else int(m.group(1))
    if count is not None:
        if isinstance(count, bool) or not isinstance(count, int | np.integer):
            raise InputError(f"count must be an integer, got {count!r}")
        if n is not None and n != int(count):
            raise InputError(f"plan {plan!r} and count {count} disagree")
        n = int(count)
    if n is None:
        raise InputError(f"plan {plan!r}: say how many rotations, e.g. free:12")
    if not 1 <= n <= MAX_TURNS:
        raise InputError(f"plan {plan!r}: N must be between 1 and {MAX_TURNS}")
    return "free", n


def _draw_angles_deg(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` turn angles uniform within +-180 deg, |angle| >= 20, pairwise >= ~10 deg apart.

    Sequential draws with rejection; the separation is ``min(10, 192 / n)`` degrees, which
    keeps the packing below the jamming density of random sequential adsorption, so the draws
    always finish.
    """
    sep = min(MIN_SEPARATION_DEG, 192.0 / n)
    out: list[float] = []
    while len(out) < n:
        a = rng.uniform(MIN_TURN_DEG, 180.0) * rng.choice([-1.0, 1.0])
        if all(abs(a - b) >= sep for b in out):
            out.append(float(a))
    return np.array(out)


def _tilt_perpendicular(rng: np.random.Generator, axis: np.ndarray, rms_deg: float) -> Rotation:
    """A small rotation about a random direction perpendicular to ``axis``, RMS ``rms_deg``.

    Two iid normal components (std ``rms_deg / sqrt(2)``) in the plane perpendicular to
    ``axis``, so the RMS angle is ``rms_deg``.  Draws 2 numbers.
    """
    p = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    p = unit(p)
    q = np.cross(axis, p)
    c = rng.standard_normal(2) * np.radians(rms_deg) / np.sqrt(2.0)
    return Rotation.from_rotvec(c[0] * p + c[1] * q)


def _towards_level(att: Rotation, axis: np.ndarray, fraction: float) -> np.ndarray:
    """Body ``axis`` turned ``fraction`` of the way to its level (horizontal) direction.

    ``att`` maps body to world (z up).  Returns a unit vector in the body frame.
    """
    w = att.apply(axis)
    level = np.array([w[0], w[1], 0.0])
    if np.linalg.norm(level) < 1e-9:  # vertical axis: no level direction to aim at
        return np.asarray(axis, dtype=float)
    level = unit(level)
    cross = np.cross(w, level)
    s = np.linalg.norm(cross)
    if s < 1e-15:
        return np.asarray(axis, dtype=float)
    angle = np.arctan2(s, float(w @ level))
    aim = Rotation.from_rotvec(cross / s * angle * fraction).apply(w)
    return unit(att.inv().apply(aim))


def simulate_gyro_rotations(
    plan: str = "qureshi-axes", seed: int = 0, rate_hz: float = 100.0,
    rotations_per_axis: int = 18, peak_rate_dps: float = 150.0, still_s: float = 5.0,
    accel_noise: float = 0.01, gyro_noise: float = 0.005, jitter_deg: float = 2.0,
    axis_jitter_deg: float = 2.0, units: str = "counts", gravity: float = G0,
    created: str | None = None, count: int | None = None, temperature: Ramp | None = None,
    clock_scale: float | None = None,
) -> tuple[Session, Calibration]:  # fmt: skip
    """Simulate hand rotations for gyroscope calibration; return the session and its truth.

    The turns, their placement, axes, angles and rates are the module notes'.

    Parameters
    ----------
    plan : str
        ``qureshi-axes``, ``free:N``, or ``free`` with ``count``.
    seed : int
        Non-negative seed; the same seed and options draw the same random numbers (the samples are
        bit for bit the same on one machine, to the last bits of the arithmetic elsewhere).  The
        part is the one :func:`imucal_cli.simulate.triad.simulate` draws for this seed.
    rate_hz, still_s : float
        Sample rate, Hz; still period before and after each turn, s (at least 10 samples).
    rotations_per_axis : int
        qureshi-axes: turns per axis (1..1000; the paper used 18).
    peak_rate_dps : float
        Largest peak rate of a turn, deg/s (<= 1000; the paper kept hand turns under 150).
    accel_noise, gyro_noise : float
        White noise per axis per sample: accelerometer m/s^2, gyroscope rad/s.
    jitter_deg, axis_jitter_deg : float
        RMS placement error of each starting face, and RMS angle between each turn's true axis
        and its nominal body axis (qureshi-axes), degrees (<= 45 each).
    units : {"counts", "m/s^2"}
        Raw units of the part (see :func:`imucal_cli.simulate.triad.random_imu`).
    gravity : float
        Local gravity, m/s^2.
    created : str, optional
        ISO 8601 UTC creation time; default now.
    count : int, optional
        Number of turns of plan ``free`` (the N of ``free:N``; both may be given if equal).
    temperature : Ramp, optional
        The part's temperature through the session: its biases follow it and the reading is
        recorded (:func:`~imucal_cli.simulate.temperature.ramp_part`).
    clock_scale : float, optional
        The part's clock runs this many device seconds per true second: device times and
        the host's arrival times are recorded (:mod:`imucal_cli.simulate.clock`).

    Returns
    -------
    session : imucal_cli.formats.session.Session
    truth : imucal_cli.model.calibration.Calibration
        Both as the module notes say.

    Raises
    ------
    InputError
        A bad plan, unit or value.
    """
    kind, n_free = parse_gyro_plan(plan, count)
    opt = _gyro_options(
        kind, n_free, seed, rate_hz, rotations_per_axis, peak_rate_dps, still_s,
        accel_noise, gyro_noise, jitter_deg, axis_jitter_deg, units, gravity,
    )  # fmt: skip
    truth, pose_ss, noise_ss = draw_part(opt["seed"], units, opt["accel_noise"],
                                         opt["gyro_noise"])  # fmt: skip
    groups = _START_FACES[kind]
    starts, timed = _draw_turns(np.random.default_rng(pose_ss), groups, opt)
    n_total = _turn_samples(opt, timed)
    tl, rec, stills = _turn_timeline(opt, groups, starts, timed)
    force, rate = tl.arrays()
    assert len(force) == n_total, (len(force), n_total)
    truth, thermal = ramp_part(truth, temperature, np.arange(n_total) / opt["rate_hz"], opt)
    session, cal = truth.session_and_truth(
        {"accel": force, "gyro": rate}, tl.segments, noise_seed=noise_ss, options=opt,
        sensor=sensor_name(opt["seed"]), created=created, root={"jitter_deg": opt["jitter_deg"]},
        extras={"accel": _still_record(tl, stills, opt, truth.mount_rotvec),
                "gyro": {"design": _DESIGN[kind], **_turn_record(rec, opt)}},
        temperature=thermal,
    )  # fmt: skip
    return clocked(session, cal, clock_scale, opt["seed"]), cal


_START_FACES = {  # per starting face: the axis turned about (None: any), nominal up, its label
    "qureshi-axes": [(_AXIS_NAMES[i], face, label) for i, face, label in _QURESHI_AXES],
    "free": [(None, 2, "+Z")],
}

_DESIGN = {
    "qureshi-axes": "Qureshi & Golnaraghi Fig. 2: turns about x and y with +Z up, about z with "
    "+X up",
    "free": "hand turns about random axes (uniform on the sphere)",
}


def _gyro_options(
    kind, n_free, seed, rate_hz, rotations_per_axis, peak_rate_dps, still_s,
    accel_noise, gyro_noise, jitter_deg, axis_jitter_deg, units, gravity,
) -> dict:  # fmt: skip
    """The options of :func:`simulate_gyro_rotations`, checked, as a JSON-ready dict."""
    seed = check_seed(seed)
    check_units(units)
    rate_hz = check_positive("rate", rate_hz, "Hz")
    if kind == "qureshi-axes":
        r = rotations_per_axis
        if isinstance(r, bool) or not isinstance(r, int | np.integer) or not 1 <= r <= MAX_TURNS:
            raise InputError(f"rotations per axis must be an integer in 1..{MAX_TURNS}, got {r!r}")
        rotations_per_axis = int(r)
    peak_rate_dps = check_positive("peak rate", peak_rate_dps, "deg/s")
    if peak_rate_dps > MAX_PEAK_RATE_DPS:
        raise InputError(f"peak rate must be at most {MAX_PEAK_RATE_DPS:g} deg/s")
    opt = {
        "plan": "qureshi-axes" if kind == "qureshi-axes" else f"free:{n_free}",
        "seed": seed,
        "rate_hz": rate_hz,
        "rotations_per_axis": rotations_per_axis if kind == "qureshi-axes" else None,
        "count": n_free,
        "peak_rate_dps": peak_rate_dps,
        "still_s": check_positive("still time", still_s, "s"),
        "accel_noise": check_positive("accel noise", accel_noise, "m/s^2", allow_zero=True),
        "gyro_noise": check_positive("gyro noise", gyro_noise, "rad/s", allow_zero=True),
        "jitter_deg": check_positive("jitter", jitter_deg, "deg", allow_zero=True),
        "axis_jitter_deg": check_positive("axis jitter", axis_jitter_deg, "deg", allow_zero=True),
        "units": units,
        "gravity": check_positive("gravity", gravity, "m/s^2"),
        "move_s": MOVE_S,
    }
    check_jitter(opt, ("jitter", "jitter_deg"), ("axis jitter", "axis_jitter_deg"))
    still_samples(opt["still_s"], rate_hz)
    return opt


def _turn_samples(opt: dict, timed: list) -> int:
    """Samples of the session: per starting face a still before every turn and one after the
    last, the turns, and the moves between the faces; refused beyond the largest session."""
    n_still = samples(opt["still_s"], opt["rate_hz"])
    n_total = sum(n_still * (len(t) + 1) + sum(x[3] for x in t) for t in timed)
    n_total += move_samples(MOVE_S, opt["rate_hz"]) * (len(timed) - 1)
    check_samples(n_total, "lower the rate, the still time or the number of rotations")
    return n_total


def _draw_turns(prng: np.random.Generator, groups: list, opt: dict) -> tuple[list, list]:
    """The plan, drawn from the pose generator in a fixed order: per starting face its
    placement, then the angles, then per turn the axis error and the peak rate.

    Returns the starting attitudes and, per group, a list of (nominal axis or None, true unit
    axis (body), angle rad, n interior samples, duration s).
    """
    eye = np.eye(3)
    starts, timed = [], []
    for axis_name, face, _ in groups:
        att = place(prng, eye[face], opt["jitter_deg"])
        starts.append(att)
        if axis_name is not None:
            nominal = eye[_AXIS_NAMES.index(axis_name)]
            angles = np.radians(_draw_angles_deg(prng, opt["rotations_per_axis"]))
        else:
            nominal = None
            angles = np.radians(prng.uniform(MIN_TURN_DEG, 180.0, opt["count"]))
            angles *= prng.choice([-1.0, 1.0], opt["count"])
        out = []
        for a in angles:
            if nominal is not None:
                aim = _towards_level(att, nominal, LEVELLING)
                u = unit(_tilt_perpendicular(prng, aim, opt["axis_jitter_deg"]).apply(aim))
            else:
                u = unit(prng.standard_normal(3))
            peak = np.radians(opt["peak_rate_dps"]) * prng.uniform(*PEAK_FRACTION)
            dur = max(SMOOTHERSTEP_PEAK * abs(a) / peak, MIN_TURN_S)
            n = max(2, int(round(dur * opt["rate_hz"])) - 1)
            out.append((nominal, u, float(a), n, (n + 1) / opt["rate_hz"]))
            att = att * Rotation.from_rotvec(a * u)
        timed.append(out)
    return starts, timed


def _turn_timeline(opt, groups, starts, timed):
    """The motion: per starting face a move to it (after the first), then still, turn,
    still, ...; each segment is the registry plan's step (:func:`imucal_cli.plans.load_plan`).
    Returns the timeline, the per-turn record and (true up, labelled up) of each still."""
    steps = iter(load_plan(opt["plan"] if opt["count"] else f"qureshi-axes:"
                           f"{opt['rotations_per_axis']}").steps)  # fmt: skip
    n_still = samples(opt["still_s"], opt["rate_hz"])
    n_move = move_samples(MOVE_S, opt["rate_hz"])
    tl = Timeline(opt["rate_hz"], opt["gravity"], starts[0])
    stills: list[tuple[np.ndarray, list[float] | None]] = []
    rec = {k: [] for k in ("seg", "label", "axis_name", "angle", "axis", "nominal", "peak", "dur")}

    def still() -> None:
        seg = tl.segment("static", tl.hold(n_still), **next(steps).segment_attrs())
        stills.append((tl.att.inv().apply(EZ), None if seg.up is None else floats(seg.up)))

    for g, ((axis_name, _, _), turns) in enumerate(zip(groups, timed, strict=True)):
        if g > 0:  # lay the unit on the next starting face (unsegmented move)
            tl.move(starts[g], n_move)
        for nominal, u, a, n, dur in turns:
            still()
            seg = tl.segment("rotation", tl.smooth_turn(u, a, n), **next(steps).segment_attrs())
            for key, value in zip(
                rec, (seg.name, seg.label, axis_name, a, u, nominal,
                      SMOOTHERSTEP_PEAK * abs(a) / dur, dur), strict=True,
            ):  # fmt: skip
                rec[key].append(value)
        still()
    return tl, rec, stills


def _still_record(tl: Timeline, stills: list, opt: dict, mount_rotvec: np.ndarray) -> dict:
    """The accel truth's per-still record (the module notes)."""
    static = [s for s in tl.segments if s.kind == "static"]
    return {
        "frame": "fixture (body) frame",
        "gravity": opt["gravity"],
        "mount_rotvec_deg": floats(np.degrees(mount_rotvec)),
        "jitter_deg": opt["jitter_deg"],
        "segments": [s.name for s in static],
        "labels": [s.label for s in static],
        "true_up": floats(unit(np.array([u for u, _ in stills]))),
        "labelled_up": [lab for _, lab in stills],
    }


def _turn_record(rec: dict, opt: dict) -> dict:
    """The gyro truth's per-turn record (the module notes)."""
    angles = np.array(rec["angle"])
    axes = np.array(rec["axis"])
    axis_err = [
        None if nom is None else float(np.degrees(np.arccos(np.clip(nom @ u, -1.0, 1.0))))
        for nom, u in zip(rec["nominal"], rec["axis"], strict=True)
    ]
    return {
        "frame": "fixture (body) frame",
        "turn_segments": rec["seg"],
        "turn_labels": rec["label"],
        "turn_axis_names": rec["axis_name"],
        "true_angle_deg": floats(np.degrees(angles)),
        "true_axis": floats(axes),
        "true_rotvec": floats(angles[:, None] * axes),
        "true_rotvec_unit": "rad, body (fixture) frame: R_after = R_before Exp(rotvec)",
        "nominal_axis": [None if v is None else floats(v) for v in rec["nominal"]],
        "axis_error_deg": axis_err,
        "peak_rate_dps": floats(np.degrees(rec["peak"])),
        "duration_s": floats(rec["dur"]),
        "axis_jitter_deg": opt["axis_jitter_deg"],
    }
