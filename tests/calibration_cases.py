"""The calibration JSON of every plan's simulated session, and of the stored calibrations, kept
in ``tests/data/calibrations/`` so that a change of the calibration model (issue 25.2) or of
the solver choice (25.3) that changes a file is seen (``tests/test_calibration_cases.py``).

How each fixture is made (this module is the only writer: never edit a fixture by hand)

- ``NAME.cal.json`` and ``NAME.truth.json`` for each entry of :data:`CASES`: ``imucal
  simulate`` with the case's options and ``--seed 1`` (after a warm-up session for ``{w}``,
  the ``qureshi18`` case's calibration for ``{a}``, :data:`CONFIG` for ``{c}``), then
  ``imucal calibrate --no-store`` through the command line as a user would; the calibration
  written (or ``{"exit": N}`` when none is) and the truth the simulator writes beside the
  session.
- ``sessions-*.json``: every calibration stored in ``sessions/`` (the ``*.truth.json`` files
  and the calibrations an ``.h5`` session stores), read and written back (:func:`stored`).
- Every document: the root's :data:`VOLATILE` members left out, the work folder's path as
  ``TMP``, members sorted by name (a JSON object's members have no order, and the writer's
  order is no contract: sorted, a change of that order changes no fixture), one space of
  indent, a final newline (:func:`fixture_text`).

Regenerating, from the repository's root with its venv::

    .venv/bin/python -m tests.calibration_cases            # every fixture
    .venv/bin/python -m tests.calibration_cases warmup six # these cases ("stored": sessions-*)
    .venv/bin/python -m tests.calibration_cases --check    # compare, write nothing

Regenerate only after a change that is meant to change the files, regenerate the whole file
(not the fields you expect to move: others move within the tolerance unseen, and the next
regeneration shows them as unrelated changes), and say in the commit what changed and why.
On a clean checkout a regeneration leaves ``git status`` clean on a machine of the recording
one's arithmetic; on another CPU it may rewrite numbers in their last digits (within
:data:`RTOL`, see there), which is not a change: ``--check`` tells them apart (it prints what
differs beyond the tolerance, and names a fixture no case writes, or a case with no fixture).
``tests/test_calibration_cases.py`` runs this writer into a temporary folder for every case
and compares its files with the committed ones (the same members and integers, texts word for
word; numbers, also those in texts, within :data:`RTOL`; :data:`SOLVER_PATH` aside), and
checks every committed file is in :func:`fixture_text`'s form.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from tests.cli_helpers import run

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "data" / "calibrations"

#: name -> (simulate options, calibrate options); ``{w}`` is a warm-up session simulated first.
CASES: dict[str, tuple[list[str], list[str]]] = {
    "six": (["--plan", "six"], []),
    "qureshi18": (["--plan", "qureshi18"], []),
    "qureshi18-model12": (["--plan", "qureshi18"], ["--model", "12"]),
    "random12": (["--plan", "random:12"], []),
    "ferraris": (["--plan", "ferraris"], []),
    "gyro-axes": (["--plan", "gyro-axes"], []),
    "qureshi-axes": (["--plan", "qureshi-axes"], []),
    "free8": (["--plan", "free:8"], []),
    "hwangbo-iron": (["--plan", "hwangbo-iron"], []),
    "hk-gyro": (["--plan", "hk-gyro"], []),
    "hk-redundant": (["--plan", "hk-redundant"], []),
    "mag-qureshi18": (["--plan", "qureshi18", "--mag"], []),
    "ramp-qureshi18": (["--plan", "qureshi18", "--ramp", "10:40"], []),
    "warmup": (["--plan", "qureshi18", "--ramp", "24:26:linear"], ["--warmup", "{w}"]),
    "clock-qureshi-axes": (["--plan", "qureshi-axes", "--clock-ppm", "400"], []),
    "gsens-qureshi-axes": (["--plan", "qureshi-axes", "--g-sensitivity", "5e-4"], []),
    "mag-unknown-random12": (["--plan", "random:12", "--mag", "--field-unknown"], []),
    "given-accel": (["--plan", "qureshi-axes"], ["--accel", "{a}"]),
    "config-labelled-known": (["--plan", "ferraris"], ["--config", "{c}"]),
    "imus3-random12": (["--plan", "random:12", "--imus", "3"], []),  # the root's imus
}
#: The config of the case ``config-*``.
CONFIG = '[accel]\nsolver = "labelled"\n[gyro]\nsolver = "known"\n'

WARMUP = ["--plan", "warmup:4", "--ramp", "8:40"]

#: Root fields that differ from run to run (not values of the calibration).
VOLATILE = ("created", "toolkit_version")


def simulated(name: str, folder: Path) -> tuple[dict, dict]:
    """``(calibration, truth)`` documents of case ``name``, computed in ``folder``."""
    sim, cal = CASES[name]
    session = folder / f"{name}.h5"
    warm = folder / f"{name}-warmup.h5"
    if "{w}" in cal:
        proc = run("simulate", *WARMUP, "--seed", "1", "--force", "-o", warm)
        assert proc.returncode == 0, proc.stderr
    proc = run("simulate", *sim, "--seed", "1", "--force", "-o", session)
    assert proc.returncode == 0, proc.stderr
    out = folder / f"{name}.cal.json"
    if "{a}" in cal:  # an earlier calibration of the same unit: the qureshi18 case's
        given, _ = simulated("qureshi18", folder)
        (folder / "given.cal.json").write_text(json.dumps(given), encoding="utf-8")
    (folder / "config.toml").write_text(CONFIG, encoding="utf-8")
    subst = {"{w}": str(warm), "{a}": str(folder / "given.cal.json"),
             "{c}": str(folder / "config.toml")}  # fmt: skip
    args = [subst.get(a, a) for a in cal]
    proc = run("calibrate", session, *args, "--no-store", "--force", "-o", out)
    assert proc.returncode in (0, 1), proc.stderr
    truth = session.with_suffix(".truth.json")

    def load(path: Path) -> dict:  # the folder's name (in notes) as TMP
        return json.loads(path.read_text(encoding="utf-8").replace(str(folder), "TMP"))

    return (load(out) if out.exists() else {"exit": proc.returncode}), load(truth)


def stored() -> dict[str, dict]:
    """Every stored calibration of the repository, read and written back: the sessions'
    truths, and the calibrations the shipped sessions store."""
    from imucal_cli.formats.calibration import (
        calibration_from_json,
        calibration_to_json,
        read_calibration,
    )
    from imucal_cli.formats.session import read_session

    out = {}
    for path in sorted((ROOT / "sessions").glob("*.json")):
        out[f"sessions-{path.name}"] = json.loads(calibration_to_json(read_calibration(path)))
    for path in sorted((ROOT / "sessions").glob("*.h5")):
        for key, text in sorted(read_session(path).calibrations.items()):
            cal = calibration_from_json(text, f"{path.name}:{key}")
            out[f"sessions-{path.stem}-{key}"] = json.loads(calibration_to_json(cal))
    return out


def strip(doc):
    """The document without its :data:`VOLATILE` root fields."""
    return {k: v for k, v in doc.items() if k not in VOLATILE} if isinstance(doc, dict) else doc


#: Numbers agree within this relative tolerance, or within it of the largest number of the
#: array they stand in, or :data:`ATOL`. Measured on another CPU's arithmetic (numpy's SSE and
#: AVX2 paths with OpenBLAS's Sandybridge and Haswell kernels against this machine's AVX-512):
#: the iterative fits stop one step apart, which moves stated std by up to 1 %, covariance
#: entries near zero by up to 13 % of themselves (0.9 % of the matrix's largest) and fitted
#: values by under 3e-5; a change of the model or of a solver moves them by more, and a moved
#: term, a left-out pose, a renamed key or a changed word is seen at once.
RTOL = 2e-2
#: Absolute floor for numbers that are zero in exact arithmetic (a residual of 1e-17).
ATOL = 1e-12
#: A solver's path, not its result: how many steps it took, why it stopped and where it started
#: (an "ellipsoid" or "updown" start that reach the same point) differ on another CPU.
SOLVER_PATH = ("iterations", "function_evaluations", "message", "init")
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def differences(a, b, path: str = "", rel: float = RTOL) -> list[str]:
    """Where two parsed documents differ (numbers within ``rel`` relative, or :data:`ATOL`,
    agree; ``rel = 0``: identical): JSON paths, at most 20."""
    out: list[str] = []
    _diff(a, b, path, rel, out)
    return out[:20]


def _close(a: float, b: float, rel: float, scale: float = 0.0) -> bool:
    return a == b or (rel > 0 and abs(a - b) <= max(rel * max(abs(a), abs(b), scale), ATOL))


def _largest(v) -> float:
    """The largest magnitude of the numbers in a (nested) list; 0 when there are none."""
    if isinstance(v, list):
        return max((_largest(x) for x in v), default=0.0)
    return abs(v) if isinstance(v, float) else 0.0


def _same_text(a: str, b: str, rel: float) -> bool:
    """Strings agree: identical, or (``rel > 0``) the same words and the numbers in them
    equal within ``rel`` or one unit of their last printed digit (a figure rounded for
    people, e.g. ``5.6 %``, can round the other way on another CPU)."""
    if a == b:
        return True
    if rel == 0 or _NUMBER.split(a) != _NUMBER.split(b):
        return False
    for x, y in zip(_NUMBER.findall(a), _NUMBER.findall(b), strict=True):
        if _close(float(x), float(y), rel):
            continue
        if "." not in x or "e" in x.lower():  # counts, and exponents: exactly
            return False
        if abs(float(x) - float(y)) > 1.01 * 10.0 ** -len(x.split(".")[1]):
            return False
    return True


def _diff(a, b, path, rel, out, scale: float = 0.0) -> None:
    if len(out) >= 20:
        return
    if isinstance(a, dict) and isinstance(b, dict):  # a JSON object's members have no order
        if set(a) != set(b):
            out.append(
                f"{path or '.'}: keys {sorted(set(a) - set(b))} more, "
                f"{sorted(set(b) - set(a))} fewer"
            )
        for k in a:
            if k in b and not (rel > 0 and k in SOLVER_PATH):
                _diff(a[k], b[k], f"{path}.{k}", rel, out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{path}: length {len(a)} != {len(b)}")
        scale = max(scale, _largest(a), _largest(b))
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            _diff(x, y, f"{path}[{i}]", rel, out, scale)
    elif isinstance(a, float) and isinstance(b, float):
        if not _close(a, b, rel, scale):
            out.append(f"{path}: {a!r} != {b!r}")
    elif isinstance(a, str) and isinstance(b, str):
        if not _same_text(a, b, rel):
            out.append(f"{path}: {a!r} != {b!r}")
    elif a != b or type(a) is not type(b):
        out.append(f"{path}: {a!r} != {b!r}")


def fixture_text(doc) -> str:
    """The text of a fixture holding ``doc``: without the :data:`VOLATILE` root members,
    members sorted by name, one space of indent, a final newline."""
    return json.dumps(strip(doc), indent=1, sort_keys=True) + "\n"


def write_case(name: str, work: Path, out: Path) -> list[Path]:
    """Simulate and calibrate case ``name`` in ``work`` and write its two fixtures into
    ``out``: the paths written."""
    cal, truth = simulated(name, work)
    paths = []
    for kind, doc in (("cal", cal), ("truth", truth)):
        paths.append(out / f"{name}.{kind}.json")
        paths[-1].write_text(fixture_text(doc), encoding="utf-8")
    return paths


def write_stored(out: Path) -> list[Path]:
    """Write the fixture of every :func:`stored` calibration into ``out``: the paths."""
    paths = []
    for name, doc in stored().items():
        paths.append(out / f"{name}.json")
        paths[-1].write_text(fixture_text(doc), encoding="utf-8")
    return paths


#: The name that regenerates the stored calibrations' fixtures (``sessions-*.json``).
STORED = "stored"


def write_fixtures(work: Path, out: Path, names=None) -> list[Path]:
    """Write the fixtures of ``names`` (cases of :data:`CASES`, or :data:`STORED`; all when
    None) into ``out``, computing in ``work``: the paths written."""
    names = [*CASES, STORED] if names is None else list(names)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in names:
        if name == STORED:
            paths += write_stored(out)
        else:
            case = work / name  # each case in a folder of its own (a session's name is the case's)
            case.mkdir(parents=True, exist_ok=True)
            paths += write_case(name, case, out)
        print(name, file=sys.stderr)
    return paths


def compare(written: list[Path], committed: Path | None = None) -> list[str]:
    """What differs between the fixtures ``written`` and the same-named ones in ``committed``
    (:data:`FIXTURES` when None) beyond the tolerance (:func:`differences`): one line each."""
    committed = FIXTURES if committed is None else committed
    out = []
    for path in written:
        old = committed / path.name
        if not old.exists():
            out.append(f"{path.name}: no committed fixture")
            continue
        new_doc = json.loads(path.read_text(encoding="utf-8"))
        old_doc = json.loads(old.read_text(encoding="utf-8"))
        out += [f"{path.name}: {d}" for d in differences(new_doc, old_doc)]
    return out


def main(argv: list[str] | None = None) -> int:
    import argparse
    import tempfile

    parser = argparse.ArgumentParser(
        prog="python -m tests.calibration_cases",
        description="Write the fixtures of tests/data/calibrations anew (see the module's "
        "docstring).",
    )
    names = f"cases to write (default: all): {', '.join(CASES)}, {STORED}"
    parser.add_argument("names", nargs="*", metavar="NAME", help=names)
    check = f"write nothing: compare with the committed fixtures (numbers within {RTOL:g})"
    parser.add_argument("--check", action="store_true", help=check + ", exit 1 if they differ")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.names) - {*CASES, STORED})
    if unknown:
        parser.error(f"no case {', '.join(unknown)}")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "fixtures" if args.check else FIXTURES
        written = write_fixtures(Path(tmp) / "work", out, args.names or None)
        if not args.check:
            return 0
        found = compare(written)
    if not args.names:
        names = {p.name for p in written}
        found += [f"{p.name}: no case writes it" for p in sorted(FIXTURES.glob("*.json"))
                  if p.name not in names]  # fmt: skip
    print("\n".join(found) or "the fixtures agree within the tolerance")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
