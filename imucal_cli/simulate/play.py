"""Simulate any plan by name: the registry's plans (:data:`imucal_cli.plans.PLANS`) or a TOML plan
file, each played by its virtual experiment (the registry's ``simulator``):

- ``poses`` (six, qureshi18, random:N, warmup:MINUTES):
  :func:`imucal_cli.simulate.triad.simulate`;
- ``rotations`` (qureshi-axes[:N], free:N):
  :func:`imucal_cli.simulate.rotations.simulate_gyro_rotations`;
- ``iron`` (hwangbo-iron, hk-gyro): :func:`imucal_cli.simulate.hk_gyro.simulate_hk_gyro`;
- ``redundant`` (hk-redundant): :func:`imucal_cli.simulate.redundant.simulate_redundant_accel`;
- ``steps`` (gyro-axes, still:MINUTES, plan files):
  :func:`imucal_cli.simulate.steps.simulate_steps`.

``imucal simulate`` (file and ``--serve``) and the virtual device call :func:`simulate_plan`, so
a plan name means the same session whichever way it is asked for.
"""

from __future__ import annotations

from imucal_cli.errors import InputError
from imucal_cli.formats.session import Session
from imucal_cli.model.calibration import Calibration
from imucal_cli.plans import find_plan, load_plan
from imucal_cli.simulate.faults import g_sensitive
from imucal_cli.simulate.hk_gyro import simulate_hk_gyro
from imucal_cli.simulate.motion import check_positive
from imucal_cli.simulate.redundant import simulate_redundant_accel
from imucal_cli.simulate.rotations import simulate_gyro_rotations
from imucal_cli.simulate.sensor import G0
from imucal_cli.simulate.steps import simulate_steps
from imucal_cli.simulate.triad import simulate

__all__ = ["simulate_plan"]


def _rotations_per_axis(arg: int | None, given: int | None) -> int:
    if arg is not None and given is not None and arg != given:
        raise InputError(f"plan qureshi-axes:{arg} and {given} rotations per axis disagree")
    return arg if arg is not None else (given if given is not None else 18)


def simulate_plan(
    plan: str,
    *,
    seed: int = 0,
    units: str = "counts",
    rate_hz: float | None = None,
    hold_s: float | None = None,
    move_s: float = 1.5,
    accel_noise: float = 0.01,
    jitter_deg: float = 2.0,
    gravity: float = G0,
    rotations_per_axis: int | None = None,
    peak_rate_dps: float = 150.0,
    still_s: float = 5.0,
    sigma_counts: float = 0.7,
    orientations: int | None = None,
    samples: int = 10,
    labelled: bool = False,
    mountings: int = 2,
    created: str | None = None,
    temperature=None,
    clock_scale: float | None = None,
    g_sensitivity: float | None = None,
) -> tuple[Session, Calibration]:
    """Simulate ``plan`` (a registry name or a TOML plan file); return the session and truth.

    ``g_sensitivity`` (rad/s per m/s^2): a g-sensitive gyro, each entry of its matrix drawn
    within +-that (:func:`imucal_cli.simulate.faults.g_sensitive`).
    Options a plan's experiment does not use are ignored.  ``rate_hz`` defaults to 100 Hz
    (hk-redundant: 50 Hz); ``hold_s``, the hold per pose, to 2 s (the iron plans' still periods:
    3 s; the hand-rotation plans use ``still_s``; hk-redundant: ``samples`` readings with the
    recorder paused between orientations, or with ``hold_s`` that long and ``move_s`` moves
    recorded, as a device streams them).  See the simulators for the others.

    Raises
    ------
    InputError
        Unknown plan, or a bad option.
    """
    session, truth = _played(
        plan, seed=seed, units=units, rate_hz=rate_hz, hold_s=hold_s, move_s=move_s,
        accel_noise=accel_noise, jitter_deg=jitter_deg, gravity=gravity,
        rotations_per_axis=rotations_per_axis, peak_rate_dps=peak_rate_dps, still_s=still_s,
        sigma_counts=sigma_counts, orientations=orientations, samples=samples,
        labelled=labelled, mountings=mountings, created=created, temperature=temperature,
        clock_scale=clock_scale,
    )  # fmt: skip
    if g_sensitivity:
        session, truth = g_sensitive(session, truth, float(g_sensitivity), seed)
    return session, truth


