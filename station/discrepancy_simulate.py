"""`station discrepancy RUN_FOLDER --simulate`: the twin learns the part.

The starting model (fitted to the run) and the extended model each become a simulated part
(procedures/model/twin.py `part_entry`); their sim configs are written next to the report
(`twin_before.yaml`, `twin_after.yaml`), the procedure the run's record names runs on a
freshly started simulated bench with each (in the measured part's socket, the part's own
thermal physics off, among the other parts of the measured cycle; the procedure's
conditions; in lockstep with the station's clock unless a speed is given; its record and
certificate name the effects it carries), and the measured run is compared window piece by
window piece with both twin runs (`twin.compare`).
"""

from __future__ import annotations

import hashlib
import logging
import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from procedures.runtime.record import read_record
from station.errors import UserError

if TYPE_CHECKING:
    from procedures.model.discrepancy import DiscrepancyResult
    from procedures.model.gyro_model import GyroModel
    from procedures.model.trajectory import Trajectory
    from procedures.model.twin import SimulationComparison

log = logging.getLogger(__name__)

# None: the bench runs in lockstep with the station's clock (station time is physics time),
# so the machine's load cannot shift the twins' windows against the part's physics; a speed
# factor runs it free (station seconds per wall second)
DEFAULT_SPEED: float | None = None
TWINS = ("before", "after")
BENCH_START_ATTEMPTS = 3  # a bench slow to write its state file is started again


def record_procedure(run_folder: Path, override: Path | None) -> tuple[Path, str | None]:
    """The procedure to simulate: `override`, else the file the run's record names (as
    recorded, else relative to the run folder's parent); with a note when the file's content
    is not the one the run used."""
    try:
        rec = read_record(run_folder)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    if override is not None:
        if not override.is_file():
            raise UserError(f"--procedure {override}: no such file; give the procedure YAML")
        path = override
    else:
        recorded = Path(rec.procedure.path)
        found = [p for p in (recorded, run_folder.parent / recorded) if p.is_file()]
        if not found:
            raise UserError(
                f"{run_folder}: the procedure the run used ({rec.procedure.path}) is not there "
                "any more; give it with --procedure PATH"
            )
        path = found[0]
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    note = None
    if rec.procedure.sha256 and digest != rec.procedure.sha256:
        note = (
            f"the procedure {path} differs from the one the run used (sha256 changed); the "
            "twins ran the file as it is now"
        )
    return path, note


def supply_current_a(run_folder: Path) -> float | None:
    """The part's mean supply current over the run's conditions (its self-heating), if
    recorded."""
    currents = [c.supply_current_a for c in read_record(run_folder).conditions
                if c.supply_current_a is not None]
    return sum(currents) / len(currents) if currents else None


SAME_CYCLE_S = 10.0  # run folders started this close together, same procedure: one cycle


def parse_utc_s(text: str) -> float:
    """Seconds of an ISO time stamp (a record's started_utc)."""
    return datetime.fromisoformat(text).timestamp()


def companions(run_folder: Path) -> dict[int, Path]:
    """The other parts of the measured run's cycle (sibling run folders started with it, the
    same procedure, other sockets), socket -> run folder. The twin runs among them (bench
    parts of their serials): a ramp turns when the last die of the load has covered the
    span, so a twin alone turned elsewhere and its plateaus left the measured timeline
    (eol-ramp, six parts in one run: 53-133 of 148 pieces compared); among the same parts
    it turns with them."""
    rec = read_record(run_folder)
    t0 = parse_utc_s(rec.started_utc)
    out: dict[int, Path] = {}
    for sibling in sorted(run_folder.parent.iterdir()):
        if sibling == run_folder or not (sibling / "record.json").is_file():
            continue
        try:
            other = read_record(sibling)
        except ValueError:
            continue
        if (other.procedure.sha256 == rec.procedure.sha256
                and other.dut.socket not in (rec.dut.socket, *out)
                and abs(parse_utc_s(other.started_utc) - t0) <= SAME_CYCLE_S):
            out[other.dut.socket] = sibling
    return dict(sorted(out.items()))


