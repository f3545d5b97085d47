"""Runs of a line of stations as records (no bench): several stations, lots, retests."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from procedures.runtime.record import RunRecord, Verdict
from tests.reports.synth_run import Part, make_record

REPO = Path(__file__).resolve().parents[2]
START = datetime(2026, 11, 2, 5, 0, tzinfo=UTC)


@dataclass(frozen=True)
class LineRun:
    folder: Path
    record: RunRecord


def line_record(serial: str, station: str, started: datetime, *, lot: str = "",
                work_order: str = "", product: str = "ADIS16130-EOL", bias_dps: float = 0.0,
                scale: float = 1.0, verdict: str = "AUTO", seed: int = 1,
                simulated: bool = False) -> RunRecord:
    """A production run (simulated=False) unless told it came from a bench simulator."""
    part = Part(serial=serial, bias_dps=bias_dps, scale=scale, started=started,
                product=product, verdict=verdict, seed=seed, simulated=simulated)
    rec = make_record(part)
    return rec.model_copy(update={
        "run_id": f"{started:%Y%m%dT%H%M%S}Z_{station}_{serial}",
        "station": {"id": station, "name": station},
        "lot": lot, "work_order": work_order,
    })


def line_runs(n_units: int, stations: list[str], seed: int = 5, root: Path = Path("/nowhere"),
              retest_share: float = 0.15) -> list[LineRun]:
    """n_units parts across stations, lots of 50, some failing first and retested later."""
    rng = np.random.default_rng(seed)
    out: list[LineRun] = []
    t = START
    retests: list[tuple[str, str, str]] = []
    for i in range(n_units):
        serial = f"U{i:05d}"
        station = stations[i % len(stations)]
        lot = f"LOT-{i // 50:03d}"
        bias = float(rng.normal(0.0, 5.5))
        t += timedelta(minutes=float(rng.uniform(4, 9)))
        rec = line_record(serial, station, t, lot=lot, work_order=f"WO-{i // 100}",
                          bias_dps=bias, scale=float(1 + rng.normal(0, 0.015)), seed=i)
        out.append(LineRun(root / rec.run_id, rec))
        if rec.verdict != Verdict.PASS or rng.uniform() < retest_share / 3:
            retests.append((serial, lot, stations[(i + 1) % len(stations)]))
        if retests and rng.uniform() < 0.3:
            s, lt, st = retests.pop(0)
            t += timedelta(minutes=2)
            rec2 = line_record(s, st, t, lot=lt, bias_dps=float(rng.normal(0.0, 3.0)), seed=i + 7)
            out.append(LineRun(root / rec2.run_id, rec2))
    return out


def station_yaml(folder: Path, station_id: str, central: str | None, results_db: str,
                 sync_interval_s: float = 0.5) -> Path:
    """A station file as config/station.yaml, with this id, results and central database."""
    folder.mkdir(parents=True, exist_ok=True)
    for sub in ("procedures", "products"):
        shutil.copytree(REPO / "config" / sub, folder / sub, dirs_exist_ok=True)
    data = yaml.safe_load((REPO / "config" / "station.yaml").read_text(encoding="utf-8"))
    data["station"]["id"] = station_id
    data.update(output_folder="runs", results_db=results_db, sync_interval_s=sync_interval_s)
    if central:
        data["central_db"] = central
    path = folder / "station.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def direct_yields(records: list, key: object) -> dict[str, tuple[int, int, int, int]]:
    """group -> (units, tests, first passes, final passes), straight from the records."""
    tests: dict[tuple[str, str], list] = {}
    for r in sorted(records, key=lambda r: (r.started_utc, r.run_id)):
        tests.setdefault((r.dut.product, r.dut.serial), []).append(r)
    out: dict[str, list[int]] = {}
    for unit_tests in tests.values():
        g = key(unit_tests[0])  # type: ignore[operator]
        row = out.setdefault(g, [0, 0, 0, 0])
        row[0] += 1
        row[1] += len(unit_tests)
        row[2] += unit_tests[0].verdict.value == "PASS"
        row[3] += unit_tests[-1].verdict.value == "PASS"
    return {g: (a, b, c, d) for g, (a, b, c, d) in out.items()}


# --------------------------------------------------------------------- signed-in dashboard

LINE_BASE = "http://127.0.0.1"  # a name the dashboard answers to (Host is checked)
LINE_PASSWORDS = {"viewer": "viewer-pass", "quality": "quality-pass", "engineer": "engineer-pass"}
LINE_NAMES = {"viewer": "Vera Viewer", "quality": "Quinn Quality", "engineer": "Emil Engineer"}


def line_users() -> Any:
    """One user per role; cheap scrypt costs (the format is the operator screen's)."""
    from station.line.users import LineUser, LineUsers
    from station.ui.auth import hash_password

    return LineUsers(tuple(LineUser(LINE_NAMES[role], role, hash_password(pw, n=2**8))
                           for role, pw in LINE_PASSWORDS.items()))


_USERS: list[Any] = []


def line_app(engine: Any, options: Any = None) -> Any:
    """The dashboard app with the test users (and the default, loopback-only host names)."""
    from station.line.access import LineAccess
    from station.line.app import create_line_app

    if not _USERS:
        _USERS.append(line_users())
    return create_line_app(engine, options, LineAccess(users=_USERS[0]))


def line_client(app: Any, role: str | None = "engineer") -> Any:
    """A TestClient of its own holding the page's session and CSRF token, signed in as `role`
    (None: a session nobody signed in on)."""
    from fastapi.testclient import TestClient

    return sign_in(TestClient(app, base_url=LINE_BASE), role)


def sign_in(client: Any, role: str | None = "engineer") -> Any:
    """`client` (an httpx.Client or TestClient of the dashboard) with the page's session and
    CSRF token, signed in as `role` (None: nobody signed in)."""
    r = client.get("/api/session")
    assert r.status_code == 200, r.text
    client.headers["X-CSRF-Token"] = r.json()["csrf"]
    if role is not None:
        r = client.post("/api/signin",
                        json={"name": LINE_NAMES[role], "password": LINE_PASSWORDS[role]})
        assert r.status_code == 200 and r.json()["role"] == role, r.text
        client.headers["X-CSRF-Token"] = r.json()["csrf"]
    return client


def sign_in_page(page: Any, url: str, role: str = "engineer") -> None:
    """Open the dashboard in chromium and sign in through its form as `role`."""
    from station.ui.headless import wait_js

    page.goto(url)
    wait_js(page, "!document.getElementById('signin').hidden")
    page.fill("#signin input[name=name]", LINE_NAMES[role])
    page.fill("#signin input[name=password]", LINE_PASSWORDS[role])
    page.click("#signin button[type=submit]")
    wait_js(page, "document.body.dataset.loaded === '1'")


def as_three_axis(record: RunRecord, shift: float, quantities: tuple[str, ...]) -> RunRecord:
    """The record as a three-axis part's: each quantity of `quantities` a 3-vector (a 3x3
    matrix for the matrix and the g-sensitivity) of values offset by `shift`, k = 2 of 1e-4."""
    block: dict[str, object] = {"axes": 3, "temp_supply_fitted": True, "readback_ok": True}
    for k, q in enumerate(quantities):
        shape = (3, 3) if q in ("matrix", "g_sensitivity_dps_per_mps2") else (3,)
        value = np.arange(np.prod(shape)).reshape(shape) * 0.001 + k + shift
        block[q] = {"value": value.tolist(), "uncertainty_k2": (0 * value + 1e-4).tolist()}
    data = record.model_dump(mode="json")
    data["calibration_three_axis"] = block
    data["calibration"] = None
    return RunRecord.model_validate(data)
