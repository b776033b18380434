"""The Hwangbo & Kanade gyroscope procedure (section IV-B, Fig. 3 (f)-(j), Fig. 5): a
gyroscope triad in a right-angle iron, swept sinusoidally by hand about the normals of three
orthogonal faces, in two mountings of the IMU in the iron, then turned 90 degrees along a
ruler.  The redundant accelerometer unit of section V is :mod:`.redundant`; randomness and
the returned ``(Session, Calibration)`` are as there.

Section IV-B, the gyroscope procedure
-------------------------------------
Frames: the *iron* frame (the fixture frame of the session's ``axis``/``up``) and the *sensor*
frame, the IMU housing.  Mounting ``m`` is the rotation ``M_m`` (sensor -> iron); mounting 1 is
the identity, so there the two frames agree; mounting 2, 3, ... are random rotations drawn from
the seed, far from the iron's symmetries and from each other.  Every event is separated by
``still_s`` of stillness, each a static segment; the segments are the steps of
:func:`imucal_cli.plans.hk_gyro_steps`:

0. with ``faces`` (plan ``hwangbo-iron``): the iron on each of its 6 faces in turn (labelled
   ``"face +Z up"``, ...), ``still_s`` each, for the accelerometer;
1. still, +Z up, mounting 1 (the biases);
2. for each mounting: for the face normals +Z, +X, +Y in turn, the iron is put on the opposite
   face (a smootherstep move of ``move_s``, unsegmented) and swept by hand about the vertical
   normal: rate ``normal * peak_rate * sin(2 pi t / (sweep_s / periods))`` for ``sweep_s``
   (``periods`` whole periods, so it ends where it started); the IMU is re-mounted between
   mountings (an unsegmented move);
3. back in mounting 1, +Z up, one ruler-guided turn of ``ruler_angle_deg`` about +Z with a
   smootherstep profile of ``turn_s``.

The attitude is integrated exactly (fixed-axis motions), so the accelerometer sees gravity turn
consistently; moves add no linear acceleration.  The earth rate is left out.

The session: raw accel and gyro (N, 3).  Static segments for the still periods, labelled
``"mounting 1: still, +Z up"``, with ``up`` (iron frame) in mounting 1 only (in other mountings
the sensor is not aligned with the iron).  Rotation segments for the sweeps, labelled
``"mounting 2: sweep about +Y"``, with ``axis`` = the face normal in the iron frame; the ruler
turn labelled ``"mounting 1: ruler-guided 90-degree turn about +Z"`` with ``axis`` and
``angle_deg``.  Orthogonality holds only between sweeps of one mounting: every segment has the
attribute ``mounting`` (int).  The truth: ``gyro``: ``matrix = inv(S_g)``, ``bias = b_g`` with
``S_g`` the sensitivity in the sensor frame (= the iron frame of mounting 1).  Extras:
``mounting_rotvec_deg`` (one rotation vector per mounting, sensor -> iron, degrees),
``segment_mounting`` (segment name -> mounting, every segment), ``sweep_axes_sensor`` (sweep
segment name -> unit axis in the sensor frame), ``ruler`` (segment, axes, angle), ``noise``.
``accel``: the accelerometer's truth in the same sensor frame.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import Calibration
from imucal_cli.model.truth import Ruler
from imucal_cli.plans import HK_FACES, hk_gyro_steps
from imucal_cli.simulate.motion import (
    Timeline,
    check_int,
    check_positive,
    check_samples,
    check_seed,
    draw_mountings,
    heading,
    move_samples,
    placed,
    samples,
    still_samples,
)
from imucal_cli.simulate.sensor import G0, draw_part, floats

__all__ = ["simulate_hk_gyro"]


def simulate_hk_gyro(
    seed: int = 0, mountings: int = 2, rate_hz: float = 100.0, sweep_s: float = 6.0,
    peak_rate: float = 2.0, still_s: float = 3.0, noise: float = 0.005, units: str = "counts",
    ruler_angle_deg: float = 90.0, created: str | None = None, periods: int = 3,
    accel_noise: float = 0.01, move_s: float = 1.5, turn_s: float = 2.0, gravity: float = G0,
    faces: bool = False,
) -> tuple[Session, Calibration]:  # fmt: skip
    """Simulate the gyroscope procedure of Hwangbo & Kanade, section IV-B (Fig. 3 f-j, Fig. 5).

    The part is :func:`imucal_cli.simulate.triad.random_imu` (16.4 LSB per deg/s gyroscope with
    1-3 % scale errors, axes off by up to 1 degree, bias up to 3 deg/s; plus its
    accelerometer), fixed in a right-angle iron in ``mountings`` ways and put through the
    procedure of the module notes (section IV-B): sweeps about three faces per mounting, then
    a ruler-guided turn.

    Parameters
    ----------
    seed : int
        Non-negative seed; the same seed and options draw the same random numbers (the samples are
        bit for bit the same on one machine, to the last bits of the arithmetic elsewhere).
    mountings : int
        Number of IMU mountings in the iron (1..8; the paper used 2).
    rate_hz : float
        Sample rate, Hz.
    sweep_s, periods : float, int
        Duration of each sinusoidal sweep, s, and the whole sine periods in it.
    peak_rate : float
        Peak angular rate of a sweep, rad/s (the swing is +-peak_rate * period / pi rad).
    still_s : float
        Duration of each still period, s (at least 10 samples).
    noise, accel_noise : float
        White noise per axis per sample (input-referred): gyroscope rad/s, accelerometer m/s^2.
    units : {"counts", "m/s^2"}
        Raw units of the part (``"rad/s"`` is accepted for ``"m/s^2"``): 16-bit counts, or a
        part of nominal gain 1 reading m/s^2 and rad/s.
    ruler_angle_deg, turn_s : float
        Signed angle of the ruler-guided turn, degrees (right hand about +Z), and its duration, s.
    created : str, optional
        ISO 8601 UTC creation time; default now.
    move_s : float
        Duration of each unsegmented move (turning the iron to a face, re-mounting), s.
    gravity : float
        Local gravity, m/s^2.
    faces : bool
        Begin with the 6 faces of the iron (plan ``hwangbo-iron``).

    Returns
    -------
    session : imucal_cli.formats.session.Session
    truth : imucal_cli.model.calibration.Calibration
        Both as the module notes say (section IV-B).

    Raises
    ------
    InputError
        A bad value.
    """
    opt = _hk_options(
        seed, mountings, rate_hz, sweep_s, peak_rate, still_s, noise, units, ruler_angle_deg,
        periods, accel_noise, move_s, turn_s, gravity, faces,
    )  # fmt: skip
    truth, pose_ss, noise_ss = draw_part(opt["seed"], opt["units"], opt["accel_noise"],
                                         opt["noise"])  # fmt: skip
    prng = np.random.default_rng(pose_ss)
    mounts = draw_mountings(prng, opt["mountings"])
    tl, sweep_axes, ruler_seg = _hk_timeline(opt, prng, mounts)
    force, rate = tl.arrays()
    assert len(force) == opt["n_total"], (len(force), opt["n_total"])
    del opt["n_total"]
    frame = "sensor frame (= the iron frame in mounting 1)"
    return truth.session_and_truth(
        {"accel": force, "gyro": rate}, tl.segments, noise_seed=noise_ss, options=opt,
        sensor=f"sim-16bit seed {opt['seed']} (hk-gyro)", created=created,
        extras={"accel": {"frame": frame, "gravity": opt["gravity"]},
                "gyro": _hk_gyro_extra(opt, frame, mounts, tl, sweep_axes, ruler_seg)},
    )  # fmt: skip


def _hk_gyro_extra(opt: dict, frame: str, mounts: list[Rotation], tl: Timeline,
                   sweep_axes: dict, ruler_seg: str) -> dict:  # fmt: skip
    """The gyro truth's record of the procedure (the module notes, section IV-B)."""
    return {
        "design": "Hwangbo & Kanade section IV-B: sweeps about 3 orthogonal iron faces per "
        "mounting, one ruler-guided turn",
        "frame": frame,
        "mounting_rotvec_deg": [floats(np.degrees(r.as_rotvec())) for r in mounts],
        "mounting_rotvec_note": "rotation vector of each mounting, sensor -> iron frame",
        "segment_mounting": {s.name: s.extra["mounting"] for s in tl.segments},
        "sweep_axes_sensor": sweep_axes,
        "peak_rate": opt["peak_rate"],
        "sweep_period_s": opt["sweep_s"] / opt["periods"],
        "ruler": Ruler(
            segment=ruler_seg,
            axis_iron=[0.0, 0.0, 1.0],
            axis_sensor=[0.0, 0.0, 1.0],
            angle_deg=opt["ruler_angle_deg"],
        ),
    }


