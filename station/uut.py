"""The UUT loop: scanned serials -> run -> certificate -> results database.

The small API the CLI uses and the browser UI will use:

    runner = UutRunner(settings, procedure_path=..., product_path=..., operator="ana")
    unsubscribe = runner.progress.subscribe(print)        # ProgressEvent stream
    runner.start({1: "SIM-0001", 2: "SIM-0002"})          # background thread; or run(...) to block
    runner.abort()                                        # operator abort (also from SIGINT)
    runner.state()                                        # {"state": "running", "step": ...}
    result = runner.wait()                                # UutResult: folders, verdicts, PDFs

`endpoints` (station/endpoints.py, from the simulated bench's state file) replaces the
addresses of station.yaml, chooses the driver of every role station.yaml leaves to its default
(the family each twin serves) and sets the clock's speed; real instruments run at speed 1.
Every instrument is opened through its configured driver (station/open_bench.py) and the
procedure is checked against what they report (`station.preflight`) before any run folder
exists; each part's run folder starts with station/part_record.py. The fixture's baud
arithmetic is station/link_speed.py, a cycle on a fresh simulated bench station/sim_run.py.
"""

from __future__ import annotations

import datetime as dt
import logging
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.clock import ScaledClock
from common.yaml_input import ConfigError
from drivers.errors import InstrumentError
from drivers.protocols import PartLink, StreamReadsBackSafe
from procedures.analysis.hysteresis import PlayOperator
from procedures.engine.engine import Engine
from procedures.engine.safe_state import SafeSettingsError, SafeStatePolicy, check_safe_temperature
from procedures.loading.config import (
    check_procedure_for_product,
    load_procedure,
    load_product,
    product_for_procedure,
)
from procedures.loading.plan import build_plan
from procedures.runtime.progress import ProgressBus, ProgressEvent
from procedures.runtime.rawdata import file_sha256
from procedures.runtime.record import (
    RAW_DATA_FILE,
    Event,
    Verdict,
    os_error_text,
    read_record,
    save_record_anywhere,
)
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import KeptRecord, PartRun
from procedures.runtime.streams import PartStream
from station import instruments as roles
from station import preflight
from station.endpoints import Endpoints
from station.errors import UserError
from station.instrument_lock import InstrumentLock, lock_instruments
from station.link_speed import link_speed_problem
from station.open_bench import (
    OpenBench,
    instrument_record,
    open_bench,
    open_part_link,
    silent_floor_s,
)
from station.part_record import new_part
from station.prompt_relay import PromptRelay
from station.run_folder import check_output_folder, recover_crashed_runs, release, validate_serial
from station.settings import LoadedSettings

log = logging.getLogger(__name__)


@dataclass
class UutResult:
    folders: dict[int, Path] = field(default_factory=dict)
    verdicts: dict[int, Verdict] = field(default_factory=dict)
    reasons: dict[int, str] = field(default_factory=dict)
    certificates: dict[int, Path] = field(default_factory=dict)
    # where each record.json was written: its run folder, the fallback folder when that
    # could not be written (procedures.runtime.record.save_record_anywhere), None when nowhere
    record_files: dict[int, Path | None] = field(default_factory=dict)
    station_time_s: float = 0.0
    wall_time_s: float = 0.0

    @property
    def exit_code(self) -> int:
        """0 all PASS, 1 any FAIL (and no error), 2 error or abort."""
        if any(
            v in (Verdict.ERROR, Verdict.ABORTED, Verdict.RUNNING) for v in self.verdicts.values()
        ):
            return 2
        return 1 if any(v is Verdict.FAIL for v in self.verdicts.values()) else 0


def safe_state_policy_of(settings: LoadedSettings) -> SafeStatePolicy:
    """How long the safe-state pass keeps trying an instrument it cannot reach: the station
    file's safe_state section."""
    retry = settings.settings.safe_state
    return SafeStatePolicy(deadline_s=retry.retry_for_s, wall_floor_s=retry.wall_floor_s)


