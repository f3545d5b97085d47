"""Realistic synthetic run folders (record.json + raw.h5) to test the reports against.

A simulated ADIS16130-like part (bias, scale, temperature and supply coefficients, white
noise) is run through stabilise, static, rate-table plateaus and the stop method at each of
four conditions; the record's measurements are derived from those parameters and limits, so a
test can make a part fail by giving it a bias or scale outside the limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from procedures.runtime.rawdata import RawDataWriter, file_sha256
from procedures.runtime.record import (
    RAW_DATA_FILE,
    Calibration,
    Coefficient,
    ConditionRecord,
    Dut,
    FileRef,
    InstrumentRecord,
    Measurement,
    Outcome,
    RunRecord,
    Verdict,
    write_record,
)

RATE_HZ = 100.0
CONDITIONS = [("T25_V4.75", 25.0, 4.75), ("T25_V5.25", 25.0, 5.25),
              ("T45_V4.75", 45.0, 4.75), ("T45_V5.25", 45.0, 5.25)]
PLATEAUS_DPS = [-200.0, -100.0, -30.0, 30.0, 100.0, 200.0]

LIMITS = {  # name -> (units, low, high, marginal_low, marginal_high)
    "bias_dps": ("deg/s", -10.0, 10.0, -9.0, 9.0),
    "scale": ("1", 0.94, 1.06, 0.95, 1.05),
    "bias_temp_coeff_dps_per_c": ("deg/s/C", -0.03, 0.03, -0.025, 0.025),
    "scale_temp_coeff_per_c": ("1/C", -5e-4, 5e-4, -4e-4, 4e-4),
    "arw_deg_per_sqrt_h": ("deg/sqrt(h)", 0.0, 2.5, 0.0, 2.0),
    "verify_max_error_pct": ("%", 0.0, 1.0, 0.0, 0.8),
}


@dataclass
class Part:
    serial: str = "SIM-0001"
    bias_dps: float = 8.6
    scale: float = 1.0567
    bias_temp_coeff_dps_per_c: float = 0.007
    bias_supply_coeff_dps_per_v: float = 0.05
    scale_temp_coeff_per_c: float = 2e-4
    scale_supply_coeff_per_v: float = 1e-3
    arw_deg_per_sqrt_h: float = 0.6
    verdict: str = "AUTO"  # AUTO: from the limits
    started: datetime = field(default_factory=lambda: datetime(2026, 11, 21, 9, 30, tzinfo=UTC))
    product: str = "ADIS16130-EOL"
    overdue: bool = False
    simulated: bool = True
    seed: int = 1


def _output(part: Part, w: np.ndarray, d_t: float, d_v: float, rng: np.random.Generator,
            ) -> np.ndarray:
    sigma = part.arw_deg_per_sqrt_h / 60.0 * math.sqrt(RATE_HZ)
    k = part.scale * (1 + part.scale_temp_coeff_per_c * d_t + part.scale_supply_coeff_per_v * d_v)
    b = (part.bias_dps + part.bias_temp_coeff_dps_per_c * d_t
         + part.bias_supply_coeff_dps_per_v * d_v)
    return k * w + b + rng.normal(0.0, sigma, w.size)


def _smooth_move(n: int, angle_deg: float, dur_s: float) -> np.ndarray:
    u = np.linspace(0, 1, n)
    return angle_deg / dur_s * 2 * np.sin(np.pi * u) ** 2  # integral over dur = angle


def _write_raw(path: Path, part: Part, run_id: str) -> dict[str, Any]:
    rng = np.random.default_rng(part.seed)
    analysis: dict[str, Any] = {"stop_method": {}, "rate_table": {}, "stability": {}}
    t_now = 0.0
    with RawDataWriter(path, {"serial": part.serial, "run_id": run_id}) as w:
        for cond, temp_c, supply_v in CONDITIONS:
            d_t, d_v = temp_c - 25.0, supply_v - 5.0

            def emit(t: np.ndarray, rate: np.ndarray, temp: np.ndarray, d_t: float = d_t,
                     d_v: float = d_v) -> None:
                y = _output(part, rate, d_t, d_v, rng)
                n = t.size
                w.append("samples", time_s=t, seq=np.arange(n), rate_code=np.zeros(n, int),
                         temp_code=np.zeros(n, int), status=np.zeros(n, np.uint8), rate_dps=y,
                         temp_c=temp, station_time_s=t)

            def seg(kind: str, idx: int, a: float, b: float, ref: float = 0.0,
                    ang: float = 0.0, temp_c: float = temp_c, supply_v: float = supply_v,
                    cond: str = cond) -> None:
                w.append("segments", condition=cond, kind=kind, index=idx, start_s=a, end_s=b,
                         ref_rate_dps=ref, ref_angle_deg=ang, temp_setpoint_c=temp_c,
                         supply_v=supply_v)

            # stabilise: 2 Hz, die temperature approaching the setpoint (tau 60 s) + self-heat
            start_temp = 25.0 if cond.startswith("T25") else 26.0
            ts = t_now + np.arange(0, 400, 0.5)
            temp = temp_c + 1.2 + (start_temp - temp_c - 1.2) * np.exp(-(ts - t_now) / 60.0)
            temp += rng.normal(0, 0.01, ts.size)
            emit(ts, np.zeros(ts.size), temp)
            stable_at = float(60.0 * math.log(max(abs(start_temp - temp_c - 1.2), 0.2) / 0.1))
            stable_at = min(stable_at, 390.0)
            seg("stabilise", 0, t_now, t_now + 400)
            analysis["stability"][cond] = {"band_c": 0.2, "max_rate_c_per_min": 0.05,
                                           "window_s": 60.0,
                                           "time_to_stability_s": stable_at, "stable": True}
            t_now += 400.0
            die = temp_c + 1.2
            # plateaus
            rin, rout = [], []
            for i, r in enumerate(PLATEAUS_DPS):
                tp = t_now + np.arange(0, 3.0, 1 / RATE_HZ)
                y_true = np.full(tp.size, r)
                emit(tp, y_true, np.full(tp.size, die))
                seg("plateau", i, tp[0] + 0.5, tp[-1], ref=r)
                t_now += 3.5
            # stop method: static 5 s, move 90 deg in 4 s, static 5 s, move back, static 5 s
            n_st, n_mv = int(5 * RATE_HZ), int(4 * RATE_HZ)
            pieces = [np.zeros(n_st), _smooth_move(n_mv, 90.0, 4.0), np.zeros(n_st),
                      _smooth_move(n_mv, -90.0, 4.0), np.zeros(n_st)]
            wtrue = np.concatenate(pieces)
            tt = t_now + np.arange(wtrue.size) / RATE_HZ
            y = _output(part, wtrue, d_t, d_v, rng)
            n = tt.size
            w.append("samples", time_s=tt, seq=np.arange(n), rate_code=np.zeros(n, int),
                     temp_code=np.zeros(n, int), status=np.zeros(n, np.uint8), rate_dps=y,
                     temp_c=np.full(n, die), station_time_s=tt)
            b0 = t_now
            static = [(b0, b0 + 3.0), (b0 + 9.5, b0 + 12.5), (b0 + 19.0, b0 + 22.0)]
            moves = [(b0 + 4.0, b0 + 9.5), (b0 + 13.0, b0 + 18.5)]
            for i, (a, b) in enumerate(static):
                seg("stop_static", i, a, b)
            for i, (a, b) in enumerate(moves):
                seg("stop_move", i, a, b, ang=90.0 if i == 0 else -90.0)
            bias = float(np.mean(y[: int(3 * RATE_HZ)]))
            mv = []
            for a, b in moves:
                sel = (tt >= a) & (tt <= b)
                ang = float(np.sum(y[sel] - bias) / RATE_HZ)
                mv.append({"start_s": a, "end_s": b, "measured_angle_deg": ang,
                           "scale_correction": abs(90.0 / ang)})
            analysis["stop_method"][cond] = {
                "bias_dps": bias, "bias_correction_dps": -bias,
                "scale_correction": float(np.mean([m["scale_correction"] for m in mv])),
                "static_windows": [list(s) for s in static], "moves": mv}
            t_now = float(tt[-1]) + 1.0
            k = part.scale * (1 + part.scale_temp_coeff_per_c * d_t
                              + part.scale_supply_coeff_per_v * d_v)
            bb = part.bias_dps + part.bias_temp_coeff_dps_per_c * d_t \
                + part.bias_supply_coeff_dps_per_v * d_v
            rin = PLATEAUS_DPS
            rout = [k * r + bb + float(rng.normal(0, 0.003)) for r in rin]
            slope, icpt = np.polyfit(rin, rout, 1)
            analysis["rate_table"][cond] = {
                "rate_in_dps": rin, "rate_out_dps": rout,
                "residual_dps": [o - (slope * i + icpt) for i, o in zip(rin, rout, strict=True)],
                "scale": float(slope), "bias_dps": float(icpt)}
        w.append("events", station_time_s=[0.0], text=["run started"])
    tau = np.logspace(-2, 2.5, 30)
    n = part.arw_deg_per_sqrt_h / 60.0
    analysis["allan"] = {
        "condition": "T25_V5.25", "tau_s": tau.tolist(),
        "adev_dps": (np.sqrt((n / np.sqrt(tau)) ** 2 + (0.664 * 12.0 / 3600) ** 2)).tolist(),
        "arw_deg_per_sqrt_h": part.arw_deg_per_sqrt_h, "bias_instability_deg_per_h": 12.0,
        "rate_random_walk_deg_per_h_per_sqrt_h": 30.0}
    return analysis


def _outcome(value: float, low: float, high: float, mlow: float, mhigh: float) -> Outcome:
    if value < low or value > high:
        return Outcome.FAIL
    if value < mlow or value > mhigh:
        return Outcome.MARGINAL
    return Outcome.PASS


def run_id_of(part: Part) -> str:
    return f"{part.started:%Y%m%dT%H%M%SZ}_{part.serial}"


def make_run(root: Path, part: Part | None = None) -> tuple[Path, RunRecord]:
    """Write a run folder (raw.h5 and record.json) under root; returns (folder, record)."""
    part = part or Part()
    folder = root / run_id_of(part)
    folder.mkdir(parents=True, exist_ok=True)
    raw_path = folder / RAW_DATA_FILE
    analysis = _write_raw(raw_path, part, run_id_of(part))
    record = make_record(part, analysis, FileRef(path=RAW_DATA_FILE, name=RAW_DATA_FILE,
                                                  sha256=file_sha256(raw_path)))
    write_record(folder, record)
    return folder, record


def make_record(part: Part, analysis: dict[str, Any] | None = None,
                raw_ref: FileRef | None = None) -> RunRecord:
    """The record of a part's run (no files written); fast, for database tests."""
    run_id = run_id_of(part)
    analysis = analysis if analysis is not None else {}
    values = {
        "bias_dps": part.bias_dps, "scale": part.scale,
        "bias_temp_coeff_dps_per_c": part.bias_temp_coeff_dps_per_c,
        "scale_temp_coeff_per_c": part.scale_temp_coeff_per_c,
        "arw_deg_per_sqrt_h": part.arw_deg_per_sqrt_h,
        "verify_max_error_pct": 0.12 + abs(part.scale - 1.0) * 0.5,
    }
    measurements = []
    for name, (units, lo, hi, mlo, mhi) in LIMITS.items():
        v = values[name]
        measurements.append(Measurement(name=name, value=v, units=units, low=lo, high=hi,
                                        marginal_low=mlo, marginal_high=mhi,
                                        outcome=_outcome(v, lo, hi, mlo, mhi),
                                        uncertainty_k2=abs(v) * 0.01 + 1e-6,
                                        description=f"{name} of the part"))
    failed = [m.name for m in measurements if m.outcome == Outcome.FAIL]
    verdict = Verdict(part.verdict) if part.verdict != "AUTO" else (
        Verdict.FAIL if failed else Verdict.PASS)

    def coeff(v: float, u: float) -> Coefficient:
        return Coefficient(value=v, uncertainty_k2=u)

    cal = Calibration(
        bias_dps=coeff(part.bias_dps, 0.02), scale=coeff(part.scale, 3e-4),
        bias_temp_coeff_dps_per_c=coeff(part.bias_temp_coeff_dps_per_c, 5e-4),
        bias_supply_coeff_dps_per_v=coeff(part.bias_supply_coeff_dps_per_v, 0.01),
        scale_temp_coeff_per_c=coeff(part.scale_temp_coeff_per_c, 2e-5),
        scale_supply_coeff_per_v=coeff(part.scale_supply_coeff_per_v, 2e-4),
        readback_ok=True,
        # as procedures/steps/program.py writes it: the part's register names
        readback={"bias_dps": part.bias_dps, "scale": part.scale,
                  "bias_tc_dps_per_c": part.bias_temp_coeff_dps_per_c,
                  "scale_tc_per_c": part.scale_temp_coeff_per_c,
                  "bias_vc_dps_per_v": part.bias_supply_coeff_dps_per_v,
                  "scale_vc_per_v": part.scale_supply_coeff_per_v,
                  "t0_c": 25.0, "v0_v": 5.0},
        interaction_check={"bias_interaction_dps": 0.004})
    due_ok = (part.started + timedelta(days=200)).date().isoformat()
    due_late = (part.started - timedelta(days=3)).date().isoformat()
    record = RunRecord(
        run_id=run_id, verdict=verdict, failed_measurements=failed,
        reason="" if verdict in (Verdict.PASS, Verdict.FAIL) else "operator pressed stop",
        simulated=part.simulated, started_utc=part.started.isoformat(),
        finished_utc=(part.started + timedelta(minutes=31)).isoformat(),
        station_local_tz="Europe/Berlin", station={"id": "EOL-03", "name": "Gyro EOL 3"},
        operator="A. Tester", software_version="0.1.0+test",
        dut=Dut(serial=part.serial, product=part.product, part_serial_register=part.serial),
        product=FileRef(path="config/products/adis16130.yaml", name="adis16130.yaml",
                        version="1.2", sha256="a" * 64),
        procedure=FileRef(path="config/procedures/eol.yaml", name="eol.yaml", version="3",
                          sha256="b" * 64),
        instruments=[
            InstrumentRecord(role="rate_table", manufacturer="SimCo", model="RT-300",
                             serial="RT1234", calibration_due=due_ok),
            InstrumentRecord(role="chamber", manufacturer="Watlow", model="F4", serial="CH77",
                             calibration_due=due_late if part.overdue else due_ok),
            InstrumentRecord(role="supply", manufacturer="SimCo", model="PS-5", serial="PS9",
                             calibration_due=due_ok),
        ],
        raw_data=raw_ref,
        conditions=[ConditionRecord(name=c, temperature_c=t, supply_v=v,
                                    die_temperature_c=t + 1.2,
                                    time_to_stability_s=analysis.get("stability", {}).get(
                                        c, {}).get("time_to_stability_s"), stable=True,
                                    supply_current_a=0.006, supply_measured_v=v - 0.0004)
                    for c, t, v in CONDITIONS],
        measurements=measurements, calibration=cal,
        verification={"residuals": [{"condition": "T25_V5.25", "rate_in_dps": r,
                                     "error_dps": 0.001 * r, "error_pct": 0.1}
                                    for r in (-150.0, 50.0, 150.0)], "max_error_pct": 0.1},
        analysis=analysis,
    )
    return record