def _hk_options(
    seed, mountings, rate_hz, sweep_s, peak_rate, still_s, noise, units, ruler_angle_deg,
    periods, accel_noise, move_s, turn_s, gravity, faces,
) -> dict:  # fmt: skip
    """The options of :func:`simulate_hk_gyro`, checked, as a JSON-ready dict (plus the
    sample count ``n_total``)."""
    opt = {
        "plan": "hwangbo-iron" if faces else "hk-gyro",
        "seed": check_seed(seed),
        "mountings": check_int("mountings", mountings, 1, 8),
        "rate_hz": check_positive("rate", rate_hz, "Hz"),
        "sweep_s": check_positive("sweep time", sweep_s, "s"),
        "peak_rate": check_positive("peak rate", peak_rate, "rad/s"),
        "still_s": check_positive("still time", still_s, "s"),
        "noise": check_positive("gyro noise", noise, "rad/s", allow_zero=True),
        "units": "m/s^2" if units == "rad/s" else units,
        "ruler_angle_deg": float(ruler_angle_deg),
        "periods": check_int("periods per sweep", periods, 1, 1000),
        "accel_noise": check_positive("accel noise", accel_noise, "m/s^2", allow_zero=True),
        "move_s": check_positive("move time", move_s, "s"),
        "turn_s": check_positive("turn time", turn_s, "s"),
        "gravity": check_positive("gravity", gravity, "m/s^2"),
    }
    if faces:
        opt["faces"] = True
    ruler, rate_hz, periods = opt["ruler_angle_deg"], opt["rate_hz"], opt["periods"]
    if not np.isfinite(ruler) or ruler == 0.0 or abs(ruler) > 180:
        raise InputError(f"ruler angle must be non-zero, within +-180 deg, got {ruler}")
    n_still = still_samples(opt["still_s"], rate_hz)
    n_sweep = samples(opt["sweep_s"], rate_hz) - 1  # interior samples: rate 0 at both ends
    if n_sweep < 4 * periods:
        raise InputError(
            f"sweep {sweep_s:g} s at {rate_hz:g} Hz is too short for {periods} periods"
        )
    m, n_move = opt["mountings"], move_samples(opt["move_s"], rate_hz)
    n_total = (
        n_still * (6 * m + 2)
        + n_sweep * 3 * m
        + n_move * (3 * m)
        + move_samples(opt["turn_s"], rate_hz)
        + (6 * (n_still + n_move) if faces else 0)
    )
    check_samples(n_total, "lower the rate, the sweep or still time, or the mountings")
    opt["n_total"] = n_total
    return opt