class UutRunner:
    """One UUT cycle at a time for one station; thread-safe `abort` and `state`."""

    def __init__(
        self,
        settings: LoadedSettings,
        *,
        procedure_path: Path | None = None,
        product_path: Path | None = None,
        operator: str = "",
        work_order: str = "",
        lot: str = "",
        out: Path | None = None,
        endpoints: Endpoints | None = None,
        certificate: bool = True,
        safe_state_policy: SafeStatePolicy | None = None,
    ) -> None:
        self.settings = settings
        # how long the safe-state pass keeps trying an instrument it cannot reach: the station
        # file's safe_state section, unless the caller (a test rig) gives its own
        self.safe_state_policy = safe_state_policy or safe_state_policy_of(settings)
        self.procedure_path = Path(procedure_path) if procedure_path else settings.procedure
        self.procedure, self.procedure_file = load_procedure(self.procedure_path)
        if product_path is None:
            if not self.procedure.product:
                raise ConfigError(
                    f"{self.procedure_path}: no product given; add 'product:' "
                    "to the procedure or pass --product"
                )
            product_path = (self.procedure_path.parent / self.procedure.product).resolve()
        self.product_path = Path(product_path)
        self.product, self.product_file = load_product(self.product_path)
        # limits derived for this procedure (the consistency judgement's per-condition limit)
        self.product = product_for_procedure(self.product, self.procedure)
        # the product limits this procedure never measures: an event on every record
        self.limit_warnings = check_procedure_for_product(
            self.procedure, self.procedure_file, self.product, self.product_file
        )
        for warning in self.limit_warnings:
            log.warning("%s", warning)
        self.operator = operator
        self.work_order = work_order
        self.lot = lot
        # resolved, so that --out naming station.yaml's output folder keeps its results_db
        self.out = Path(out).expanduser().resolve() if out else settings.output_folder
        self.endpoints = endpoints
        self.certificate = certificate
        self.progress = ProgressBus()
        if endpoints is not None and endpoints.operator:  # the simulated operator's eyes

            self.progress.subscribe(PromptRelay(endpoints.operator))
        self._lock = threading.Lock()
        self._ctx: RunContext | None = None
        self._engine: Engine | None = None
        self._thread: threading.Thread | None = None
        self._result: UutResult | None = None
        self._state = "idle"
        self._abort_requested = ""
        self._abort_error = False
        self._error: BaseException | None = None

    # ------------------------------------------------------------ API for the CLI and the UI

    def recover(self) -> list[Path]:
        """Mark ERROR the runs a crashed station left RUNNING in the output folder."""
        # signing (pyhanko, cryptography): loaded only when used
        from station.certify import recovered_run_sealer

        folders = recover_crashed_runs(self.out, seal=recovered_run_sealer(self.settings))
        self._mark_crashed_in_db(folders)
        return folders

    def validate(self, duts: dict[int, str]) -> dict[int, str]:
        """Check the link speed, sockets and serials before anything is written or any
        instrument is touched; UserError says what to fix."""
        self.check_link_speed()
        self.check_safe_settings()
        check_output_folder(self.out, self.settings.settings.min_free_space_mb)
        if not duts:
            raise UserError("no part given: scan at least one serial (--dut SERIAL)")
        n_sockets = self.settings.settings.instruments.fixture.sockets
        if self.endpoints is not None:
            n_sockets = max(n_sockets, max(self.endpoints.duts, default=0))
        clean: dict[int, str] = {}
        for sock, serial in duts.items():
            if not 1 <= sock <= n_sockets:
                raise UserError(f"socket {sock} does not exist on this fixture (1..{n_sockets})")
            clean[sock] = validate_serial(serial, self.product.serial_pattern)
        if len(set(clean.values())) != len(clean):
            raise UserError("the same serial was scanned for two sockets; rescan the labels")
        return clean

    def check_link_speed(self) -> None:
        """The fixture's baud (station.yaml) must carry the procedure's output rate in the
        product's frames (a three-axis part's are longer). Checked on the simulated bench too,
        where a pty has no baud: the procedure must suit the station."""
        problem = link_speed_problem(
            self.procedure.output_rate_hz,
            self.settings.settings.instruments.fixture.baud,
            axes=self.product.axes,
        )
        if problem is not None:
            raise UserError(
                f"procedure {self.procedure_path.name} cannot run on this station ("
                f"{self.settings.source.path}): {problem}"
            )

    def check_safe_settings(self, chamber_limits_c: tuple[float, float] | None = None) -> None:
        """The chamber's safe temperature within the product's handling range (and the
        chamber's setpoint limits once known); UserError in one line otherwise."""
        try:
            check_safe_temperature(
                self.procedure.chamber.safe_temp_c,
                self.product.handling_temp_range_c,
                chamber_limits_c,
            )
        except SafeSettingsError as exc:
            raise UserError(f"procedure {self.procedure_path.name}: {exc}") from None

    @property
    def needs_table(self) -> bool:
        return self.procedure.needs_table

    def check_drivers(self, sockets: list[int]) -> None:
        """Resolve every role's driver and check its settings, without connecting: a bad
        driver name or setting is a UserError, one station.yaml file:line per problem."""
        problems: list[str] = []
        for role in roles.station_roles(self.needs_table):
            plan = roles.plan_role(self.settings, role, self.endpoints)
            if plan is not None:
                problems += roles.check_settings(self.settings, plan)
        ports = self.fixture_ports()
        for sock in sockets:
            if ports.get(sock):
                plan = roles.plan_part(self.settings, sock, ports[sock], self.endpoints)
                problems += roles.check_settings(self.settings, plan)
        if problems:
            raise UserError("\n".join(dict.fromkeys(problems)))

    def connect(self, sockets: list[int]) -> OpenBench:
        """Open the instruments and check the procedure against what they report (the
        pre-flight). Any problem is a UserError, one line each, with nothing written and
        nothing left open: an unreachable instrument refuses the run."""
        self.check_drivers(sockets)
        try:
            opened = open_bench(
                self.settings, sockets, self.endpoints, self.needs_table,
                self.procedure.stream.silent_timeout_s,
            )
        except (InstrumentError, OSError) as exc:
            raise UserError(
                f"{exc}; the run is refused until every instrument answers"
            ) from None
        try:
            problems = preflight.instrument_problems(
                self.procedure, self.procedure_file, self.product, opened.bench, len(sockets),
                opened.names,
            )
        except InstrumentError as exc:
            opened.close()
            raise UserError(f"pre-flight: an instrument did not answer: {exc}") from None
        except BaseException:
            opened.close()
            raise
        if problems:
            opened.close()
            raise UserError("\n".join(problems))
        return opened

    def preflight(self, duts: dict[int, str]) -> dict[int, str]:
        """Every check before a run, the instruments opened and closed again (the UI's
        START): UserError, one line per problem, nothing written."""
        duts = self.validate(duts)
        self.check_ports(duts)
        with self.lock_instruments():  # another process's instruments are not even asked
            self.connect(sorted(duts)).close()
        return duts

    def fixture_ports(self) -> dict[int, str]:
        """Socket -> fixture port: the bench's sockets, or station.yaml's."""
        if self.endpoints is not None:
            return dict(self.endpoints.duts)
        return dict(self.settings.settings.instruments.fixture.ports)

    def check_ports(self, duts: dict[int, str]) -> None:
        """Every scanned socket needs a fixture port; refuse before any folder exists."""
        ports = self.fixture_ports()
        for s in sorted(duts):
            if not ports.get(s):
                raise UserError(
                    f"socket {s} has no fixture port (station.yaml instruments.fixture.ports "
                    "or the bench's sockets); load fewer parts or configure the socket"
                )

    def start(self, duts: dict[int, str]) -> None:
        """Start a run in a background thread (validation errors are raised here)."""
        duts = self.validate(duts)
        self.check_ports(duts)
        with self._lock:
            if self._state == "running":
                raise UserError("a run is already in progress; wait for it or abort it")
            self._state = "running"
            self._result = None
        self._thread = threading.Thread(
            target=self._thread_main, args=(duts,), name="uut-run", daemon=True
        )
        self._thread.start()

    def wait(self, timeout_s: float | None = None) -> UutResult | None:
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self._error is not None:
            raise self._error
        return self._result

    def abort(self, reason: str = "the operator aborted the run", *, error: bool = False) -> None:
        """Stop the run in progress (or the one about to start): ABORTED, or ERROR when
        `error` (station/exit_path.py: an uncaught exception in a station thread). The first
        request's reason stands."""
        with self._lock:
            ctx = self._ctx
            if not self._abort_requested:
                self._abort_requested, self._abort_error = reason, error
        if ctx is not None:
            ctx.abort(reason, error)

    @property
    def context(self) -> RunContext | None:
        """The live run's context (its parts and their streams), None between runs."""
        return self._ctx

    def state(self) -> dict[str, Any]:
        last: ProgressEvent | None = self.progress.last
        out: dict[str, Any] = {"state": self._state}
        if last is not None:
            out.update(
                step=last.step,
                condition=last.condition,
                fraction=last.fraction,
                remaining_s=last.remaining_s,
                sockets=last.sockets,
            )
        engine = self._engine
        if engine is not None and engine.safe_state is not None:
            # the station's own safe-state readback of the last run (never the simulator's)
            out["safe_state"] = engine.safe_state.as_record()
        if self._result is not None:
            out["verdicts"] = {s: str(v) for s, v in self._result.verdicts.items()}
            out["folders"] = {s: str(p) for s, p in self._result.folders.items()}
        return out

    def _thread_main(self, duts: dict[int, str]) -> None:
        try:
            self._result = self.run(duts)
        except BaseException as exc:  # surfaced by wait()
            self._error = exc
            self._state = "error"

    # ------------------------------------------------------------ one cycle

    def run(self, duts: dict[int, str]) -> UutResult:
        """Validate, lock the instruments against any other station process (refused in one
        line when one holds them), open them and check the procedure against them (nothing
        is written if any check fails), create run folders, run the procedure,
        certificates, results database."""
        duts = self.validate(duts)
        self.check_ports(duts)
        lock = self.lock_instruments()
        try:
            return self._run_locked(duts)
        finally:
            lock.release()

    def lock_instruments(self) -> InstrumentLock:
        """OS locks on every instrument a run of this station drives: the roles' addresses
        and every fixture port (the run asks the unscanned sockets too); InstrumentsBusy,
        one line, when another process holds one (station/instrument_lock.py)."""
        pairs: list[tuple[str, str]] = []
        for role in roles.station_roles(self.needs_table):
            plan = roles.plan_role(self.settings, role, self.endpoints)
            if plan is None:
                continue
            ports = plan.settings.get("ports") or {}
            addresses = [str(a) for a in ports.values()] or [plan.address]
            pairs += [(a, f"{plan.label} at {a}") for a in addresses if a]
        for sock, port in sorted(self.fixture_ports().items()):
            if port:
                pairs.append((port, f"fixture of socket {sock} at {port}"))
        return lock_instruments(pairs)

    def _run_locked(self, duts: dict[int, str]) -> UutResult:
        self._engine = None
        wall0 = dt.datetime.now(dt.UTC)
        self.recover()
        opened = self.connect(sorted(duts))
        parts: list[PartRun] = []
        try:
            self._state = "running"
            counts = opened.bench.table.counts_per_rev() if opened.bench.table else None
            for sock, serial in sorted(duts.items()):
                try:
                    parts.append(new_part(self, sock, serial, counts))
                except OSError as exc:  # the disk filled or went read-only since validate
                    raise UserError(
                        f"{os_error_text(exc)}; free space or choose another --out"
                    ) from None
            unscanned, unknown = self._unscanned_parts(opened.bench.clock, set(duts))
            if unscanned:
                for part in parts:
                    part.verdict = Verdict.ERROR
                    part.reason = "; ".join(
                        f"socket {s} holds a part that was not scanned: scan it or take it out"
                        for s in unscanned
                    )
                self._finish_unstarted(parts)
            else:
                self._run_engine(opened, parts, unknown)
        finally:
            with self._lock:
                self._abort_requested = ""  # consumed by this run (or too late for it)
                self._ctx = None
            opened.close()
            for part in parts:
                release(part.folder)
        result = UutResult(folders={p.socket: p.folder for p in parts})
        for part in parts:
            if part.kept is not None:  # where the record went (path None: nowhere)
                result.record_files[part.socket] = part.kept.path
            result.verdicts[part.socket] = part.record.verdict
            result.reasons[part.socket] = part.record.reason
            cert = self._certificate(part.folder)
            if cert is not None:
                result.certificates[part.socket] = cert
            self._store(part)
        result.station_time_s = max(
            (p.record.timings.get("total", 0.0) for p in parts), default=0.0
        )
        result.wall_time_s = (dt.datetime.now(dt.UTC) - wall0).total_seconds()
        self._result = result
        self._state = "finished"
        return result

    def _unscanned_parts(
        self, clock: ScaledClock, scanned: set[int]
    ) -> tuple[list[int], list[str]]:
        """Ask every other fixture socket whether it holds a part (before any power: a part
        that was not scanned draws current, so the supply limit and the per-part current
        would be wrong). Returns the sockets holding a part, and warnings for those that
        could not be asked."""
        present: list[int] = []
        unknown: list[str] = []
        for sock, port in sorted(self.fixture_ports().items()):
            if sock in scanned or not port:
                continue
            link: PartLink | None = None
            try:
                link = open_part_link(
                    self.settings, sock, port, clock, self.procedure.stream.silent_timeout_s,
                    self.endpoints,
                )
                if link.part_present():
                    present.append(sock)
                _stop_stream(link, sock)  # a crashed run may have left it streaming
            except (InstrumentError, OSError) as exc:
                unknown.append(
                    f"socket {sock} (not scanned) could not be asked whether it holds a part "
                    f"({exc}); make sure it is empty"
                )
            finally:
                if link is not None:
                    try:
                        link.close()
                    except Exception as exc:  # closing a dead link must not stop the run
                        log.info("closing the fixture link of socket %s: %s", sock, exc)
        return present, unknown

    def _run_engine(
        self, opened: OpenBench, parts: list[PartRun], warnings: list[str] | None = None
    ) -> None:
        bench = opened.bench
        cfg = self.settings.settings.instruments
        for part in parts:
            part.record.instruments = list(opened.instruments)
            part.record.instruments.append(
                instrument_record(
                    f"fixture_{part.socket}",
                    None,
                    self.fixture_ports().get(part.socket, ""),
                    cfg.fixture.calibration_due,
                )
            )
            part.stream = PartStream(
                part.socket,
                bench.links[part.socket],
                bench.clock,
                part.writer,
                silent_floor_s(self.procedure.stream.silent_timeout_s, bench.clock),
            )
            typical = self.product.thermal_typical
            if typical is not None:
                part.stream.hysteresis = PlayOperator(typical.hysteresis_width_c)
        overdue = [i.role for i in opened.instruments if i.calibration_overdue]
        ctx = RunContext(bench, self.procedure, self.product, parts, self.progress)
        with self._lock:
            self._ctx = ctx
            pending_abort, pending_error = self._abort_requested, self._abort_error
        if pending_abort:
            ctx.abort(pending_abort, pending_error)
        for warning in [*(warnings or []), *self.limit_warnings]:
            ctx.records.event(warning, level="WARNING")
        for part in parts:  # the supply limit must allow for parts that may sit there
            part.unasked_sockets = len(warnings or [])
        if overdue:
            ctx.records.event(
                f"instrument calibration overdue: {', '.join(overdue)}", level="WARNING"
            )
            if self.settings.settings.refuse_overdue_instruments:
                for part in parts:
                    ctx.parts.drop(
                        part,
                        Verdict.ERROR,
                        f"instrument calibration overdue ({', '.join(overdue)}); "
                        "recalibrate them or set refuse_overdue_instruments: false",
                    )
        try:
            start_temp = bench.chamber.read_temperature()
        except InstrumentError:
            start_temp = None
        engine = Engine(ctx, build_plan(self.procedure, start_temp), self.safe_state_policy)
        self._engine = engine
        engine.run()
        for part in parts:
            kept = part.writer is None or part.writer.failure is None
            raw = part.folder / RAW_DATA_FILE
            if kept and raw.exists() and part.record.raw_data is not None:
                try:
                    part.record.raw_data.sha256 = file_sha256(raw)
                except OSError as exc:
                    log.error("cannot hash %s: %s", raw, exc.strerror or exc)
                    continue
                part.kept = KeptRecord(save_record_anywhere(part.folder, part.record))
        with self._lock:
            self._ctx = None

    def _finish_unstarted(self, parts: list[PartRun]) -> None:
        now = dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds")
        for part in parts:
            part.record.verdict = part.verdict or Verdict.ERROR
            part.record.reason = part.reason
            part.record.finished_utc = now
            part.record.events.append(
                Event(
                    time_utc=now,
                    station_time_s=0.0,
                    level="ERROR",
                    step="connect",
                    message=part.reason,
                )
            )
            if part.writer is not None:
                try:
                    part.writer.close()
                except OSError as exc:
                    log.error("%s", exc)
            part.kept = KeptRecord(save_record_anywhere(part.folder, part.record))

    # ------------------------------------------------------------ after the run

    def _certificate(self, folder: Path) -> Path | None:
        """The signed certificate (when wanted) and the folder's signed manifest."""
        # signing (pyhanko, cryptography): loaded only when used
        from station.certify import finish_run_folder

        return finish_run_folder(folder, self.settings, certificate=self.certificate,
                                 decision_rule=self.product.decision_rule)

    def _results_db(self) -> Any:
        try:
            from station.results_db import ResultsDB
        except ModuleNotFoundError:
            return None
        return ResultsDB(
            self.settings.results_db
            if self.out == self.settings.output_folder
            else self.out / "results.sqlite"
        )

    def _store(self, part: PartRun) -> None:
        try:
            db = self._results_db()
            if db is not None:  # locally first, then forwarded to the line's central db
                # sqlalchemy: loaded only when a database is used
                from station.db.sync import store_finished_run

                store_finished_run(db, self.settings, part.folder, part.record,
                                   state=lambda: self._state)
        except Exception as exc:  # the run folder is the master copy; the index can be rebuilt
            log.error("results database: could not add %s: %s", part.folder, exc)

    def _mark_crashed_in_db(self, folders: list[Path]) -> None:
        if not folders:
            return

        try:
            db = self._results_db()
            if db is None:
                return
            for folder in folders:
                db.add_run(folder, read_record(folder))
        except Exception as exc:
            log.error("results database: could not record crashed runs: %s", exc)


def _stop_stream(link: PartLink, sock: int) -> None:
    """STOP an unscanned socket's stream and read it back (logged when it does not stop: the
    run never configures that socket, so it goes on)."""
    try:
        link.stop_stream()
        back = link.check_stream_stopped() if isinstance(link, StreamReadsBackSafe) else None
    except (InstrumentError, OSError) as exc:
        log.warning("socket %d (not scanned): could not stop its stream: %s", sock, exc)
        return
    if back is not None and not back.safe:
        log.warning("socket %d (not scanned): its stream did not stop: %s", sock, back.detail)

