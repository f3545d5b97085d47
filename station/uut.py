"""The UUT loop: scanned serials -> run -> certificate -> results database.

The small API the CLI uses and the browser UI will use:

    runner = UutRunner(settings, procedure_path=..., product_path=..., operator="ana")
    unsubscribe = runner.progress.subscribe(print)        # ProgressEvent stream
    runner.start({1: "SIM-0001", 2: "SIM-0002"})          # background thread; or run(...) to block
    runner.abort()                                        # operator abort (also from SIGINT)
    runner.state()                                        # {"state": "running", "step": ...}
    result = runner.wait()                                # UutResult: folders, verdicts, PDFs

`endpoints` (from the simulated bench's state file) replaces the addresses of station.yaml,
chooses the driver of every role station.yaml leaves to its default (the family each twin
serves) and sets the clock's speed; real instruments run at speed 1. Every instrument is
opened through its configured driver (`station.instruments`, `drivers.registry`) and the
procedure is checked against what they report (`station.preflight`) before any run folder
exists.
"""

from __future__ import annotations

import datetime as dt
import logging
import socket as socketlib
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from common.clock import ScaledClock
from common.yaml_input import ConfigError
from drivers.errors import InstrumentError
from drivers.fixture_protocol import (
    OUTPUT_RATES_HZ,
    SAMPLE3_FRAME_SIZE,
    SAMPLE_FRAME_SIZE,
    sample_stream_baud,
)
from drivers.protocols import (
    Chamber,
    InstrumentIdentity,
    PartLink,
    RateTable,
    StreamReadsBackSafe,
    Supply,
)
from procedures.engine.engine import Engine
from procedures.engine.safe_state import SafeSettingsError, SafeStatePolicy, check_safe_temperature
from procedures.loading.config import (
    ProcedureConfig,
    ProductConfig,
    check_procedure_for_product,
    load_procedure,
    load_product,
    product_for_procedure,
)
from procedures.loading.plan import build_plan
from procedures.runtime.progress import ProgressBus, ProgressEvent
from procedures.runtime.rawdata import RawDataWriter, file_sha256
from procedures.runtime.record import (
    RAW_DATA_FILE,
    Dut,
    Event,
    FileRef,
    InstrumentRecord,
    RunRecord,
    Verdict,
    os_error_text,
    read_record,
    save_record_anywhere,
    write_record,
)
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import Bench, KeptRecord, PartRun
from procedures.runtime.streams import PartStream
from station import __version__, preflight
from station import instruments as roles
from station.bench_clock import station_clock
from station.errors import UserError
from station.instrument_lock import InstrumentLock, lock_instruments
from station.prompt_relay import PromptRelay
from station.run_folder import (
    check_output_folder,
    create_run_folder,
    recover_crashed_runs,
    release,
    validate_serial,
)
from station.settings import LoadedSettings
from station.station_file import load_settings

if TYPE_CHECKING:
    from drivers.sim.launcher import BenchEndpoints

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Endpoints:
    """Where the instruments are, when they are not where station.yaml says (the sim bench)."""

    speed: float
    rate_table: str
    chamber: str
    supply: str
    duts: dict[int, str]
    # role -> the family its twin serves (the station picks `<role>.<family>`)
    families: dict[str, str] = field(default_factory=dict)
    # where the simulated operator reads the station's prompts ('' = nobody simulated)
    operator: str = ""
    # socket -> the inclinometer twin on that socket's fixture (none when the bench has none)
    inclinometers: dict[int, str] = field(default_factory=dict)
    lockstep: bool = False  # the bench's world moves only when the station's clock asks
    control: str = ""  # the bench's control channel (host:port)

    @classmethod
    def of_bench(cls, e: BenchEndpoints) -> Endpoints:
        """The simulated bench's endpoints (its state file) as the station's."""
        return cls(
            speed=e.speed, rate_table=e.rate_table, chamber=e.chamber, supply=e.supply,
            duts=dict(e.duts), families=dict(e.families),
            operator=str(e.raw.get("operator", "") or ""),
            inclinometers={int(k): str(v) for k, v in (e.raw.get("inclinometers") or {}).items()},
            lockstep=e.lockstep, control=e.control,
        )

    def address(self, role: str) -> str:
        """The twin's address of a station role in its driver's form ('' if none)."""
        return str(getattr(self, role, "") or "") if role in (
            "rate_table", "chamber", "supply") else ""

    def serves(self, role: str) -> bool:
        """Whether the bench has a twin for a station role (the inclinometer: one on a
        fixture); a role it does not serve must never be reached at station.yaml's address."""
        if role == "inclinometer":
            return bool(self.inclinometers)
        return bool(self.address(role))


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


# ---------------------------------------------------------------- instruments


@dataclass
class OpenBench:
    bench: Bench
    instruments: list[InstrumentRecord]
    closers: list[Callable[[], None]]
    names: dict[str, str] = field(default_factory=dict)  # role -> "driver at address"

    def close(self) -> None:
        for closer in reversed(self.closers):
            try:
                closer()
            except Exception as exc:  # closing a dead link must not hide the run's result
                log.info("closing an instrument: %s", exc)


