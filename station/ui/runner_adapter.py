"""The UI's only door to the end-of-line engine (station/uut.py).

The web layer talks to a `Runner`: start a run for {socket: serial}, abort it, list the
procedures and products, report the instruments. The runner reports back through a sink
with plain dict events (the UI's own vocabulary, documented on `Runner.start`), so the pages
never depend on the engine's internal types. `EngineRunner` is the real one; tests may
substitute any object with the same methods.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

log = logging.getLogger(__name__)

EventSink = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class Choice:
    """A procedure the engineer may select."""

    name: str
    path: str
    description: str = ""


@dataclass(frozen=True)
class ProductChoice:
    """A product, with the pattern its serial labels must match (a Python regex)."""

    name: str
    path: str
    serial_pattern: str
    serial_example: str = ""


@dataclass(frozen=True)
class StartRequest:
    serials: dict[int, str]  # socket -> scanned serial
    procedure_path: str
    product_path: str
    operator: str = ""


@dataclass(frozen=True)
class InstrumentLight:
    """An instrument's three lights: connected, in calibration (not overdue), faulted."""

    name: str
    connected: bool
    in_calibration: bool | None  # None: the station does not know the due date
    faulted: bool
    calibration_due: str = ""  # ISO date
    detail: str = ""


@dataclass
class StationInfo:
    """What the runner knows about the station before any run."""

    name: str = "station"
    sockets: list[int] = field(default_factory=lambda: [1])
    simulated: bool = False
    out_dir: str = "runs"


class Runner(Protocol):
    info: StationInfo

    def procedures(self) -> list[Choice]: ...

    def products(self) -> list[ProductChoice]: ...

    def default_selection(self) -> tuple[str, str]:
        """(procedure path, product path) selected when the station starts."""
        ...

    def instruments(self) -> list[InstrumentLight]: ...

    def start(self, request: StartRequest, sink: EventSink) -> str:
        """Start the run in the background and return its id at once.

        Events sent to `sink` (from any thread), each a dict with a "type":
          {"type": "steps", "steps": [name, ...]}
          {"type": "progress", "step": str, "step_index": int, "step_count": int,
           "condition": str, "fraction": 0..1, "remaining_s": wall seconds | None}
          {"type": "samples", "socket": int, "t_s": [..], "rate_dps": [..], "temp_c": [..]}
          {"type": "instruments", "instruments": [InstrumentLight as a dict, ...]}
          {"type": "log", "level": str, "message": str}
          {"type": "finished", "results": [{"socket", "serial", "verdict", "reason",
           "failed": [{"name", "value", "units", "low", "high"}], "run_folder"}],
           "safe_state": {name: bool} | None}
        "finished" is always the last event of a run, also after an abort or an error.
        """
        ...

    def abort(self) -> None:
        """Ask the running run to stop; cleanup (safe state) still runs, then "finished"."""
        ...

    def close(self) -> None: ...


def engine_available() -> bool:
    """True when station/uut.py (the end-of-line engine) is part of this build."""
    try:
        import station.uut  # noqa: F401
    except ModuleNotFoundError as exc:
        if exc.name == "station.uut":
            return False
        raise
    return True
