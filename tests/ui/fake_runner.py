"""An in-process stand-in for the engine, for the UI-mechanics tests only.

It walks through named steps on a timer, streams samples, writes a real record.json (the
pinned format) and a small PDF per part, fails parts whose serial contains "BAD", and honours
abort by ending ABORTED after its cleanup. With `prompt` set it asks the operator (a
kind="prompt" event) at the manual step and clears it (prompt_done) when `answer()` is called.
The real engine is exercised by test_station_sim.py.
"""

from __future__ import annotations

import math
import threading
from datetime import UTC, datetime
from pathlib import Path

from procedures.runtime.record import (
    Dut,
    FileRef,
    Measurement,
    Outcome,
    RunRecord,
    Verdict,
    write_record,
)
from station.errors import UserError
from station.ui.history import result_from_record
from station.ui.instruments import InstrumentLight
from station.ui.runner_adapter import Choice, EventSink, ProductChoice, StartRequest, StationInfo

# (step type name, condition), as the engine names them
STEPS = [
    ("connect", ""),
    ("power_identify", ""),
    ("thermal", "T45_V5.25"),
    ("rate_table", "T45_V5.25"),
    ("manual_stop", "T45_V5.25"),
    ("fit", ""),
    ("verify", ""),
]
DISPOSITIONS = {
    "PASS": "Place in tray A",
    "FAIL": "Red bin: do not ship",
    "ERROR": "Retest once, then call the engineer",
}
PDF = (
    b"%PDF-1.4\n1 0 obj<</Type/Catalog/Pages 2 0 R>>endobj\n"
    b"2 0 obj<</Type/Pages/Kids[]/Count 0>>endobj\ntrailer<</Root 1 0 R>>\n%%EOF\n"
)


class FakeRunner:
    def __init__(self, out_dir: Path, sockets: list[int] | None = None, step_s: float = 0.05):
        self.info = StationInfo(
            name="Fake station", sockets=sockets or [1, 2], simulated=True, out_dir=str(out_dir)
        )
        self.out_dir = out_dir
        self.step_s = step_s
        self.started: list[StartRequest] = []
        self.prompt: tuple[str, list[int]] | None = None  # asked at the manual_stop step
        self._answered = threading.Event()
        self.safe_state_calls = 0
        self._abort = threading.Event()
        self._thread: threading.Thread | None = None
        self.lights = [
            InstrumentLight("rate table", True, True, False, "2027-06-30"),
            InstrumentLight("chamber", True, False, False, "2020-01-01", "calibration overdue"),
            InstrumentLight("supply", True, None, False),
        ]

    def procedures(self) -> list[Choice]:
        return [Choice("eol-full", "/cfg/full.yaml"), Choice("eol-short", "/cfg/short.yaml")]

    def products(self) -> list[ProductChoice]:
        return [
            ProductChoice(
                "GYR-130",
                "/cfg/gyr130.yaml",
                r"^[A-Z]{2,4}-[0-9]{4,8}$",
                "SIM-0001",
                dict(DISPOSITIONS),
            ),
            ProductChoice("GYR-200", "/cfg/gyr200.yaml", r"^G2-[0-9]{6}$", "G2-000001"),
        ]

    def default_selection(self) -> tuple[str, str]:
        return "/cfg/full.yaml", "/cfg/gyr130.yaml"

    def instruments(self) -> list[InstrumentLight]:
        return list(self.lights)

    def start(self, request: StartRequest, sink: EventSink) -> str:
        refused = [s for s in request.serials.values() if s.startswith("NO-")]
        if refused:  # as the engine does for a part it will not run
            raise UserError(f"serial {refused[0]} is refused by the engine; rescan the label")
        self.started.append(request)
        self._abort.clear()
        run_id = f"fake-{len(self.started)}"
        self._thread = threading.Thread(target=self._run, args=(request, sink), daemon=True)
        self._thread.start()
        return run_id

    def abort(self) -> None:
        self._abort.set()

    def close(self) -> None:
        self._abort.set()
        if self._thread is not None:
            self._thread.join(5)

    def answer(self) -> None:
        """The operator did what the prompt asked."""
        self._answered.set()

    def wait(self, timeout_s: float = 10.0) -> None:
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _run(self, request: StartRequest, sink: EventSink) -> None:
        labels = [f"{step} {cond}".strip() for step, cond in STEPS]
        items = [{"step": step, "condition": cond} for step, cond in STEPS]
        sink({"type": "steps", "steps": labels, "items": items})
        aborted = False
        t = 1000.0  # the bench's clock: the screen counts from the run's start
        for i, (step, condition) in enumerate(STEPS):
            if self._abort.is_set():
                aborted = True
                break
            remaining = (len(STEPS) - i) * self.step_s
            sink(
                {
                    "type": "progress",
                    "step": labels[i],
                    "step_type": step,
                    "step_index": i,
                    "step_count": len(STEPS),
                    "condition": condition,
                    "fraction": i / len(STEPS),
                    "remaining_s": remaining,
                    "sockets": {str(k): "RUNNING" for k in request.serials},
                }
            )
            for socket in request.serials:
                ts = [t + k * 0.1 for k in range(10)]
                sink(
                    {
                        "type": "samples",
                        "socket": socket,
                        "t_s": ts,
                        "rate_dps": [100 * math.sin(x) for x in ts],
                        "temp_c": [25 + 0.1 * x for x in ts],
                    }
                )
            t += 1.0
            if step == "manual_stop" and self.prompt is not None:
                message, sockets = self.prompt
                sink({"type": "prompt", "message": message, "sockets": sockets})
                while not self._answered.wait(0.05) and not self._abort.is_set():
                    pass
                sink({"type": "prompt_done"})
            self._abort.wait(self.step_s)
        self.safe_state_calls += 1
        results = [
            self._write(s, serial, request, aborted) for s, serial in request.serials.items()
        ]
        sink(
            {
                "type": "finished",
                "results": results,
                "safe_state": {"all": True, "rate_table": True, "chamber": True, "supply": True},
            }
        )

    def _write(self, socket: int, serial: str, request: StartRequest, aborted: bool) -> dict:
        now = datetime.now(UTC)
        folder = self.out_dir / f"{now:%Y%m%dT%H%M%S%fZ}_{serial}"
        bad = "BAD" in serial
        bias = 14.2 if bad else 1.3
        outcome = Outcome.FAIL if bad else Outcome.PASS
        verdict = Verdict.ABORTED if aborted else Verdict.FAIL if bad else Verdict.PASS
        record = RunRecord(
            run_id=folder.name,
            verdict=verdict,
            started_utc=now.isoformat(),
            finished_utc=now.isoformat(),
            operator=request.operator,
            reason="aborted by the operator"
            if aborted
            else "raw_bias_dps out of limits"
            if bad
            else "",
            dut=Dut(serial=serial, socket=socket),
            product=FileRef(path=request.product_path, name="GYR-130", sha256="0" * 64),
            procedure=FileRef(path=request.procedure_path, name="eol-full", sha256="0" * 64),
            measurements=[]
            if aborted
            else [
                Measurement(
                    name="raw_bias_dps",
                    value=bias,
                    units="deg/s",
                    low=-10,
                    high=10,
                    outcome=outcome,
                )
            ],
        )
        write_record(folder, record)
        if not aborted:
            (folder / "certificate.pdf").write_bytes(PDF)
        return result_from_record(record, folder)