def _check_entry(entry: dict[str, Any], model_name: str) -> None:
    """UserError before any bench starts if the bench cannot hold the model as a part."""
    # the simulated bench: loaded only when asked for
    from drivers.sim.config import SimConfigError, parse_sim_config

    try:
        parse_sim_config({"parts": [entry]}, source=f"twin of model {model_name}")
    except SimConfigError as exc:
        raise UserError(
            f"the model {model_name} cannot be a simulated part ({exc}); --simulate needs "
            "values the bench accepts"
        ) from exc


def run_twin(
    entry: dict[str, Any], procedure: Path, out: Path, speed: float | None,
    effects: tuple[str, ...] = (), others: list[dict[str, Any]] | None = None,
    bench: dict[str, Any] | None = None,
) -> tuple[Path, str]:
    """One station run of `procedure` on a bench holding the twin part (the honest thermal
    physics off: the part carries only the model's `effects`, which its record and
    certificate name); (run folder, verdict)."""
    # the simulated bench: loaded only when asked for
    from drivers.sim.launcher import BenchStartError
    from procedures.model.twin import TWIN_SIM_CONFIG
    from procedures.runtime.record import read_record
    from station.sim_run import run_simulated

    for attempt in range(1, BENCH_START_ATTEMPTS + 1):
        try:
            result, _ = run_simulated([entry, *(others or [])], procedure_path=procedure,
                                      out=out, speed=speed,
                                      sim_config=bench or TWIN_SIM_CONFIG,
                                      certificate=True,
                                      part_effects={int(entry["socket"]): effects})
            break
        except BenchStartError as exc:  # slow to start on a loaded machine: start it again
            if attempt == BENCH_START_ATTEMPTS:
                raise UserError(
                    f"the simulated bench for the twin run did not start in "
                    f"{BENCH_START_ATTEMPTS} attempts ({exc}); is the machine overloaded?"
                ) from exc
            log.warning("the bench did not start (%s); starting it again (%d of %d)", exc,
                        attempt + 1, BENCH_START_ATTEMPTS)
        except Exception as exc:  # the bench or the station could not run the twin
            log.exception("twin run failed")
            raise UserError(f"the twin run on the simulated bench failed: {exc}") from exc
    folder = result.folders.get(int(entry["socket"]))
    if folder is None:
        raise UserError(f"the twin run on the simulated bench left no run folder in {out}")
    verdict = str(read_record(folder).verdict)
    if verdict not in ("PASS", "FAIL"):
        raise UserError(
            f"the twin run ended {verdict} ({folder}); see its record.json for the reason"
        )
    return folder, verdict


AIR_MATCH_C = 0.02  # a twin's die further than this from the measured: its air is given


@dataclass
class TwinRuns:
    """What the twin runs of one measured run share: the procedure, the measured part's
    socket and supply current, the other parts of its cycle, and the air given to sockets."""

    run_folder: Path
    procedure: Path
    out: Path
    serial: str
    speed: float | None
    current: float | None
    arw: float
    others: dict[int, Path]  # socket -> the measured run folder of a companion part
    air_c: dict[int, float] = field(default_factory=dict)

    def parts(self) -> list[dict[str, Any]]:
        return [{"socket": k, "serial": read_record(f).dut.serial}
                for k, f in sorted(self.others.items())]

    def run(self, label: str, model: GyroModel, say: Callable[[str], None]
            ) -> tuple[Path, dict[str, Any]]:
        """The twin of `model` through the procedure: its run folder and JSON detail."""
        from procedures.model.twin import part_entry, twin_bench, twin_config

        socket = max(read_record(self.run_folder).dut.socket, 1)  # the measured one's air
        entry = part_entry(model, self.serial, socket=socket, measured_arw_deg_per_sqrt_h=self.arw,
                           supply_current_a=self.current)
        _check_entry(entry, model.name)
        config = self.out / f"twin_{label}.yaml"
        config.write_text(yaml.safe_dump(twin_config(entry, self.air_c), sort_keys=False),
                          encoding="utf-8")
        runs = self.out / f"twin_{label}_runs"
        if runs.exists():  # a previous --simulate into the same --out, or a first pass
            shutil.rmtree(runs)
        say(f"simulate: running {self.procedure.name} on the bench with the {model.name} twin")
        folder, verdict = run_twin(entry, self.procedure, runs, self.speed,
                                   tuple(model.effects), self.parts(), twin_bench(self.air_c))
        return folder, {"model": model.name, "sim_config": str(config),
                        "run_folder": str(folder), "verdict": verdict}

    def air_to_give(self, measured: Trajectory, twin_folder: Path) -> dict[int, float]:
        """Each socket's air that puts the twin run's dies at the measured ones (the
        measured die minus the twin's over the first pieces, added to the twin bench's own
        air); empty when every die is within AIR_MATCH_C already (the default bench)."""
        from drivers.sim.config import ThermalPhysicsConfig
        from drivers.sim.thermal_physics import socket_air_offset_c
        from procedures.model.run_folder import load_data
        from procedures.model.twin import TWIN_SIM_CONFIG, die_offset_c

        pairs = {max(read_record(self.run_folder).dut.socket, 1): (measured, twin_folder)}
        offsets = {k: _offset(m, f, self.serial) for k, (m, f) in pairs.items()}
        if all(abs(v) <= AIR_MATCH_C or math.isnan(v) for v in offsets.values()):
            return {}
        for k, folder in self.others.items():  # their dies too: the ramp turns with them
            serial = read_record(folder).dut.serial
            twin = next(iter(sorted(twin_folder.parent.glob(f"*_{serial}"))), None)
            if twin is not None:
                offsets[k] = die_offset_c(load_data(folder, dut=serial),
                                          load_data(twin, dut=serial))
        own = ThermalPhysicsConfig(**TWIN_SIM_CONFIG["part_physics"]["thermal"])
        return {k: socket_air_offset_c(0, k, own) + v for k, v in offsets.items()
                if not math.isnan(v)}


