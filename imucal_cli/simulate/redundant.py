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
sweep about +Y"``); the truth repeats the mapping (``gyro.segment_mounting``).

Section V, the redundant unit's session and truth
-------------------------------------------------
The session: ``accel_units="counts"``, ``/raw/accel`` (N, 4), no gyro; one static segment per
orientation labelled ``"orientation 7"`` (1-based), or the pose name (``"face +Z up"``) with
``up`` when labelled.  The truth: an accel section only, ``matrix`` (3, 4) = 9.80665 *
pinv(S^T) with ``S`` (3, 4) the sensitivity axes in counts per g as columns, ``bias`` (4,)
counts; so ``matrix @ (raw - bias)`` is the specific force in m/s^2.  Extras:
``S_counts_per_g``, ``gains_V_per_g``, ``bias_V``, ``angles_deg`` (Table I order),
``noise_counts``, ``quantisation_counts``, ``noise_total_counts``, ``counts_per_volt``,
``true_up`` (one unit vector per orientation, in segment order), ``segments``, ``labels``.

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

import itertools

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import Calibration
from imucal_cli.model.truth import Ruler
from imucal_cli.plans import HK_FACES, hk_gyro_steps, plan_poses
from imucal_cli.simulate.motion import (
    MAX_SAMPLES,
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
    unit,
)
from imucal_cli.simulate.sensor import G0, ChannelGroup, Imu, draw_part, floats, spawn

__all__ = [
    "ADC_MAX",
    "ADC_VOLTS",
    "COUNTS_PER_VOLT",
    "NOMINAL_AXES",
    "QUANTISATION_COUNTS",
    "pairwise_angles_deg",
    "simulate_hk_gyro",
    "simulate_redundant_accel",
]

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
    u = unit(np.asarray(S, dtype=float).T)
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
        p = unit(np.cross(u, rng.standard_normal(3)))
        tilt = np.radians(rng.uniform(0.0, max_deg))
        out[:, j] = np.cos(tilt) * u + np.sin(tilt) * p
    return out


# --------------------------------------------------------------------------------------------
# Section V: the redundant accelerometer unit
# --------------------------------------------------------------------------------------------


def simulate_redundant_accel(
    seed: int = 0, sigma_counts: float = 0.7, orientations: int | None = None,
    samples: int = 10, rate_hz: float = 50.0, labelled: bool = False, gravity: float = G0,
    created: str | None = None, perturb: bool = False, gap_s: float = 2.0,
) -> tuple[Session, Calibration]:  # fmt: skip
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
    truth : imucal_cli.model.calibration.Calibration
        Both as the module notes say (section V).

    Raises
    ------
    InputError
        A bad value, or more than 18 labelled orientations.
    """
    opt = _redundant_options(seed, sigma_counts, orientations, samples, rate_hz, labelled,
                             gravity, perturb, gap_s)  # fmt: skip
    k_poses, samples = opt["orientations"], opt["samples"]
    truth_ss, pose_ss, noise_ss = spawn(opt["seed"])
    group, gains, bias_v = _redundant_part(truth_ss, perturb, opt["sigma_counts"])
    labels, up = _orientations(opt, pose_ss)
    tl = Timeline(opt["rate_hz"], opt["gravity"], Rotation.identity())
    for k in range(k_poses):
        span = (k * samples, (k + 1) * samples)
        tl.segment("static", span, labels[k], up=up[k] if labelled else None)
    f_g = np.repeat(up * (opt["gravity"] / G0), samples, axis=0)  # (N, 3) in g
    extra = _redundant_extra(opt, group, gains, bias_v)
    extra.update(segments=[s.name for s in tl.segments], labels=labels, true_up=floats(up))
    return Imu(groups=(group,)).session_and_truth(
        {"accel": f_g}, tl.segments, noise_seed=noise_ss, options=opt, time=_hold_times(opt),
        sensor=f"sim-hk-redundant (2 x dual-axis, 45 deg) seed {opt['seed']}",
        extras={"accel": extra}, created=created,
    )  # fmt: skip


def _orientations(opt: dict, pose_ss) -> tuple[list[str], np.ndarray]:
    """Labels and true up directions (K, 3) of the orientations: the iron's first poses when
    labelled (nothing drawn), else random directions from the pose generator."""
    k_poses = opt["orientations"]
    if opt["labelled"]:
        poses = plan_poses("qureshi18")[:k_poses]
        return [label for label, _ in poses], np.array([u for _, u in poses], dtype=float)
    up = unit(np.random.default_rng(pose_ss).standard_normal((k_poses, 3)))
    return [f"orientation {k + 1}" for k in range(k_poses)], up


def _hold_times(opt: dict) -> np.ndarray:
    """Sample times: ``samples`` per hold at ``rate_hz``, holds ``gap_s`` apart, s."""
    samples, rate_hz = opt["samples"], opt["rate_hz"]
    hold_s = samples / rate_hz
    return (
        np.arange(opt["orientations"])[:, None] * (hold_s + opt["gap_s"])
        + np.arange(samples)[None, :] / rate_hz
    ).ravel()


def _redundant_extra(opt: dict, group: ChannelGroup, gains, bias_v) -> dict:
    """The accel truth's record of the redundant part (the module notes, section V)."""
    S = group.S.T  # (3, 4) counts per g, columns s_j
    return {
        "design": "Hwangbo & Kanade section V: two dual-axis accelerometers, n = 4, 45 deg",
        "gravity": opt["gravity"],
        "g_unit": "standard gravity 9.80665 m/s^2 (of V/g and counts per g)",
        "S_counts_per_g": floats(S),
        "S_layout": "3 x 4, column j = gain_j * counts_per_volt * unit sensitivity axis s_j",
        "gains_V_per_g": floats(gains),
        "bias_V": floats(bias_v),
        "angles_deg": pairwise_angles_deg(S),
        "counts_per_volt": COUNTS_PER_VOLT,
        "adc_range_counts": [0, ADC_MAX],
        "adc_range_V": [0.0, ADC_VOLTS],
        "noise_counts": opt["sigma_counts"],
        "quantisation_counts": float(QUANTISATION_COUNTS),
        "noise_total_counts": float(np.hypot(opt["sigma_counts"], QUANTISATION_COUNTS)),
        "noise_unit": "counts per channel per sample (Gaussian before rounding; rounding adds "
        "about 1/sqrt(12))",
        "perturbed": bool(opt["perturb"]),
    }


