"""The true motion of the virtual IMU: attitudes, smooth turns, holds, and the segments.

Frames: world (z up), body = fixture frame; an attitude ``R`` (:class:`Rotation`) maps body to
world.  A still unit reads the specific force ``R^T (0, 0, g)``; a turn about a fixed body axis
``u`` with angle profile ``theta(t)`` has the attitude ``R0 Exp(theta(t) u)`` and the body rate
``theta'(t) u``, exact in closed form.  The earth rate is left out.

:class:`Timeline` appends holds, moves and turns sample by sample and records the segments;
every simulator builds its motion with it, then puts it through the sensor model
(:meth:`imucal_cli.simulate.sensor.Imu.record`).  The ``check_*`` helpers validate simulator
options with one-line :class:`~imucal_cli.errors.InputError` messages.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Segment

__all__ = [
    "EZ",
    "MAX_SAMPLES",
    "Timeline",
    "check_int",
    "check_jitter",
    "check_positive",
    "check_seed",
    "draw_mountings",
    "fixed_axis",
    "heading",
    "hold_samples",
    "move_samples",
    "place",
    "placed",
    "placement_tilts",
    "samples",
    "still_samples",
    "smootherstep",
    "unit",
    "up_to_vertical",
]

EZ = np.array([0.0, 0.0, 1.0])
"""World up."""

MAX_SAMPLES = 20_000_000
"""Largest simulated session, samples."""


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) scaled to unit length along the last axis."""
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def up_to_vertical(u: np.ndarray) -> Rotation:
    """Smallest rotation (body -> world) that takes body vector ``u`` (unit) onto world +Z."""
    axis = np.cross(u, EZ)
    s, c = np.linalg.norm(axis), float(u @ EZ)
    if s < 1e-12:
        return Rotation.identity() if c > 0 else Rotation.from_rotvec([np.pi, 0.0, 0.0])
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c))


def smootherstep(n: int, dur: float) -> tuple[np.ndarray, np.ndarray]:
    """Profile ``s`` (0 -> 1) and ``ds/dt`` (1/s) at the ``n`` interior samples of a move.

    ``s = 10 tau^3 - 15 tau^4 + 6 tau^5``: zero rate and angular acceleration at both ends;
    the neighbouring still samples sit at ``tau = 0`` and ``tau = 1`` (``dur`` s apart).
    """
    tau = np.arange(1, n + 1) / (n + 1)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2 / dur
    return s, ds


def heading(rng: np.random.Generator) -> Rotation:
    """A uniform random turn about the world vertical (draws 1 number)."""
    return Rotation.from_rotvec([0.0, 0.0, rng.uniform(0.0, 2.0 * np.pi)])


def placement_tilts(rng: np.random.Generator, jitter_deg: float, count: int) -> np.ndarray:
    """Horizontal tilt vectors (count, 3) of hand placements, rad: the two horizontal
    components iid normal with std ``jitter_deg / sqrt(2)`` (RMS tilt ``jitter_deg``)."""
    tilt = np.zeros((count, 3))
    tilt[:, :2] = rng.standard_normal((count, 2)) * np.radians(jitter_deg) / np.sqrt(2.0)
    return tilt


def placed(up: np.ndarray, turn: Rotation, tilt: np.ndarray | None = None) -> Rotation:
    """Attitude (body -> world) of a unit put down with body ``up`` (unit) vertical, turned
    by ``turn`` about the vertical, then tilted by the rotation vector ``tilt``."""
    if tilt is not None:
        turn = Rotation.from_rotvec(tilt) * turn  # (tilt turn) up-to-vertical, in this order
    return turn * up_to_vertical(up)


def place(rng: np.random.Generator, up: np.ndarray, jitter_deg: float) -> Rotation:
    """A hand placement on the face ``up``: a random tilt (:func:`placement_tilts`, RMS
    ``jitter_deg``), then a random heading (draws 3 numbers, in that order)."""
    tilt = placement_tilts(rng, jitter_deg, 1)[0]
    return placed(up, heading(rng), tilt)


def fixed_axis(
    att: Rotation, axis: np.ndarray, theta: np.ndarray, dtheta: np.ndarray
) -> tuple[Rotation, np.ndarray]:
    """Attitudes ``att Exp(theta axis)`` (N rotations) and body rates ``dtheta axis`` (N, 3)."""
    return att * Rotation.from_rotvec(theta[:, None] * axis), dtheta[:, None] * axis


# --------------------------------------------------------------------------------------------
# Mountings of the unit in a fixture (Hwangbo & Kanade's right-angle iron)
# --------------------------------------------------------------------------------------------

