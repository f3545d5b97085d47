"""Station-run folders of the honest thermal bench and the workflow's answer on each (issue 29).

`station run --sim` runs a shipped procedure on several parts at once with the parts' thermal
physics as a sim config sets them (drivers/sim/config.py ThermalPhysicsConfig: the honest
default, `mode: ideal`, or one effect alone by zeroing the others); the workflow analyses each
part's run folder from the ideal first-order model. The bench's truth is each part's draws
(drivers/sim/thermal_physics.draw_thermal, deterministic per serial) and its first-order
coefficients (drivers/sim/population.draw_population), from which the base variables the
part's hidden effects depend on follow:

- the element's lag: the part's bias and scale follow the element's temperature, which trails
  the sensor's by about tau x its rate: bias_temp_coeff x tau x dT/dt (`temperature_rate`) and
  scale_temp_coeff x tau x w dT/dt (`rate`, `temperature_rate`);
- the gradient bias: `temperature_rate`;
- the hysteresis: `temperature_direction`.

What a folder can show of them is each effect's size there (tests/model/thermal_truth.py:
z against the workflow's own test, expected to be named above a threshold). A folder's answer
matches the truth (`verdict`) when every named effect depends on the variables of a drawn
effect (never misnamed), every expected effect is named, and the gap after is within 1.5 x
the floor of the same part with the thermal physics off.

Used by tests/model/test_discrepancy_thermal_station.py and
benchmarks/bench_discrepancy_station.py --thermal.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import thermal_truth as tt
import yaml

from drivers.sim.config import ThermalPhysicsConfig
from drivers.sim.population import draw_population
from drivers.sim.thermal_physics import ThermalDraws, draw_thermal
from procedures.model.discrepancy import UNEXPLAINED_GAP_RATIO, run_discrepancy
from procedures.model.gyro_model import first_order_model
from procedures.model.run_folder import load_data
from procedures.runtime.record import read_record

ROOT = Path(__file__).resolve().parents[2]
PROCEDURES = {
    "ramp": ROOT / "config" / "procedures" / "eol-ramp.yaml",
    "rate-table": ROOT / "config" / "procedures" / "eol-rate-table.yaml",
}
_OFF = {
    "element_tau_s": 0.0, "element_tau_sigma_s": 0.0,
    "gradient_dps_per_c_per_min": 0.0, "gradient_sigma_dps_per_c_per_min": 0.0,
    "hysteresis_dps": 0.0, "hysteresis_sigma_dps": 0.0, "socket_air_sigma_c": 0.0,
}
# the sim's `part_physics.thermal` per bench: the honest default (the product's typical
# spreads), none of it, and each bias effect alone at a magnitude the ramp shows
BENCHES: dict[str, dict[str, Any]] = {
    "honest": {},
    "ideal": {"mode": "ideal"},
    "gradient-only": {**_OFF, "gradient_dps_per_c_per_min": 0.01},
    "hysteresis-only": {**_OFF, "hysteresis_dps": 0.05},
}
THERMAL_WORDS = ("temperature_rate", "temperature_direction")


@dataclass(frozen=True)
class Truth:
    """A part's hidden thermal effects as the bench drew them, and their base variables."""

    draws: ThermalDraws
    bias_temp_coeff_dps_per_c: float
    scale_temp_coeff_per_c: float
    scale: float = 1.0

    @property
    def words(self) -> frozenset[str]:
        """The thermal base variables the part's hidden effects depend on."""
        d, out = self.draws, set()
        if d.element_tau_s > 0 or d.gradient_dps_per_c_per_min != 0:
            out.add("temperature_rate")
        if d.hysteresis_dps > 0:
            out.add("temperature_direction")
        return frozenset(out)

    def allows(self, regressors: tuple[str, ...]) -> bool:
        """A named effect matches the truth: it depends on a thermal variable the part's
        effects depend on, and otherwise only on what the first-order model already uses
        (the rate: a lag of the scale's temperature law is w x dT/dt)."""
        thermal = set(regressors) & set(THERMAL_WORDS)
        rest = set(regressors) - set(THERMAL_WORDS)
        return bool(thermal) and thermal <= self.words and rest <= {"rate", "temperature"}

    def part(self) -> tt.PartTruth:
        d = self.draws
        return tt.PartTruth(d.element_tau_s, d.gradient_dps_per_c_per_min, d.hysteresis_dps,
                            d.hysteresis_width_c, self.bias_temp_coeff_dps_per_c, self.scale,
                            self.scale_temp_coeff_per_c)

    def label(self) -> str:
        d = self.draws
        return (f"tau {d.element_tau_s:.0f} s, grad {d.gradient_dps_per_c_per_min:+.4f}, "
                f"h {d.hysteresis_dps:.3f}")


