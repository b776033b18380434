"""`imucal simulate --imus N`: several IMUs on one rigid body (issue 28): the options and their
checks, beside :mod:`imucal_cli.cli.simulate`."""

from __future__ import annotations

from typing import Annotated

import typer

from imucal_cli.errors import InputError
from imucal_cli.plans import find_plan
from imucal_cli.simulate.imu_set import MAX_IMUS, simulate_set

Imus = Annotated[int, typer.Option(
    "--imus", metavar="N",
    help=f"Simulate N IMUs (1..{MAX_IMUS}) on one rigid body going through a pose plan (six, "
    "qureshi18, random:N): the first, 'reference', in /raw, the others (imu1, imu2, ...) in "
    "/imus with their own parts, noises (0.5-2 times), rates (1-2 times --rate), time stamps, "
    "mounting rotations (--imu-rotation) and time offsets (--imu-offset); the truth holds "
    "each one's calibration, rotation to the reference and time offset. With --serve, each "
    "line carries every IMU's triads (ax.1,...,gz.1 after the reference's fields).",
)]  # fmt: skip
ImuRotation = Annotated[float, typer.Option(
    "--imu-rotation", metavar="DEG",
    help="--imus: each other IMU is mounted rotated from the reference by up to this angle, "
    "degrees (random axis).",
)]  # fmt: skip
ImuOffset = Annotated[float, typer.Option(
    "--imu-offset", metavar="MS",
    help="--imus: each other IMU's time offset is uniform within +-this, milliseconds.",
)]  # fmt: skip

ServeImu = Annotated[int | None, typer.Option(
    "--serve-imu", metavar="K",
    help="--serve --imus N: stream IMU K of the set alone (0 the reference), one port per IMU: "
    "start one --serve per IMU with the same --seed, and capture them with --port A --port B.",
)]  # fmt: skip

#: Options that do not combine with --imus, as --help names them.
NOT_WITH_IMUS = {"mag": "--mag", "ramp": "--ramp", "clock_ppm": "--clock-ppm",
                 "g_sensitivity": "--g-sensitivity"}  # fmt: skip


def check_set_options(imus: int, plan: str, given) -> None:
    """Refuse ``--imus`` with what it does not simulate: plans that are not pose plans, a
    magnetometer, a temperature ramp, a clock error, a g-sensitive gyro, another line
    protocol than numbers."""
    if not 1 <= imus <= MAX_IMUS:
        raise InputError(f"--imus must be from 1 to {MAX_IMUS}, got {imus}")
    if imus == 1:
        for name in ("imu_rotation", "imu_offset", "serve_imu"):
            if given(name):
                raise InputError(f"--{name.replace('_', '-')} goes with --imus N (N >= 2)")
        return
    spec = find_plan(plan)[0]
    if spec is None or spec.simulator != "poses" or spec.key == "warmup":
        raise InputError(f"--imus simulates the pose plans (six, qureshi18, random:N), not "
                         f"{plan!r}")  # fmt: skip
    bad = [flag for name, flag in NOT_WITH_IMUS.items() if given(name)]
    if given("protocol"):
        bad.append("--protocol (a set is served as lines of numbers)")
    if bad:
        raise InputError(f"--imus does not combine with {', '.join(bad)}")


def serve_options(imus: int, rotation_deg: float, offset_ms: float,
                  member: int | None) -> dict:  # fmt: skip
    """What ``--serve`` passes to the device for a set (nothing for one IMU)."""
    if imus <= 1:
        return {}
    if member is not None and not 0 <= member < imus:  # before the serve says anything
        raise InputError(f"--serve-imu must be from 0 to {imus - 1}, got {member}")
    return {"imus": imus, "max_rotation_deg": rotation_deg, "max_offset_s": offset_ms / 1e3,
            "serve_imu": member}


def simulate_imus(imus: int, plan: str, seed: int, *, rate: float, hold: float | None,
                  accel_noise: float, jitter_deg: float, units: str, move: float,
                  rotation_deg: float, offset_ms: float, synchronous: bool = False):  # fmt: skip
    """The set's session and truth (:func:`~imucal_cli.simulate.imu_set.simulate_set`)."""
    return simulate_set(imus, plan, seed, rate_hz=rate, hold_s=2.0 if hold is None else hold,
                        accel_noise=accel_noise, jitter_deg=jitter_deg, units=units,
                        move_s=move, max_rotation_deg=rotation_deg,
                        max_offset_s=offset_ms / 1000.0, synchronous=synchronous)  # fmt: skip
