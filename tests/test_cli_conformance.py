"""CLI conformance (issue 12): every command's --help without a terminal, piped into a reader
that goes away, and with NO_COLOR; --version, -h, one-line errors, the exit-status table.

What only a process shows (a closed pipe, the program's exit path, the streams a shell script
sees) runs the installed ``imucal`` in a subprocess; help texts and completions, which are the
same text in or out of a process (each command's help is compared once with the process's, and
a completion once through the shell's protocol), run :func:`imucal_cli.cli.main` in this
process, without the seconds of a new interpreter per call.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest

from imucal_cli import __version__
from imucal_cli.cli import app
from imucal_cli.cli.app import EXIT_CODES, load_commands

from .cli_helpers import IMUCAL, run

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX pipes")

load_commands()  # a command's module is otherwise imported when a command line names it
COMMANDS = sorted(c.name or c.callback.__name__ for c in app.registered_commands)
ENV = {**os.environ, "NO_COLOR": "1", "COLUMNS": "80"}
DOCS = Path(__file__).resolve().parents[1] / "docs"
COMMANDS_PAGE = DOCS / "commands.md"  # the exit statuses and the --json schemas
CAPTURE_PAGE = DOCS / "capture.md"  # the columns of a line and their time units


@contextmanager
def _environment(**values: str):
    """``os.environ`` with ``values`` set, restored afterwards."""
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _help(*args: str) -> subprocess.CompletedProcess:
    """``imucal ARGS`` in this process, as a shell script without a terminal runs it."""
    with _environment(NO_COLOR="1", COLUMNS="80"):
        return run(*args)


def _help_process(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([IMUCAL, *args], capture_output=True, text=True, env=ENV, timeout=120)


def _closed_pipe(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """Run with stdout a pipe whose reader is already gone: every write meets EPIPE."""
    read, write = os.pipe()
    os.close(read)
    try:
        return subprocess.run([IMUCAL, *args], stdout=write, stderr=subprocess.PIPE, text=True,
                              cwd=cwd, env=ENV, timeout=120)  # fmt: skip
    finally:
        os.close(write)


@pytest.mark.parametrize("command", ["", *COMMANDS])
def test_help_without_a_terminal(command):
    args = [command] if command else []
    proc = _help(*args, "--help")
    assert proc.returncode == 0 and proc.stderr == ""
    text = proc.stdout
    assert "\x1b[" not in text  # NO_COLOR, and no colour codes into a pipe anyway
    assert _help(*args, "-h").stdout == text  # -h is --help
    # metavars a person can read: no Python types, no {braces}
    assert not re.search(r"<(str|int|float|bool|path|list)", text), text
    assert not re.search(r"\{[A-Za-z_.|]+\}", text.splitlines()[0]), text.splitlines()[0]
    # not hard-wrapped at 80 columns although COLUMNS=80: one line per option, defaults whole
    options = []
    for line in text[text.index("Options:") :].splitlines()[1:]:
        if line and not line.startswith(" "):
            break  # the next section
        options.append(line)
    for line in options:
        assert not line or line.startswith("  -"), f"wrapped: {line!r}"


@pytest.mark.parametrize("command", ["", "calibrate", "capture"])
def test_help_as_a_process(command):
    """The program's help is the text the in-process tests examine, and the reader going away
    after the first line is no error (one case per kind: the program, a command, a long one)."""
    args = [command] if command else []
    proc = _help_process(*args, "--help")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert proc.stdout == _help(*args, "--help").stdout
    piped = _closed_pipe(*args, "--help", cwd=Path.cwd())
    assert piped.returncode == 0 and piped.stderr == "", piped.stderr


def test_the_root_help_lists_a_command_it_has_not_loaded_by_its_own_short_help():
    """``imucal --help`` imports no command's module: each command's line is made from its
    sentence in ``cli/app.py``'s ``SUMMARIES``, and is the line the command's own help makes, at
    any width (the whole text, process against all commands loaded: test_help_as_a_process)."""
    import typer

    from imucal_cli.cli.app import COMMANDS as TABLE
    from imucal_cli.cli.app import NO_WRAP_WIDTH, Commands

    group = typer.main.get_command(app)
    for name in TABLE:
        command = group.get_command(typer.Context(group), name)
        for limit in (10, 30, 45, 60, 74, 100, NO_WRAP_WIDTH):
            assert Commands.stand_in(name).get_short_help_str(limit) == \
                command.get_short_help_str(limit), (name, limit)


def test_help_keeps_square_brackets_and_shows_what_the_readme_says():
    capture = _help("capture", "--help").stdout
    assert "[[step]]" in capture
    assert "[default: capture-<date>-<time>.h5]" in capture
    assert "[default: 115200]" in capture and "[default: t,ax,ay,az,gx,gy,gz,temp]" in capture
    assert "semicolons" in capture  # the separators docs/capture.md names
    assert "pip install 'imucal-cli[plot]'" in _help("report", "--help").stdout
    simulate = _help("simulate", "--help").stdout
    for fault in ("--garbage", "--stall-after SECONDS", "--vanish-after SECONDS",
                  "--malformed-every N"):  # fmt: skip
        assert re.search(rf"^\s+{re.escape(fault)}\s", simulate, re.M), fault
    for command in COMMANDS:  # every command states its exit status
        assert "Exit status" in _help(command, "--help").stdout, command


def test_every_command_names_the_same_time_units_as_the_docs():
    from imucal_cli.formats.columns import TIME_UNITS

    for command in ("capture", "import", "apply"):
        assert f"--time-unit {'|'.join(TIME_UNITS)} " in _help(command, "--help").stdout, command
    listed = "(" + ", ".join(f"`{u}`" for u in TIME_UNITS) + ")"
    assert f"`--time-unit` {listed}" in " ".join(CAPTURE_PAGE.read_text(encoding="utf-8").split())


def test_version_and_exit_status_table():
    for flag in ("--version", "-V"):
        proc = run(flag)
        assert proc.returncode == 0 and proc.stdout.strip() == f"imucal {__version__}"
    root = _help("--help").stdout
    page = COMMANDS_PAGE.read_text(encoding="utf-8")
    for code, what in EXIT_CODES:
        assert re.search(rf"^\s*{code}\s+{re.escape(what)}$", root, re.M), (code, root)
        assert f"| {code} | {what} |" in page, (code, "docs/commands.md exit-status table")


@pytest.mark.parametrize(
    "args, words",
    [(["capture"], ["Missing option '--port'", "imucal capture --help"]),
     (["report"], ["Missing argument", "imucal report --help"]),
     (["calibrate", "--model"], ["--model", "requires an argument"]),
     (["simulate", "--bogus"], ["No such option: --bogus"])],
)  # fmt: skip
def test_usage_errors_are_one_line_without_a_doubled_prefix(args, words):
    proc = run(*args)
    assert proc.returncode == 2 and proc.stdout == ""
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and err.startswith("imucal: error: "), err
    assert "imucal: error: imucal" not in err and "Error:" not in err
    for word in words:
        assert word in err, (word, err)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    folder = tmp_path_factory.mktemp("conformance")
    proc = run("simulate", "--plan", "qureshi18", "--seed", "3", "-o", folder / "s.h5")
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", folder / "s.h5", "-o", folder / "s.cal.json")
    assert proc.returncode == 0, proc.stderr
    return folder


def test_epipe_keeps_the_commands_own_status(calibrated):
    """`imucal report X | head -1`: the reader goes away; the command still ends with its own
    status, quietly; a command that writes files still writes them."""
    report = _closed_pipe("report", "s.cal.json", cwd=calibrated)
    assert report.returncode == 0 and report.stderr == "", report.stderr
    out = calibrated / "again.cal.json"
    again = _closed_pipe("calibrate", "s.h5", "-o", out.name, "--no-store", cwd=calibrated)
    assert again.returncode == 0 and again.stderr == "" and out.exists()
    missing = _closed_pipe("report", "nothing.json", cwd=calibrated)
    assert missing.returncode == 2 and missing.stderr.startswith("imucal: error: ")
    head = subprocess.run(f"set -o pipefail; {IMUCAL} report s.cal.json | head -1", shell=True,
                          executable="/bin/bash", cwd=calibrated, capture_output=True,
                          text=True, env=ENV, timeout=120)  # fmt: skip
    assert head.returncode == 0 and head.stderr == "" and len(head.stdout.splitlines()) == 1


def test_output_into_a_pipe_is_not_hard_wrapped(calibrated):
    document = json.loads((calibrated / "s.cal.json").read_text())
    warning = "a warning long enough to be wrapped at eighty columns: " + "word " * 30
    document["accel"]["warnings"] = [warning.strip()]
    (calibrated / "w.cal.json").write_text(json.dumps(document))
    proc = subprocess.run([IMUCAL, "report", "w.cal.json"], capture_output=True, text=True,
                          cwd=calibrated, env=ENV, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert f"- {warning.strip()}" in proc.stdout.splitlines()  # one whole line, grep finds it
    assert "\x1b[" not in proc.stdout


def test_every_command_that_prints_results_has_json(calibrated, tmp_path):
    """--json: one JSON document on stdout, nothing else, with a format name (schemas in
    docs/commands.md)."""
    csv = tmp_path / "raw.csv"
    csv.write_text("t,ax,ay,az\n" + "".join(f"{i / 100},0,0,{9.8 + (i % 3) * 1e-3}\n"
                                             for i in range(600)))  # fmt: skip
    many = [tmp_path / "a.h5", tmp_path / "b.h5"]  # results beside them, none there yet
    for copy in many:
        copy.write_bytes((calibrated / "s.h5").read_bytes())
    cases = {
        "imucal-simulate": ["simulate", "--plan", "six", "-o", tmp_path / "j.h5", "--json"],
        "imucal-calibrate": ["calibrate", calibrated / "s.h5", "-o", tmp_path / "j.cal.json",
                             "--no-store", "--json"],
        "imucal-report": ["report", calibrated / "s.cal.json", "--json"],
        "imucal-apply": ["apply", calibrated / "s.cal.json", calibrated / "s.h5", "-o",
                         tmp_path / "o.h5", "--json"],
        "imucal-import": ["import", csv, "-o", tmp_path / "raw.h5", "--json"],
        "imucal-label": ["label", calibrated / "s.h5", "--faces", "--dry-run", "--json"],
        "imucal-calibrate-many": ["calibrate", *many, "--no-store", "--json"],
        "imucal-history": ["report", calibrated / "s.cal.json", calibrated / "s.cal.json",
                           "--json"],
    }  # fmt: skip
    for name, args in cases.items():
        proc = run(*args)
        assert proc.returncode == 0, (name, proc.stderr)
        document = json.loads(proc.stdout)
        assert document["format"] == name and document["format_version"] >= 1, name
        assert f"`{name}`" in COMMANDS_PAGE.read_text(encoding="utf-8"), f"{name}: schema in docs"
    calibrate = json.loads(run(*cases["imucal-calibrate"][:-1], "--force", "--json").stdout)
    assert calibrate["calibration"]["accel"]["solver"] == "gravity"


def _completion_env(line: str) -> dict[str, str]:
    """The variables bash's completion function sets for ``line`` (the word after the last
    space is completed)."""
    words = line.split()
    cword = len(words) if line.endswith(" ") else len(words) - 1
    return {"COMP_WORDS": line, "COMP_CWORD": str(cword), "_IMUCAL_COMPLETE": "complete_bash"}


def _complete(line: str) -> list[str]:
    """What bash completion offers for ``line``, asked in this process."""
    with _environment(**_completion_env(line)):
        proc = run()
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    return proc.stdout.split()


def test_shell_completion_of_commands_options_plans_and_values():
    assert "--install-completion" in _help("--help").stdout
    assert _complete("imucal cal") == ["calibrate"]
    assert set(_complete("imucal ")) >= set(COMMANDS)
    assert "--json" in _complete("imucal report --js")
    # capture and simulate complete the same plans (one registry, issue 9.4)
    assert _complete("imucal capture --plan q") == ["qureshi18", "qureshi-axes"]
    assert set(_complete("imucal simulate --plan hk")) == {"hk-redundant", "hk-gyro"}
    assert _complete("imucal capture --plan st") == _complete("imucal simulate --plan st")
    assert _complete("imucal capture --plan st") == ["still:"]
    assert _complete("imucal capture --accel-units ") == ["counts", "V", "g", "m/s^2"]
    assert _complete("imucal export --format y") == ["yaml"]
    # a path: nothing offered, so the shell completes file names (complete -o default)
    assert _complete("imucal calibrate ") == []
    # The script for a named shell, as docs/commands.md shows (no detection of the calling shell,
    # which fails where the test runs under no shell: "Shell not supported")
    for shell, words in (("bash", "complete -o default"), ("zsh", "compdef"),
                         ("fish", "complete --command imucal")):  # fmt: skip
        with _environment(_IMUCAL_COMPLETE=f"source_{shell}"):
            script = run()
        assert script.returncode == 0 and words in script.stdout, (shell, script.stdout)


def test_shell_completion_through_the_program():
    """The installed program answers bash's completion protocol as the in-process cases do."""
    proc = subprocess.run([IMUCAL], capture_output=True, text=True, timeout=120,
                          env={**ENV, **_completion_env("imucal capture --plan q")})  # fmt: skip
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert proc.stdout.split() == ["qureshi18", "qureshi-axes"]