def _hk_timeline(opt: dict, prng: np.random.Generator, mounts: list[Rotation]):
    """The iron procedure (the module notes, steps 0-3): returns the timeline, the sweep axes
    in the sensor frame per segment, and the ruler turn's segment name."""
    eye = np.eye(3)
    ez = eye[2]
    rate_hz = opt["rate_hz"]
    n_still = samples(opt["still_s"], rate_hz)
    n_sweep = samples(opt["sweep_s"], rate_hz) - 1
    n_move = move_samples(opt["move_s"], rate_hz)
    faces = opt.get("faces", False)
    steps = iter(hk_gyro_steps(opt["mountings"], faces, opt["ruler_angle_deg"]))
    sweep_axes: dict[str, list[float]] = {}

    def iron_pose(face: int, sign: float = 1.0) -> Rotation:
        return placed(sign * eye[face], heading(prng))  # the iron stands square: no tilt

    def still() -> None:
        tl.segment("static", tl.hold(n_still), **next(steps).segment_attrs())

    def sweep(axis_sensor) -> str:
        span = tl.turn(axis_sensor, theta, dtheta)
        return tl.segment("rotation", span, **next(steps).segment_attrs()).name

    tl = None
    if faces:  # 0. the iron on its 6 faces, mounting 1 (the accelerometer)
        for face, sign in ((f, s) for f in (2, 0, 1) for s in (1.0, -1.0)):
            pose = iron_pose(face, sign) * mounts[0]
            if tl is None:
                tl = Timeline(rate_hz, opt["gravity"], pose)
            else:
                tl.move(pose, n_move)
            still()
        tl.move(iron_pose(2) * mounts[0], n_move)
    else:
        tl = Timeline(rate_hz, opt["gravity"], iron_pose(2) * mounts[0])
    # 1. initial still, mounting 1, +Z up.
    still()
    # 2. sweeps about three orthogonal face normals, per mounting.
    omega = 2.0 * np.pi * opt["periods"] / opt["sweep_s"]
    t_sweep = np.arange(1, n_sweep + 1) / rate_hz
    theta = opt["peak_rate"] / omega * (1.0 - np.cos(omega * t_sweep))
    dtheta = opt["peak_rate"] * np.sin(omega * t_sweep)
    for m, mount in enumerate(mounts, start=1):
        for k, (face, _) in enumerate(HK_FACES):
            if m > 1 or k > 0:
                tl.move(iron_pose(face) * mount, n_move)
                still()
            axis_sensor = mount.as_matrix().T @ eye[face]
            sweep_axes[sweep(axis_sensor)] = floats(axis_sensor)
            still()
    # 3. ruler-guided turn in mounting 1, +Z up.
    tl.move(iron_pose(2) * mounts[0], n_move)
    still()
    n_turn = move_samples(opt["turn_s"], rate_hz)
    span = tl.smooth_turn(ez, np.radians(opt["ruler_angle_deg"]), n_turn)
    ruler = tl.segment("rotation", span, **next(steps).segment_attrs()).name
    still()
    return tl, sweep_axes, ruler
