"""Writing runs: one run's row and measurements replaced in one transaction, retests linked.

The same code writes a station's local database (from a record) and the central database
(rows copied by the sync), so a run looks the same in both.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import sqlalchemy as sa

from procedures.runtime.record import RunRecord, three_axis_block
from station.db import rollups
from station.db.bulk import insert_new
from station.db.links import lock_units, relink_units, with_links
from station.db.schema import CAL_KEYS, calibration_elements, measurements, outbox, runs


def utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def normalise_utc(text: str | None) -> str | None:
    """ISO-8601 text as `YYYY-MM-DDTHH:MM:SS+00:00` (naive times are taken as UTC)."""
    if text is None:
        return None
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return text
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    return t.astimezone(UTC).isoformat(timespec="seconds")


def run_row(folder: Path, rec: RunRecord) -> dict[str, Any]:
    """The runs-table row of a record (attempt and first test are set by relink_units)."""
    cal = rec.calibration
    row: dict[str, Any] = {
        "run_id": rec.run_id,
        "serial": rec.dut.serial,
        "product": rec.dut.product or rec.product.name or rec.product.path,
        "verdict": rec.verdict.value,
        "reason": rec.reason,
        "failed_measurements": json.dumps(list(rec.failed_measurements)),
        "simulated": int(rec.simulated),
        "started_utc": normalise_utc(rec.started_utc),
        "finished_utc": normalise_utc(rec.finished_utc),
        "station_id": str(rec.station.get("id", "")),
        "operator": rec.operator,
        "software_version": rec.software_version,
        "procedure_name": rec.procedure.name or rec.procedure.path,
        "procedure_sha256": rec.procedure.sha256,
        "product_sha256": rec.product.sha256,
        "raw_sha256": rec.raw_data.sha256 if rec.raw_data else "",
        "folder": str(folder.resolve()),
        "work_order": getattr(rec, "work_order", "") or "",
        "lot": getattr(rec, "lot", "") or "",
        "axes": 3 if three_axis_block(rec) is not None else 1,
        "socket": rec.dut.socket,
    }
    for k in CAL_KEYS:
        c = getattr(cal, k) if cal is not None else None
        row[f"cal_{k}"] = c.value if c is not None else None
        row[f"cal_{k}_u"] = c.uncertainty_k2 if c is not None else None
    return row


_AXES = "xyz"
ELEMENT_QUANTITIES = (
    "bias_dps", "matrix", "g_sensitivity_dps_per_mps2", "bias_temp_coeff_dps_per_c",
    "bias_supply_coeff_dps_per_v", "scale_temp_coeff_per_c", "scale_supply_coeff_per_v",
)


def element_rows(rec: RunRecord) -> list[dict[str, Any]]:
    """The calibration_elements rows of a three-axis record (none for a single-axis one)."""
    cal = three_axis_block(rec)
    if cal is None:
        return []
    out: list[dict[str, Any]] = []
    for quantity in ELEMENT_QUANTITIES:
        arr = getattr(cal, quantity)
        for i, axis in enumerate(_AXES):
            value, u = arr.value[i], arr.uncertainty_k2[i]
            cells = (list(zip(value, u, strict=True)) if isinstance(value, list)
                     else [(value, u)])
            for j, (v, uk2) in enumerate(cells):
                out.append({"run_id": rec.run_id, "seq": len(out), "quantity": quantity,
                            "axis": axis, "column_axis": _AXES[j] if len(cells) == 3 else None,
                            "value": v, "uncertainty_k2": uk2})
    return out


def measurement_rows(rec: RunRecord) -> list[dict[str, Any]]:
    return [
        {
            "run_id": rec.run_id, "seq": i, "name": m.name, "condition": m.condition,
            "value": m.value, "units": m.units, "low": m.low, "high": m.high,
            "marginal_low": m.marginal_low, "marginal_high": m.marginal_high,
            "outcome": m.outcome.value, "uncertainty_k2": m.uncertainty_k2,
        }
        for i, m in enumerate(rec.measurements)
    ]


def replace_runs(
    con: sa.Connection,
    rows: Sequence[dict[str, Any]],
    meas: Sequence[dict[str, Any]],
    *,
    queue: bool,
    elements: Sequence[dict[str, Any]] = (),
) -> None:
    """Upsert runs by run_id and link their units' tests: a run already there is deleted
    with its measurements and elements, and every row inserted with ON CONFLICT DO NOTHING,
    so a copy another writer inserted meanwhile (two syncs of one station) is kept, not
    doubled. The runs go in with their links set; then the units' other runs are relinked.

    queue: also put each run in the outbox for the central database (a station's local copy).
    """
    if not rows:
        return
    ids = [r["run_id"] for r in rows]
    units = sorted({(r["product"], r["serial"]) for r in rows})
    lock_units(con, units)  # first: a second writer of these units waits for this one
    present, old_serials = _present(con, ids)
    serials = {r["serial"] for r in rows} | old_serials
    rollups.subtract(con, serials)  # the units as they were; counted again once written
    _delete_runs(con, present)
    insert_new(con, runs, with_links(con, rows))
    insert_new(con, measurements, meas)
    insert_new(con, calibration_elements, elements)
    relink_units(con, units)
    rollups.add(con, serials)
    if queue:
        _queue(con, ids)


def _present(con: sa.Connection, ids: list[str]) -> tuple[list[str], set[str]]:
    """The runs already there, and their serials (as they were written)."""
    found: list[str] = []
    serials: set[str] = set()
    for chunk in _chunks(ids, 500):
        for run_id, serial in con.execute(
                sa.select(runs.c.run_id, runs.c.serial).where(runs.c.run_id.in_(chunk))):
            found.append(run_id)
            serials.add(serial)
    return found, serials


def _delete_runs(con: sa.Connection, ids: list[str]) -> None:
    for chunk in _chunks(ids, 500):
        con.execute(measurements.delete().where(measurements.c.run_id.in_(chunk)))
        con.execute(calibration_elements.delete().where(
            calibration_elements.c.run_id.in_(chunk)))
        con.execute(runs.delete().where(runs.c.run_id.in_(chunk)))


def _queue(con: sa.Connection, ids: list[str]) -> None:
    now = utc_now()
    known = set()
    for chunk in _chunks(ids, 500):
        known |= set(con.scalars(sa.select(outbox.c.run_id).where(outbox.c.run_id.in_(chunk))))
    if known:
        con.execute(
            outbox.update()
            .where(outbox.c.run_id == sa.bindparam("rid"))
            .values(version=outbox.c.version + 1, queued_utc=now),
            [{"rid": i} for i in known],
        )
    new = [{"run_id": i, "version": 1, "sent_version": 0, "queued_utc": now}
           for i in ids if i not in known]
    if new:
        con.execute(outbox.insert(), new)


def _chunks(items: list[str], size: int) -> Iterable[list[str]]:
    for i in range(0, len(items), size):
        yield items[i : i + size]