def test_calibrate_summary_off_a_terminal_is_plain_lines(calibrated, tmp_path):
    """``calibrate``'s summary into a pipe: plain lines (no colour codes, no style tags),
    the first what ran, the last where it was written."""
    session = calibrated / "s.h5"
    env = {k: v for k, v in ENV.items() if k not in ("FORCE_COLOR", "TTY_COMPATIBLE")}
    proc = subprocess.run([IMUCAL, "calibrate", session, "-o", "out.json", "--no-store"],
                          capture_output=True, text=True, cwd=tmp_path, env=env,
                          timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("accel: gravity (9-parameter), 18 poses")
    assert lines[-1] == "wrote out.json" and "[" not in proc.stdout.replace("[mag]", "")
    assert "\x1b[" not in proc.stdout


def test_several_sessions_table_prints_bracketed_names_as_they_are(calibrated, tmp_path,
                                                                   monkeypatch):  # fmt: skip
    """In this process (the table is the same text; calibrate's summary into a pipe from a
    process is the test above)."""
    import shutil

    for name in ("[red]a.h5", "b.h5"):
        shutil.copy(calibrated / "s.h5", tmp_path / name)
    monkeypatch.chdir(tmp_path)
    proc = _help("calibrate", "[red]a.h5", "b.h5", "--no-store")
    assert proc.returncode == 0, proc.stderr
    assert "│ [red]a.h5 │" in proc.stdout  # the name, not a style tag


def test_one_process_runs_command_after_command_from_one_group():
    """The click group is built once per process (building it anew for each command line
    read every command's signature again: 28 ms a call); a command named after the first
    line ran is still loaded into it, and each line gets its own outcome."""
    from imucal_cli.cli import _command

    _command.cache_clear()
    first = run("--version")
    group = _command()
    for name in ("label", "noise", "report"):
        assert run(name, "--help").returncode == 0 and name in group.commands
    bad = run("report", "--no-such-option")
    assert bad.returncode == 2 and bad.stderr.startswith("imucal: error: ")
    assert first.returncode == 0 and run("--version").stdout == first.stdout
    assert _command.cache_info().misses == 1 and _command() is group
