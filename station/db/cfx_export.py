"""The MES export: each run as an IPC-CFX `CFX.Production.TestAndInspection.UnitsTested`
message (IPC-2591), one JSON envelope per line. Why CFX and not ATML: docs/line-database.md.

A run is one tested unit (UnitIdentifier = serial); each measurement (per condition) is one
test with one NumericMeasurement carrying its limits. Limits are the product file's, as
recorded with the run; outcome MARGINAL is Passed (inside the limits), NOT_MEASURED Skipped.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Iterator
from typing import Any

import sqlalchemy as sa

from station.db.schema import measurements, runs

MESSAGE_NAME = "CFX.Production.TestAndInspection.UnitsTested"
CFX_VERSION = "2.0"
_RUN_RESULT = {"PASS": "Passed", "FAIL": "Failed", "ERROR": "Error", "ABORTED": "Aborted"}
_TEST_RESULT = {"PASS": "Passed", "MARGINAL": "Passed", "FAIL": "Failed",
                "NOT_MEASURED": "Skipped"}
# stable ids: the same run exported twice gives the same message ids (an MES can dedupe)
_NAMESPACE = uuid.UUID("6f1e4e0a-57c1-4c55-9d0c-3c6a2f0b1d11")


def _uid(*parts: object) -> str:
    return str(uuid.uuid5(_NAMESPACE, "/".join(str(p) for p in parts)))


def units_tested(run: dict[str, Any], meas: list[dict[str, Any]], source: str) -> dict[str, Any]:
    """The CFX envelope of one run (run: a runs-table row; meas: its measurements rows)."""
    tests = []
    for m in meas:
        name = m["name"] if not m["condition"] else f"{m['name']} @ {m['condition']}"
        result = _TEST_RESULT.get(m["outcome"], "Error")
        measured: dict[str, Any] = {
            "$type": "CFX.Structures.NumericMeasurement, CFX",
            "UniqueIdentifier": _uid(run["run_id"], "m", m["seq"]),
            "MeasurementName": m["name"],
            "TimeRecorded": run["finished_utc"],
            "Sequence": m["seq"],
            "Result": result,
            "MeasuredValue": {
                "Value": m["value"],
                "ValueUnits": m["units"],
                "MinimumAcceptableValue": m["low"],
                "MaximumAcceptableValue": m["high"],
            },
        }
        tests.append({
            "UniqueIdentifier": _uid(run["run_id"], "t", m["seq"]),
            "TestName": name,
            "TestStartTime": run["started_utc"],
            "TestEndTime": run["finished_utc"],
            "TestConditions": [],
            "TestProcedure": run["procedure_name"],
            "Result": result,
            "Measurements": [measured],
        })
    body = {
        "TransactionId": _uid(run["run_id"], "transaction"),
        "TestMethod": "Automated",
        "Tester": {"OperatorIdentifier": run["operator"], "ActorType": "Human",
                   "LoginName": run["operator"]} if run["operator"] else None,
        "RecipeName": run["procedure_name"],
        "RecipeRevision": run["procedure_sha256"][:12],
        "SamplingInformation": {"SamplingMethod": "NoSampling", "LotSize": None,
                                "SampleSize": None},
        "TestedUnits": [{
            "UnitIdentifier": run["serial"],
            "UnitPositionNumber": 1,
            "OverallResult": _RUN_RESULT.get(run["verdict"], "Error"),
            "Tests": tests,
        }],
    }
    return {
        "MessageName": MESSAGE_NAME,
        "Version": CFX_VERSION,
        "TimeStamp": run["finished_utc"] or run["started_utc"],
        "UniqueID": _uid(run["run_id"], "message"),
        "Source": source or run["station_id"],
        "Target": None,
        "RequestID": None,
        "MessageBody": body,
        # not part of CFX: how to find the run again (an MES ignores unknown members)
        "GyrocalRun": {"RunId": run["run_id"], "Product": run["product"], "Lot": run["lot"],
                       "WorkOrder": run["work_order"], "Attempt": run["attempt"],
                       "FirstRunId": run["first_run_id"], "StationId": run["station_id"]},
    }


def export_lines(con: sa.Connection, where: list[sa.ColumnElement[bool]], source: str = "",
                 batch: int = 500) -> Iterator[str]:
    """One JSON line per finished run matching the filters, oldest first."""
    query = (sa.select(runs).where(runs.c.verdict != "RUNNING", *where)
             .order_by(runs.c.started_utc, runs.c.run_id))
    found = [dict(r) for r in con.execute(query).mappings()]
    for i in range(0, len(found), batch):
        chunk = found[i : i + batch]
        by_run: dict[str, list[dict[str, Any]]] = {r["run_id"]: [] for r in chunk}
        rows = con.execute(
            sa.select(measurements).where(measurements.c.run_id.in_(list(by_run)))
            .order_by(measurements.c.run_id, measurements.c.seq)
        ).mappings()
        for m in rows:
            by_run[m["run_id"]].append(dict(m))
        for r in chunk:
            yield json.dumps(units_tested(r, by_run[r["run_id"]], source), sort_keys=False)
