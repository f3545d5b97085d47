"""The station's live state as the pages see it, and the rules around starting a run.

One run at a time per fixture: a second Start while a run is in progress is refused with a
message naming the run. Serials are validated here against the product's pattern (never
trust the page), and Start is refused while an instrument the run needs is unreachable or
faulted. Every change is published to the hub; `snapshot()` is what a page that (re)connects
receives first, so a reload mid-run shows the run in progress (with any operator prompt).

The engine's names become plain-word phrases here (station/ui/plain_words.py): each progress
event gets "words", the step list "step_words", each failed measurement "words", each result
the product's disposition for its verdict. Chart time is counted from the run's first sample.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from station.errors import UserError
from station.ui import plain_words
from station.ui.hub import Hub
from station.ui.runner_adapter import ProductChoice, Runner, StartRequest

log = logging.getLogger(__name__)

SERIAL_MAX_CHARS = 64
CHART_MAX_POINTS = 1200  # per socket; older points are thinned, never the newest
SAMPLE_PUSH_INTERVAL_S = 0.2  # live chart updates at most 5 times a second


class RunRefusedError(UserError):
    """Start refused: a run is in progress, or the request is incomplete."""


class SerialRejectedError(UserError):
    """A scanned serial does not fit the product's pattern."""

    def __init__(self, socket: int, message: str) -> None:
        super().__init__(message)
        self.socket = socket


def _now_utc() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


