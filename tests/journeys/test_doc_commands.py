"""Every shell command in README.md and docs/ runs as the doc shows it and exits as it says.

The commands are read from the Markdown (tests/journeys/doc_commands.py), so a doc that
drifts from the code fails here: a renamed option, a file that moved, an exit code that
changed. They run through the installed `station` command from a scratch folder that holds
the repository's config/, benchmarks/ and dev.py (so `config/...` paths resolve as in a
checkout), with the doc's placeholders (RUN_FOLDER, NAME, OLD.yaml, rec.csv, ...) given real
files. A command that cannot run here says why in its doc (`<!-- doc-test: skip ... -->`).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tests.analysis.hand_turned import hand_turned_session, random_truth
from tests.analysis.synth import article_record
from tests.journeys.doc_commands import REPO, DocCommand, all_commands

BIN = Path(sys.executable).parent
LINKED = ("config", "benchmarks", "dev.py", "tests")
PLACEHOLDER = re.compile(r"^[A-Z][A-Z_]{2,}$")
COMMANDS = all_commands()
TIMEOUT_S = 600
VERDICTS = {"PASS", "FAIL", "ERROR", "ABORTED"}  # values, not placeholders


def _id(command: DocCommand) -> str:
    return command.where


def _marks(command: DocCommand) -> list[pytest.MarkDecorator]:
    return [pytest.mark.station_grid] if "long" in command.markers else []


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A scratch folder laid out like a checkout: config/, benchmarks/, dev.py, tests/."""
    work = tmp_path_factory.mktemp("docs")
    for name in LINKED:
        (work / name).symlink_to(REPO / name)
    return work


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _run(argv: list[str], cwd: Path, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, cwd=cwd, env=_env(), input=stdin, capture_output=True,
                          text=True, timeout=TIMEOUT_S)


@pytest.fixture(scope="module")
def givens(workdir: Path) -> dict[str, str]:
    """Real files and values for the placeholders the docs use."""
    rng = np.random.default_rng(7)
    t, y = article_record(rng)
    rows = "\n".join(f"{a:.6f},{b:.9g}" for a, b in zip(t, y, strict=True))
    (workdir / "rec.csv").write_text("time_s,rate_dps\n" + rows + "\n")
    session = hand_turned_session(rng, random_truth(rng))
    cols = np.column_stack([session.gyro_dps, session.accel_mps2])
    header = "gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"
    np.savetxt(workdir / "session.csv", cols, delimiter=",", header=header, comments="",
               fmt="%.10g")
    sections = {k: {"start": a, "end": b} for k, (a, b) in session.sections.items()}
    (workdir / "sections.json").write_text(json.dumps(sections))
    shutil.copy(REPO / "tests/data/old_form/eol-rate-table.yaml", workdir / "OLD.yaml")
    return {"NAME": "Quality Engineer", "OLD.yaml": "OLD.yaml"}


@pytest.fixture(scope="module")
def run_folder(workdir: Path) -> str:
    """RUN_FOLDER: the folder a run as README.md shows it prints."""
    done = _run([str(BIN / "station"), "run", "--sim", "--dut", "SIM-0001",
                 "--out", str(workdir / "runs")], workdir)
    assert done.returncode == 0, done.stdout + done.stderr
    found = re.search(r"run folder: (\S+)", done.stdout)
    assert found, done.stdout
    return found.group(1)


def _argv(command: DocCommand, values: dict[str, str]) -> list[str]:
    argv = [values.get(word, word) for word in command.argv()]
    unknown = [w for w in argv[1:] if PLACEHOLDER.match(w) and w not in VERDICTS]
    assert not unknown, (
        f"{command.where}: no value for {unknown} in this test: add it to `givens`, or "
        f"mark the doc's block with <!-- doc-test: skip WHY -->"
    )
    program = argv[0]
    if program in ("station", "pytest", "pdfsig"):
        found = shutil.which(program, path=_env()["PATH"])
        argv[0] = found or program
    elif program == "python3":
        argv[0] = sys.executable
    return argv


def _values(command: DocCommand, request: pytest.FixtureRequest) -> dict[str, str]:
    values = dict(request.getfixturevalue("givens"))
    if "RUN_FOLDER" in command.text or command.markers.get("cwd") == "RUN_FOLDER":
        values["RUN_FOLDER"] = request.getfixturevalue("run_folder")
    return values


