"""`station run`, `station demo` and `station schema`.

`run` is one UUT cycle (exit 0 PASS, 1 FAIL, 2 error or abort); `--sim` starts the simulated
bench as its own process for the duration of the run. `demo` runs the default procedure on
one simulated part. Both show a progress display; SIGTERM, Ctrl-C, SIGHUP and SIGQUIT end
the run as a clean abort (the bench made safe, the record ABORTED and sealed, exit 2), see
station/exit_path.py.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import shutil
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from common.yaml_input import ConfigError, read_yaml
from procedures.loading.config import ProcedureConfig, ProductConfig, load_procedure, load_product
from procedures.loading.step_list import procedure_json_schema
from procedures.runtime.progress import ProgressEvent
from station.endpoints import Endpoints
from station.errors import UserError
from station.exit_path import ExitPath, exit_bound_s
from station.settings import CONFIG_DIR, StationSettings
from station.station_file import load_settings
from station.uut import UutRunner

DEMO_SERIAL = "SIM-0001"
DEMO_SPEED = 120.0
DEFAULT_SIM_SPEED = 100.0

SCHEMAS: dict[str, type[BaseModel]] = {
    "procedure": ProcedureConfig,
    "product": ProductConfig,
    "station": StationSettings,
}


def _schema(args: argparse.Namespace) -> int:
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create {out}: {exc.strerror}; choose another --out") from exc
    for name, model in SCHEMAS.items():
        path = out / f"{name}.schema.json"
        schema = model.model_json_schema()
        if model is ProcedureConfig:  # steps: each registered step type's settings
            schema = procedure_json_schema(schema)
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        schema.setdefault("title", f"gyrocal {name} file")
        path.write_text(json.dumps(schema, indent=2) + "\n", encoding="utf-8")
        print(path)
    return 0


LINE_WIDTH = 100  # a progress line's bound when the output is not a terminal (a log)


def sockets_text(states: dict[int, str], width: int) -> str:
    """Each socket's state in at most `width` characters: "1:RUNNING 2:FAIL" while it fits,
    else the commonest state counted and the others with their sockets ("30 RUNNING;
    FAIL: 3,17; ERROR: 9"), cut with "..." only if even that is too long."""
    full = " ".join(f"{k}:{v}" for k, v in sorted(states.items()))
    if len(full) <= width:
        return full
    by_state: dict[str, list[int]] = {}
    for sock, state in sorted(states.items()):
        by_state.setdefault(state, []).append(sock)
    common = max(by_state, key=lambda v: len(by_state[v]))
    text = "; ".join(
        [f"{len(by_state[common])} {common}"]
        + [f"{v}: {','.join(map(str, ks))}" for v, ks in by_state.items() if v != common]
    )
    return text if len(text) <= width else text[: max(width - 3, 0)] + "..."


class ProgressDisplay:
    """One updating line on a terminal (within its width); one line per step otherwise
    (within LINE_WIDTH): 32 sockets' states once made 405-character lines."""

    def __init__(self, stream: Any = None, width: int | None = None) -> None:
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        if width is None:
            columns = shutil.get_terminal_size((LINE_WIDTH + 1, 24)).columns
            width = columns - 1 if self.tty else LINE_WIDTH
        self.width = max(width, 40)
        self._last_step = ""

    def __call__(self, ev: ProgressEvent) -> None:
        if ev.kind in ("prompt", "prompt_done"):
            self._prompt(ev)
            return
        step = " ".join(s for s in (ev.step, ev.condition, ev.phase) if s)
        remaining = "" if ev.remaining_s is None else f"~{ev.remaining_s / 60:4.1f} min left"
        head = (
            f"[{100 * ev.fraction:3.0f}%] {step:<26} {remaining:<15} "
            f"t={ev.station_time_s:7.0f} s  "
        )
        line = (head + sockets_text(ev.sockets, self.width - len(head)))[: self.width]
        if self.tty:
            self.stream.write("\r" + line.ljust(self.width))
            if ev.kind == "finished":
                self.stream.write("\n")
            self.stream.flush()
        elif (
            ev.kind in ("step", "finished", "part")
            and step != self._last_step
            or ev.kind == "finished"
        ):
            self._last_step = step
            print(line, file=self.stream, flush=True)

    def _prompt(self, ev: ProgressEvent) -> None:
        """An instruction to the operator on its own line (never overwritten by progress):
        `>>> OPERATOR (socket 1): Turn ...`; `prompt_done` says it was seen done."""
        sockets = ", ".join(str(s) for s in sorted(ev.sockets))
        who = f" (socket{'s' if len(ev.sockets) > 1 else ''} {sockets})" if sockets else ""
        if ev.kind == "prompt":
            text = f">>> OPERATOR{who}: {ev.message}"
            if self.tty:
                text = "\a" + text
        else:
            text = f"    done{who}" + (f": {ev.message}" if ev.message else "")
        lead = "\n" if self.tty else ""
        print(lead + text, file=self.stream, flush=True)


def _duts(values: list[str]) -> dict[int, str]:
    """`--dut SERIAL` fills sockets 1, 2, ...; `--dut 3=SERIAL` names the socket."""
    out: dict[int, str] = {}
    next_socket = 1
    for v in values:
        sock_text, sep, serial = v.partition("=")
        if sep and sock_text.strip().isdigit():
            sock = int(sock_text)
        else:
            sock, serial = next_socket, v
        serial = serial.strip()  # as the station stores it; the sim part must match
        if sock in out:
            raise UserError(f"socket {sock} given twice; one serial per socket")
        out[sock] = serial
        next_socket = max(out) + 1
    return out


def _scanned_parts(duts: dict[int, str], axes: int) -> list[dict[str, Any]]:
    """One simulated part per scanned serial, of the product's kind (a three-axis product's
    parts are three-axis parts, each in its cube)."""
    return [{"socket": s, "serial": serial, **({"three_axis": {}} if axes == 3 else {})}
            for s, serial in sorted(duts.items())]


def _product_axes(args: argparse.Namespace) -> int:
    """The rate axes of the product the run will test (1 when the files do not say; the
    runner refuses a bad procedure or product itself, in its own words)."""
    try:
        settings = load_settings(Path(args.station) if args.station else None)
        procedure_path = Path(args.procedure) if args.procedure else settings.procedure
        procedure, _ = load_procedure(procedure_path)
        product = (Path(args.product) if args.product else
                   (procedure_path.parent / (procedure.product or "")).resolve())
        return int(load_product(product)[0].axes)
    except (ConfigError, ValueError, OSError):
        return 1


def _sim_config(
    path: str | None, duts: dict[int, str], axes: int = 1
) -> tuple[Any, float | None]:
    """The bench config to start: the given file, or one part per scanned serial."""
    if path:
        p = Path(path)
        if not p.is_file():
            raise UserError(f"--sim-config {path}: no such file")
        # the simulated bench: loaded only when asked for
        from drivers.sim.config import SimConfigError, load_sim_config

        try:
            load_sim_config(p)  # refused here, before a bench or a run folder exists
            data = read_yaml(p).data
        except (SimConfigError, ValueError) as exc:
            raise UserError(f"--sim-config {exc}") from None
        has_speed = isinstance(data, dict) and "speed" in data
        speed = None if has_speed else DEFAULT_SIM_SPEED
        if isinstance(data, dict) and not data.get("parts"):  # e.g. config/sim/manual.yaml
            return {**data, "parts": _scanned_parts(duts, axes)}, speed
        return p.resolve(), speed
    return {"parts": _scanned_parts(duts, axes)}, DEFAULT_SIM_SPEED


def _check_out(out: str | None) -> None:
    """Refuse an --out that cannot hold run folders before a bench or a folder exists."""
    if out and Path(out).exists() and not Path(out).is_dir():
        raise UserError(f"--out {out} is a file, not a folder; choose another --out")


@contextlib.contextmanager
def _bench_errors() -> Iterator[None]:
    """A simulated bench that will not start is an error (exit 2), said in one line."""
    # the simulated bench: loaded only when asked for
    from drivers.sim.launcher import BenchStartError

    try:
        yield
    except BenchStartError as exc:
        lines = [t.strip() for t in str(exc).splitlines() if t.strip()]
        detail = lines[-1] if lines else "no error output"
        detail = detail.partition("station bench: error: ")[2] or detail
        raise UserError(f"the simulated bench did not start: {detail}") from None


@dataclasses.dataclass(frozen=True)
class AttachedBench:
    """A simulated bench this station did not start (`station bench --state FILE`): it keeps
    running after the run, whatever becomes of this process."""

    endpoints: Any


@contextlib.contextmanager
def _attached_bench(state: Path) -> Iterator[AttachedBench]:
    """The bench whose state file `state` is, checked alive before anything else happens."""
    # the simulated bench: loaded only when asked for
    from drivers.sim.launcher import BenchEndpoints

    try:
        endpoints = BenchEndpoints.from_state(json.loads(state.read_text(encoding="utf-8")))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserError(
            f"--sim-bench {state}: not a bench state file ({exc}); give the file that "
            "`station bench --state FILE` wrote"
        ) from None
    if endpoints.pid:
        try:
            os.kill(endpoints.pid, 0)
        except ProcessLookupError:
            raise UserError(
                f"--sim-bench {state}: the bench (pid {endpoints.pid}) is not running; start "
                "it again with station bench --state"
            ) from None
        except PermissionError:
            pass  # alive, another user's
    yield AttachedBench(endpoints)


def run_cycle(
    args: argparse.Namespace,
    duts: dict[int, str],
    *,
    sim: bool,
    sim_config: Any = None,
    speed: float | None = None,
    sim_bench: Path | None = None,
) -> int:
    """Shared by run and demo: load files, maybe start the bench, run, print the outcome."""
    _check_labels(args)
    settings, runner_kwargs, probe = _checked_runner(args, duts)
    bench_cm = _bench(duts, sim=sim, sim_config=sim_config, speed=speed, sim_bench=sim_bench)
    wall0 = time.monotonic()
    # every signal and any thread's uncaught exception end the run one way (station/exit_path.py)
    bound_s = exit_bound_s(probe.safe_state_policy)
    exit_path = ExitPath(getattr(args, "command", "run"), bound_s=bound_s)
    with exit_path, _bench_errors(), bench_cm as bench:
        endpoints = None
        if bench is not None:
            endpoints = Endpoints.of_bench(bench.endpoints)
            pace = "in lockstep" if endpoints.lockstep else f"at {endpoints.speed:g}x"
            print(f"simulated bench running {pace} (pid {bench.endpoints.pid})", flush=True)
        runner = UutRunner(settings, endpoints=endpoints, **runner_kwargs)
        display = ProgressDisplay()
        runner.progress.subscribe(display)
        exit_path.attach(lambda reason, error: runner.abort(reason, error=error))
        result = runner.run(duts)
    _print_outcome(result, duts, time.monotonic() - wall0)
    return result.exit_code


def _check_labels(args: argparse.Namespace) -> None:
    """The operator, work order and lot: short printable text, or UserError."""
    operator = getattr(args, "operator", "") or ""
    if len(operator) > 200 or not operator.isprintable():
        raise UserError("--operator must be at most 200 printable characters (a name or badge)")
    for flag in ("work_order", "lot"):
        value = getattr(args, flag, "") or ""
        if len(value) > 100 or not value.isprintable():
            raise UserError(f"--{flag.replace('_', '-')} must be at most 100 printable characters")


def _checked_runner(args: argparse.Namespace, duts: dict[int, str]) -> tuple[Any, Any, Any]:
    """The settings, the runner's arguments and a runner that has checked them (serials, the
    output folder and its space) and recovered the runs a stopped station left RUNNING:
    refused before a bench or a run folder exists."""
    try:
        settings = load_settings(Path(args.station) if args.station else None)
        runner_kwargs: Any = dict(
            procedure_path=Path(args.procedure) if args.procedure else None,
            product_path=Path(args.product) if getattr(args, "product", None) else None,
            operator=getattr(args, "operator", "") or "",
            work_order=getattr(args, "work_order", "") or "",
            lot=getattr(args, "lot", "") or "",
            out=Path(args.out) if args.out else None,
        )
        probe = UutRunner(settings, **runner_kwargs)
        _check_out(args.out)
        for folder in probe.recover():  # a folder it cannot write is logged and left as it is
            print(
                f"marked as ERROR (the station stopped during that run): {folder}", file=sys.stderr
            )
        # bad serials, an output folder that cannot be written or is short of space: refused
        # before a bench or a run folder exists
        probe.validate(duts)
    except ConfigError as exc:
        raise UserError(str(exc)) from None
    return settings, runner_kwargs, probe


def _bench(
    duts: dict[int, str],
    *,
    sim: bool,
    sim_config: Any,
    speed: float | None,
    sim_bench: Path | None,
) -> Any:
    """The bench's context manager (not entered yet): one attached to, one started, or none."""
    if speed is not None:
        from drivers.sim.config import speed_problem

        if problem := speed_problem(speed):
            raise UserError(problem)
    if sim_bench is not None:
        return _attached_bench(sim_bench)
    if sim:
        from drivers.sim.launcher import launch_bench

        return launch_bench(
            config=sim_config,
            speed=speed,
            sockets=max(duts) if isinstance(sim_config, dict) else None,
            lockstep=speed is None,  # pinned: lockstep unless a speed is given
        )
    return contextlib.nullcontext(None)


def _print_outcome(result: Any, duts: dict[int, str], wall: float) -> None:
    for sock in sorted(result.verdicts):
        print(
            f"socket {sock} {duts[sock]}: {result.verdicts[sock]}"
            + (f" - {result.reasons[sock]}" if result.reasons[sock] else "")
        )
        print(f"  run folder: {result.folders[sock]}")
        record = result.record_files.get(sock, result.folders[sock] / "record.json")
        if sock in result.certificates:
            print(f"  certificate: {result.certificates[sock]}")
        elif record is None:
            print("  record: could not be written anywhere (its verdict is in the log above)")
        else:
            print(f"  record: {record}")
    print(f"station time {result.station_time_s / 60:.1f} min, wall time {wall:.1f} s")


def _run(args: argparse.Namespace) -> int:
    duts = _duts(args.dut)
    if args.sim_bench:
        if args.sim_config or args.speed is not None:
            raise UserError(
                "--sim-bench runs on a bench already started: its config and speed are that "
                "bench's; leave out --sim-config and --speed"
            )
        return run_cycle(args, duts, sim=True, sim_bench=Path(args.sim_bench))
    sim_path = args.sim_config
    if args.sim and not sim_path:
        try:
            settings = load_settings(Path(args.station) if args.station else None)
        except ConfigError as exc:
            raise UserError(str(exc)) from None
        if settings.settings.sim_config:
            sim_path = str(settings.resolve(settings.settings.sim_config))
    sim_config, _ = _sim_config(sim_path, duts, _product_axes(args)) if args.sim else (None, None)
    # lockstep (station time is physics time) unless --speed asks for a scaled clock
    return run_cycle(args, duts, sim=args.sim, sim_config=sim_config, speed=args.speed)


def _demo(args: argparse.Namespace) -> int:
    duts = {1: DEMO_SERIAL}
    args.station = args.station or None
    args.procedure = args.procedure or str(CONFIG_DIR / "procedures" / "eol-ramp.yaml")
    code = run_cycle(
        args,
        duts,
        sim=True,
        sim_config={"parts": [{"socket": 1, "serial": DEMO_SERIAL}]},
        speed=args.speed,  # lockstep unless --speed asks for a scaled clock
    )
    return 0 if code in (0, 1) else code


def register(subparsers: argparse._SubParsersAction) -> None:
    r = subparsers.add_parser("run", help="one UUT cycle: calibrate the scanned parts")
    r.add_argument(
        "--dut",
        action="append",
        required=True,
        metavar="SERIAL",
        help="scanned serial; repeat for more sockets (or SOCKET=SERIAL)",
    )
    r.add_argument("--procedure", help="procedure file (default: station.yaml's)")
    r.add_argument("--product", help="product file (default: the procedure's product)")
    r.add_argument("--station", help="station file (default: config/station.yaml)")
    r.add_argument("--operator", default="", help="operator name or badge")
    r.add_argument("--work-order", default="", help="work order the parts are built under")
    r.add_argument("--lot", default="", help="production lot of the parts")
    r.add_argument("--sim", action="store_true", help="start the simulated bench for this run")
    r.add_argument(
        "--sim-config",
        help="simulated bench configuration (YAML) for --sim; without it (and without "
        "sim_config in station.yaml) the simulated bench gets one part per scanned serial, "
        "in the scanned socket, its parameters drawn from the population (same serial, same "
        "part)",
    )
    r.add_argument("--speed", type=float, help="simulated bench speed factor (with --sim)")
    r.add_argument(
        "--sim-bench",
        metavar="STATE_FILE",
        help="run on the simulated bench already running as its own process (the state file "
        "`station bench --state STATE_FILE` wrote) instead of starting one; implies --sim, "
        "and the bench keeps running after the run",
    )
    r.add_argument(
        "--out",
        help="output folder for run folders (default: station.yaml's output_folder); an --out "
        "other than that folder also moves the results database to OUT/results.sqlite "
        "(station.yaml's results_db is kept when --out is absent or names that same folder)",
    )
    r.set_defaults(handler=_run)
    d = subparsers.add_parser("demo", help="the station on the simulated bench, one part")
    d.add_argument("--out", help="output folder (default: station.yaml's)")
    d.add_argument("--procedure", help="procedure file (default: the full rate-table procedure)")
    d.add_argument("--station", help="station file (default: config/station.yaml)")
    d.add_argument(
        "--speed",
        type=float,
        help=f"bench speed factor, e.g. {DEMO_SPEED:g} (default: lockstep, as fast as it computes)",
    )
    d.add_argument("--operator", default="demo")
    d.set_defaults(handler=_demo)
    p = subparsers.add_parser(
        "schema", help="write JSON Schemas of the station, product and procedure files"
    )
    p.add_argument("--out", default="schemas", help="folder for the *.schema.json files")
    p.set_defaults(handler=_schema)
