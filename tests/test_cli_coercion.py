"""cli/coercion.py: option values converted without pydantic give what typer's own (pydantic)
coercion gives, and the commands run without importing pydantic (issue 14: start-up)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

typer_coercion = pytest.importorskip("typer._coercion")

from typer.models import OptionInfo  # noqa: E402

from imucal_cli.cli import coercion  # noqa: E402  (importing the CLI installs it)

ROOT = Path(__file__).resolve().parents[1]

VALUES = [
    "1", "-2", "+3", "007", "0", "-0", "12345678901234567890", "1.5", "-2.5", ".5", "5.", "1e3",
    "1E-3", "2.5e+2", "1e400", "inf", "-inf", "nan", "1_000", "0x10", "", " 2 ", "abc", "１２",
    "3.0",
]  # fmt: skip


def _both(annotation, value):
    """(ours, typer's): the value or the error message."""
    import typer

    descriptor = typer_coercion.resolve_type_descriptor(annotation, OptionInfo())
    ours = typer.core.build_runtime_param(descriptor)
    theirs = typer_coercion.build_runtime_param(descriptor)
    assert type(ours).__name__ == "PlainParam"
    results = []
    for rp in (ours, theirs):
        try:
            results.append(("ok", rp._coerce_value(value, param=None, ctx=None)))
        except Exception as exc:  # noqa: BLE001  the message is what is compared
            results.append(("error", str(getattr(exc, "message", exc))))
    return results


@pytest.mark.parametrize("annotation", [int, float, str])
@pytest.mark.parametrize("value", VALUES)
def test_plain_values_as_typer_gives_them(annotation, value):
    ours, theirs = _both(annotation, value)
    assert ours[0] == theirs[0]
    if ours[0] == "ok" and isinstance(ours[1], float) and ours[1] != ours[1]:
        assert theirs[1] != theirs[1]  # both NaN
    else:
        assert ours == theirs
        assert type(ours[1]) is type(theirs[1])


@pytest.mark.parametrize("value", [1, 2.5, True, "x.h5", Path("y.h5")])
def test_defaults_and_paths_as_typer_gives_them(value):
    for annotation in (int, float, Path, list[Path]):
        ours, theirs = _both(annotation, [value] if annotation == list[Path] else value)
        assert ours == theirs
        assert type(ours[1]) is type(theirs[1])


def test_installed_once():
    assert coercion.install()
    import typer

    assert getattr(typer.core.build_runtime_param, "imucal_plain", False)


def test_commands_import_no_pydantic(tmp_path):
    """``imucal calibrate`` and ``imucal report`` run without pydantic (0.06-0.1 s of CPU)."""
    demo = tmp_path / "demo.h5"
    shutil.copy(ROOT / "sessions" / "qureshi18-seed1.h5", demo)
    cal = tmp_path / "c.json"
    for argv in (
        ["calibrate", str(demo), "-o", str(cal), "--no-store", "-j", "1", "--gravity", "9.81"],
        ["report", str(cal)],
    ):
        code = (
            "import sys\nfrom imucal_cli.cli import main\n"
            f"sys.argv = ['imucal', *{argv!r}]\n"
            "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
            "print('pydantic' in sys.modules)\n"
        )
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              timeout=600)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.strip().splitlines()[-1] == "False", argv
