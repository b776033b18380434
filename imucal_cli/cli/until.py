"""``imucal capture --until`` / ``--config``: the targets, the refit, and what the summary says
of them (issue 27; the capture modes are in :mod:`imucal_cli.capture`)."""

from __future__ import annotations

from pathlib import Path

from imucal_cli.calibrate.refit import refit
from imucal_cli.capture.guided import AdaptiveOptions, Refit
from imucal_cli.errors import InputError
from imucal_cli.formats.config import Config, load_config
from imucal_cli.formats.targets import Targets, merged, parse_until, targets_from_config

__all__ = ["MIN_HOLD_S", "adaptive_options", "refit_with", "summary_rows", "targets_of"]

MIN_HOLD_S = 0.5
"""With targets, the shortest hold unless --hold says, s."""


def targets_of(until: str | None, config: Path | None) -> tuple[Targets | None, Config]:
    """The targets of ``--until`` over the config's ``[targets]`` (None: no targets) and the
    config (its solvers refit the session so far)."""
    cfg = load_config(config)
    base = targets_from_config(cfg.targets)
    given = parse_until(until) if until is not None else Targets()
    targets = merged(base, given)
    if not targets:
        if config is not None:
            raise InputError(f"--config {config}: a capture reads only [targets] and the "
                             "solvers for them, and it has no [targets] (or give --until)")
        return None, cfg
    for t in targets:
        solver = getattr(cfg, t.sensor).solver
        if solver == "none":
            raise InputError(f"a target for the {t.sensor} ({t.describe()}) but its [{t.sensor}] "
                             'solver is "none" in the config')  # fmt: skip
    return targets, cfg


def refit_with(cfg: Config):
    """The capture's refit: :func:`imucal_cli.calibrate.refit.refit` with ``cfg``."""

    def run(session) -> Refit:
        cal, notes = refit(session, cfg)
        return Refit(cal, notes)

    return run


def adaptive_options(targets: Targets, cfg: Config, hold: float | None) -> AdaptiveOptions:
    """How the guided capture runs with ``targets`` (``hold``: --hold, the shortest hold)."""
    return AdaptiveOptions(targets, refit=refit_with(cfg),
                           min_hold_s=MIN_HOLD_S if hold is None else float(hold),
                           gravity=cfg.gravity or 9.80665)  # fmt: skip


def summary_rows(statuses: list) -> list[dict]:
    """The targets in ``capture --json``: ``{"sensor", "term", "target", "std", "unit",
    "met", "axis"}`` (``std`` null where the capture did not determine it)."""
    return [{"sensor": s.target.sensor, "term": s.target.term, "target": s.target.value,
             "std": s.std, "unit": s.target.unit, "met": s.met, "axis": s.axis or None}
            for s in statuses]  # fmt: skip