class Controller:
    def __init__(self, runner: Runner, hub: Hub) -> None:
        self.runner = runner
        self.hub = hub
        self._lock = threading.RLock()
        procedure, product = runner.default_selection()
        self._selection = {"procedure": procedure, "product": product}
        self._generation = 0
        self._run: dict[str, Any] | None = None
        self._last: dict[str, Any] | None = None
        self._instruments = [asdict(i) for i in runner.instruments()]
        self._chart: dict[int, dict[str, list[float]]] = {}
        self._pending: dict[int, dict[str, list[float]]] = {}
        self._last_push_s = 0.0
        self._t0_s: float | None = None  # the run's first sample time (the chart's zero)
        self._dispositions: dict[str, str] = {}  # the running product's, by verdict
        self.run_folders: dict[str, Path] = {}  # certificate key -> run folder

    # ------------------------------------------------------------------ reading

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            return {
                "type": "snapshot",
                "station": asdict(self.runner.info),
                "selection": self._selection_view(),
                "run": self._run_view(),
                "last": self._last,
                "instruments": self._instruments,
                "chart": {str(k): v for k, v in self._chart.items()},
            }

    def refresh_instruments(self) -> None:
        """Probe the instruments now (between runs only) and push the lights if they changed."""
        if self.busy():
            return
        lights = [asdict(i) for i in self.runner.instruments()]
        with self._lock:
            if self._run is not None or lights == self._instruments:
                return
            self._instruments = lights
            self.hub.publish({"type": "instruments", "instruments": lights})

    def watch_instruments(self, interval_s: float, stop: threading.Event) -> threading.Thread:
        """Refresh the lights every `interval_s` between runs until `stop` is set."""

        def loop() -> None:
            while not stop.wait(interval_s):
                try:
                    self.refresh_instruments()
                except Exception:  # a probe must never take the station down
                    log.exception("instrument probe failed")

        thread = threading.Thread(target=loop, name="ui-instruments", daemon=True)
        thread.start()
        return thread

    def busy(self) -> bool:
        with self._lock:
            return self._run is not None

    def product(self) -> ProductChoice:
        path = self._selection["product"]
        for product in self.runner.products():
            if product.path == path:
                return product
        raise UserError(f"product {path} is no longer available; an engineer must select one")

    def _selection_view(self) -> dict[str, Any]:
        procedure = next(
            (p for p in self.runner.procedures() if p.path == self._selection["procedure"]), None
        )
        try:
            product: ProductChoice | None = self.product()
        except UserError:
            product = None
        return {
            "procedure": self._selection["procedure"],
            "procedure_name": procedure.name if procedure else "",
            "product": self._selection["product"],
            "product_name": product.name if product else "",
            "serial_pattern": product.serial_pattern if product else "",
            "serial_example": product.serial_example if product else "",
            "dispositions": dict(product.dispositions) if product else {},
        }

    def _run_view(self) -> dict[str, Any] | None:
        if self._run is None:
            return None
        return {k: v for k, v in self._run.items() if not k.startswith("_")}

    # ------------------------------------------------------------------ commands

    def validate_serial(self, socket: int, serial: str) -> str:
        """Return the serial as it will be used (trimmed) or raise SerialRejectedError with why."""
        if socket not in self.runner.info.sockets:
            raise SerialRejectedError(socket, f"socket {socket} does not exist on this fixture")
        text = serial.strip()
        if not text:
            raise SerialRejectedError(socket, f"socket {socket}: no serial; scan the part's label")
        if len(text) > SERIAL_MAX_CHARS:
            raise SerialRejectedError(
                socket, f"socket {socket}: serial longer than {SERIAL_MAX_CHARS} characters; rescan"
            )
        product = self.product()
        if not re.fullmatch(product.serial_pattern, text):
            example = f" such as {product.serial_example}" if product.serial_example else ""
            raise SerialRejectedError(
                socket,
                f"socket {socket}: serial {text!r} is not a {product.name} serial "
                f"(expected {product.serial_pattern}{example}); check the part and rescan",
            )
        return text

    def instrument_problems(self, sockets: set[int] | None = None) -> list[str]:
        """Why the last lights forbid a run: each unreachable or faulted instrument (a
        socket's fixture only when that socket is loaded)."""
        problems = []
        with self._lock:
            lights = list(self._instruments)
        for light in lights:
            socket = light.get("socket")
            if socket is not None and sockets is not None and socket not in sockets:
                continue
            name = light.get("name", "an instrument")
            if not light.get("connected"):
                problems.append(f"{name} is not reachable; check its cable and power")
            elif light.get("faulted"):
                detail = light.get("detail") or "a fault"
                problems.append(f"{name} reports {detail}; clear it first")
        return problems

    def start(
        self, serials: dict[int, str], operator: str = "", work_order: str = "", lot: str = ""
    ) -> str:
        """Validate and start a run; RunRefusedError or SerialRejectedError says why not."""
        loaded_sockets = {s for s, v in serials.items() if v.strip()}
        if not self.busy() and self.instrument_problems(loaded_sockets):
            self.refresh_instruments()  # the lights may be stale: look once more
        with self._lock:
            if self._run is not None:
                serial_list = ", ".join(self._run["serials"].values())
                raise RunRefusedError(
                    f"a run is already in progress on this fixture ({serial_list}, "
                    f"run {self._run['run_id']}); wait for it to finish or abort it first"
                )
            loaded = {s: v for s, v in serials.items() if v.strip()}
            if not loaded:
                raise RunRefusedError(
                    "no serial scanned; scan the label of each part in the fixture"
                )
            clean = {s: self.validate_serial(s, v) for s, v in sorted(loaded.items())}
            if len(set(clean.values())) != len(clean):
                raise RunRefusedError("the same serial is scanned in two sockets; rescan each part")
            problems = self.instrument_problems(set(clean))
            if problems:
                raise RunRefusedError("START refused: " + "; ".join(problems))
            try:
                self._dispositions = dict(self.product().dispositions)
            except UserError:
                self._dispositions = {}
            self._generation += 1
            generation = self._generation
            previous_last, self._last = self._last, None  # shown until the next Start
            self._run = {
                "run_id": "",
                "serials": {str(k): v for k, v in clean.items()},
                "procedure": self._selection["procedure"],
                "product": self._selection["product"],
                "operator": operator,
                "work_order": work_order,
                "lot": lot,
                "started_utc": _now_utc(),
                "steps": [],
                "step_words": [],
                "progress": None,
                "prompt": None,
                "aborting": False,
            }
            self._t0_s = None
            self._chart = {s: {"t_s": [], "rate_dps": [], "temp_c": []} for s in clean}
            self._pending = {s: {"t_s": [], "rate_dps": [], "temp_c": []} for s in clean}
            request = StartRequest(
                serials=clean,
                procedure_path=self._selection["procedure"],
                product_path=self._selection["product"],
                operator=operator,
                work_order=work_order,
                lot=lot,
            )
            self.hub.publish({"type": "run", "run": self._run_view()})

            def sink(event: dict[str, Any]) -> None:
                self._on_event(generation, event)

            try:
                run_id = self.runner.start(request, sink)
            except UserError:
                self._undo_start(previous_last)
                raise
            except Exception as exc:
                log.exception("the engine refused to start")
                self._undo_start(previous_last)
                raise RunRefusedError(f"the station could not start the run: {exc}") from exc
            if self._run is not None and self._generation == generation:
                self._run["run_id"] = run_id
                self.hub.publish({"type": "run", "run": self._run_view()})
            return run_id

    def _undo_start(self, previous_last: dict[str, Any] | None) -> None:
        """The engine refused: no run, and the previous verdict back on the screen."""
        self._run = None
        self._generation += 1
        self._last = previous_last
        self.hub.publish({"type": "run", "run": None})
        self.hub.publish({"type": "last", "last": previous_last})

    def abort(self) -> None:
        with self._lock:
            if self._run is None:
                raise RunRefusedError("no run in progress: nothing to abort")
            self._run["aborting"] = True
            self.hub.publish({"type": "run", "run": self._run_view()})
        self.runner.abort()

    def select(self, procedure: str | None, product: str | None) -> None:
        """Change procedure and/or product (the app checks the engineer role first)."""
        with self._lock:
            if self._run is not None:
                raise RunRefusedError("a run is in progress; change the selection after it ends")
            if procedure is not None:
                if procedure not in {p.path for p in self.runner.procedures()}:
                    raise UserError(f"unknown procedure {procedure!r}; pick one from the list")
                self._selection["procedure"] = procedure
            if product is not None:
                if product not in {p.path for p in self.runner.products()}:
                    raise UserError(f"unknown product {product!r}; pick one from the list")
                self._selection["product"] = product
            self.hub.publish({"type": "selection", "selection": self._selection_view()})

    # ------------------------------------------------------------------ engine events

    def _on_event(self, generation: int, event: dict[str, Any]) -> None:
        with self._lock:
            if generation != self._generation:
                return  # a late event from a run that is already over
            kind = event.get("type")
            if kind == "samples":
                self._on_samples(event)
                return
            if kind == "instruments":
                self._instruments = list(event.get("instruments", []))
            elif kind == "steps" and self._run is not None:
                event = {**event, "step_words": _step_words(event)}
                self._run["steps"] = list(event.get("steps", []))
                self._run["step_words"] = event["step_words"]
            elif kind == "progress" and self._run is not None:
                progress = {k: v for k, v in event.items() if k != "type"}
                step_type = str(event.get("step_type") or plain_words.step_type_of(
                    str(event.get("step", ""))))
                progress["words"] = plain_words.step_phrases(
                    step_type, str(event.get("condition") or ""),
                    str(event.get("phase") or ""))
                progress["received_utc"] = _now_utc()
                self._run["progress"] = progress
                event = {"type": "progress", **progress}
            elif kind == "prompt" and self._run is not None:
                prompt = {
                    "message": str(event.get("message", ""))[:500],
                    "sockets": [int(s) for s in event.get("sockets", [])],
                }
                self._run["prompt"] = prompt
                event = {"type": "prompt", **prompt}
            elif kind == "prompt_done" and self._run is not None:
                self._run["prompt"] = None
                event = {"type": "prompt_done"}
            elif kind == "finished":
                self._flush_samples(force=True)
                self._finish(event)
                return
            self.hub.publish(event)

    def _on_samples(self, event: dict[str, Any]) -> None:
        socket = int(event.get("socket", 0))
        pending = self._pending.get(socket)
        if pending is None:
            return
        times = [float(v) for v in event.get("t_s", [])]
        if times and self._t0_s is None:
            self._t0_s = times[0]
        t0 = self._t0_s or 0.0
        pending["t_s"].extend(v - t0 for v in times)
        for key in ("rate_dps", "temp_c"):
            pending[key].extend(float(v) for v in event.get(key, []))
        self._flush_samples(force=False)

    def _flush_samples(self, *, force: bool) -> None:
        now = time.monotonic()
        if not force and now - self._last_push_s < SAMPLE_PUSH_INTERVAL_S:
            return
        self._last_push_s = now
        for socket, pending in self._pending.items():
            n = min(len(pending["t_s"]), len(pending["rate_dps"]), len(pending["temp_c"]))
            if n == 0:
                continue
            step = max(1, n // 40)  # at most ~40 points per push per socket
            chunk = {k: pending[k][:n:step] for k in pending}
            for k in pending:
                pending[k] = []
            chart = self._chart.setdefault(socket, {"t_s": [], "rate_dps": [], "temp_c": []})
            for k, values in chunk.items():
                chart[k].extend(values)
            if len(chart["t_s"]) > CHART_MAX_POINTS:
                for k in chart:
                    chart[k] = chart[k][::2]
            self.hub.publish({"type": "samples", "socket": socket, **chunk})

    def _finish(self, event: dict[str, Any]) -> None:
        results = []
        for result in event.get("results", []):
            view = dict(result)
            view["failed"] = [
                {**f, "words": plain_words.failure_phrase(f)} for f in view.get("failed") or []
            ]
            view["disposition"] = self._dispositions.get(str(view.get("verdict", "")), "")
            folder = view.pop("run_folder", None)
            view["certificate_url"] = None
            if folder:
                key = Path(folder).name
                self.run_folders[key] = Path(folder)
                view["run_key"] = key
                if (Path(folder) / "certificate.pdf").is_file():
                    view["certificate_url"] = f"/runs/{key}/certificate.pdf"
            results.append(view)
        run = self._run or {}
        self._last = {
            "run_id": run.get("run_id", ""),
            "finished_utc": _now_utc(),
            "results": results,
            "safe_state": event.get("safe_state"),
            "message": event.get("message", ""),
        }
        self._run = None
        self._generation += 1  # nothing from that run may change the state any more
        self.hub.publish({"type": "finished", "last": self._last})
        # The lights after the run (a fault the run met shows at once), off the engine's thread.
        threading.Thread(target=self._refresh_after_run, name="ui-refresh", daemon=True).start()

    def _refresh_after_run(self) -> None:
        try:
            self.refresh_instruments()
        except Exception:
            log.exception("instrument probe after the run failed")


def _step_words(event: dict[str, Any]) -> list[list[plain_words.Phrase]]:
    """Plain words for each planned step: from its "items" ({step, condition}) when the
    runner sends them, else from the labels ("thermal T45_V5.25")."""
    items = event.get("items")
    if not isinstance(items, list):
        items = []
        for label in event.get("steps", []):
            step, _, condition = str(label).partition(" ")
            items.append({"step": step, "condition": condition})
    return [
        plain_words.step_phrases(str(i.get("step", "")), str(i.get("condition") or ""))
        for i in items
        if isinstance(i, dict)
    ]