def _record(
    role: str,
    ident: InstrumentIdentity | None,
    address: str,
    due: dt.date | None = None,
) -> InstrumentRecord:
    return InstrumentRecord(
        role=role,
        manufacturer=ident.manufacturer if ident else "",
        model=ident.model if ident else "",
        serial=ident.serial if ident else "",
        firmware=ident.firmware if ident else "",
        address=address,
        calibration_due=due.isoformat() if due else None,
        calibration_overdue=bool(due and due < dt.date.today()),
    )


# share of the fixture link's baud the sample stream may take; the rest carries replies
LINK_BAUD_SHARE = 0.9
_STANDARD_BAUDS = (19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600)


def link_speed_problem(output_rate_hz: int, baud: int, axes: int = 1) -> str | None:
    """Why a fixture link at `baud` cannot carry samples at `output_rate_hz`, or None
    (`axes=3`: a three-axis part's longer frames)."""
    needed = sample_stream_baud(output_rate_hz, axes)
    if needed <= LINK_BAUD_SHARE * baud:
        return None
    enough = [b for b in _STANDARD_BAUDS if needed <= LINK_BAUD_SHARE * b]
    raise_to = f"to {enough[0]:,}" if enough else f"above {needed / LINK_BAUD_SHARE:,.0f}"
    fits = [r for r in OUTPUT_RATES_HZ if sample_stream_baud(r, axes) <= LINK_BAUD_SHARE * baud]
    lower_to = f" to {fits[-1]} Hz or less" if fits else ""
    frame_size = SAMPLE3_FRAME_SIZE if axes == 3 else SAMPLE_FRAME_SIZE
    return (
        f"an output rate of {output_rate_hz} Hz needs {needed:,} baud for its "
        f"{frame_size}-byte sample frames, more than {LINK_BAUD_SHARE:.0%} of the "
        f"fixture's {baud:,} baud (the rest is kept for replies): raise instruments.fixture.baud "
        f"in station.yaml {raise_to} (the fixtures must be set to the same rate) or lower "
        f"power.output_rate_hz in the procedure{lower_to}"
    )


def open_part_link(
    settings: LoadedSettings,
    socket: int,
    port: str,
    clock: ScaledClock,
    silent_after_s: float,
    endpoints: Endpoints | None = None,
) -> PartLink:
    """The part driver of one socket (station.yaml's part role, default `part.fixture`), at the
    fixture's configured baud; it judges silence after `silent_after_s` station s (floored)."""
    plan = roles.plan_part(settings, socket, port, endpoints)
    link: PartLink = roles.open_role(settings, plan, clock)
    if hasattr(link, "silent_after_s"):
        # frame loss is judged by the engine against the procedure's fraction, not by the
        # driver; silence needs a wall-time floor too: at 200x, 5 station s are 25 wall ms
        link.silent_after_s = silent_floor_s(silent_after_s, clock)
    return link


def silent_floor_s(silent_after_s: float, clock: ScaledClock, wall_floor_s: float = 1.0) -> float:
    """Station seconds of silence before a part counts as silent (at least `wall_floor_s` wall,
    and two of a lockstep clock's steps: a step's frames arrive only after it)."""
    return max(silent_after_s, wall_floor_s * clock.speed, 2 * clock.check_every_s)


def open_bench(
    settings: LoadedSettings,
    sockets: list[int],
    endpoints: Endpoints | None,
    needs_table: bool,
    silent_after_s: float = 5.0,
) -> OpenBench:
    """Open every role through its configured driver (station.yaml `driver:`, or the family
    the bench's twin serves). A bad driver name or setting is a UserError (file:line); an
    instrument that cannot be reached raises `station.instruments.Unreachable`."""
    closers: list[Callable[[], None]] = []
    clock = station_clock(endpoints, closers)
    records: list[InstrumentRecord] = []
    names: dict[str, str] = {}
    opened: dict[str, Any] = {}
    try:
        for role in roles.station_roles(needs_table):
            plan = roles.plan_role(settings, role, endpoints)
            if plan is None:
                continue
            driver = roles.open_role(settings, plan, clock)
            closers.append(driver.close)
            opened[role] = driver
            names[role] = f"the {plan.label} ({plan.name} at {plan.address})"
            records.append(
                _record(role, roles.identity(driver), plan.address, plan.calibration_due)
            )
        ports = endpoints.duts if endpoints else settings.settings.instruments.fixture.ports
        links: dict[int, PartLink] = {}
        for s in sockets:
            port = ports.get(s)
            if not port:
                raise UserError(
                    f"socket {s} has no fixture port (station.yaml instruments.fixture.ports "
                    "or the bench's sockets); load fewer parts or configure the socket"
                )
            link = open_part_link(settings, s, port, clock, silent_after_s, endpoints)
            closers.append(link.close)
            links[s] = link
        chamber: Chamber = opened["chamber"]
        supply: Supply = opened["supply"]
        table: RateTable | None = opened.get("rate_table")
        return OpenBench(
            Bench(chamber=chamber, supply=supply, links=links, clock=clock, table=table,
                  inclinometer=opened.get("inclinometer")),
            records,
            closers,
            names,
        )
    except BaseException:
        OpenBench(None, [], closers).close()  # type: ignore[arg-type]
        raise


