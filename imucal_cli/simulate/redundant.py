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

The gyroscope procedure (section IV-B) is :mod:`.hk_gyro`'s.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import Calibration
from imucal_cli.plans import plan_poses
from imucal_cli.simulate.hk_gyro import simulate_hk_gyro  # re-exported
from imucal_cli.simulate.motion import (
    MAX_SAMPLES,
    Timeline,
    check_int,
    check_positive,
    check_seed,
    smootherstep,
    unit,
)
from imucal_cli.simulate.sensor import G0, ChannelGroup, Imu, floats, spawn

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
    move_s: float | None = None,
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
    ``gap_s`` while it is turned to the next one, so ``/raw/time`` jumps between holds. With
    ``move_s`` the recorder runs on (a device streaming to ``capture``): the unit turns to
    the next orientation in ``move_s``, gravity's direction following a smootherstep slerp
    (no linear acceleration), and the time runs on without a jump.

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
    move_s : float, optional
        Instead of the gap, a move of this long between holds, recorded, s (> 0).

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
    if move_s is not None:
        opt["move_s"] = check_positive("move", move_s, "s")
    truth_ss, pose_ss, noise_ss = spawn(opt["seed"])
    group, gains, bias_v = _redundant_part(truth_ss, perturb, opt["sigma_counts"])
    labels, up = _orientations(opt, pose_ss)
    tl = Timeline(opt["rate_hz"], opt["gravity"], Rotation.identity())
    f_g, time, spans = _unit_path(up, opt)
    for k, span in enumerate(spans):
        tl.segment("static", span, labels[k], up=up[k] if labelled else None)
    extra = _redundant_extra(opt, group, gains, bias_v)
    extra.update(segments=[s.name for s in tl.segments], labels=labels, true_up=floats(up))
    return Imu(groups=(group,)).session_and_truth(
        {"accel": f_g * (opt["gravity"] / G0)}, tl.segments, noise_seed=noise_ss, options=opt,
        time=time,
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


def _unit_path(up: np.ndarray, opt: dict) -> tuple[np.ndarray, np.ndarray, list]:
    """Gravity's unit direction in the unit's frame at every sample (N, 3), the sample times
    (N,), s, and each hold's sample span: the paper's holds with the recorder paused between
    them, or (``move_s`` in ``opt``) holds joined by recorded smootherstep slerps."""
    samples, rate = opt["samples"], opt["rate_hz"]
    if "move_s" not in opt:
        spans = [(k * samples, (k + 1) * samples) for k in range(len(up))]
        return np.repeat(up, samples, axis=0), _hold_times(opt), spans
    n_move = max(int(round(opt["move_s"] * rate)), 1)
    parts, spans, at = [], [], 0
    for k, u in enumerate(up):
        parts.append(np.repeat(u[None], samples, axis=0))
        spans.append((at, at + samples))
        at += samples
        if k + 1 < len(up):
            s, _ = smootherstep(n_move, (n_move + 1) / rate)
            parts.append(_slerp(u, up[k + 1], s))
            at += n_move
    f = np.concatenate(parts)
    return f, np.arange(len(f)) / rate, spans


def _slerp(a: np.ndarray, b: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Unit vectors on the great circle from ``a`` to ``b`` at fractions ``s`` (k,), (k, 3)
    (about any axis square to ``a`` when they are opposite)."""
    axis = np.cross(a, b)
    angle = float(np.arctan2(np.linalg.norm(axis), a @ b))
    if np.linalg.norm(axis) < 1e-9:
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    axis = axis / np.linalg.norm(axis)
    return Rotation.from_rotvec(np.outer(s * angle, axis)).apply(a)


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
