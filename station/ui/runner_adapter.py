"""The UI's only door to the end-of-line engine (station/uut.py).

The web layer talks to a `Runner`: start a run for {socket: serial}, abort it, list the
procedures and products, report the instruments. The runner reports back through a sink
with plain dict events (the UI's own vocabulary, documented on `Runner.start`), so the pages
never depend on the engine's internal types. `EngineRunner` is the real one; tests may
substitute any object with the same methods.
"""

from __future__ import annotations

import datetime as dt
import logging
import re
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from common.yaml_input import ConfigError
from procedures.loading.config import load_procedure, load_product
from procedures.loading.plan import build_plan
from procedures.runtime.record import read_record
from station import instruments as roles
from station.errors import UserError
from station.exit_path import exit_bound_s
from station.ui.history import result_from_record
from station.ui.instruments import InstrumentAddress, InstrumentLight, probe

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
    # what the operator does with a part of each verdict (the product file's dispositions:)
    dispositions: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class StartRequest:
    serials: dict[int, str]  # socket -> scanned serial
    procedure_path: str
    product_path: str
    operator: str = ""
    work_order: str = ""
    lot: str = ""


@dataclass
class StationInfo:
    """What the runner knows about the station before any run."""

    name: str = "station"
    sockets: list[int] = field(default_factory=lambda: [1])
    simulated: bool = False
    out_dir: str = "runs"
    # Never the simulated bench's control endpoint: it answers anyone who reaches it, so the
    # pages get what they need of the bench through this server only.


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
          {"type": "steps", "steps": [label, ...],
           "items": [{"step": step type name, "condition": str}, ...] (optional)}
          {"type": "progress", "step": label, "step_type": step type name (optional),
           "step_index": int, "step_count": int, "condition": str,
           "phase": the step's phase ("heating", ...; "" or absent when it names none),
           "fraction": 0..1,
           "remaining_s": wall seconds | None, "sockets": {socket: state} (optional)}
          {"type": "prompt", "message": plain-words instruction, "sockets": [int, ...]}
          {"type": "prompt_done"}  (the prompt is answered: clear it)
          {"type": "samples", "socket": int, "t_s": [..], "rate_dps": [..], "temp_c": [..]}
          {"type": "instruments", "instruments": [InstrumentLight as a dict, ...]}
          {"type": "log", "level": str, "message": str}
          {"type": "finished", "results": [{"socket", "serial", "verdict", "reason",
           "failed": [{"name", "value", "units", "low", "high"}], "run_folder"}],
           "safe_state": {"all": bool, name: bool, "unsafe": [why]} | None}
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


# ---------------------------------------------------------------- the real engine


CONNECT_STEP = "connect"  # the step type of the connecting phase (plain words: its catalog)


def _label(name: str, condition: str) -> str:
    return f"{name} {condition}".strip()


class WallPace:
    """Station seconds per wall second, to show the time left in wall time: 1 on real
    instruments, the bench's speed on a scaled clock; in lockstep (the station runs as fast
    as it computes) measured over the run so far, once `settle_wall_s` have passed."""

    def __init__(self, endpoints: Any, settle_wall_s: float = 2.0) -> None:
        self.speed: float | None = 1.0
        if endpoints is not None:
            self.speed = None if getattr(endpoints, "lockstep", False) else endpoints.speed
        self.settle_wall_s = settle_wall_s
        self._start: tuple[float, float] | None = None

    def wall_s(self, remaining_s: float | None, station_s: float) -> float | None:
        """The wall seconds left for `remaining_s` station seconds (None: not known yet)."""
        if remaining_s is None:
            return None
        if self.speed is not None:
            return remaining_s / self.speed
        now = time.monotonic()
        if self._start is None:
            self._start = (now, station_s)
            return None
        wall, station = now - self._start[0], station_s - self._start[1]
        if wall < self.settle_wall_s or station <= 0:
            return None
        return remaining_s * wall / station


