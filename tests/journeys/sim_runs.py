"""One `station run` per command line in a test session, whichever journey asks for it.

The operator's journey and the discrepancy journey both run the shipped 8- and 32-socket
loads exactly as README.md shows them; each load takes minutes of the long grid, so the
second journey to ask gets the first one's run (its output and its run folders) instead of
running it again. The runs live in one temporary folder for the session.
"""

from __future__ import annotations

import atexit
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
STATION = Path(sys.executable).parent / "station"  # the installed console script


@dataclass(frozen=True)
class SimRun:
    proc: subprocess.CompletedProcess[str]
    out: Path  # the run's --out: its run folders and results database
    wall_s: float


_RUNS: dict[tuple[str, ...], SimRun] = {}
_ROOT: list[Path] = []


def _session_folder() -> Path:
    if not _ROOT:
        _ROOT.append(Path(tempfile.mkdtemp(prefix="journey-runs-")))
        atexit.register(shutil.rmtree, _ROOT[0], True)
    return _ROOT[0]


def station_run_once(*args: str, timeout_s: float = 3000) -> SimRun:
    """`station run ARGS --out <a folder of its own>` from the repository root, once per
    ARGS in this session. Nothing must write into the run folders but `station discrepancy`'s
    own `<run folder>_discrepancy/` beside them."""
    key = tuple(args)
    if key not in _RUNS:
        out = _session_folder() / f"run{len(_RUNS)}"
        t0 = time.monotonic()
        proc = subprocess.run([str(STATION), "run", *args, "--out", str(out)], cwd=REPO,
                              capture_output=True, text=True, timeout=timeout_s)
        _RUNS[key] = SimRun(proc, out, time.monotonic() - t0)
    return _RUNS[key]
