"""The README and the manual (`docs/*.md`) stay true to the code.

- Every relative link and image resolves to a file of the repository, and a `#anchor` into a Markdown
  page names one of its headings (GitHub's heading ids).  http(s) and mailto links are not followed.
- Every `python -m MODULE` written in a code block or in inline code names a module of this project
  (`jaxpose`, `experiments`, `benchmarks`) whose `--help` works, and every `--flag` written after it
  on the same command line (continuation lines ending in a backslash included) is one its `--help`
  lists.  `--preset`, `--dataset` and `--rows` choose which flags exist, so the help is asked with them
  (`python -m experiments.ablation --dataset h36m --help`).  Commands of other tools (`pytest`, `pip`)
  are not checked.

Each help text is produced once per session, in-process where the module has a `main` (called as
`main([..., "--help"])`, or with `sys.argv` set where `main()` reads it), else by a subprocess.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
import inspect
import io
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PROJECT_PACKAGES = ("jaxpose", "experiments", "benchmarks")
OTHER_TOOLS = {"pytest", "pip"}  # `python -m` commands of other tools: not checked
SELECTORS = ("--preset", "--dataset", "--rows")  # read before the rest: they decide which flags exist
ALWAYS_ACCEPTED = {"--help", "-h"}
COMMAND_ENDS = {"&&", "||", "|", ";", "&", ">", ">>", "<"}
FLAG = re.compile(r"--[A-Za-z0-9][\w.\-]*")


def relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


@dataclass(frozen=True)
class Page:
    """A Markdown page split into its prose (inline code replaced) and its code."""

    path: Path
    prose: list[tuple[int, str]]  # (line number, text with inline code spans replaced by "code")
    code_lines: list[tuple[int, str]]  # (line number, a line of a fenced code block)
    inline_code: list[tuple[int, str]]  # (line number, the text of an inline code span)
    headings: list[str]


def parse(path: Path) -> Page:
    prose, code_lines, headings = [], [], []
    fence = None
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        stripped = line.strip()
        marker = re.match(r"(`{3,}|~{3,})", stripped)
        if fence is None and marker:
            fence = marker.group(1)
        elif fence is not None:
            if stripped.startswith(fence) and not stripped[len(fence) :].strip():
                fence = None
            else:
                code_lines.append((number, line))
        else:
            prose.append((number, line))
            if heading := re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line):
                headings.append(heading.group(1))
    # Inline code may run over a line break inside a paragraph: match over the joined prose.
    text = "\n".join(line for _, line in prose)
    starts = [0]
    for _, line in prose:
        starts.append(starts[-1] + len(line) + 1)

    def line_of(offset: int) -> int:
        index = max(i for i, start in enumerate(starts[:-1]) if start <= offset)
        return prose[index][0]

    inline_code = []
    spans = list(re.finditer(r"(`+)(.+?)\1", text, re.S))
    for span in spans:
        inline_code.append((line_of(span.start()), span.group(2).replace("\n", " ")))
    replaced = re.sub(r"(`+)(.+?)\1", lambda span: "code" + "\n" * span.group(0).count("\n"), text, flags=re.S)
    prose = list(zip([number for number, _ in prose], replaced.split("\n")))
    return Page(path, prose, code_lines, inline_code, headings)


def github_anchors(headings: list[str]) -> set[str]:
    """The ids GitHub gives headings: lower case, punctuation dropped, spaces to hyphens, -1, -2 for repeats."""
    anchors, seen = set(), {}
    for heading in headings:
        text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text only
        slug = re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        anchors.add(slug if count == 0 else f"{slug}-{count}")
    return anchors


PARSED = {path: parse(path) for path in PAGES}


# ---------------------------------------------------------------------------------------------- links

LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$")


def link_targets(page: Page) -> list[tuple[int, str]]:
    targets = []
    for number, line in page.prose:
        targets += [(number, match.group(1)) for match in LINK.finditer(line)]
        if match := REFERENCE.match(line):
            targets.append((number, match.group(1)))
    return targets


def broken_links(page: Page) -> list[str]:
    problems = []
    for number, target in link_targets(page):
        if re.match(r"[a-z][a-z0-9+.\-]*:", target, re.I):  # http:, https:, mailto:
            continue
        where = f"{relative(page.path)}:{number}: {target}"
        path_part, _, anchor = target.partition("#")
        file = (page.path.parent / path_part).resolve() if path_part else page.path
        if not file.exists():
            problems.append(f"{where}: no file {file}")
        elif anchor and file.suffix == ".md":
            headings = PARSED[file].headings if file in PARSED else parse(file).headings
            if anchor not in github_anchors(headings):
                problems.append(f"{where}: no heading with id #{anchor} in {relative(file)}")
    return problems


@pytest.mark.parametrize("path", PAGES, ids=relative)
def test_relative_links_and_images_resolve(path):
    problems = broken_links(PARSED[path])
    assert not problems, "broken links:\n" + "\n".join(problems)


def test_the_manual_has_its_pages():
    assert (ROOT / "docs").is_dir() and len(PAGES) > 5, PAGES


# ------------------------------------------------------------------------------------------- commands


@dataclass(frozen=True)
class Command:
    page: str
    line: int
    module: str
    args: tuple[str, ...]

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line} {self.module}"


def command_texts(page: Page) -> list[tuple[int, str]]:
    """(line, one command line): code-block lines with their backslash continuations, inline code spans."""
    texts, pending, start = [], "", 0
    for number, line in page.code_lines:
        if not pending:
            start = number
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        texts.append((start, pending + line))
        pending = ""
    if pending:
        texts.append((start, pending))
    return texts + page.inline_code


def commands_of(page: Page) -> list[Command]:
    commands = []
    for number, text in command_texts(page):
        tokens = text.split()
        for i in range(len(tokens) - 2):
            if tokens[i] in ("python", "python3") and tokens[i + 1] == "-m":
                args = []
                for token in tokens[i + 3 :]:
                    if token in COMMAND_ENDS or token.startswith("#"):
                        break
                    args.append(token)
                module = tokens[i + 2].strip("`'\"(),;")
                commands.append(Command(relative(page.path), number, module, tuple(args)))
    return commands


COMMANDS = [command for path in PAGES for command in commands_of(PARSED[path])]
OURS = [command for command in COMMANDS if command.module.split(".")[0] in PROJECT_PACKAGES]


def flags_of(args: tuple[str, ...]) -> list[str]:
    """The `--flags` of a command line as written: `[--x y]` optional groups and `--x=y` included."""
    flags = []
    for token in args:
        match = FLAG.match(token.lstrip("[("))
        if match:
            flags.append(match.group(0))
    return flags


def help_request(command: Command) -> tuple[str, ...]:
    """The arguments to ask this command's help with: its selectors (which change the flags) and a
    subcommand named before any flag (`python -m jaxpose.formats.camera_file check FILE`)."""
    request = []
    args = list(command.args)
    for i, token in enumerate(args[:-1]):
        for selector in SELECTORS:
            if token == selector:
                request += [selector, args[i + 1]]
            elif token.startswith(selector + "="):
                request.append(token)
    first = args[0] if args else ""
    if first and not first.startswith("-"):
        choices = re.findall(r"\{([\w,\-]+)\}", help_text(command.module, ()))
        if any(first in group.split(",") for group in choices):
            request.insert(0, first)
    return tuple(request)


@functools.lru_cache(maxsize=None)
def help_text(module_name: str, request: tuple[str, ...]) -> str:
    """`python -m module_name *request --help`, its output; fails the test if it does not exit 0."""
    argv = [*request, "--help"]
    # The commands are run from the repository root, where `benchmarks` (not an installed package) imports.
    root_added = str(ROOT) not in sys.path
    if root_added:
        sys.path.insert(0, str(ROOT))
    try:
        module = importlib.import_module(module_name)
    finally:
        if root_added:
            sys.path.remove(str(ROOT))
    main = getattr(module, "main", None)
    output = io.StringIO()
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "200"  # wide enough that no flag name is wrapped
    try:
        if callable(main):
            takes_argv = any(
                p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD, p.VAR_POSITIONAL)
                for p in inspect.signature(main).parameters.values()
            )
            saved_argv = sys.argv
            if not takes_argv:
                sys.argv = [f"python -m {module_name}", *argv]
            try:
                with contextlib.redirect_stdout(output), contextlib.redirect_stderr(output):
                    main(argv) if takes_argv else main()
            except SystemExit as stop:
                command = f"python -m {module_name} {' '.join(argv)}"
                assert stop.code in (0, None), f"{command} exited {stop.code}:\n{output.getvalue()}"
            else:
                pytest.fail(f"python -m {module_name} {' '.join(argv)} did not exit after printing its help")
            finally:
                sys.argv = saved_argv
            return output.getvalue()
        done = subprocess.run(
            [sys.executable, "-m", module_name, *argv], cwd=ROOT, capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0, f"python -m {module_name} {' '.join(argv)} exited {done.returncode}:\n{done.stderr}"
        return done.stdout
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns


def test_every_python_m_command_is_checked_or_another_tool():
    others = sorted({c.module for c in COMMANDS if c.module.split(".")[0] not in PROJECT_PACKAGES} - OTHER_TOOLS)
    assert not others, f"python -m commands of unknown modules (a typo, or add the tool to OTHER_TOOLS): {others}"
    assert len(OURS) > 20, [c.id for c in OURS]


@pytest.mark.parametrize("command", OURS, ids=lambda command: command.id)
def test_command_exists_and_takes_its_flags(command):
    text = help_text(command.module, help_request(command))
    listed = set(FLAG.findall(text)) | ALWAYS_ACCEPTED  # selectors too: the help a command shows lists them
    unknown = [flag for flag in flags_of(command.args) if flag not in listed]
    assert not unknown, (
        f"{command.id}: python -m {command.module} {' '.join(command.args)}\n"
        f"flags its --help does not list: {unknown}"
    )
