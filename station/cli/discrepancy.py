"""`station discrepancy DATA [--model base|first_order|PATH] [--dut SERIAL] [--json PATH]
[--out DIR] [--export-csv PATH]`: find where the gyro model and a run's data disagree and
name the effect.

Every output path is checked before the data are loaded and analysed (seconds), so a typo
fails at once; results go to a folder of their own per input (never inside a run folder:
run folders are records)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from procedures.model.data import write_csv
from station.discrepancy_simulate import DEFAULT_SPEED, record_procedure, simulate
from station.errors import UserError

if TYPE_CHECKING:
    from procedures.model.discrepancy import DiscrepancyResult
    from procedures.model.trajectory import Trajectory
    from procedures.model.twin import SimulationComparison

log = logging.getLogger(__name__)

STDOUT = "-"


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "discrepancy",
        help="find where the model and the data disagree and name the effect",
        description=(
            "Fit the gyro model to a run (a run folder; a part's newest run folder in a "
            "folder of run folders, with --dut; or a CSV with columns time_s, gyro_dps, "
            "ref_rate_dps, ref_angle_deg, temp_c, supply_v), find where the residuals exceed "
            "the noise floor, name the catalog effect that explains it, add it, refit and "
            "repeat. Writes discrepancy.json, the extended model YAML and a PDF report. "
            "See docs/discrepancy.md."
        ),
    )
    _add_input_args(p)
    _add_output_args(p)
    p.add_argument(
        "--alpha",
        type=float,
        default=None,
        help="family-wise false-alarm rate per iteration (default 0.01)",
    )
    _add_simulation_args(p)
    p.set_defaults(handler=handler)


def _add_input_args(p: argparse.ArgumentParser) -> None:
    """The data and the starting model."""
    p.add_argument(
        "data",
        type=Path,
        help="run folder (record.json + raw.h5), folder of run folders (with --dut), or CSV",
    )
    p.add_argument(
        "--model",
        default="base",
        help="starting model: base, first_order or a model YAML file (default base)",
    )
    p.add_argument(
        "--dut",
        metavar="SERIAL",
        help="serial of the part: picks its run folder in a folder of run folders (the newest "
        "by folder name if there are several) or checks the run folder given",
    )


def _add_output_args(p: argparse.ArgumentParser) -> None:
    """Where the JSON, the report, the model and an exported CSV go."""
    p.add_argument(
        "--json",
        type=Path,
        metavar="PATH",
        help="write the JSON result here; '-' prints it to stdout (the summary then goes to "
        "stderr); default OUT/discrepancy.json",
    )
    p.add_argument(
        "--out",
        type=Path,
        metavar="DIR",
        help="folder for the report, model and JSON (created if missing); default "
        "<folder of the CSV>/<CSV name without .csv>_discrepancy for a CSV, "
        "<folder holding the run folder>/<run folder name>_discrepancy for a run folder",
    )
    p.add_argument(
        "--export-csv",
        type=Path,
        metavar="PATH",
        help="also write the loaded data as a discrepancy CSV (time_s, gyro_dps, "
        "ref_rate_dps, ref_angle_deg, temp_c, supply_v, segment_kind), then analyse",
    )


def _add_simulation_args(p: argparse.ArgumentParser) -> None:
    """--simulate and how it runs."""
    p.add_argument(
        "--simulate",
        action="store_true",
        help="(a run folder only) run the run's procedure on the simulated bench with the "
        "starting model and with the extended model as the part, and report the simulation "
        "gap of each against the measurement (JSON simulation_gap_before_dps, "
        "simulation_gap_after_dps)",
    )
    p.add_argument(
        "--procedure",
        type=Path,
        metavar="PATH",
        help="with --simulate: the procedure to simulate (default: the one the record names)",
    )
    p.add_argument(
        "--sim-speed",
        type=float,
        default=None,
        metavar="X",
        help="with --simulate: run the simulated bench free at this speed, station seconds "
        "per wall second (default: in lockstep with the station's clock, which the "
        "machine's load cannot disturb)",
    )


@dataclasses.dataclass(frozen=True)
class _Input:
    """What DATA resolved to: the CSV, or the run folder (and why that one)."""

    path: Path  # the CSV or the run folder read
    run_folder: Path | None
    note: str | None  # which of several run folders of the part was used


def _resolve_input(data: Path, dut: str | None) -> _Input:
    # the discrepancy model: loaded only by this command
    from procedures.model.run_folder import find_run_folder

    if data.is_file():
        if data.suffix.lower() != ".csv":
            raise UserError(f"{data}: expected a .csv file or a run folder")
        return _Input(data, None, None)
    if not data.exists():
        raise UserError(f"{data}: no such file or folder; give a run folder or a CSV")
    try:
        choice = find_run_folder(data, dut)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    return _Input(choice.folder, choice.folder, choice.note)


def default_out(inp: _Input) -> Path:
    """`<dir>/<stem>_discrepancy` for a CSV, `<parent>/<run folder name>_discrepancy` for a
    run folder: one folder per input, outside the run folder."""
    if inp.run_folder is None:
        return inp.path.parent / f"{inp.path.stem}_discrepancy"
    folder = inp.run_folder.resolve()
    return folder.parent / f"{folder.name}_discrepancy"


def _check_out(out: Path) -> list[Path]:
    """Create the output folder now (so a bad --out fails before the analysis); returns
    the folders created, to remove again if nothing gets written."""
    if out.exists() and not out.is_dir():
        raise UserError(
            f"output folder {out} is a file; give --out a folder (it is created if missing)"
        )
    missing = [p for p in (out, *out.parents) if not p.exists()]
    try:
        out.mkdir(parents=True, exist_ok=True)
        _probe_writable(out)
    except OSError as exc:
        _remove_empty(missing)
        raise UserError(
            f"output folder {out}: cannot create or write there ({exc.strerror or exc}); "
            "give --out a folder you can write to"
        ) from None
    return missing


def _probe_writable(folder: Path) -> None:
    """OSError unless a file can be created in `folder` (also right for root, where
    os.access says yes to everything)."""
    fd, name = tempfile.mkstemp(dir=folder, prefix=".station-write-check-")
    os.close(fd)
    os.unlink(name)


def _remove_empty(created: list[Path]) -> None:
    for p in created:  # deepest first
        try:
            p.rmdir()
        except OSError:
            break


def _check_file(option: str, path: Path, inputs: tuple[Path, ...]) -> None:
    """A file the command will write: its folder must exist and be writable; never an
    existing folder, never the input itself. Nothing is created."""
    if path.is_dir():
        raise UserError(f"{option} {path} is a folder; give a file name, e.g. {path / 'x'}")
    if any(path.resolve() == i.resolve() for i in inputs):
        raise UserError(f"{option} {path} is the input data; give another file name")
    parent = path.parent
    if not parent.is_dir():
        raise UserError(
            f"{option} {path}: folder {parent} does not exist; create it or give another path"
        )
    try:
        _probe_writable(parent)
        if path.exists():
            with path.open("r+b"):
                pass
    except OSError as exc:
        raise UserError(
            f"{option} {path}: cannot write there ({exc.strerror or exc}); give a path you can "
            "write to"
        ) from None


def handler(args: argparse.Namespace) -> int:
    # the discrepancy model: loaded only by this command
    from procedures.model.discrepancy import DEFAULT_ALPHA

    alpha = DEFAULT_ALPHA if args.alpha is None else args.alpha
    if not 0 < alpha < 0.5:
        raise UserError(f"--alpha {alpha} is out of range; give a rate between 0 and 0.5")
    inp = _resolve_input(args.data, args.dut)
    _check_simulate_args(args, inp)
    json_stdout = args.json is not None and str(args.json) == STDOUT
    if args.export_csv is not None and str(args.export_csv) == STDOUT:
        raise UserError("--export-csv needs a file path (not '-')")
    out = args.out or default_out(inp)
    if args.json is not None and not json_stdout:
        _check_file("--json", args.json, (inp.path,))
    if args.export_csv is not None:
        _check_file("--export-csv", args.export_csv, (inp.path,))
    created = _check_out(out)
    written = False
    try:
        written = _run(args, inp, out, alpha, json_stdout)
    finally:
        if not written:
            _remove_empty(created)
    return 0


def _check_simulate_args(args: argparse.Namespace, inp: _Input) -> None:
    simulate = getattr(args, "simulate", False)
    procedure = getattr(args, "procedure", None)
    speed = getattr(args, "sim_speed", None)
    if not simulate:
        if procedure is not None or speed is not None:
            raise UserError("--procedure and --sim-speed go with --simulate; add --simulate")
        return
    if inp.run_folder is None:
        raise UserError(
            f"{args.data}: --simulate needs a station run folder (the procedure it ran is "
            "simulated); a CSV names no procedure"
        )

    record_procedure(inp.run_folder, procedure)  # found before the data are analysed
    if speed is not None:
        # the simulated bench: loaded only when asked for
        from drivers.sim.config import speed_problem

        problem = speed_problem(speed)
        if problem:
            raise UserError(problem.replace("--speed", "--sim-speed"))


def _run(
    args: argparse.Namespace, inp: _Input, out: Path, alpha: float, json_stdout: bool
) -> bool:
    # the discrepancy model: loaded only by this command
    from procedures.model.model_io import load_model

    console = sys.stderr if json_stdout else sys.stdout
    try:
        model = load_model(args.model)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    if inp.run_folder is not None and _three_axis(inp.run_folder):
        return _run_axes(args, inp, out, alpha, json_stdout, model, console)
    traj = _trajectory(args, inp)
    payload, report_failure, result, simulation = _analyse(
        args, inp, traj, model, alpha, out, console)
    json_path = _write_json(args, out, json_stdout, payload)
    _print_summary(result, out, json_path, Path(payload["model_path"]),
                   payload.get("report_path"), console, simulation)
    if report_failure:
        raise UserError(f"{report_failure}; the JSON and model were written")
    return True


def _three_axis(folder: Path) -> bool:
    # the discrepancy model: loaded only by this command
    from procedures.model.run_folder_xyz import is_three_axis

    return is_three_axis(folder)


def _run_axes(
    args: argparse.Namespace, inp: _Input, out: Path, alpha: float, json_stdout: bool,
    model: Any, console: Any,
) -> bool:
    """A three-axis run folder: each axis through the workflow on its own (docs/three-axis.md);
    out/axis-x/ ... hold each axis's model and report, discrepancy.json all three."""
    # the discrepancy model: loaded only by this command
    from procedures.model.run_folder_xyz import AXES, load_axis

    assert inp.run_folder is not None
    if getattr(args, "simulate", False) or args.export_csv is not None:
        raise UserError(f"{args.data}: a three-axis run folder is analysed per axis; "
                        "--simulate and --export-csv are for single-axis runs (leave them out)")
    per_axis: list[dict[str, Any]] = []
    failures: list[str] = []
    json_target = None if json_stdout else (args.json or out / "discrepancy.json")
    for axis in AXES:
        try:
            traj = load_axis(inp.run_folder, axis, dut=args.dut)
        except ValueError as exc:
            raise UserError(str(exc)) from exc
        axis_out = out / f"axis-{axis}"
        axis_out.mkdir(parents=True, exist_ok=True)
        print(f"axis {axis}:", file=console)
        payload, failure, result, _sim = _analyse(args, inp, traj, model, alpha, axis_out,
                                                  console)
        _print_summary(result, axis_out, json_target, Path(payload["model_path"]),
                       payload.get("report_path"), console)
        per_axis.append({"axis": axis, **payload})
        if failure:
            failures.append(failure)
    source = inp.path.resolve()
    combined = {"data": str(args.data), "source": str(source), "run_folder": str(source),
                "serial": per_axis[0].get("serial"), "out": str(out), "axes": per_axis}
    json_path = _write_json(args, out, json_stdout, combined)
    print(f"json: {json_path if json_path is not None else 'stdout'} (all three axes)",
          file=console)
    if failures:
        raise UserError(f"{'; '.join(failures)}; the JSON and models were written")
    return True