def truth(serial: str, bench: str) -> Truth:
    pop = draw_population(serial)
    return Truth(draws=draw_thermal(serial, ThermalPhysicsConfig(**BENCHES[bench])),
                 bias_temp_coeff_dps_per_c=pop["bias_temp_coeff_dps_per_c"],
                 scale_temp_coeff_per_c=pop["scale_temp_coeff_per_c"], scale=pop["scale"])


def station_run(work: Path, bench: str, procedure: str, serials: list[str]) -> dict[str, Path]:
    """One `station run --sim` of `procedure` on these parts (one socket each) on `bench`:
    each part's run folder (PASS or FAIL; a part that ended otherwise is left out)."""
    out = work / "runs"
    if all(any(out.glob(f"*_{s}")) for s in serials):  # already run there: read again
        return _finished(out, serials)
    work.mkdir(parents=True, exist_ok=True)
    cfg = work / "sim.yaml"
    cfg.write_text(yaml.safe_dump({
        "part_physics": {"thermal": BENCHES[bench]},
        "fixture": {"sockets": len(serials)},
        "parts": [{"socket": i + 1, "serial": s} for i, s in enumerate(serials)],
    }))
    station = Path(sys.executable).parent / "station"
    args = [str(station), "run", "--sim", "--sim-config", str(cfg),
            "--procedure", str(PROCEDURES[procedure]), "--out", str(out)]
    for s in serials:
        args += ["--dut", s]
    done = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    folders = _finished(out, serials)
    if done.returncode not in (0, 1, 2) or not folders:  # 2: a part's ERROR, or refused
        raise RuntimeError((done.stdout + done.stderr)[-2000:])
    return folders


def _finished(out: Path, serials: list[str]) -> dict[str, Path]:
    folders = {}
    for s in serials:
        found = sorted(p for p in out.glob(f"*_{s}") if p.is_dir())
        if found and read_record(found[-1]).verdict in ("PASS", "FAIL"):
            folders[s] = found[-1]
    return folders


Named = tuple[tuple[str, tuple[str, ...]], ...]  # (effect, its regressors) in order


@dataclass(frozen=True)
class Analysis:
    """The workflow's answer on one folder, and what the folder shows of the part's truth."""

    named: Named
    gap_before_dps: float
    gap_after_dps: float
    floor_dps: float
    sizes: tuple[tt.EffectSize, ...]
    z_expected: float


@dataclass(frozen=True)
class FolderResult:
    serial: str
    procedure: str
    bench: str
    answer: Analysis
    ideal_floor_dps: float  # the same part's, same procedure, thermal physics off

    @property
    def named(self) -> Named:
        return self.answer.named

    @property
    def ratio(self) -> float:
        return self.answer.gap_after_dps / self.ideal_floor_dps


def analyse(folder: Path, serial: str, t: Truth) -> Analysis:
    """The workflow from first_order on the folder, and each of the part's effects' size
    there (thermal_truth.sizes)."""
    traj = load_data(folder, dut=serial)
    res = run_discrepancy(traj, first_order_model())
    named = tuple((it.effect, tuple(it.regressors)) for it in res.iterations)
    return Analysis(named, res.gap_initial_dps, res.gap_final_dps, res.noise_floor_dps,
                    tuple(tt.sizes(traj, res, t.part())), tt.z_expected(res))


