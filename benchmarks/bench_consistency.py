"""Stop method against rate table against the simulated bench's truth, over many parts, and
the consistency judgement's false-reject rate before and after it became a product setting.

At each condition of each part: the stop-method scale and the rate-table scale, each against
the true scale at the die temperature of its own windows and the measured supply
(docs/interfaces.md: scale * (1 + sT dT + sV dV)), in units of its own standard (k=1) uncertainty,
and the station's normalised difference (measurement `stop_table_consistency`). With honest
standard uncertainties each z has mean ~0 and SD ~1, and about 4.6 % / 0.3 % lie beyond 2 / 3.

The false-reject rate is over good parts (the simulated population's parts have no effect
that makes the stop and the table disagree): the share of parts the consistency judgement
rejects. Before: the fixed |E_n| <= 3 at each condition, no second measurement, judged on
each condition's first E_n (the station's first measurement is the old station's, unchanged).
After: the station's own verdict under the product's `consistency:` rule (the limit derived
for a per-part rate, the condition measured once more when a part fails only this).

The parts run through the station itself (`station run --sim`'s path, lockstep, many sockets
per load): every effect the judgement sees (noise, bias instability, the die's temperature,
the hand-off between the rate table and the stop moves) is the bench's, which an analysis on
synthetic data would have to imitate. In lockstep a 32-socket load takes a few wall minutes.

    python3 benchmarks/bench_consistency.py [--parts 224] [--sockets 32] [--speed X]
                                            [--first-serial 3201] [--json rows.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from procedures.analysis.consistency import part_false_reject_rate  # noqa: E402
from station.sim_run import run_simulated  # noqa: E402

OLD_LIMIT = 3.0  # the fixed per-condition |E_n| limit gyr130 had before the product setting

T_REF_C = 25.0
V_REF_V = 5.0


def _window_temp_c(raw: Path, condition: str, kinds: tuple[str, ...]) -> float:
    """Mean die temperature (the part's own sensor) over a condition's segments of `kinds`."""
    with h5py.File(raw, "r") as f:
        t = f["samples/time_s"][:]
        temp = f["samples/temp_c"][:]
        seg = f["segments"]
        kind = [k.decode() if isinstance(k, bytes) else str(k) for k in seg["kind"][:]]
        cond = [c.decode() if isinstance(c, bytes) else str(c) for c in seg["condition"][:]]
        start, end = seg["start_s"][:], seg["end_s"][:]
    mask = np.zeros(t.size, dtype=bool)
    for k, c, a, b in zip(kind, cond, start, end, strict=True):
        if k in kinds and c == condition:
            mask |= (t >= a) & (t <= b)
    return float(temp[mask].mean()) if mask.any() else math.nan


def true_scale(params: dict[str, Any], temp_c: float, supply_v: float) -> float:
    return float(params["scale"]) * (
        1.0
        + float(params["scale_temp_coeff_per_c"]) * (temp_c - T_REF_C)
        + float(params["scale_supply_coeff_per_v"]) * (supply_v - V_REF_V)
    )


def rows_from_run(folder: Path, params: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per condition that has both scales and the consistency measurement."""
    rec = json.loads((folder / "record.json").read_text(encoding="utf-8"))
    stops = rec["analysis"].get("stop_method", {})
    tables = rec["analysis"].get("rate_table", {})
    en = {
        m["condition"]: m["value"]
        for m in rec["measurements"]
        if m["name"] == "stop_table_consistency" and m["value"] is not None
    }
    rows = []
    for c in rec["conditions"]:
        name = c["name"]
        if name not in stops or name not in tables or name not in en:
            continue
        supply_v = c.get("supply_measured_v") or c["supply_v"]
        t_stop = _window_temp_c(folder / "raw.h5", name, ("stop_static", "stop_move"))
        t_table = _window_temp_c(folder / "raw.h5", name, ("plateau",))
        s, tb = stops[name], tables[name]
        truth_stop = true_scale(params, t_stop, supply_v)
        truth_table = true_scale(params, t_table, supply_v)
        rows.append(
            {
                "serial": rec["dut"]["serial"],
                "condition": name,
                "scale_stop": s["scale"],
                "u_stop": s["u_scale"],
                "scale_table": tb["scale"],
                "u_table": tb["u_scale"],
                "truth_stop": truth_stop,
                "truth_table": truth_table,
                "die_stop_c": t_stop,
                "die_table_c": t_table,
                "z_stop": (s["scale"] - truth_stop) / s["u_scale"],
                "z_table": (tb["scale"] - truth_table) / tb["u_scale"],
                "en": en[name],
            }
        )
    return rows


def part_judgement(folder: Path) -> dict[str, Any]:
    """One part: its first E_n at each condition (before any second measurement), whether
    the station's record fails the consistency, and what it measured again."""
    rec = json.loads((folder / "record.json").read_text(encoding="utf-8"))
    final = {m["condition"]: m for m in rec["measurements"]
             if m["name"] == "stop_table_consistency"}
    again = {e["condition"]: e for e in rec["analysis"].get("remeasured", [])
             if e.get("measurement") == "stop_table_consistency"}
    first = {c: (again[c]["first"]["value"] if c in again else m["value"])
             for c, m in final.items()}
    first.update({c: e["first"]["value"] for c, e in again.items() if c not in first})
    return {
        "serial": rec["dut"]["serial"],
        "verdict": rec["verdict"],
        "first_en": {c: v for c, v in first.items() if v is not None},
        "fails_after": any(m["outcome"] == "FAIL" for m in final.values()),
        "remeasured": sorted(again),
        "limit": next((m["high"] for m in final.values() if m.get("high") is not None), None),
        "other_failures": [f for f in rec.get("failed_measurements", [])
                           if not f.startswith("stop_table_consistency")],
    }


def print_false_reject(parts: list[dict[str, Any]]) -> None:
    """The share of good parts the consistency judgement rejects, before and after."""
    judged = [p for p in parts if p["first_en"]]
    n_cond = max((len(p["first_en"]) for p in judged), default=0)
    before = [p for p in judged if any(abs(v) > OLD_LIMIT for v in p["first_en"].values())]
    after = [p for p in judged if p["fails_after"]]
    again = [p for p in judged if p["remeasured"]]
    limit = next((p["limit"] for p in judged if p["limit"] is not None), None)
    print(f"\nconsistency judgement over {len(judged)} good parts ({n_cond} conditions each)")
    print(f"  before: |E_n| <= {OLD_LIMIT:g} at each condition, no second measurement: "
          f"{len(before)} rejected = {100 * len(before) / max(len(judged), 1):.2f} % "
          f"(expected for N(0,1): {100 * part_false_reject_rate(OLD_LIMIT, n_cond):.2f} %)"
          + (f"  [{', '.join(p['serial'] for p in before)}]" if before else ""))
    lim = f"{limit:.2f}" if limit is not None else "?"
    print(f"  after:  |E_n| <= {lim} (product's per-part rate), a lone failure measured once "
          f"more: {len(after)} rejected = {100 * len(after) / max(len(judged), 1):.2f} % "
          f"(expected <= {100 * part_false_reject_rate(limit, n_cond) if limit else 0:.2f} % "
          f"before the second measurement); {len(again)} parts measured again"
          + (f"  [{', '.join(p['serial'] + ':' + ','.join(p['remeasured']) for p in again)}]"
             if again else ""))
    others = [p for p in judged if p["other_failures"]]
    if others:
        print(f"  ({len(others)} parts failed other limits: "
              f"{'; '.join(p['serial'] + ' ' + ','.join(p['other_failures']) for p in others)})")


def stats(z: list[float]) -> str:
    a = np.asarray(z, dtype=np.float64)
    return (
        f"n {a.size:4d}  mean {a.mean():+6.2f}  SD {a.std(ddof=1):5.2f}  "
        f"|z|>2 {100 * np.mean(np.abs(a) > 2):5.1f} %  |z|>3 {100 * np.mean(np.abs(a) > 3):5.1f} %"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", type=int, default=224)
    ap.add_argument("--sockets", type=int, default=32)
    ap.add_argument("--speed", type=float, default=None)
    ap.add_argument("--procedure", default=str(ROOT / "config/procedures/eol-rate-table.yaml"))
    ap.add_argument("--first-serial", type=int, default=3201)
    ap.add_argument("--json", type=Path, help="also write every row to this file")
    args = ap.parse_args()
    out = Path(tempfile.mkdtemp(prefix="bench-consistency-"))
    rows: list[dict[str, Any]] = []
    parts_judged: list[dict[str, Any]] = []
    serial, done = args.first_serial, 0
    t0 = time.monotonic()
    while done < args.parts:
        n = min(args.sockets, args.parts - done)
        parts = [{"socket": s, "serial": f"SIM-{serial + s - 1:04d}"} for s in range(1, n + 1)]
        serial += n
        done += n
        result, truth = run_simulated(
            parts, procedure_path=Path(args.procedure), out=out, speed=args.speed
        )
        for s in sorted(result.folders):
            params = truth["sockets"][str(s)]["parameters"]
            rows.extend(rows_from_run(result.folders[s], params))
            parts_judged.append(part_judgement(result.folders[s]))
        print(f"  ... {done} parts, {len(rows)} conditions ({time.monotonic() - t0:.0f} s wall)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1), encoding="utf-8")
    if not rows:
        print("no condition gave both scales: nothing to judge")
        return 1
    print("\nz = (estimate - truth) / u(k=1); normalised difference as the station measures it")
    print(f"scale_stop  {stats([r['z_stop'] for r in rows])}")
    print(f"scale_table {stats([r['z_table'] for r in rows])}")
    print(f"E_n         {stats([r['en'] for r in rows])}")
    print(
        f"median u: stop {np.median([r['u_stop'] for r in rows]):.2e}, "
        f"table {np.median([r['u_table'] for r in rows]):.2e}; "
        f"die temperature stop - table: mean "
        f"{np.mean([r['die_stop_c'] - r['die_table_c'] for r in rows]):+.3f} C"
    )
    print_false_reject(parts_judged)
    print(f"wall time {time.monotonic() - t0:.0f} s; run folders in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
