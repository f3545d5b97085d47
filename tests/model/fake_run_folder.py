"""Write a generator run as an engine-style run folder (record.json + raw.h5).

Mimics what the engine logs: samples on the fixture clock with a station-time estimate,
table snapshots only at window edges, supply readings at condition changes, one row per
analysed window in /segments. Transitions carry no table data, as in a real run. With
`latched_counts_per_rev`, every sample also carries the table's encoder count latched at
the sample (the fixture's hardware sync), taken from the generator's reference angle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from procedures.runtime.rawdata import RawDataWriter
from procedures.runtime.record import Dut, FileRef, RunRecord, Verdict, write_record

STATION_OFFSET_S = 1000.0  # station clock = fixture clock + offset


def write_run_folder(
    folder: Path,
    run: dict[str, object],
    serial: str = "SYN-0001",
    latched_counts_per_rev: int | None = None,
    encoder_index_offset_deg: float = 0.0,
) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    t = np.asarray(run["time_s"])
    n = t.size
    rate = np.asarray(run["ref_rate_dps"])
    angle = np.asarray(run["ref_angle_deg"])
    supply = np.asarray(run["supply_v"])
    attrs: dict[str, object] = {"serial": serial, "run_id": "r1"}
    status = np.zeros(n, dtype=np.uint8)
    counts = np.zeros(n, dtype=np.int64)
    if latched_counts_per_rev:
        attrs["encoder_counts_per_rev"] = latched_counts_per_rev
        status |= 1 << 5  # ENCODER_LATCHED
        turns = (np.unwrap(angle, period=360.0) + encoder_index_offset_deg) / 360.0
        counts = np.floor(turns * latched_counts_per_rev).astype(np.int64) % (1 << 32)
    with RawDataWriter(folder / "raw.h5", attrs) as w:
        w.append("supply", station_time_s=[STATION_OFFSET_S - 2.0], voltage_v=[supply[0]],
                 current_a=[0.02])
        w.append("samples", time_s=t, seq=np.arange(n), rate_code=np.zeros(n, dtype=np.int32),
                 temp_code=np.zeros(n, dtype=np.int32), status=status,
                 rate_dps=np.asarray(run["gyro_dps"]), temp_c=np.asarray(run["temp_c"]),
                 station_time_s=t + STATION_OFFSET_S, encoder_counts=counts)
        # the engine logs the supply just before and just after each change of setting
        for j in np.flatnonzero(np.abs(np.diff(supply)) > 0.1) + 1:
            w.append("supply", station_time_s=t[[j - 1, j]] + STATION_OFFSET_S,
                     voltage_v=supply[[j - 1, j]], current_a=[0.02, 0.02])
        cond = 0
        for i, (kind, a, b) in enumerate(run["segments"]):  # type: ignore[union-attr]
            ia, ib = np.searchsorted(t, [a, b])
            ib = min(ib, n) - 1
            if ib <= ia:
                continue
            if kind == "stabilise":
                cond += 1
            if kind in ("transition",):
                continue
            for j in (ia, ib):  # two encoder snapshots per window
                w.append("table", station_time_s=[t[j] + STATION_OFFSET_S],
                         controller_time_s=[t[j]], encoder_counts=[0],
                         position_deg=[angle[j]], rate_dps=[rate[j]], status=[0])
            w.append("segments", condition=f"C{cond}", kind=kind, index=i, start_s=t[ia],
                     end_s=t[ib], ref_rate_dps=float(np.median(rate[ia:ib])),
                     ref_angle_deg=float(angle[ia]), temp_setpoint_c=np.nan,
                     supply_v=float(np.round(np.median(supply[ia:ib]), 3)))
    ref = FileRef(path="x", sha256="0" * 64)
    record = RunRecord(run_id="r1", verdict=Verdict.PASS, started_utc="2026-01-01T00:00:00Z",
                       dut=Dut(serial=serial), product=ref, procedure=ref)
    write_record(folder, record)
    return folder