def _redundant_options(seed, sigma_counts, orientations, samples, rate_hz, labelled, gravity,
                       perturb, gap_s) -> dict:  # fmt: skip
    """The options of :func:`simulate_redundant_accel`, checked, as a JSON-ready dict."""
    opt = {
        "plan": "hk-redundant",
        "seed": check_seed(seed),
        "sigma_counts": check_positive("sigma", sigma_counts, "counts", allow_zero=True),
    }
    rate_hz = check_positive("rate", rate_hz, "Hz")
    gravity = check_positive("gravity", gravity, "m/s^2")
    gap_s = check_positive("gap", gap_s, "s", allow_zero=True)
    samples = check_int("samples per orientation", samples, 1, MAX_SAMPLES)
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
    k_poses = check_int("orientations", orientations, 1, MAX_ORIENTATIONS)
    n_total = k_poses * samples
    if n_total > MAX_SAMPLES:
        raise InputError(f"{n_total} samples (more than {MAX_SAMPLES}): fewer samples please")
    opt.update(orientations=k_poses, samples=samples, rate_hz=rate_hz, labelled=bool(labelled),
               gravity=gravity, perturb=bool(perturb), gap_s=gap_s)  # fmt: skip
    return opt


def _redundant_part(
    truth_ss, perturb: bool, sigma_counts: float
) -> tuple[ChannelGroup, np.ndarray, np.ndarray]:
    """The redundant unit as a channel group (input in g, ADC counts out, ``sigma_counts``
    output noise), its gains (V/g) and biases (V).  The nominal part draws nothing;
    ``perturb`` draws gains, biases and axis tilts from the truth generator."""
    axes = NOMINAL_AXES.copy()
    gains = np.full(4, NOMINAL_GAIN_V_PER_G)
    bias_v = np.full(4, NOMINAL_BIAS_V)
    if perturb:
        trng = np.random.default_rng(truth_ss)
        gains = gains * (1.0 + trng.uniform(-PERTURB_GAIN_MAX, PERTURB_GAIN_MAX, 4))
        bias_v = bias_v + trng.uniform(-PERTURB_BIAS_MAX_V, PERTURB_BIAS_MAX_V, 4)
        axes = _lean(trng, axes, PERTURB_TILT_MAX_DEG)
    S = COUNTS_PER_VOLT * axes * gains  # (3, 4) counts per g, columns s_j
    group = ChannelGroup(
        name="accel",
        input_unit="g",
        units="counts",
        S=S.T,
        b=COUNTS_PER_VOLT * bias_v,
        noise_out=sigma_counts,
        nominal=COUNTS_PER_VOLT * NOMINAL_GAIN_V_PER_G,
        quantise=True,
        limits=(0.0, float(ADC_MAX)),
        scale_error=gains / NOMINAL_GAIN_V_PER_G - 1.0,
    )
    return group, gains, bias_v


# --------------------------------------------------------------------------------------------
# Section IV-B: the gyroscope procedure
# --------------------------------------------------------------------------------------------


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