class ProgressRelay:
    """The engine's progress events as the UI's: the step list (a step the plan did not
    name is inserted where it happens), progress with the wall time left, prompts, logs."""

    def __init__(self, plan: Any, pace: WallPace, sink: EventSink) -> None:
        self.labels = [CONNECT_STEP] + [_label(s.name, s.condition) for s in plan]
        self.items = [{"step": CONNECT_STEP, "condition": ""}] + [
            {"step": s.name, "condition": s.condition} for s in plan
        ]
        self.index = 0
        self.pace = pace
        self.sink = sink

    def _steps(self) -> None:
        self.sink({"type": "steps", "steps": list(self.labels), "items": list(self.items)})

    def announce(self, serials: dict[int, str]) -> None:
        """The steps, and the connecting phase at once: connecting the instruments takes the
        engine a moment before its first step event, and the operator sees that phase instead
        of a silent screen."""
        self._steps()
        self.sink(
            {
                "type": "progress",
                "step": CONNECT_STEP,
                "step_type": CONNECT_STEP,
                "step_index": 0,
                "step_count": len(self.labels),
                "condition": "",
                "fraction": 0.0,
                "remaining_s": None,
                "sockets": {str(k): "RUNNING" for k in serials},
            }
        )

    def on_event(self, ev: Any) -> None:
        if ev.kind == "step":
            self._enter_step(ev)
        elif ev.kind == "prompt":
            self.sink({"type": "prompt", "message": ev.message, "sockets": sorted(ev.sockets)})
            return
        elif ev.kind == "prompt_done":
            self.sink({"type": "prompt_done"})
            return
        elif ev.kind not in ("progress", "part"):
            if ev.kind == "log" and ev.message:
                self.sink({"type": "log", "level": "INFO", "message": ev.message})
            return
        self.sink(
            {
                "type": "progress",
                "step": _label(ev.step, ev.condition) or "starting",
                "step_type": ev.step,
                "step_index": self.index,
                "step_count": len(self.labels),
                "condition": ev.condition,
                "phase": ev.phase,
                "fraction": float(ev.fraction),
                "remaining_s": self.pace.wall_s(ev.remaining_s, ev.station_time_s),
                "sockets": {str(k): v for k, v in ev.sockets.items()},
            }
        )

    def _enter_step(self, ev: Any) -> None:
        label = _label(ev.step, ev.condition)
        try:
            self.index = self.labels.index(label, max(self.index, 0))
        except ValueError:
            self.labels.insert(self.index + 1, label)
            self.items.insert(self.index + 1, {"step": ev.step, "condition": ev.condition})
            self.index += 1
            self._steps()


