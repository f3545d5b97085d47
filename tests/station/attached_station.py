"""`station ...` whose `--sim` bench is one already running: the signal grid's.

    python tests/station/attached_station.py STATE_FILE run --sim --dut SIM-0001 ...

Everything is the real station (its CLI, its signal handling, its run) except that
`launch_bench` attaches to the bench that wrote STATE_FILE (`station bench --state`) instead
of starting and stopping one: that bench is its own process, so the test reads its truth
after this station has exited, however it exited.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def main() -> int:
    state_file = Path(sys.argv[1])
    sys.path.insert(0, str(ROOT))
    import drivers.sim.launcher as launcher

    @contextmanager
    def attach(*args: Any, **kwargs: Any) -> Iterator[launcher.BenchHandle]:
        endpoints = launcher.BenchEndpoints.from_state(json.loads(state_file.read_text()))
        control = launcher.ControlClient(endpoints.control)
        try:
            yield launcher.BenchHandle(endpoints, control, None, state_file)  # type: ignore[arg-type]
        finally:
            control.close()

    launcher.launch_bench = attach
    from station.cli.main import main as station_main

    return station_main(sys.argv[2:])


if __name__ == "__main__":
    sys.exit(main())
