"""Effects that couple the axes of a three-axis part (issue 29): how the discrepancy workflow's
cross-axis terms (procedures/model/cross_axis.py) fare over simulated parts through the
station (eol-three-axis, lockstep, loads of up to 8, distinct serials).

- Null parts (first-order, as the population draws them): per axis, the effects named with
  the cross-axis terms searched and without them. A cross-axis term named on a null axis is a
  false alarm of the new candidates; any change in the other effects named is their doing.
- Crossed parts: one effect on one pair of axes (the pair drawn, the two kinds in turn): a
  cross-coupling drifting with temperature (C = 2e-5 per C) or a g-squared cross term
  (Q = 3e-4 deg/s per (m/s^2)^2), in the bench's own physics (drivers/sim/cross_axis.py).
  Named right: that term first on the axis it acts on, no cross-axis term on the others.

    python3 benchmarks/bench_three_axis_cross.py [--null 16] [--crossed 8] [--load 8] [--seed 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from procedures.model.cross_axis import is_cross_id  # noqa: E402
from procedures.model.discrepancy import DiscrepancyResult, run_discrepancy  # noqa: E402
from procedures.model.gyro_model import first_order_model  # noqa: E402
from procedures.model.run_folder_xyz import AXES, load_axis  # noqa: E402

PROCEDURE = ROOT / "config/procedures/eol-three-axis.yaml"
MAGNITUDE = {"w_dT": ("cross_temp_coeff_per_c", 2e-5),
             "a2": ("g2_cross_dps_per_mps2_sq", 3e-4)}


def crossed_part(i: int, rng: np.random.Generator) -> tuple[dict[str, Any], str]:
    """A part's three_axis block with one effect on a drawn pair, and the term it should get."""
    kind = ("w_dT", "a2")[i % 2]
    target, source = rng.choice(3, size=2, replace=False)
    key, value = MAGNITUDE[kind]
    m = np.zeros((3, 3))
    m[target, source] = value
    return {key: m.tolist()}, f"lib_{AXES[target]}from{AXES[source]}_{kind}"


def run_loads(parts: list[dict[str, Any]], load: int, out: Path) -> list[Path]:
    from station.sim_run import run_simulated

    folders: list[Path] = []
    for k in range(0, len(parts), load):
        chunk = [{**p, "socket": s + 1} for s, p in enumerate(parts[k:k + load])]
        t0 = time.monotonic()
        result, _truth = run_simulated(chunk, procedure_path=PROCEDURE, out=out / f"load{k}")
        folders += [result.folders[s + 1] for s in range(len(chunk))]
        print(f"load of {len(chunk)}: {time.monotonic() - t0:.0f} s", flush=True)
    return folders


def analyse(folder: Path, axis: str, cross: bool) -> DiscrepancyResult:
    traj = load_axis(folder, axis)
    if not cross:
        traj = dataclasses.replace(traj, axis="", axis_variables={})
    return run_discrepancy(traj, first_order_model())


def named(folder: Path, axis: str, cross: bool) -> list[str]:
    return analyse(folder, axis, cross).effects_added


def null_parts(folders: list[Path]) -> None:
    axes = false_alarms = changed = 0
    for folder in folders:
        for a in AXES:
            with_cross, without = named(folder, a, True), named(folder, a, False)
            axes += 1
            false_alarms += any(is_cross_id(e) for e in with_cross)
            rest = [e for e in with_cross if not is_cross_id(e)]
            changed += rest != without
            print(f"null {folder.name} {a}: {with_cross or '-'} (without cross terms: "
                  f"{without or '-'})", flush=True)
    print(f"null: {axes} axes, a cross-axis term named on {false_alarms} "
          f"({100 * false_alarms / max(axes, 1):.1f} %); other effects named differently on "
          f"{changed}")


def crossed_parts(folders: list[Path], expected: list[str]) -> None:
    right = misnamed = 0
    ratios = []
    for folder, effect in zip(folders, expected, strict=True):
        res = {a: analyse(folder, a, True) for a in AXES}
        got = {a: r.effects_added for a, r in res.items()}
        target = effect[4]
        ok = got[target][:1] == [effect]
        wrong = [e for a in AXES for e in got[a] if is_cross_id(e) and e != effect]
        right += ok
        misnamed += bool(wrong)
        if ok:
            kind = "a2" if effect.endswith("_a2") else "w_dT"
            ratios.append(res[target].iterations[0].parameters["coeff"] / MAGNITUDE[kind][1])
        print(f"crossed {folder.name} ({effect}): {got}", flush=True)
    print(f"crossed: named first on its axis on {right} of {len(folders)}; another cross-axis "
          f"term named on {misnamed}; coefficient / truth "
          f"{', '.join(f'{r:.2f}' for r in ratios)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--null", type=int, default=16, help="first-order parts")
    ap.add_argument("--crossed", type=int, default=8, help="parts with one cross-axis effect")
    ap.add_argument("--load", type=int, default=8, help="parts per station run")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    nulls = [{"serial": f"XN-{args.seed % 10}{i:03d}", "three_axis": {}}
             for i in range(args.null)]
    crossed, expected = [], []
    for i in range(args.crossed):
        block, effect = crossed_part(i, rng)
        crossed.append({"serial": f"XC-{args.seed % 10}{i:03d}", "three_axis": block})
        expected.append(effect)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        null_parts(run_loads(nulls, args.load, out / "null"))
        crossed_parts(run_loads(crossed, args.load, out / "crossed"), expected)


if __name__ == "__main__":
    main()