def _help_lists_options(command: DocCommand, cwd: Path) -> None:
    """A synopsis: every option it names is one the program's --help lists."""
    words = command.text.split()
    head = [words[0]]
    for w in words[1:]:
        if w.startswith(("-", "[")) or PLACEHOLDER.match(w) or "." in w and w != words[1]:
            break
        head.append(w)
    argv = _argv(DocCommand(command.path, command.line, " ".join(head)), {}) + ["--help"]
    shown = _run(argv, cwd)
    assert shown.returncode == 0, shown.stderr
    options = set(re.findall(r"--[a-z][\w-]*", command.text))
    missing = sorted(o for o in options if o not in shown.stdout)
    assert not missing, f"{command.where}: {' '.join(head)} --help does not list {missing}"


def _journey_runs_it(command: DocCommand) -> None:
    """`journey FILE::TEST`: a journey test runs this very command with more to check (its
    verdicts, certificates, progress lines); it must exist and use the command's files."""
    file, _, test = command.markers["journey"].partition("::")
    source = (REPO / "tests" / "journeys" / file).read_text(encoding="utf-8")
    assert f"def {test}(" in source, f"{command.where}: no test {test} in {file}"
    files = [w for w in command.argv() if w.endswith(".yaml")]
    missing = [f for f in files if f not in source]
    assert not missing, f"{command.where}: {file}::{test} does not run {missing}"


def _wait_until_up(target: str, proc: subprocess.Popen[str], cwd: Path) -> None:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"exited {proc.returncode} before it was up"
        if target.startswith("http"):
            try:
                with urllib.request.urlopen(target, timeout=2) as reply:
                    if reply.status == 200:
                        return
            except OSError:
                pass
        elif (cwd / target).exists():
            return
        time.sleep(0.3)
    raise AssertionError(f"{target} did not come up within 120 s")


def _serve(argv: list[str], target: str, cwd: Path) -> Iterator[int]:
    proc = subprocess.Popen(argv, cwd=cwd, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        _wait_until_up(target, proc, cwd)
        proc.send_signal(signal.SIGINT)  # the doc's "until Ctrl-C"
        proc.wait(timeout=60)
        yield proc.returncode
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize(
    "command", [pytest.param(c, id=_id(c), marks=_marks(c)) for c in COMMANDS]
)
def test_doc_command_runs_as_shown(
    command: DocCommand, workdir: Path, request: pytest.FixtureRequest
) -> None:
    if "skip" in command.markers:
        pytest.skip(f"{command.where}: {command.markers['skip']}")
    if "journey" in command.markers:
        _journey_runs_it(command)
        return
    if command.is_synopsis:
        _help_lists_options(command, workdir)
        return
    argv = _argv(command, _values(command, request))
    cwd = workdir
    if command.markers.get("cwd") == "RUN_FOLDER":
        cwd = Path(request.getfixturevalue("run_folder"))
    expected = int(command.markers.get("exit", "0"))
    if "serve" in command.markers:
        code = next(_serve(argv, command.markers["serve"], cwd))
        assert code == expected, f"{command.where}: exit {code} after Ctrl-C"
        return
    stdin = command.markers.get("stdin", "").replace("\\n", "\n") or None
    done = _run(argv, cwd, stdin)
    assert done.returncode == expected, (
        f"{command.where}: `{command.text}` exited {done.returncode}, the doc says "
        f"{expected}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    )
    assert "Traceback" not in done.stderr, done.stderr[-3000:]


def test_the_docs_show_commands_and_each_is_known() -> None:
    """The reader finds the docs' commands (a change to the Markdown that hid them all
    would make the test above vacuous), and every marker is one this test understands."""
    where = {c.where.split(":")[0] for c in COMMANDS}
    assert {"README.md", "docs/records.md", "docs/discrepancy.md"} <= where
    assert len(COMMANDS) >= 30
    known = {"skip", "long", "exit", "serve", "stdin", "cwd", "journey"}
    for c in COMMANDS:
        assert set(c.markers) <= known, f"{c.where}: unknown doc-test marker {c.markers}"
        if "skip" in c.markers:
            assert c.markers["skip"].strip(), f"{c.where}: a skip must say why"