# ---------------------------------------------------------------- the runner


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
                    parts.append(self._new_part(sock, serial, counts))
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
                _record(
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

    def _new_part(self, sock: int, serial: str, counts_per_rev: int | None) -> PartRun:
        folder = create_run_folder(self.out, serial)
        info = self.settings.settings.station
        now = dt.datetime.now(dt.UTC)
        record = RunRecord(
            run_id=folder.name,
            verdict=Verdict.RUNNING,
            simulated=self.endpoints is not None,
            started_utc=now.isoformat(timespec="milliseconds"),
            station_local_tz=str(dt.datetime.now().astimezone().tzinfo),
            station={
                "id": info.id,
                "name": info.name,
                "location": info.location,
                "host": socketlib.gethostname(),
            },
            operator=self.operator,
            work_order=self.work_order,
            lot=self.lot,
            software_version=__version__,
            dut=Dut(serial=serial, socket=sock, product=self.product.product),
            product=FileRef(
                path=str(self.product_path),
                name=self.product.product,
                version=self.product.part_number,
                sha256=self.product_file.sha256,
            ),
            procedure=FileRef(
                path=str(self.procedure_path),
                name=self.procedure.name,
                version=self.procedure.version,
                sha256=self.procedure_file.sha256,
            ),
            station_config=FileRef(
                path=str(self.settings.source.path),
                name=info.id,
                sha256=self.settings.source.sha256,
            ),
            raw_data=FileRef(path=RAW_DATA_FILE, name="raw data (HDF5)", sha256=""),
        )
        write_record(folder, record)
        writer = RawDataWriter(
            folder / RAW_DATA_FILE,
            {
                "serial": serial,
                "run_id": folder.name,
                "socket": sock,
                "procedure": self.procedure.name,
                "product": self.product.product,
                "station": info.id,
                "simulated": self.endpoints is not None,
                "software_version": __version__,
                "time_base": "fixture clock (s); station_time_s: station clock estimate",
                # scales /samples/encoder_counts (the fixture latches the table's encoder);
                # the table driver says how many counts it has per turn
                **({"encoder_counts_per_rev": counts_per_rev} if counts_per_rev else {}),
                **({"axes": 3} if self.product.axes == 3 else {}),
            },
            extra_groups=("samples_xyz",) if self.product.axes == 3 else (),
        )
        return PartRun(socket=sock, serial=serial, folder=folder, record=record, writer=writer)

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


def procedure_product(
    procedure_path: Path, product_path: Path | None
) -> tuple[ProcedureConfig, ProductConfig]:
    """Load both files (ConfigError with file:line:field on any problem)."""
    procedure, procedure_file = load_procedure(procedure_path)
    if product_path is None:
        if not procedure.product:
            raise ConfigError(
                f"{procedure_path}: no product given; add 'product:' or pass --product"
            )
        product_path = (procedure_path.parent / procedure.product).resolve()
    product, product_file = load_product(product_path)
    check_procedure_for_product(procedure, procedure_file, product, product_file)
    return procedure, product_for_procedure(product, procedure)


def run_simulated(
    parts: list[dict[str, Any]],
    *,
    procedure_path: Path | None = None,
    out: Path,
    speed: float | None = None,
    settings: LoadedSettings | None = None,
    certificate: bool = False,
    on_progress: Callable[[ProgressEvent], None] | None = None,
) -> tuple[UutResult, dict[str, Any]]:
    """One UUT cycle on a freshly started simulated bench holding `parts` (sim config
    entries); returns the result and the bench's truth at the end (for benchmarks and tests).
    Without `speed` the bench runs in lockstep (station time is physics time)."""
    from drivers.sim.launcher import launch_bench  # the simulated bench: loaded only when asked for

    sockets = max(int(p["socket"]) for p in parts)
    settings = settings or load_settings()
    # the procedure's step modules import while the bench process starts (seconds of each)
    warm = threading.Thread(
        target=_warm_up, args=(procedure_path or settings.procedure,), daemon=True
    )
    warm.start()
    with launch_bench(
        config={"parts": parts}, speed=speed, sockets=sockets, lockstep=speed is None
    ) as bench:
        warm.join()
        runner = UutRunner(
            settings,
            procedure_path=procedure_path,
            out=out,
            endpoints=Endpoints.of_bench(bench.endpoints),
            certificate=certificate,
            operator="benchmark",
        )
        if on_progress is not None:
            runner.progress.subscribe(on_progress)
        result = runner.run({int(p["socket"]): str(p["serial"]) for p in parts})
        truth = bench.control.truth()
    return result, truth


def _warm_up(procedure_path: Path) -> None:
    """Load the procedure once, for its imports (UutRunner loads it again and reports any
    error in it)."""
    try:
        load_procedure(Path(procedure_path))
    except Exception:  # noqa: BLE001 - reported by the runner's own load
        log.debug("warm-up load of %s failed", procedure_path, exc_info=True)
