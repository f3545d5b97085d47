"""Numbers a quality engineer can stand behind (issue 30, deliverable 4), over the API:
simulated runs are left out of every panel unless asked for (`?simulated=include`), and
the yields left equal a count written out here over the inserted production runs; no Cpk
below MIN_CPK_N values, with the reason; the chart carries the product's limits."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import timedelta
from typing import Any

import pytest
from fastapi.testclient import TestClient

from procedures.runtime.record import RunRecord
from reports.lot_stats import MIN_CPK_N
from station.db.connect import dispose_all
from station.line.spc import capability
from station.results_db import ResultsDB
from tests.linedb.linekit import START, line_app, line_client, line_record, line_runs
from tests.reports.synth_run import LIMITS

REAL_STATIONS = ["EOL-A", "EOL-B"]
BENCH = "SIM-BENCH"  # a station only ever run against the simulator
N_BENCH = 7


def simulated_runs() -> list[RunRecord]:
    """Simulated runs that would drag the yields down: most fail (bias beyond +/-10 deg/s),
    on the real stations and on a bench station of their own."""
    out = []
    for i in range(30):
        station = BENCH if i < N_BENCH else REAL_STATIONS[i % 2]
        t = START + timedelta(days=3, minutes=7 * i)
        out.append(line_record(f"S{i:04d}", station, t, lot="LOT-000", work_order="WO-0",
                               bias_dps=25.0 if i % 3 else 0.5, seed=100 + i, simulated=True))
    return out


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, list[Any]]]:
    folder = tmp_path_factory.mktemp("quality")
    real = [r.record for r in line_runs(60, REAL_STATIONS, seed=8, root=folder / "runs")]
    records = real + simulated_runs()
    db = ResultsDB(folder / "line.sqlite")
    db.add_records([(folder / "runs" / r.run_id, r) for r in records])
    with line_client(line_app(db.engine)) as c:
        yield c, records
    dispose_all()


def count_yields(records: list[Any], station: str | None = None) -> tuple[int, int, int, int]:
    """(units, tests, first passes, final passes), straight from the inserted records: a
    unit's tests in start order, the first decides first pass, the latest final pass."""
    tests: dict[str, list[Any]] = {}
    for r in sorted(records, key=lambda r: r.started_utc):
        tests.setdefault(r.dut.serial, []).append(r)
    units = [t for t in tests.values() if station in (None, t[0].station["id"])]
    return (len(units), sum(len(t) for t in units),
            sum(t[0].verdict.value == "PASS" for t in units),
            sum(t[-1].verdict.value == "PASS" for t in units))


def _row(table: list[dict[str, Any]], group: str) -> tuple[int, int, int, int]:
    r = next(r for r in table if r["group"] == group)
    return r["units"], r["tests"], r["first_pass"], r["final_pass"]


def test_yields_leave_simulated_runs_out(line: tuple[TestClient, list[Any]]) -> None:
    client, records = line
    real = [r for r in records if not r.simulated]
    y = client.get("/api/yields").json()
    assert _row(y["all"], "all") == count_yields(real)
    for sid in REAL_STATIONS:
        assert _row(y["station"], sid) == count_yields(real, sid)
    assert BENCH not in [r["group"] for r in y["station"]]
    with_sim = client.get("/api/yields", params={"simulated": "include"}).json()
    assert _row(with_sim["all"], "all") == count_yields(records)
    assert _row(with_sim["station"], BENCH)[0] == N_BENCH
    assert with_sim["all"][0]["first_pass_yield"] < y["all"][0]["first_pass_yield"]


def test_capability_chart_runs_and_stations_leave_simulated_runs_out(
        line: tuple[TestClient, list[Any]]) -> None:
    client, records = line
    sim_ids = {r.run_id for r in records if r.simulated}
    runs = client.get("/api/runs").json()["runs"]
    assert runs and not {r["run_id"] for r in runs} & sim_ids
    runs_all = client.get("/api/runs", params={"simulated": "include"}).json()["runs"]
    assert {r["run_id"] for r in runs_all} & sim_ids
    chart = client.get("/api/chart").json()
    assert chart["points"] and not {p["run_id"] for p in chart["points"]} & sim_ids
    both = client.get("/api/chart", params={"simulated": "include"}).json()
    assert {p["run_id"] for p in both["points"]} & sim_ids
    cap = _cap(client.get("/api/capability").json(), "bias_dps")
    assert cap["n"] == count_yields([r for r in records if not r.simulated])[0]
    s = client.get("/api/stations").json()
    assert [x["station_id"] for x in s["stations"]] == REAL_STATIONS
    assert not {r["run_id"] for x in s["stations"] for r in x["recent"]} & sim_ids
    assert s["simulated_left_out"] == len(sim_ids)
    s_all = client.get("/api/stations", params={"simulated": "include"}).json()
    assert BENCH in [x["station_id"] for x in s_all["stations"]]
    assert s_all["simulated_left_out"] == 0


def test_simulated_parameter_is_checked(line: tuple[TestClient, list[Any]]) -> None:
    r = line[0].get("/api/yields", params={"simulated": "yes"})
    assert r.status_code == 422 and "include or exclude" in r.json()["error"]
    assert line[0].get("/api/yields", params={"simulated": "exclude"}).json() == \
        line[0].get("/api/yields").json()


def _cap(body: dict[str, Any], name: str) -> dict[str, Any]:
    return next(c for c in body["capability"] if c["name"] == name)


def test_no_cpk_below_the_minimum_with_the_reason(line: tuple[TestClient, list[Any]]) -> None:
    client, _ = line
    few = client.get("/api/capability",
                     params={"station": BENCH, "simulated": "include"}).json()
    cap = _cap(few, "bias_dps")
    assert cap["n"] == N_BENCH and cap["cpk"] is None and cap["ci_low"] is None
    assert cap["reason"] == f"too few (n = {N_BENCH}, need {MIN_CPK_N})"
    enough = _cap(client.get("/api/capability").json(), "bias_dps")
    assert enough["n"] >= MIN_CPK_N and enough["cpk"] is not None and enough["reason"] is None


def test_cpk_starts_at_exactly_the_minimum() -> None:
    assert capability(MIN_CPK_N - 1, 0.0, 1.0, -5.0, 5.0).reason == \
        f"too few (n = {MIN_CPK_N - 1}, need {MIN_CPK_N})"
    at = capability(MIN_CPK_N, 0.0, 1.0, -5.0, 5.0)
    assert at.cpk == pytest.approx(5 / 3) and at.reason is None
    assert capability(MIN_CPK_N, 0.0, 0.0, -5.0, 5.0).reason == "no spread (all values equal)"
    assert capability(MIN_CPK_N, 0.0, 1.0, None, None).reason == "no limits"


def test_chart_carries_the_product_limits(line: tuple[TestClient, list[Any]]) -> None:
    client, _ = line
    for coefficient in ("bias_dps", "scale"):
        chart = client.get("/api/chart", params={"coefficient": coefficient}).json()
        _, low, high, _, _ = LIMITS[coefficient]
        assert (chart["product_low"], chart["product_high"]) == (low, high)
    none = client.get("/api/chart", params={"coefficient": "bias_supply_coeff_dps_per_v"}).json()
    assert none["product_low"] is None and none["product_high"] is None