def _trajectory(args: argparse.Namespace, inp: _Input) -> Trajectory:
    # the discrepancy model: loaded only by this command
    from procedures.model.run_folder import load_data

    console = sys.stderr if args.json is not None and str(args.json) == STDOUT else sys.stdout
    try:
        traj = load_data(inp.path, dut=args.dut)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    if inp.note:
        traj = dataclasses.replace(traj, notes=(inp.note, *traj.notes))
    if args.export_csv is not None:
        try:
            write_csv(args.export_csv, traj, with_kinds=True)
        except OSError as exc:
            raise UserError(f"--export-csv {args.export_csv}: cannot write it ({exc})") from None
        print(f"data: {traj.n} samples written to {args.export_csv}", file=console)
    return traj


def _analyse(
    args: argparse.Namespace, inp: _Input, traj: Trajectory, model: Any, alpha: float,
    out: Path, console: Any,
) -> tuple[dict[str, Any], str | None, DiscrepancyResult, SimulationComparison | None]:
    """The workflow on one trajectory: its JSON payload (model and report written to out),
    why the report could not be written (or None), the result and any simulation."""
    # the discrepancy model: loaded only by this command
    from procedures.model.discrepancy import run_discrepancy
    from procedures.model.model_io import save_model
    from procedures.model.output import result_to_json

    try:
        result = run_discrepancy(traj, model, alpha=alpha)
    except ValueError as exc:
        raise UserError(f"{args.data}: {exc}") from exc
    source = inp.path.resolve()
    payload = result_to_json(result)
    payload.update(
        data=str(args.data),
        source=str(source),
        run_folder=str(source) if inp.run_folder is not None else None,
        serial=traj.serial or None,
        out=str(out),
    )
    if args.export_csv is not None:
        payload["exported_csv"] = str(args.export_csv)
    simulation = None
    if getattr(args, "simulate", False) and inp.run_folder is not None:
        simulation, detail = _simulate(args, inp.run_folder, traj, result, out, console)
        payload.update(simulation.to_json())
        payload.update(detail)
    try:
        model_path = save_model(result.final_model, out / "model.yaml")
    except OSError as exc:
        raise UserError(f"cannot write the model to {out} ({exc}); check --out") from None
    payload["model_path"] = str(model_path)
    report_path = out / "discrepancy_report.pdf"
    report_failure: str | None = None
    try:
        from reports.discrepancy_report import write_report

        write_report(result, report_path, title_data=data_line(source, traj.serial),
                     simulation=simulation)
        payload["report_path"] = str(report_path)
    except OSError as exc:  # disk full, no permission: the JSON is still written
        payload["report_error"] = str(exc)
        report_failure = f"cannot write the report {report_path} ({exc})"
    except Exception as exc:  # the JSON and model are still useful without the PDF
        log.exception("discrepancy report failed")
        payload["report_error"] = str(exc)
    return payload, report_failure, result, simulation


