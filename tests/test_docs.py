"""The user documentation: a README a newcomer reads in minutes, reference pages in ``docs/``
that hold everything else, and links between them that resolve.

Fast and offline: the pages are read as text and compared with the code's own registries
(the typer commands and their options, the config dataclasses, the plans, the import and export
formats, the benchmarks). ``make docs`` builds the same pages with MkDocs ``--strict``.
"""

from __future__ import annotations

import ast
import re
import tomllib
import unicodedata
from dataclasses import MISSING, fields, is_dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))
USER_DOCS = [README, *PAGES]

README_MAX_BYTES = 20_000
"""A README read in five minutes: under 20 KB (it was 99.6 KB before the reference pages)."""


def _prose(text: str) -> str:
    """The text without fenced code blocks and inline code (links there are examples)."""
    text = re.sub(r"^[ \t]*(```|~~~).*?^[ \t]*\1", "", text, flags=re.S | re.M)
    return re.sub(r"`[^`\n]*`", "", text)


def _slug(heading: str) -> str:
    """The anchor MkDocs (Python-Markdown's toc) gives a heading; GitHub's is the same for the
    headings these pages use (letters, digits, spaces, hyphens and brackets)."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link: its text
    text = text.replace("`", "").replace("*", "")
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def _headings(path: Path) -> list[tuple[int, str]]:
    """(level, text) of every heading outside code blocks."""
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"^[ \t]*(```|~~~).*?^[ \t]*\1", "", text, flags=re.S | re.M)
    return [(len(m[1]), m[2].strip()) for m in re.finditer(r"^(#{1,6})\s+(.+?)\s*#*$", text, re.M)]


def _anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    anchors = set()
    for _, text in _headings(path):
        slug = _slug(text)
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        anchors.add(slug if n == 0 else f"{slug}_{n}")
    return anchors


def _sections(path: Path, level: int) -> dict[str, str]:
    """Heading text -> the text under it, up to the next heading of this level or higher."""
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"^[ \t]*(```|~~~).*?^[ \t]*\1", "", text, flags=re.S | re.M)
    parts = re.split(rf"^(#{{1,{level}}}\s+.+)$", text, flags=re.M)
    out = {}
    for head, body in zip(parts[1::2], parts[2::2], strict=True):
        if len(head) - len(head.lstrip("#")) == level:
            out[head.lstrip("#").strip()] = body
    return out


def test_readme_is_short():
    size = len(README.read_bytes())
    assert size < README_MAX_BYTES, f"README.md is {size} bytes: move detail into docs/"


@pytest.mark.parametrize("page", USER_DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_resolves(page):
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", _prose(page.read_text("utf-8"))):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        dest = (page.parent / file).resolve() if file else page
        if not dest.is_file():
            broken.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(f"{target}: no heading #{anchor} in {dest.name}")
    assert not broken, broken


@pytest.mark.parametrize("page", USER_DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_issue_numbers_or_shared_paths_in_user_documentation(page):
    text = page.read_text(encoding="utf-8")
    assert not re.findall(r"\bissues?\s*#?\d", text, re.I), "issue numbers are for developers"
    assert "../shared" not in text, "name the recording (MaD Lab's example ...), not its path"


def test_every_page_is_in_the_site_navigation():
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    listed = set(re.findall(r":\s*([\w.-]+\.md)\s*$", config, re.M))
    assert listed == {p.name for p in PAGES}, "mkdocs.yml nav and docs/*.md differ"


def _commands():
    """Every command by its name after ``imucal``: a group's sub-commands as ``GROUP SUB``
    (``registry list``) beside the group itself."""
    import typer

    from imucal_cli.cli import app

    group = typer.main.get_command(app)
    ctx = typer.Context(group)
    out = {}
    for name in group.list_commands(ctx):  # click's contract: the commands load when asked for
        command = group.get_command(ctx, name)
        out[name] = command
        if hasattr(command, "commands"):  # a group (typer's own click)
            out.update({f"{name} {sub}": c for sub, c in command.commands.items()})
    return out


def test_every_command_and_option_has_its_section_in_commands_page():
    sections = _sections(DOCS / "commands.md", 2)
    for name, command in sorted(_commands().items()):
        body = sections.get(f"imucal {name}")
        assert body is not None, f"docs/commands.md: no section `## imucal {name}`"
        for param in command.params:
            if param.param_type_name != "option":
                continue
            longest = max(param.opts + param.secondary_opts, key=len)
            assert f"`{longest}`" in body, f"docs/commands.md, imucal {name}: {longest}"


def test_commands_page_holds_the_exit_statuses_of_every_command():
    from imucal_cli.cli.app import EXIT_CODES

    text = (DOCS / "commands.md").read_text(encoding="utf-8")
    for code, what in EXIT_CODES:
        assert f"| {code} | {what} |" in text, code


def _config_tables(obj, path=""):
    """(table path, dataclass instance) of the config and every nested table."""
    yield path, obj
    for f in fields(obj):
        if f.default is MISSING and is_dataclass(f.default_factory):
            yield from _config_tables(getattr(obj, f.name), f"{path}.{f.name}".lstrip("."))


def test_every_config_key_is_documented_with_its_default():
    from imucal_cli.formats.config import Config, rule_of

    page = DOCS / "config.md"
    sections = {name.strip("[]"): body for name, body in _sections(page, 2).items()}
    for path, table in _config_tables(Config()):
        body = sections.get(path or "Top level")
        assert body is not None, f"docs/config.md: no section `## [{path}]`"
        for f in fields(table):
            if f.default is MISSING and is_dataclass(f.default_factory):
                continue
            row = re.search(rf"^\| `{f.name}` \| ([^|]+) \|", body, re.M)
            assert row, f"docs/config.md [{path}]: no row for `{f.name}`"
            cell = row[1].strip()
            default = getattr(table, f.name)
            if default is None:
                assert cell.startswith("unset"), (path, f.name, cell)
                continue
            stated = tomllib.loads(f"x = {cell.strip('`')}")["x"]
            if rule_of(f).kind == "number":
                assert stated == pytest.approx(default), (path, f.name, cell)
            else:
                assert stated == default, (path, f.name, cell)


def test_every_plan_format_and_benchmark_is_documented():
    from imucal_cli.formats.importers import FORMATS
    from imucal_cli.plans import BUILTIN_PLANS
    from imucal_cli.use.export import EXPORT_FORMATS

    capture = (DOCS / "capture.md").read_text(encoding="utf-8")
    for plan in BUILTIN_PLANS:
        assert f"| `{plan}` |" in capture, f"docs/capture.md: plan {plan}"
    imports = (DOCS / "import.md").read_text(encoding="utf-8")
    for fmt in FORMATS:
        assert f"`{fmt}`" in imports, f"docs/import.md: --format {fmt}"
    exports = (DOCS / "export.md").read_text(encoding="utf-8")
    for fmt in EXPORT_FORMATS:
        assert f"| `{fmt}`" in exports, f"docs/export.md: --format {fmt}"
    tree = ast.parse((ROOT / "bench" / "__main__.py").read_text(encoding="utf-8"))
    names = next(
        ast.literal_eval(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "BENCHMARKS"
    )
    headings = {text for _, text in _headings(DOCS / "accuracy.md")}
    for name in names:
        assert name in headings, f"docs/accuracy.md: no section for the {name} benchmark"


def _command_lines(text: str):
    """Every ``imucal COMMAND ...`` line of the code blocks (continuation lines joined,
    comments and a ``$`` prompt dropped)."""
    for block in re.findall(r"^[ \t]*```[^\n]*\n(.*?)^[ \t]*```", text, re.S | re.M):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #")[0].strip().removeprefix("$ ")
            for part in re.split(r"&&|\|", line):
                words = part.split()
                if len(words) >= 2 and words[0] == "imucal":
                    yield words


@pytest.mark.parametrize("page", USER_DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_command_line_shown_uses_real_commands_and_options(page):
    commands = _commands()
    wrong = []
    for words in _command_lines(page.read_text(encoding="utf-8")):
        name, rest = words[1], words[2:]
        if name.startswith("-"):  # imucal --install-completion, --version
            continue
        if rest and f"{name} {rest[0]}" in commands:  # a group's sub-command
            name, rest = f"{name} {rest[0]}", rest[1:]
        command = commands.get(name)
        if command is None:
            wrong.append(f"imucal {name}: no such command")
            continue
        known = {o for p in command.params for o in p.opts + p.secondary_opts}
        wrong += [f"imucal {name} {w}" for w in rest
                  if w.startswith("-") and w.split("=")[0] not in known]  # fmt: skip
    assert not wrong, wrong
