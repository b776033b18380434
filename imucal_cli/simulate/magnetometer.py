"""The virtual magnetometer: a cheap 3-axis part on the board of the virtual IMU, with truth.

The part is one more :class:`~imucal_cli.simulate.sensor.ChannelGroup` of the shared sensor
model (``mag``, input the magnetic field in microtesla, fixture frame)::

    raw = clip(quantise(S @ (h + n) + b), low, high),       S = gain (I + E) A L Mount^T,

- ``b``: hard iron, the offset of the sensor and the field of magnetised parts on the board
  (uniform within +-:data:`HARD_IRON_MAX_UT` per axis, in raw units);
- ``E``: soft iron, symmetric (diagonal within +-:data:`SOFT_IRON_DIAG_MAX`, off-diagonal
  within +-:data:`SOFT_IRON_OFF_MAX`) and the gain errors (+-:data:`MAG_SCALE_ERROR_MAX`);
- ``A``: the sensitivity axes of the die, each leaning up to 1 degree;
- ``L``: the layout of the magnetometer's axes relative to the accelerometer's (``ak8963``:
  x and y swapped, z reversed, as the MPU-9250's AK8963; ``aligned``: the same axes), and a
  small die misalignment (up to 2 degrees, random axis);
- ``Mount``: the package's rotation in the fixture, shared with the accelerometer and gyro.

The truth calibration is ``matrix = S^-1`` (uT per raw unit), ``bias = b``: the field in the
fixture frame.  The local field is ``F`` microtesla with inclination ``I`` (below the
horizontal, positive down), pointing north along the world ``x`` axis: ``h_world = F (cos I,
0, -sin I)``; a still unit with attitude ``R`` (body to world) reads ``h = R^T h_world``.

:func:`simulate_mag` runs a pose plan of :mod:`imucal_cli.simulate.triad` with tumbles between
the holds (the unit turned through random attitudes, so the motion sweeps the sphere of field
directions) and records the magnetometer beside the accelerometer and gyroscope.  The part is
drawn from a fourth generator of the seed (``SeedSequence(seed).spawn(4)[3]``), so one seed is
one physical part in every plan and the accelerometer and gyroscope are those of the same seed
without a magnetometer.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import Calibration
from imucal_cli.formats.session import MAG_UNITS, UT_PER_MAG_UNIT, Session
from imucal_cli.simulate.motion import check_positive
from imucal_cli.simulate.sensor import ChannelGroup, tilted_axes
from imucal_cli.simulate.triad import simulate_stream, stream_session, truth_calibration

__all__ = [
    "LAYOUTS",
    "MAG_LSB_PER_UT",
    "MAG_RANGE_UT",
    "earth_field",
    "random_magnetometer",
    "simulate_mag",
]

MAG_LSB_PER_UT = 1.0 / 0.15
"""AK8963 in 16-bit mode: 0.15 uT per LSB, about 6.67 counts per uT."""

MAG_RANGE_UT = 32760 * 0.15
"""Full scale, uT: +-32760 counts at 0.15 uT per LSB (4914 uT)."""

HARD_IRON_MAX_UT = 40.0  # |hard iron| per axis, uT
SOFT_IRON_DIAG_MAX = 0.06  # soft iron: symmetric, diagonal within +-6 %
SOFT_IRON_OFF_MAX = 0.04  # off-diagonal within +-4 %
MAG_SCALE_ERROR_MAX = 0.05  # per-axis gain error within +-5 %
AXIS_TILT_MAX_DEG = 1.0  # each sensitivity axis leans <= 1 deg
DIE_MISALIGN_MAX_DEG = 2.0  # the magnetometer die sits rotated <= 2 deg from its layout

LAYOUTS = {
    "ak8963": np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),
    "aligned": np.eye(3),
}
"""Magnetometer axes in accelerometer axes (row i: the magnetometer's axis i)."""


def earth_field(field_uT: float, inclination_deg: float) -> np.ndarray:
    """The local field in the world frame (x north, z up), uT: ``F (cos I, 0, -sin I)``."""
    inc = np.radians(inclination_deg)
    return field_uT * np.array([np.cos(inc), 0.0, -np.sin(inc)])


def random_magnetometer(
    rng: np.random.Generator,
    units: str = "counts",
    noise_uT: float = 0.4,
    layout: str = "ak8963",
    mount_rotvec: np.ndarray | None = None,
) -> ChannelGroup:
    """Draw a cheap magnetometer on a board (the ``mag`` group of the sensor model).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the draws; the same number is made for every ``units``.
    units : {"counts", "uT", "nT", "gauss"}
        Raw units: ``counts`` (0.15 uT per LSB, integers, +-32760) or a part of nominal gain 1
        in the physical unit (no quantisation, same saturation point).
    noise_uT : float
        White noise per axis per sample, uT (input-referred).
    layout : {"ak8963", "aligned"}
        Axes relative to the accelerometer (:data:`LAYOUTS`).
    mount_rotvec : ndarray, shape (3,), optional
        The package's rotation in the fixture (the accelerometer's, :class:`Imu`), rad.
    """
    if units not in MAG_UNITS:
        raise InputError(f"magnetometer units {units!r}: use {', '.join(MAG_UNITS)}")
    if layout not in LAYOUTS:
        raise InputError(f"magnetometer layout {layout!r}: use {', '.join(LAYOUTS)}")
    hard_uT = rng.uniform(-HARD_IRON_MAX_UT, HARD_IRON_MAX_UT, 3)
    diag = rng.uniform(-SOFT_IRON_DIAG_MAX, SOFT_IRON_DIAG_MAX, 3)
    off = rng.uniform(-SOFT_IRON_OFF_MAX, SOFT_IRON_OFF_MAX, 3)
    scale = rng.uniform(-MAG_SCALE_ERROR_MAX, MAG_SCALE_ERROR_MAX, 3)
    axes = tilted_axes(rng, AXIS_TILT_MAX_DEG)
    die_axis = rng.standard_normal(3)
    die = Rotation.from_rotvec(
        die_axis / np.linalg.norm(die_axis) * np.radians(rng.uniform(0, DIE_MISALIGN_MAX_DEG))
    ).as_matrix()
    soft = np.eye(3) + np.array([[diag[0], off[0], off[1]], [off[0], diag[1], off[2]],
                                 [off[1], off[2], diag[2]]])  # fmt: skip
    mount = np.zeros(3) if mount_rotvec is None else np.asarray(mount_rotvec, float)
    fixture_to_chip = Rotation.from_rotvec(mount).as_matrix().T
    gain = MAG_LSB_PER_UT if units == "counts" else 1.0 / UT_PER_MAG_UNIT[units]
    # raw = gain diag(1 + scale) A L_die (soft h) + b: the soft iron distorts the field on the
    # board (fixture frame), then the die measures it along its axes.
    S = gain * np.diag(1.0 + scale) @ axes @ die @ LAYOUTS[layout] @ fixture_to_chip @ soft
    full = MAG_RANGE_UT * gain
    return ChannelGroup(
        name="mag",
        input_unit="uT",
        units=units,
        S=S,
        b=hard_uT * gain,
        noise_in=np.full(3, float(noise_uT)),
        nominal=gain,
        quantise=units == "counts",
        limits=(-full, full),
        scale_error=scale,
        datasheet={"hard_iron_uT": hard_uT},
    )


def simulate_mag(
    plan: str = "qureshi18",
    seed: int = 0,
    *,
    field_uT: float = 48.0,
    inclination_deg: float = 60.0,
    mag_units: str = "counts",
    mag_noise: float = 0.4,
    layout: str = "ak8963",
    field_known: bool = True,
    tumble_s: float = 4.0,
    created: str | None = None,
    **options,
) -> tuple[Session, Calibration]:
    """A pose plan with tumbles between the holds, recorded with a magnetometer too.

    Parameters
    ----------
    plan, seed, options
        As :func:`imucal_cli.simulate.triad.simulate` (``rate_hz``, ``hold_s``, ``units``, ...).
    field_uT, inclination_deg : float
        The local field: magnitude (uT, 20..70 on Earth) and inclination (degrees, -90..90).
    mag_units : {"counts", "uT", "nT", "gauss"}
        Raw units of the magnetometer.
    mag_noise : float
        Magnetometer white noise per axis per sample, uT.
    layout : {"ak8963", "aligned"}
        The magnetometer's axes relative to the accelerometer's.
    field_known : bool
        Write ``magnetic_field_uT`` into the session (else the calibration cannot know it).
    tumble_s : float
        Time of the tumble between two holds, s (0: a plain move, which sweeps little).

    Returns
    -------
    session : Session
        With ``mag`` (N, 3), ``mag_units`` and (``field_known``) ``magnetic_field_uT``.
    truth : Calibration
        The triad's truth plus a ``mag`` section: ``matrix = S^-1``, ``bias = b``, and the
        field, inclination, hard iron (uT), soft iron and layout.
    """
    field_uT = check_positive("field", field_uT, "uT")
    if not 1.0 <= field_uT <= 1000.0:
        raise InputError(f"field must be within 1..1000 uT (Earth: 20..70), got {field_uT:g}")
    if not -90.0 <= float(inclination_deg) <= 90.0:
        raise InputError(f"inclination must be within -90..90 deg, got {inclination_deg:g}")
    mag_noise = check_positive("magnetometer noise", mag_noise, "uT", allow_zero=True)
    tumble_s = check_positive("tumble", tumble_s, "s", allow_zero=True)
    stream = simulate_stream(plan=plan, seed=seed, tumble_s=tumble_s, **options)
    part_ss, noise_ss = np.random.SeedSequence(int(seed)).spawn(4)[3].spawn(2)
    group = random_magnetometer(np.random.default_rng(part_ss), mag_units, mag_noise, layout,
                                stream.truth.mount_rotvec)  # fmt: skip
    h_world = earth_field(field_uT, float(inclination_deg))
    h_body = stream.attitudes.inv().apply(h_world)
    raw = group.raw(h_body, *group.draw_noise(np.random.default_rng(noise_ss), len(h_body)))
    truth = truth_calibration(stream, created)
    mag_truth = group.truth({
        "model": "calibrated = matrix @ (raw - bias)",
        "quantised": group.quantise,
        **group.describe(),
        "field_uT": float(field_uT),
        "inclination_deg": float(inclination_deg),
        "layout": layout,
        "frame": "fixture frame (the accelerometer truth's frame)",
        "tumble_s": float(tumble_s),
    })  # fmt: skip
    truth = replace(truth, mag=mag_truth)
    truth.extra["simulator"] = {
        **truth.extra["simulator"], "mag_units": mag_units, "mag_noise": float(mag_noise),
        "field_uT": float(field_uT), "inclination_deg": float(inclination_deg),
        "layout": layout, "field_known": bool(field_known), "tumble_s": float(tumble_s),
    }  # fmt: skip
    session = replace(
        stream_session(stream, truth.created), mag=raw, mag_units=mag_units,
        magnetic_field_uT=float(field_uT) if field_known else None,
    )  # fmt: skip
    return session, truth