def _write_json(
    args: argparse.Namespace, out: Path, json_stdout: bool, payload: dict[str, Any]
) -> Path | None:
    text = json.dumps(payload, indent=2)
    json_path = None if json_stdout else (args.json or out / "discrepancy.json")
    if json_path is None:
        print(text)
    else:
        try:
            json_path.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise UserError(f"cannot write the JSON to {json_path} ({exc})") from None
    return json_path


def _simulate(
    args: argparse.Namespace,
    run_folder: Path,
    traj: Trajectory,
    result: DiscrepancyResult,
    out: Path,
    console: Any,
) -> tuple[SimulationComparison, dict[str, Any]]:
    """Both twins run on the bench and compared with the measurement (JSON keys added)."""
    return simulate(
        run_folder,
        traj,
        result,
        out,
        procedure=args.procedure,
        speed=DEFAULT_SPEED if args.sim_speed is None else float(args.sim_speed),
        say=lambda line: print(line, file=console),
    )


def data_line(source: Path, serial: str) -> str:
    """The report's "Data:" line: the run folder or CSV read, and the part."""
    return f"{source} (part {serial})" if serial else str(source)


def _print_summary(
    result: DiscrepancyResult,
    out: Path,
    json_path: Path | None,
    model_path: Path,
    report: str | None,
    console: Any,
    simulation: SimulationComparison | None = None,
) -> None:
    def say(line: str) -> None:
        print(line, file=console)

    for note in result.notes:
        say(f"note: {note}")
    say(
        f"gap {result.gap_initial_dps:.4g} deg/s at start, noise floor "
        f"{result.noise_floor_dps:.4g} deg/s"
    )
    for it in result.iterations:
        say(
            f"named {it.effect}: gap {it.gap_before_dps:.4g} -> {it.gap_after_dps:.4g} deg/s "
            f"(p_holm {it.evidence['p_holm']:.2g})"
        )
        say(f"  {it.formula} [depends on: {', '.join(it.regressors)}]")
        if it.evidence.get("preferred_over"):
            what = ("its variant(s)" if it.evidence["rule"].startswith("a term and its")
                    else "its look-alike interaction(s)")
            how = ("the better fit" if what == "its variant(s)"
                   else "the main effect (marginality)")
            say(f"  named before {what} {', '.join(it.evidence['preferred_over'])}: {how}")
    for ns in result.not_separable:
        say(f"not separable: {' / '.join(ns['effects'])}: {ns['reason']}")
    if result.not_identifiable:
        say(
            f"not identifiable: {', '.join(result.not_identifiable)}: no independent "
            "signature in this data (the model already spans it), not tested"
        )
    if not result.iterations and not result.not_separable:
        say("nothing named: no candidate effect is significant")
    ratio = result.gap_final_dps / result.noise_floor_dps
    say(f"gap {result.gap_final_dps:.4g} deg/s at end ({ratio:.2f} x floor)")
    if result.unexplained_remains:
        say(f"WARNING: {result.unexplained_message}")
    if simulation is not None:
        for note in simulation.notes:
            say(f"note: {note}")
        f = simulation.noise_floor_dps
        say(
            f"simulation gap {simulation.gap_before_dps:.4g} deg/s with the starting model as "
            f"the twin ({simulation.gap_before_dps / f:.2f} x floor), "
            f"{simulation.gap_after_dps:.4g} deg/s with the extended model "
            f"({simulation.gap_after_dps / f:.2f} x floor); noise floor {f:.4g} deg/s over "
            f"{len(simulation.keys)} window pieces (windows cut to at most 10 s)"
        )
    say(f"out: {out}")
    say(f"json: {json_path if json_path is not None else 'stdout'}")
    say(f"model: {model_path}")
    if report:
        say(f"report: {report}")
