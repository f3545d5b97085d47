"""The line operator's terminal journey (issue 26, Deliver 2): `station run` through the
installed `station` command, as README.md and docs/manual-stop.md show it, on each shipped
station file with its sim config. Each run must end with every part judged and a
certificate; the only addition to the documented command is `--out` (a temporary folder, so
a test leaves the repository's runs/ alone).

The one-socket run is in the default suite (about 30 s wall); the 8- and 32-socket loads and
the hand-turned bench are long and carry `station_grid` (CI's long-grid step)."""

from __future__ import annotations

import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.journeys.sim_runs import station_run_once

ROOT = Path(__file__).resolve().parents[2]
STATION = Path(sys.executable).parent / "station"  # the installed command (dev.py's .venv)
LINE_WIDTH = 100  # station run's progress lines in a log (station/cli/run.py)


@dataclass
class Run:
    code: int
    stdout: str
    stderr: str
    verdicts: dict[int, tuple[str, str]]  # socket -> (serial, verdict)
    certificates: dict[int, Path]
    wall_s: float


def station_run(*args: str) -> Run:
    """The run of `station run ARGS --out <a temporary folder>` (once per session: the
    discrepancy journey analyses the same loads, tests/journeys/sim_runs.py)."""
    if not STATION.exists():
        pytest.skip(f"no installed station command at {STATION}: run `python3 dev.py test`")
    shared = station_run_once(*args)
    r, wall = shared.proc, shared.wall_s
    verdicts = {int(m[1]): (m[2], m[3]) for m in
                re.finditer(r"^socket (\d+) (\S+): (PASS|FAIL|ERROR|ABORTED)", r.stdout, re.M)}
    certs: dict[int, Path] = {}
    current = None
    for line in r.stdout.splitlines():
        if m := re.match(r"socket (\d+) ", line):
            current = int(m[1])
        elif (m := re.match(r"\s+certificate: (.+)$", line)) and current is not None:
            certs[current] = Path(m[1])
    assert "Traceback" not in r.stderr, r.stderr[-3000:]
    return Run(r.returncode, r.stdout, r.stderr, verdicts, certs, wall)


def _every_part_passed(run: Run, serials: dict[int, str]) -> None:
    assert run.code == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert {s: v for s, v in run.verdicts.items()} == {
        s: (serial, "PASS") for s, serial in serials.items()}, run.stdout[-3000:]
    for sock in serials:
        pdf = run.certificates.get(sock)
        assert pdf is not None and pdf.read_bytes().startswith(b"%PDF"), (sock, pdf)


def _progress_lines_bounded(run: Run) -> None:
    progress = [line for line in run.stdout.splitlines() if line.startswith("[")]
    assert progress, run.stdout[:2000]
    assert max(len(line) for line in progress) <= LINE_WIDTH, max(progress, key=len)


def test_one_part_on_config_station_yaml() -> None:
    """README: `station run --sim --dut SIM-0001` (config/station.yaml, the bench in lockstep)."""
    run = station_run("--sim", "--dut", "SIM-0001")
    _every_part_passed(run, {1: "SIM-0001"})
    assert "simulated bench running in lockstep" in run.stdout
    _progress_lines_bounded(run)
    # the first time left the run showed is within a tenth of the station time it took
    record = json.loads((run.certificates[1].parent / "record.json").read_text())
    estimated = record["analysis"]["plan"]["estimated_station_s"]
    total = record["timings"]["total"]
    assert abs(estimated - total) <= 0.1 * total, (estimated, total)
    print(f"1 socket: wall {run.wall_s:.0f} s, station {total / 60:.1f} min")


EIGHT = {k: f"SIM-010{k}" for k in range(1, 9)}


@pytest.mark.station_grid
@pytest.mark.timeout(3600)
def test_eight_sockets_sim_config_as_readme_shows() -> None:
    """README: `station run --sim --sim-config config/sim/eight_sockets.yaml --dut 1=SIM-0101
    ...`. Socket 8's part has every optional effect (k2, k3, asymmetry, ...), beyond the
    first-order model the station fits: it is the one part built to FAIL its verification,
    certificate and all; the seven others PASS."""
    run = station_run("--sim", "--sim-config", "config/sim/eight_sockets.yaml",
                      *[a for k, s in EIGHT.items() for a in ("--dut", f"{k}={s}")])
    assert run.code == 1, run.stdout[-3000:] + run.stderr[-2000:]
    assert run.verdicts == {**{k: (s, "PASS") for k, s in EIGHT.items() if k < 8},
                            8: ("SIM-0108", "FAIL")}, run.stdout[-3000:]
    assert sorted(run.certificates) == list(range(1, 9))
    assert "residual_scale_error" in run.stdout  # it fails its verification, as built
    print(f"8 sockets (eight_sockets.yaml): wall {run.wall_s:.0f} s")


@pytest.mark.station_grid
@pytest.mark.timeout(3600)
def test_thirty_two_parts_on_station_32() -> None:
    """README: `station run --sim --station config/station-32.yaml --dut 1=SIM-3201 ...
    --dut 32=SIM-3232` (its sim config: config/sim/thirty_two_sockets.yaml)."""
    serials = {k: f"SIM-32{k:02d}" for k in range(1, 33)}
    run = station_run("--sim", "--station", "config/station-32.yaml",
                      *[a for k, s in serials.items() for a in ("--dut", f"{k}={s}")])
    _progress_lines_bounded(run)  # 32 sockets once made 405-character lines
    _every_part_passed(run, serials)
    print(f"32 sockets: wall {run.wall_s:.0f} s")


@pytest.mark.station_grid
@pytest.mark.timeout(3600)
def test_one_part_on_the_hand_turned_bench() -> None:
    """docs/manual-stop.md: `station run --sim --station config/station-manual.yaml --dut
    SIM-0001`; the simulated operator answers each prompt by turning the fixture."""
    run = station_run("--sim", "--station", "config/station-manual.yaml", "--dut", "SIM-0001")
    prompts = [line for line in run.stdout.splitlines() if line.startswith(">>> OPERATOR")]
    assert prompts and all("socket 1" in p for p in prompts), run.stdout[-2000:]
    _every_part_passed(run, {1: "SIM-0001"})
    print(f"hand-turned bench: {len(prompts)} prompts, wall {run.wall_s:.0f} s")