CUBE_GROUP = Rotation.create_group("O")
"""The 24 rotations that take a cube (the iron) onto itself."""


def orbit_distance_deg(a: Rotation, b: Rotation) -> np.ndarray:
    """Smallest angle between ``b`` and ``a * G`` over the iron's 24 symmetries ``G``, degrees.

    ``b`` may hold several rotations (one distance each).  Two mountings whose distance is near
    0 put the swept face normals onto the same sensor axes (up to sign and order), so they add
    no new constraints.
    """
    rel = np.atleast_3d((a.inv() * b).as_matrix()).reshape(-1, 3, 3)  # a^T b
    group = CUBE_GROUP.as_matrix()  # (24, 3, 3)
    # angle of G^T rel: cos = (trace(G^T rel) - 1) / 2, trace(G^T R) = sum(G * R)
    cos = (np.einsum("gij,kij->kg", group, rel) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos.max(axis=1), -1.0, 1.0)))


def draw_mountings(rng: np.random.Generator, count: int) -> list[Rotation]:
    """Mounting 1 = identity; each further mounting the best of 256 uniform random rotations.

    "Best" maximises the distance (:func:`orbit_distance_deg`) to every earlier mounting, so
    the swept axes of each mounting point in new directions of the sensor frame.
    """
    out = [Rotation.identity()]
    for _ in range(count - 1):
        cands = Rotation.random(256, random_state=rng)
        scores = np.min([orbit_distance_deg(m, cands) for m in out], axis=0)
        out.append(cands[int(np.argmax(scores))])
    return out


# --------------------------------------------------------------------------------------------
# Option checks
# --------------------------------------------------------------------------------------------


def check_positive(name: str, value: float, unit_: str, allow_zero: bool = False) -> float:
    """``value`` as a float, refused unless finite and > 0 (>= 0 with ``allow_zero``)."""
    value = float(value)
    ok = np.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        bound = ">= 0" if allow_zero else "> 0"
        raise InputError(f"{name} must be a finite number {bound} {unit_}, got {value:g}")
    return value


