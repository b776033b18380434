"""Issue 13.5: the imports follow the package map in DEVELOPERS.md.

The map's table lists the packages from the bottom layer up, each with what it may import.
Every ``import`` in ``imucal_cli/`` (also those inside functions, the lazy ones) must go to a
package that its row names, and every row may name only packages listed above it: a lower layer
never imports a higher one (solvers importing formats or cli, formats importing pipeline, ...),
and the table cannot describe a circle.  A new package, or a new dependency, is a change of
the map: make it in DEVELOPERS.md, where the next engineer reads it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "imucal_cli"
#: Importable from anywhere: the package's own ``__init__`` (its version), ``__main__``, and
#: ``errors``, the bottom row (every layer raises its errors).
FREE = {"imucal_cli", "__main__", "errors"}


def layer_table() -> list[tuple[str, str]]:
    """``(package, what it may import)`` per row of DEVELOPERS.md's layout table, in order."""
    text = (ROOT / "DEVELOPERS.md").read_text(encoding="utf-8")
    section = text.split("## Layout", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in section.splitlines():
        m = re.match(r"\| `imucal_cli/([a-z_]+)(?:\.py|/)` \|.*\| ([^|]*) \|\s*$", line)
        if m:
            rows.append((m.group(1), m.group(2)))
    return rows


def _allowed(rows: list[tuple[str, str]]) -> dict[str, set[str]]:
    names = [name for name, _ in rows]
    out = {}
    for name, may in rows:
        if may.strip() == "everything":
            out[name] = set(names) - {name}
        else:
            out[name] = {n for n in names if re.search(rf"\b{n}\b", may)}
    return out


def _package_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def _imports(path: Path, text: str | None = None) -> list[tuple[int, str]]:
    """``(line, imported imucal_cli module)`` of every import in one file (its ``text``, by
    default read), relative ones resolved."""
    here = list(path.relative_to(ROOT).with_suffix("").parts[:-1])  # the module's package
    found = []
    tree = ast.parse(path.read_text(encoding="utf-8") if text is None else text)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = here[: len(here) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            found += [(node.lineno, f"{module}.{a.name}") for a in node.names]
    return [(line, m) for line, m in found if m.split(".")[0] == "imucal_cli"]


def test_the_map_lists_every_package_once_and_only_downwards():
    rows = layer_table()
    names = [name for name, _ in rows]
    assert len(names) == len(set(names)), names
    on_disk = {
        p.stem for p in PACKAGE.iterdir() if p.suffix == ".py" or (p / "__init__.py").exists()
    }
    missing = on_disk - {"imucal_cli", "__main__", "__init__"} - set(names)
    assert not missing, f"DEVELOPERS.md: {sorted(missing)} not in the map"
    allowed = _allowed(rows)
    for i, name in enumerate(names):
        upward = allowed[name] - set(names[:i])
        assert not upward, f"DEVELOPERS.md: {name} may import {sorted(upward)}, listed above it"


def test_no_layer_imports_a_higher_one():
    allowed = _allowed(layer_table())
    packages = set(allowed) | FREE
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = _package_of(".".join(path.relative_to(ROOT).with_suffix("").parts))
        if source in FREE or source == "__init__":
            continue
        for line, module in _imports(path):
            target = _package_of(module)
            if target not in packages:  # a name of the root package (its __version__)
                target = "imucal_cli"
            if target != source and target not in FREE and target not in allowed[source]:
                wrong.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    assert not wrong, wrong


def test_the_check_sees_lazy_and_relative_imports():
    """What the check reads: function-level and relative imports, resolved to their package."""
    text = ("import numpy\nfrom imucal_cli import __version__, plans\n\n\ndef f():\n"
            "    from ..calibrate.session import calibrate_session\n"
            "    from . import session\n    from .session import Session\n")  # fmt: skip
    got = [m for _, m in _imports(PACKAGE / "formats" / "x.py", text)]
    assert got == ["imucal_cli.__version__", "imucal_cli.plans",
                   "imucal_cli.calibrate.session.calibrate_session", "imucal_cli.formats.session",
                   "imucal_cli.formats.session.Session"]  # fmt: skip
    assert "calibrate" not in _allowed(layer_table())["formats"]


#: What is not a sensor's in ``estimators/``: the estimators two sensors share.
SHARED_ESTIMATORS = {"factorization", "factorization_model", "factorization_refine",
                     "ellipsoid"}
SENSOR_FOLDERS = {"accel", "gyro", "mag", "thermal", "clock"}
#: The estimators of a set of several IMUs (its accelerometers jointly, the rotations, the time
#: offsets): the set's, not one sensor's.
SET_FOLDER = "imu_set"


def test_estimators_are_grouped_by_sensor():
    """Issue 25.4: an estimator lives in its sensor's folder (or is one two sensors share, or
    the several-IMU set's);
    the design analysis, apart, imports no estimator (the layers above)."""
    root = PACKAGE / "estimators"
    stray = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.name == "__init__.py":
            continue
        if len(rel.parts) == 1 and rel.stem not in SHARED_ESTIMATORS:
            stray.append(str(rel))
        if len(rel.parts) > 1 and rel.parts[0] not in SENSOR_FOLDERS | {SET_FOLDER}:
            stray.append(str(rel))
    assert not stray, stray
    assert {p.name for p in root.iterdir() if p.is_dir() and p.name != "__pycache__"} == (
        SENSOR_FOLDERS | {SET_FOLDER})  # fmt: skip


def test_one_session_reader():
    """Issue 25.4: sessions are read by ``formats/session`` only (``read_session``,
    ``open_samples``): no module elsewhere opens one itself (``use/apply.py`` had its own)."""
    inner = ("imucal_cli.formats.session.h5open", "imucal_cli.formats.session.reader")
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        if rel.parts[:2] == ("formats", "session"):
            continue
        for line, module in _imports(path):
            if module.startswith(inner) or module.endswith((".open_for_reading",
                                                            ".raw_datasets")):  # fmt: skip
                wrong.append(f"{rel}:{line} imports {module}")
        text = path.read_text(encoding="utf-8")
        if "h5py.File(" in text and rel.parts[0] != "formats":
            wrong.append(f"{rel}: opens an HDF5 file itself")
    assert not wrong, wrong


def test_the_registry_is_a_layer_of_its_own():
    """Issue 29: the registry sits above ``use`` (it judges and compares units with use's limits
    and history) and below the CLI: no layer under it knows a database, so a report, an export
    or a certificate from a file works without one."""
    allowed = _allowed(layer_table())
    assert allowed["registry"] == {"model", "formats", "use"}
    below = ("numerics", "design", "estimators", "planning", "model", "formats", "plans",
             "simulate", "calibrate", "use", "capture")
    assert not [name for name in below if "registry" in allowed[name]]


def test_the_program_starts_without_scipy_stats_and_signal():
    """DEVELOPERS.md "Imports": scipy.stats and scipy.signal cost every ``imucal`` process
    0.6-0.9 s of CPU at start-up, so only the two functions that need them import them; a
    module-level ``from scipy import stats`` (a chi-square tail comes from scipy.special's
    ``chdtrc``) brings the cost back to every command and every test through the device."""
    import subprocess
    import sys

    code = "import sys; from imucal_cli.cli.app import load_commands; load_commands(); " \
           "print(sorted(m for m in sys.modules if m in ('scipy.stats', 'scipy.signal')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120).stdout  # fmt: skip
    assert out.strip() == "[]", out


def test_every_command_is_in_the_table_of_commands():
    """Issue 29.5: the root imports a command's module when a command line names it
    (``cli/app.py``'s ``COMMANDS``): a module that registers a command must be in the table,
    or its command would not exist; and the table's names are the names the modules register."""
    import typer

    from imucal_cli.cli.app import COMMANDS, app, load_commands

    registers = {p.stem for p in (PACKAGE / "cli").glob("*.py")
                 if re.search(r"^@app\.command\(|^app\.add_typer\(", p.read_text(), re.M)}
    assert registers == set(COMMANDS.values())
    load_commands()
    registered = [c.name or c.callback.__name__ for c in app.registered_commands]
    registered += [g.name for g in app.registered_groups]
    assert sorted(registered) == sorted(COMMANDS)
    group = typer.main.get_command(app)
    assert [group.get_command(typer.Context(group), n).name for n in COMMANDS] == list(COMMANDS)


def test_a_command_loads_its_own_modules_only():
    """Issue 29.5: ``imucal registry lot`` (10,000 units in under 2 s of CPU, start-up
    included) imports the registry's command module and what it needs, not the other
    commands' (calibrate, capture, simulate: the solvers, scipy); ``imucal --version`` and
    ``imucal --help`` import no command at all."""
    import subprocess
    import sys

    code = ("import sys\nfrom imucal_cli.cli import main\ntry:\n    main()\n"
            "except SystemExit:\n    pass\n"
            "print(' '.join(sorted(m for m in sys.modules if m.startswith(('imucal_cli.', "
            "'scipy')))), file=sys.stderr)")  # fmt: skip

    def loaded(*args: str) -> set[str]:
        proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True,
                              text=True, timeout=120)  # fmt: skip
        return set(proc.stderr.strip().splitlines()[-1].split())

    lot = loaded("registry", "lot", "LOT", "--registry", str(ROOT / "no-such-registry.db"))
    assert "imucal_cli.cli.registry" in lot and "imucal_cli.registry.lot" in lot
    others = {m for m in lot if m.startswith(("imucal_cli.cli.", "imucal_cli.calibrate",
                                              "imucal_cli.estimators", "imucal_cli.simulate",
                                              "imucal_cli.capture", "scipy"))}  # fmt: skip
    assert others <= {"imucal_cli.cli.app", "imucal_cli.cli.registry",
                      "imucal_cli.cli.registry_render", "imucal_cli.cli.options",
                      "imucal_cli.cli.completion", "imucal_cli.cli.console"}, sorted(others)
    for args in (["--version"], ["--help"]):  # the root's help lists the commands unloaded
        root = loaded(*args)
        assert not {m for m in root if m.startswith(("imucal_cli.cli.", "scipy"))} - {
            "imucal_cli.cli.app"}, (args, sorted(root))