def _played(plan, *, seed, units, rate_hz, hold_s, move_s, accel_noise, jitter_deg, gravity,
            rotations_per_axis, peak_rate_dps, still_s, sigma_counts, orientations, samples,
            labelled, mountings, created, temperature, clock_scale):  # fmt: skip
    """The plan played by its experiment (:func:`simulate_plan`)."""
    spec, arg = find_plan(plan)
    extras = {k: v for k, v in (("temperature", temperature), ("clock_scale", clock_scale))
              if v is not None}  # fmt: skip
    if extras and (spec is None or spec.simulator not in ("poses", "rotations")):
        raise InputError("a temperature ramp or clock error works for plans six, qureshi18, "
                         "random:N, warmup:MINUTES, qureshi-axes and free:N")  # fmt: skip
    rate = 100.0 if rate_hz is None else rate_hz
    common = {"seed": seed, "units": units, "accel_noise": accel_noise, "created": created}
    if spec is None or spec.simulator == "steps":
        return simulate_steps(load_plan(plan), rate_hz=rate, hold_s=2.0 if hold_s is None
                              else hold_s, move_s=move_s, jitter_deg=jitter_deg,
                              gravity=gravity, **common)  # fmt: skip
    if spec.simulator == "poses":
        return _poses(spec.build(arg), hold_s, rate_hz=rate, move_s=move_s,
                      jitter_deg=jitter_deg, gravity=gravity, **extras, **common)  # fmt: skip
    if spec.simulator == "rotations":
        rpa = _rotations_per_axis(arg, rotations_per_axis) if spec.key != "free" else 18
        return simulate_gyro_rotations(
            plan=spec.key if spec.key != "free" else f"free:{arg}", rate_hz=rate,
            rotations_per_axis=rpa, peak_rate_dps=peak_rate_dps, still_s=still_s,
            jitter_deg=jitter_deg, gravity=gravity, **extras, **common,
        )  # fmt: skip
    if spec.simulator == "iron":
        return simulate_hk_gyro(
            mountings=mountings, rate_hz=rate, still_s=3.0 if hold_s is None else hold_s,
            gravity=gravity, faces=spec.key == "hwangbo-iron", **common,
        )  # fmt: skip
    rate = 50.0 if rate_hz is None else rate_hz
    stream = {} if hold_s is None else {  # held and moved as a device streams (--serve)
        "samples": max(int(round(check_positive("hold", hold_s, "s") * rate)), 1),
        "move_s": move_s}
    return _redundant(units, **{"seed": seed, "sigma_counts": sigma_counts,
                                "orientations": orientations, "samples": samples,
                                "rate_hz": rate, "labelled": labelled, "gravity": gravity,
                                "created": created, **stream})  # fmt: skip


def _poses(built, hold_s: float | None, **options) -> tuple[Session, Calibration]:
    """A pose plan (:func:`imucal_cli.simulate.triad.simulate`); a plan's own hold wins over
    ``hold_s``, as in the steps (default 2 s)."""
    own = {step.hold_s for step in built.steps}
    if len(own) == 1 and None not in own:
        hold_s = own.pop()
    return simulate(plan=built.name, hold_s=2.0 if hold_s is None else hold_s, **options)


def _redundant(units: str, **options) -> tuple[Session, Calibration]:
    """Plan hk-redundant (:func:`imucal_cli.simulate.redundant.simulate_redundant_accel`):
    11-bit ADC codes, so ``units`` must be counts."""
    if units != "counts":
        raise InputError(
            f"plan hk-redundant records 11-bit ADC codes: units must be counts, not {units!r}"
        )
    return simulate_redundant_accel(**options)
