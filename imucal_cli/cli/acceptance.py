"""What ``imucal calibrate`` does with ``--limits`` and ``--registry`` (issue 29.1, 29.2): the
unit judged against its product's limits, the calibration recorded, the verdict said, and the
exit status of a rejected unit (:data:`REJECTED`).

Everything that can be refused is refused before any session is solved: the product file, the
registry (opened, created and migrated), the serial of every session (``--serial``, else the
session's ``sensor``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.markup import escape

from imucal_cli.errors import ImucalError, InputError
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.session import open_samples
from imucal_cli.formats.session.digest import session_digest
from imucal_cli.model.calibration import Calibration
from imucal_cli.registry import REGISTRY_ENV
from imucal_cli.use.limits import Acceptance, ProductLimits, judge_calibration, load_limits

from .console import make_console

if TYPE_CHECKING:  # the registry's modules load SQLAlchemy and Alembic (0.5-0.7 s of CPU): only
    # where --registry (or IMUCAL_REGISTRY) names one, never for a plain calibrate
    from imucal_cli.registry.store import Registry

__all__ = ["REJECTED", "Unit", "prepare", "worst"]

REJECTED = 4
"""Exit status of a unit saved and judged outside its product's limits (``--limits``)."""


@dataclass
class Unit:
    """The registry, the limits and the unit's names for one ``calibrate`` run."""

    registry: Registry | None
    limits: ProductLimits | None
    serials: dict[str, str] = field(default_factory=dict)  #: session path -> serial
    product: str | None = None
    lot: str | None = None
    station: str | None = None
    operator: str | None = None

    def finish(self, cal: Calibration, session: Path) -> tuple[int, dict[str, Any], list[str]]:
        """Judge and record one saved calibration.

        Returns
        -------
        code : int
            :data:`REJECTED` when judged outside the limits, 1 when it could not be recorded
            (said), else 0.
        doc : dict
            ``acceptance`` and ``registry`` for ``--json``.
        lines : list of str
            What to print (rich markup, escaped).
        """
        doc: dict[str, Any] = {}
        lines: list[str] = []
        acceptance: Acceptance | None = None
        if self.limits is not None:
            acceptance = judge_calibration(cal, self.limits)
            doc["acceptance"] = acceptance.to_dict()
            lines += verdict_lines(acceptance)
        code = REJECTED if acceptance is not None and not acceptance.passed else 0
        if self.registry is None:
            return code, doc, lines
        from imucal_cli.registry.record import UnitInfo, record_calibration

        serial = self.serials[str(session)]
        try:
            digest = session_digest(session)
            done = record_calibration(
                self.registry, cal,
                UnitInfo(serial, self.product or (self.limits and self.limits.product), self.lot,
                         self.station, self.operator),
                session_sha256=digest, acceptance=acceptance, limits=self.limits,
            )  # fmt: skip
        except ImucalError as exc:
            doc["registry"] = {"registry": self.registry.name, "recorded": False,
                               "error": str(exc)}  # fmt: skip
            lines.append(f"[bold red]not recorded[/]: {escape(str(exc))}")
            return code or 1, doc, lines
        doc["registry"] = {"registry": self.registry.name, "recorded": True, "new": done.new,
                           "serial": serial, "uid": done.uid, "recorded_at": done.recorded_at,
                           "session_sha256": digest}  # fmt: skip
        what = "recorded" if done.new else "already recorded (the same calibration):"
        lines.append(f"{what} {escape(serial)} in {escape(self.registry.name)} "
                     f"(calibration {done.uid}, session sha256 {digest[:16]}...)")  # fmt: skip
        return code, doc, lines

    def finish_saved(self, session: Path, output: Path) -> tuple[int, dict[str, Any], list[str]]:
        """:meth:`finish` for a calibration ``calibrate`` wrote to ``output`` (several
        sessions: read back from its JSON)."""
        try:
            cal = read_calibration(output)
        except ImucalError as exc:
            return 1, {"registry": {"recorded": False, "error": str(exc)}}, [escape(str(exc))]
        return self.finish(cal, session)

    def close(self) -> None:
        if self.registry is not None:
            self.registry.close()


def verdict_lines(acceptance: Acceptance) -> list[str]:
    """``accepted``/``REJECTED`` and each failed check (rich markup)."""
    product = f" ({escape(acceptance.product)})" if acceptance.product else ""
    if acceptance.passed:
        n = len(acceptance.checks)
        return [f"[bold green]accepted[/]{product}: {n} checks within the limits of "
                f"{escape(acceptance.source)}"]  # fmt: skip
    lines = [f"[bold red]REJECTED[/]{product}: {len(acceptance.failed)} of "
             f"{len(acceptance.checks)} checks outside the limits of "
             f"{escape(acceptance.source)} (exit {REJECTED})"]  # fmt: skip
    lines += [f"  [red]failed[/]: {escape(line)}" for line in acceptance.failed]
    return lines


def prepare(
    sessions: list[Path],
    *,
    registry: str | None,
    limits: Path | None,
    serial: str | None,
    product: str | None,
    lot: str | None,
    station: str | None,
    operator: str | None,
) -> Unit | None:
    """Check the options, load the limits, open the registry and find every session's serial,
    before anything is solved; None when neither ``--limits`` nor ``--registry`` is given.

    Raises
    ------
    InputError
        A name without ``--registry``, ``--serial`` with several sessions, a session naming no
        sensor without ``--serial``, a bad product file, a registry that cannot be opened.
    """
    names = {"--serial": serial, "--product": product, "--lot": lot, "--station": station,
             "--operator": operator}  # fmt: skip
    if registry is None:
        given = [flag for flag, value in names.items() if value is not None]
        if given:
            raise InputError(f"{given[0]} names the unit in the registry: give --registry PATH|URL "
                             f"(or set {REGISTRY_ENV})")  # fmt: skip
        if limits is None:
            return None
    if serial is not None and len(sessions) > 1:
        raise InputError("--serial names one unit: with several sessions each is recorded under "
                         "its session's sensor")  # fmt: skip
    product_limits = None if limits is None else load_limits(limits)
    serials: dict[str, str] = {}
    if registry is not None:
        from imucal_cli.registry.record import check_serial

        for flag, value in names.items():
            if value is not None:
                check_serial(value, flag.lstrip("-"))
        for session in sessions:
            serials[str(session)] = check_serial(serial or _sensor_of(session), "serial")
    unit = Unit(None, product_limits, serials, product, lot, station, operator)
    if registry is not None:
        from imucal_cli.registry.store import open_registry

        unit.registry = open_registry(registry, create=True)
    return unit


def _sensor_of(session: Path) -> str:
    """The session's ``sensor`` attribute (its serial), or the error that asks for --serial."""
    with open_samples(session) as samples:
        sensor = samples.sensor
    if not sensor:
        raise InputError(f"{session}: the session names no sensor: give --serial (or set it "
                         "with imucal label --sensor)")  # fmt: skip
    return sensor


_RANK = {0: 0, REJECTED: 1, 1: 2, 2: 3}


def worst(codes) -> int:
    """The exit status of several sessions: 2, then 1, then :data:`REJECTED`, then 0."""
    return max(codes, key=lambda c: _RANK.get(c, 4), default=0)


def print_lines(lines: list[str], *, stderr: bool = False) -> None:
    """Lines of rich markup on the command's console."""
    if lines:
        console = make_console(stderr=stderr)
        for line in lines:
            console.print(line, soft_wrap=True)