class EngineRunner:
    """`Runner` over station/uut.py: one UutRunner per run, its progress bus translated.

    With a simulated bench (`control` given) each Start first loads the scanned parts into
    the bench's sockets (a serial listed in `sim_parts` gets that entry's parameters, any
    other serial a part drawn from the population), and the finished event carries the
    twins' own report of the safe state.
    """

    def __init__(
        self,
        settings: Any,  # station.settings.LoadedSettings
        *,
        out: Path | None = None,
        endpoints: Any = None,  # station.endpoints.Endpoints
        control: Any = None,  # drivers.sim.control_client.ControlClient
        sim_parts: dict[str, dict[str, Any]] | None = None,
        sample_interval_s: float = 0.25,
    ) -> None:
        self.settings = settings
        self.out = Path(out) if out else settings.output_folder
        self.endpoints = endpoints
        self.control = control
        self.sim_parts = sim_parts or {}
        self.sample_interval_s = sample_interval_s
        s = settings.settings
        n_sockets = s.instruments.fixture.sockets
        if endpoints is not None:
            n_sockets = max(endpoints.duts, default=n_sockets)
        self.info = StationInfo(
            name=s.station.name or s.station.id,
            sockets=list(range(1, n_sockets + 1)),
            simulated=endpoints is not None,
            out_dir=str(self.out),
        )
        self._uut: Any = None
        self._thread: threading.Thread | None = None
        self._control_lock = threading.Lock()
        self._file_cache: dict[tuple[str, str], tuple[tuple[int, int], Any]] = {}
        self._uut_cache: tuple[Any, Any] | None = None

    # ------------------------------------------------------------ choices

    def _cached(self, path: Path, loader: Callable[[Path], tuple[Any, Any]]) -> Any:
        """A config file's model, parsed again only when the file changes (a page load
        lists every procedure and product; parsing them all each time costs ~100 ms)."""
        st = path.stat()
        key = (str(path), loader.__name__)
        signature = (st.st_mtime_ns, st.st_size)
        hit = self._file_cache.get(key)
        if hit is None or hit[0] != signature:
            hit = (signature, loader(path)[0])
            self._file_cache[key] = hit
        return hit[1]

    def _uut_for(self, procedure: Path, product: Path | None) -> Any:
        """The engine's UutRunner for this selection, reused while its files are unchanged."""
        # the engine: loaded when a run starts (a UI-only build has none: engine_available)
        from station.uut import UutRunner

        files = [procedure] + ([product] if product else [])
        key = tuple((str(f), f.stat().st_mtime_ns, f.stat().st_size) for f in files)
        if self._uut_cache is None or self._uut_cache[0] != key:
            uut = UutRunner(
                self.settings,
                procedure_path=procedure,
                product_path=product,
                out=self.out,
                endpoints=self.endpoints,
            )
            self._uut_cache = (key, uut)
        return self._uut_cache[1]

    def _yaml_files(self, sub: str) -> list[Path]:
        folder = self.settings.folder / sub
        return sorted(folder.glob("*.yaml")) if folder.is_dir() else []

    def _loaded(
        self, paths: set[Path], loader: Callable[[Path], tuple[Any, Any]], what: str
    ) -> Iterator[tuple[Path, Any]]:
        """Each file of `paths` that loads, in order, with what it holds; the others are
        logged and skipped (the `what` list skips them)."""
        for path in sorted(paths):
            try:
                loaded = self._cached(path, loader)
            except (ConfigError, OSError) as exc:
                log.warning("%s list skips %s: %s", what, path, exc)
                continue
            yield path, loaded

    def procedures(self) -> list[Choice]:
        paths = {
            self.settings.procedure.resolve(),
            *(p.resolve() for p in self._yaml_files("procedures")),
        }
        return [
            Choice(proc.name, str(path), proc.description)
            for path, proc in self._loaded(paths, load_procedure, "procedure")
        ]

    def products(self) -> list[ProductChoice]:
        choices = []
        paths = {p.resolve() for p in self._yaml_files("products")}
        default_product = self._default_product()
        if default_product is not None:
            paths.add(default_product)
        for path, prod in self._loaded(paths, load_product, "product"):
            choices.append(
                ProductChoice(
                    prod.product,
                    str(path),
                    prod.serial_pattern,
                    _example_serial(prod.serial_pattern),
                    _dispositions(prod),
                )
            )
        return choices

    def _default_product(self) -> Path | None:
        try:
            proc = self._cached(self.settings.procedure.resolve(), load_procedure)
        except (ConfigError, OSError):
            return None
        if not proc.product:
            return None
        return (self.settings.procedure.parent / proc.product).resolve()

    def default_selection(self) -> tuple[str, str]:
        product = self._default_product()
        return str(self.settings.procedure.resolve()), str(product) if product else ""

    def warm_up(self) -> None:
        """Load the default selection's engine now, so the first Start is as quick as the rest."""
        procedure, product = self.default_selection()
        try:
            self._uut_for(Path(procedure), Path(product) if product else None)
        except Exception as exc:  # noqa: BLE001 - Start will report it with its own message
            log.warning("could not prepare the default procedure: %s", exc)

    # ------------------------------------------------------------ instruments

    def instruments(self) -> list[InstrumentLight]:
        if self.busy():
            return []
        cfg = self.settings.settings.instruments
        e = self.endpoints
        addresses = []
        for role in roles.station_roles(needs_table=True):
            entry = getattr(cfg, role, None)
            if entry is None:
                continue
            name = roles.ROLE_NAMES[role]
            try:
                plan = roles.plan_role(self.settings, role, e)
            except UserError as exc:
                addresses.append(InstrumentAddress(name, "", entry.calibration_due, None, str(exc)))
                continue
            if plan is not None:
                addresses.append(
                    InstrumentAddress(name, plan.address, entry.calibration_due, plan)
                )
        for sock in self.info.sockets:
            port = e.duts.get(sock, "") if e else cfg.fixture.ports.get(sock, "")
            try:
                part = roles.plan_part(self.settings, sock, port, e) if port else None
            except UserError as exc:
                addresses.append(
                    InstrumentAddress(f"fixture {sock}", "", cfg.fixture.calibration_due,
                                      None, str(exc), socket=sock)
                )
                continue
            addresses.append(
                InstrumentAddress(
                    f"fixture {sock}", port, cfg.fixture.calibration_due, part, socket=sock
                )
            )
        return probe(addresses)

    # ------------------------------------------------------------ running

    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, request: StartRequest, sink: EventSink) -> str:
        if self._thread is not None:
            self._thread.join(2.0)  # "finished" is its last act; let it end
        if self.busy():
            raise UserError("a run is already in progress; wait for it or abort it")
        try:
            uut = self._uut_for(
                Path(request.procedure_path),
                Path(request.product_path) if request.product_path else None,
            )
        except ConfigError as exc:
            raise UserError(str(exc)) from None
        except OSError as exc:
            raise UserError(f"cannot read the procedure or product file: {exc}") from None
        # every pre-flight check, the instruments opened and closed again: START is refused
        # (nothing written) while an instrument is unreachable or a setting is out of its limits
        serials = uut.preflight(dict(request.serials))
        uut.operator = request.operator
        uut.work_order = request.work_order
        uut.lot = request.lot
        self._uut = uut
        run_id = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
        self._thread = threading.Thread(
            target=self._run, args=(uut, serials, sink), name="ui-run", daemon=True
        )
        self._thread.start()
        return run_id

    def abort(
        self, reason: str = "the operator pressed ABORT on the station screen", error: bool = False
    ) -> None:
        """Stop the run in progress (`error`: ERROR, an uncaught exception in the station)."""
        if self._uut is not None:
            self._uut.abort(reason, error=error)

    def close(self) -> None:
        """Abort a run in progress and wait, bounded, for its end (the safe state, the
        record sealed): as long as the station's exit path gives a stop."""
        # the engine: loaded when a run starts (a UI-only build has none: engine_available)
        from station.uut import safe_state_policy_of

        self.abort()
        if self._thread is not None:
            self._thread.join(exit_bound_s(safe_state_policy_of(self.settings)))

    def _load_sim_parts(self, serials: dict[int, str]) -> None:
        if self.control is None:
            return
        with self._control_lock:
            for sock in self.info.sockets:
                if sock not in serials:  # the operator took that part out: it draws no current
                    self.control.unload(sock)
            for sock, serial in serials.items():
                part = {k: v for k, v in self.sim_parts.get(serial, {}).items() if k != "socket"}
                part["serial"] = serial
                self.control.load(sock, part)

    def _run(self, uut: Any, serials: dict[int, str], sink: EventSink) -> None:
        relay = ProgressRelay(build_plan(uut.procedure), WallPace(self.endpoints), sink)
        relay.announce(serials)
        unsubscribe = uut.progress.subscribe(relay.on_event)
        stop_samples = threading.Event()
        sampler = threading.Thread(
            target=self._sample_loop, args=(uut, sink, stop_samples), name="ui-samples", daemon=True
        )
        sampler.start()
        try:
            results, message = self._run_parts(uut, serials)
        finally:
            stop_samples.set()
            sampler.join(2)
            unsubscribe()
        sink(
            {
                "type": "finished",
                "results": results,
                "safe_state": station_safe_state(uut),
                "message": message,
            }
        )

    def _run_parts(
        self, uut: Any, serials: dict[int, str]
    ) -> tuple[list[dict[str, Any]], str]:
        """Each socket's result and the run's error message ('' when it ran to its end)."""
        try:
            self._load_sim_parts(serials)
            result = uut.run(serials)
            return [
                self._result(sock, serials[sock], result.folders.get(sock))
                for sock in sorted(serials)
            ], ""
        except Exception as exc:  # the UI must always get its "finished"
            log.exception("the run failed")
            message = f"the run stopped with an error: {exc}"
            return [
                self._result(sock, serials[sock], None, message) for sock in sorted(serials)
            ], message

    def _result(
        self, sock: int, serial: str, folder: Path | None, error: str = ""
    ) -> dict[str, Any]:
        if folder is not None:
            try:
                return result_from_record(read_record(folder), folder)
            except ValueError as exc:
                error = str(exc)
        return {
            "socket": sock,
            "serial": serial,
            "verdict": "ERROR",
            "reason": error,
            "failed": [],
            "run_folder": str(folder) if folder else None,
        }

    def _sample_loop(self, uut: Any, sink: EventSink, stop: threading.Event) -> None:
        """Forward each part's new samples (the engine keeps them in its PartStreams)."""
        seen: dict[int, float] = {}
        while not stop.wait(self.sample_interval_s):
            ctx = uut.context  # the live run's context, None before and after
            for part in getattr(ctx, "parts", None) or []:
                stream = getattr(part, "stream", None)
                if stream is None:
                    continue
                try:
                    last = stream.last_time_s()
                    if last is None or last <= seen.get(part.socket, -1e300):
                        continue
                    start = seen.get(part.socket, last - 5.0)
                    win = stream.window(start + 1e-9, last + 1e-9)
                except Exception as exc:  # noqa: BLE001 - a chart must never stop a run
                    log.debug("samples of socket %s unavailable: %s", part.socket, exc)
                    continue
                seen[part.socket] = last
                n = len(win["time_s"])
                if n == 0:
                    continue
                step = max(1, n // 50)
                sink(
                    {
                        "type": "samples",
                        "socket": part.socket,
                        "t_s": win["time_s"][::step].tolist(),
                        "rate_dps": win["rate_dps"][::step].tolist(),
                        "temp_c": win["temp_c"][::step].tolist(),
                    }
                )


def _dispositions(product: Any) -> dict[str, str]:
    """The product file's dispositions by verdict ({} when it has none)."""
    found = getattr(product, "dispositions", None)
    if found is None:
        return {}
    return {verdict: text for verdict, text in found.model_dump().items() if text}


def _example_serial(pattern: str) -> str:
    """A readable example for the commonest serial patterns, '' when not obvious."""
    m = re.fullmatch(r"\^?\[A-Z\]\{(\d+)(?:,\d+)?\}-\[0-9\]\{(\d+)(?:,\d+)?\}\$?", pattern)
    if m:
        return "ABCD"[: int(m.group(1))] + "-" + "12345678"[: int(m.group(2))]
    return ""


def station_safe_state(uut: Any) -> dict[str, Any] | None:
    """The station's own safe-state readback of the run just finished (what each
    instrument reported about itself), never the simulator's truth: a real station has no
    such channel. {"all": bool, <instrument>: bool, ..., "unsafe": [why, ...]}."""
    state = uut.state() if callable(getattr(uut, "state", None)) else {}
    report = state.get("safe_state") if isinstance(state, dict) else None
    if not isinstance(report, dict) or not isinstance(report.get("instruments"), dict):
        return None
    out: dict[str, Any] = {"all": bool(report.get("all_safe"))}
    unsafe: list[str] = []
    for name, inst in report["instruments"].items():
        safe = bool(inst.get("safe")) if isinstance(inst, dict) else False
        out[str(name)] = safe
        if not safe:
            detail = inst.get("detail", "") if isinstance(inst, dict) else ""
            unsafe.append(f"{str(name).replace('_', ' ')}: {detail}")
    out["unsafe"] = unsafe
    return out