def _offset(measured: Trajectory, twin_folder: Path, serial: str) -> float:
    from procedures.model.run_folder import load_data
    from procedures.model.twin import die_offset_c

    return die_offset_c(measured, load_data(twin_folder, dut=serial))


def simulate(
    run_folder: Path,
    measured: Trajectory,
    result: DiscrepancyResult,
    out: Path,
    *,
    procedure: Path | None = None,
    speed: float | None = DEFAULT_SPEED,
    say: Callable[[str], None] = lambda _line: None,
) -> tuple[SimulationComparison, dict[str, Any]]:
    """Run both twins and compare; returns the comparison and the JSON detail (twin configs,
    run folders, verdicts). A first twin run whose die is not at the measured die's (a bench
    with other air than the default's, a real part) is run again with the air given."""
    # the discrepancy model: loaded only by this command
    from procedures.model.run_folder import load_data
    from procedures.model.twin import compare

    proc, proc_note = record_procedure(run_folder, procedure)
    others = companions(run_folder)
    # a load's parts share the supply: their records hold the load's current per part, not
    # the part's own (eol-rate-table, six parts: the twin's die 1 C cold); the bench's own
    # then (the measured part's on the simulated bench)
    current = None if others else supply_current_a(run_folder)
    twins = TwinRuns(run_folder, proc, out, measured.serial or "SIM-TWIN", speed, current,
                     result.noise.arw_deg_per_sqrt_h, others)
    models = {"before": result.initial_model, "after": result.final_model}
    folders: dict[str, Path] = {}
    detail: dict[str, Any] = {"simulation_procedure": str(proc.resolve()),
                              "simulation_companions": [p["serial"] for p in twins.parts()]}
    for label in TWINS:
        folders[label], detail[f"simulation_twin_{label}"] = twins.run(label, models[label], say)
        if label == "before" and (air := twins.air_to_give(measured, folders[label])):
            twins.air_c = air
            say(f"simulate: the twin's die was not the measured one's; again with the air "
                f"{', '.join(f'socket {k}: {v:+.3f} C' for k, v in sorted(air.items()))}")
            folders[label], detail[f"simulation_twin_{label}"] = twins.run(
                label, models[label], say)
    detail["simulation_air_given_c"] = {str(k): v for k, v in sorted(twins.air_c.items())}
    try:
        trajs = {k: load_data(f, dut=twins.serial) for k, f in folders.items()}
        comparison = compare(measured, trajs["before"], trajs["after"], result.noise)
    except ValueError as exc:
        raise UserError(f"{run_folder}: {exc}") from exc
    if proc_note:
        comparison = replace(comparison, notes=(proc_note, *comparison.notes))
    return comparison, detail