def _names(regressors: tuple[str, ...], effect: tt.EffectSize) -> bool:
    """A named term with these regressors names the effect: its thermal variable, and the
    rate exactly when the effect has it (a scale law, w x ...)."""
    thermal = set(effect.regressors) & set(THERMAL_WORDS)
    return thermal <= set(regressors) and (("rate" in regressors)
                                            == ("rate" in effect.regressors))


def verdict(row: FolderResult, t: Truth, every_gap: bool = True) -> list[str]:
    """What is wrong with a folder's answer (empty: right): every named effect matches the
    truth (never misnamed), every effect the folder is expected to show (thermal_truth) is
    named, the gap after within 1.5 x the ideal floor (with `every_gap` False: only where
    an effect is named or expected; a folder that shows none keeps its gap, its own floor
    being above the ideal folder's)."""
    wrong = [f"{e} {regs} not in the truth" for e, regs in row.named if not t.allows(regs)]
    wrong += [f"{s.name} (z {s.z:.1f}) not named" for s in row.answer.sizes
              if s.expected and not any(_names(regs, s) for _, regs in row.named)]
    shown = bool(row.named) or any(s.expected for s in row.answer.sizes)
    if row.ratio > UNEXPLAINED_GAP_RATIO and (every_gap or shown):
        wrong.append(f"gap after {row.ratio:.2f} x the ideal floor")
    return wrong


_SHORT = {"lag (scale)": "lag", "rate bias": "rbias", "hysteresis": "hyst"}


def sizes_label(a: Analysis) -> str:
    """Each effect's z (its gap / floor), a star where it is expected to be named."""
    return ", ".join(f"{_SHORT[s.name]} {s.z:.1f}{'*' if s.expected else ''} "
                     f"({s.gap_over_floor:.2f})" for s in a.sizes) or "-"


def table(rows: list[FolderResult], truths: dict[str, Truth]) -> str:
    lines = [f"{'part':9} {'procedure':10} {'bench':15} {'truth':32} "
             f"{'z (gap/floor), * expected':52} {'named (regressors)':44} "
             f"{'before':>7} {'after':>7} {'floor':>7} {'ideal':>7} {'after/ideal':>11} match"]
    for r in rows:
        named = "; ".join(f"{e} ({','.join(regs)})" for e, regs in r.named) or "-"
        t = truths[r.serial + r.bench]
        a = r.answer
        lines.append(
            f"{r.serial:9} {r.procedure:10} {r.bench:15} {t.label():32} {sizes_label(a):52} "
            f"{named:44} {a.gap_before_dps:7.4f} {a.gap_after_dps:7.4f} {a.floor_dps:7.4f} "
            f"{r.ideal_floor_dps:7.4f} {r.ratio:11.2f} {'yes' if not verdict(r, t) else 'NO'}")
    return "\n".join(lines)


def markdown(rows: list[FolderResult], truths: dict[str, Truth]) -> str:
    """The same table in Markdown (docs/discrepancy.md)."""
    out = ["| part | procedure | bench | truth (tau, gradient, h) | z (gap / floor), * expected "
           "| named (regressors) | before | after | floor | ideal | after / ideal | match |",
           "| --- " * 12 + "|"]
    for r in rows:
        d, a = truths[r.serial + r.bench].draws, r.answer
        named = "; ".join(f"{e} ({', '.join(regs)})" for e, regs in r.named) or "-"
        cells = [r.serial, r.procedure, r.bench,
                 f"{d.element_tau_s:.0f} s, {d.gradient_dps_per_c_per_min:+.4f}, "
                 f"{d.hysteresis_dps:.3f}", sizes_label(a), named,
                 f"{a.gap_before_dps:.4f}", f"{a.gap_after_dps:.4f}", f"{a.floor_dps:.4f}",
                 f"{r.ideal_floor_dps:.4f}", f"{r.ratio:.2f}",
                 "yes" if not verdict(r, truths[r.serial + r.bench]) else "no"]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)