def check_seed(seed) -> int:
    """A non-negative integer seed."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def check_int(name: str, value, low: int, high: int) -> int:
    """An integer within ``low..high``."""
    if (
        isinstance(value, bool)
        or not isinstance(value, int | np.integer)
        or not low <= value <= high
    ):
        raise InputError(f"{name} must be an integer from {low} to {high}, got {value!r}")
    return int(value)


def samples(seconds: float, rate_hz: float) -> int:
    """Whole samples in ``seconds`` at ``rate_hz``."""
    return int(round(seconds * rate_hz))


def move_samples(seconds: float, rate_hz: float) -> int:
    """Interior samples of a move lasting about ``seconds`` (at least 2)."""
    return max(2, samples(seconds, rate_hz))


MIN_HOLD_SAMPLES = 10
"""Fewest samples of a hold (a pose) or a still period."""


def hold_samples(hold_s: float, rate_hz: float) -> int:
    """Samples per pose of a ``hold_s`` hold, refused below :data:`MIN_HOLD_SAMPLES`."""
    n = samples(hold_s, rate_hz)
    if n < MIN_HOLD_SAMPLES:
        raise InputError(
            f"hold {hold_s:g} s at {rate_hz:g} Hz gives {n} samples per pose; "
            f"at least {MIN_HOLD_SAMPLES} are needed"
        )
    return n


def still_samples(still_s: float, rate_hz: float) -> int:
    """Samples of a ``still_s`` still period, refused below :data:`MIN_HOLD_SAMPLES`."""
    n = samples(still_s, rate_hz)
    if n < MIN_HOLD_SAMPLES:
        raise InputError(
            f"still {still_s:g} s at {rate_hz:g} Hz gives {n} samples: >= {MIN_HOLD_SAMPLES}"
        )
    return n


def check_jitter(opt: dict, *keys: tuple[str, str]) -> None:
    """Refuse a placement or axis error over 45 degrees: ``keys`` are (name, option key)."""
    for name, key in keys or (("jitter", "jitter_deg"),):
        if opt[key] > 45.0:
            raise InputError(f"{name} must be at most 45 deg, got {opt[key]:g}")


def check_samples(n_total: int, advice: str) -> None:
    """Refuse a session of more than :data:`MAX_SAMPLES` samples, with what to lower."""
    if n_total > MAX_SAMPLES:
        raise InputError(
            f"the session would have {n_total} samples (more than {MAX_SAMPLES}): {advice}"
        )


# --------------------------------------------------------------------------------------------
# The timeline
# --------------------------------------------------------------------------------------------


class Timeline:
    """The true specific force and rate of a motion, built piece by piece, and its segments.

    Parameters
    ----------
    rate_hz : float
        Sample rate, Hz.
    gravity : float
        Local gravity, m/s^2.
    attitude : Rotation
        Attitude (body -> world) at the first sample.
    """

    def __init__(self, rate_hz: float, gravity: float, attitude: Rotation) -> None:
        self.rate_hz = rate_hz
        self.gravity = gravity
        self.att = attitude
        self.n = 0
        self.segments: list[Segment] = []
        self._force: list[np.ndarray] = []
        self._rate: list[np.ndarray] = []
        self._quat: list[np.ndarray] = []  # attitude of every sample (a magnetometer sees it)

    def _append(self, force: np.ndarray, rate: np.ndarray, path: Rotation | None = None
                ) -> tuple[int, int]:  # fmt: skip
        start = self.n
        self._force.append(force)
        self._rate.append(rate)
        quat = self.att.as_quat() if path is None else path.as_quat()
        self._quat.append(np.broadcast_to(quat, (len(force), 4)))
        self.n += len(force)
        return start, self.n

    def gravity_in_body(self, path: Rotation) -> np.ndarray:
        """Specific force (N, 3) of a still unit along the attitudes ``path``."""
        return path.inv().apply(self.gravity * EZ)

    def hold(self, n: int, force: np.ndarray | None = None) -> tuple[int, int]:
        """``n`` still samples at the current attitude (or reading ``force``, (3,) m/s^2)."""
        if force is None:
            force = self.att.inv().apply(self.gravity * EZ)
        return self._append(np.broadcast_to(force, (n, 3)), np.zeros((n, 3)))

    def move(self, target: Rotation, n: int, lift_m: float | None = None) -> tuple[int, int]:
        """A smootherstep slerp of ``n`` interior samples to ``target``; lifted by ``lift_m``.

        The lift (height ``lift_m sin^4(pi tau)``: zero velocity and acceleration at both
        ends) adds a vertical linear acceleration; None leaves it out.
        """
        rv = (self.att.inv() * target).as_rotvec()
        dur = (n + 1) / self.rate_hz
        s, ds = smootherstep(n, dur)
        path, rate = fixed_axis(self.att, rv, s, ds)
        if lift_m is None:
            force = self.gravity_in_body(path)
        else:
            x = np.pi * (np.arange(1, n + 1) / (n + 1))  # pi tau
            sx, cx = np.sin(x), np.cos(x)
            lift_acc = lift_m * (np.pi / dur) ** 2 * (12.0 * sx**2 * cx**2 - 4.0 * sx**4)
            world = np.zeros((n, 3))
            world[:, 2] = self.gravity + lift_acc
            force = path.inv().apply(world)
        span = self._append(force, rate, path)
        self.att = target
        return span

    def turn(
        self, axis: np.ndarray, theta: np.ndarray, dtheta: np.ndarray,
        angle: float | None = None,
    ) -> tuple[int, int]:  # fmt: skip
        """A motion about the fixed body ``axis`` (unit) with angle ``theta`` (rad) and rate
        ``dtheta`` (rad/s) per sample; it ends turned by ``angle`` rad (None: where it began)."""
        path, rate = fixed_axis(self.att, axis, theta, dtheta)
        span = self._append(self.gravity_in_body(path), rate, path)
        if angle is not None:
            self.att = self.att * Rotation.from_rotvec(angle * axis)
        return span

    def smooth_turn(self, axis: np.ndarray, angle: float, n: int) -> tuple[int, int]:
        """A smootherstep turn by ``angle`` rad about the body ``axis`` over ``n`` samples."""
        s, ds = smootherstep(n, (n + 1) / self.rate_hz)
        return self.turn(axis, angle * s, angle * ds, angle=angle)

    def segment(self, kind: str, span: tuple[int, int], label: str, **attrs) -> Segment:
        """Record samples ``span`` (start, stop) as the next segment (``0000``, ...)."""
        seg = Segment(
            name=f"{len(self.segments):04d}", kind=kind, start=span[0], stop=span[1],
            label=label, **attrs,
        )  # fmt: skip
        self.segments.append(seg)
        return seg

    def attitudes(self) -> Rotation:
        """Attitude (body -> world) of every sample, N rotations."""
        if not self._quat:
            return Rotation.identity(0)
        return Rotation.from_quat(np.concatenate(self._quat))

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Specific force and body rate, (N, 3) each, m/s^2 and rad/s."""
        if not self._force:
            return np.empty((0, 3)), np.empty((0, 3))
        return np.concatenate(self._force), np.concatenate(self._rate)
