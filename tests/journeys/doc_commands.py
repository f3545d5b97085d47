"""The shell commands that README.md and docs/ show, read from the Markdown itself.

A command is a line of a code block (indented by four spaces, or fenced) that starts with a
program a user types: `station`, `python3`, `pytest`, or `$ ` before one. A line ending in
`\\` goes on on the next line; text after `  #` is the doc's comment, not the command.

What a command needs beyond "run it and expect exit 0" is said in the doc, in an HTML
comment (invisible when rendered) on the line before its code block:

    <!-- doc-test: skip WHY -->        not run here (real hardware, the test suite itself)
    <!-- doc-test: long -->            run only with the long grids (pytest -m station_grid)
    <!-- doc-test: exit N -->          the exit code the doc promises
    <!-- doc-test: serve URL|FILE -->  runs until Ctrl-C: started, URL answers or FILE
                                       appears, then Ctrl-C, and it must exit 0
    <!-- doc-test: stdin TEXT -->      what the user types (\\n for Enter)
    <!-- doc-test: journey FILE::TEST --> run by that journey test of tests/journeys/, which
                                       checks more than the exit code (not run twice)

Several comments may stand before one block; `<!-- doc-test "station run --station": skip
... -->` applies only to the block's commands that start with the quoted words. A command
with `[...]` in it is a synopsis: each option it names must be one its `--help` lists.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PROGRAMS = ("station", "python3", "pytest", "pdfsig")
MARKER = re.compile(r'<!--\s*doc-test(?:\s+"([^"]+)")?:\s*([\w-]+)\s*(.*?)\s*-->')
FENCE = re.compile(r"^\s*```(\w*)\s*$")
SHELL_FENCES = {"", "sh", "bash", "shell", "console"}


@dataclass(frozen=True)
class DocCommand:
    """One command as a doc shows it, with what its doc says about running it."""

    path: Path
    line: int
    text: str
    markers: dict[str, str] = field(default_factory=dict)

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(REPO)}:{self.line}"

    @property
    def is_synopsis(self) -> bool:
        return "[" in self.text and "]" in self.text

    def argv(self) -> list[str]:
        return expand_ellipsis(shlex.split(self.text))


def doc_files() -> list[Path]:
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def _command_start(line: str) -> str | None:
    text = line.strip()
    if text.startswith("$ "):
        text = text[2:].strip()
    first = text.split(" ", 1)[0]
    if first not in PROGRAMS or re.match(r"^\S+ [\w-]+: ", text):
        return None  # `station run: error: ...` is what a command printed
    return text


def _strip_comment(text: str) -> str:
    """Drop the doc's `# ...` remark (two spaces before it; `#` inside a word stays)."""
    return re.split(r"\s{2,}#|\s#\s", text, maxsplit=1)[0].rstrip()


Markers = list[tuple[str, str, str]]  # (command prefix or "", kind, value)


def _for(markers: Markers, command: str) -> dict[str, str]:
    return {kind: value for prefix, kind, value in markers if command.startswith(prefix)}


def _blocks(lines: list[str]) -> list[tuple[list[tuple[int, str]], Markers]]:
    """Code blocks as ([(line number, text)], the markers standing just before the block)."""
    blocks: list[tuple[list[tuple[int, str]], Markers]] = []
    markers: Markers = []
    current: list[tuple[int, str]] = []
    fence: str | None = None
    prev_blank = True
    for number, line in enumerate(lines, 1):
        fence_match = FENCE.match(line)
        marker = MARKER.search(line)
        indented = line.startswith("    ")
        if fence is not None and not fence_match:
            if fence in SHELL_FENCES:
                current.append((number, line))
            continue
        if fence_match or marker or (line.strip() and not (indented and (current or prev_blank))):
            if current:  # a block ends: it takes the markers before it
                blocks.append((current, markers))
                current, markers = [], []
            elif not (fence_match or marker):
                markers = []  # prose between a marker and its block: the marker is stale
        if fence_match:
            fence = None if fence is not None else fence_match.group(1)
        elif marker:
            markers.append((marker.group(1) or "", marker.group(2), marker.group(3)))
        elif indented and (current or prev_blank):
            current.append((number, line))
        prev_blank = not line.strip()
    if current:
        blocks.append((current, markers))
    return blocks


def commands_in(path: Path) -> list[DocCommand]:
    """Every command in one Markdown file, continuation lines joined."""
    out: list[DocCommand] = []
    for block, markers in _blocks(path.read_text(encoding="utf-8").splitlines()):
        pending: tuple[int, str] | None = None
        for number, line in block:
            if pending is not None:
                start, text = pending
                text = text[:-1].rstrip() + " " + _strip_comment(line.strip())
                pending = (start, text) if text.endswith("\\") else None
                if pending is None:
                    out.append(DocCommand(path, start, text, _for(markers, text)))
                continue
            if line.strip().startswith("[") and out and out[-1].line >= block[0][0]:
                last = out.pop()  # a synopsis goes on: `    [--more] [--options]`
                out.append(DocCommand(path, last.line, f"{last.text} {line.strip()}", last.markers))
                continue
            command = _command_start(line)
            if command is None:
                continue
            command = _strip_comment(command)
            if command.endswith("\\"):
                pending = (number, command)
            else:
                out.append(DocCommand(path, number, command, _for(markers, command)))
    return out


def all_commands() -> list[DocCommand]:
    return [c for path in doc_files() for c in commands_in(path)]


_DUT = re.compile(r"(\d+)=([A-Za-z-]*?)(\d+)$")


def expand_ellipsis(argv: list[str]) -> list[str]:
    """`--dut 1=SIM-3201 ... --dut 32=SIM-3232` as the 32 `--dut` options it stands for."""
    if "..." not in argv:
        return argv
    i = argv.index("...")
    first, last = _DUT.match(argv[i - 1]), _DUT.match(argv[i + 2]) if i + 2 < len(argv) else None
    if not (first and last and argv[i - 2] == argv[i + 1]):
        raise ValueError(f"cannot expand '...' in {' '.join(argv)}: write both ends out")
    lo, hi = int(first.group(1)), int(last.group(1))
    start, width, prefix = int(first.group(3)), len(first.group(3)), first.group(2)
    middle: list[str] = []
    for k in range(lo + 1, hi):
        middle += [argv[i - 2], f"{k}={prefix}{start + k - lo:0{width}d}"]
    return expand_ellipsis(argv[:i] + middle + argv[i + 1:])
