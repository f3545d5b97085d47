"""Yields, Cpk with Bissell's interval, and the Western Electric rules, against direct
computations written out here."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from station.db.connect import dispose_all
from station.db.yields import shift_names, yields_by
from station.line import queries
from station.line.queries import Filters
from station.line.spc import bissell_interval, capability, cpk, western_electric
from station.results_db import ResultsDB
from tests.linedb.linekit import direct_yields, line_runs


@pytest.fixture(scope="module")
def line_db(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ResultsDB, list]]:
    folder = tmp_path_factory.mktemp("line")
    runs = line_runs(240, ["EOL-A", "EOL-B", "EOL-C"], seed=11, root=folder)
    db = ResultsDB(folder / "line.sqlite")
    db.add_records([(r.folder, r.record) for r in runs])
    yield db, [r.record for r in runs]
    dispose_all()


def _shift(r: object) -> str:
    hour = int(r.started_utc[11:13])  # type: ignore[attr-defined]
    names = shift_names([6, 14, 22])
    return names[0] if 6 <= hour < 14 else names[1] if 14 <= hour < 22 else names[2]


@pytest.mark.parametrize("group,key", [
    (None, lambda r: "all"),
    ("station", lambda r: r.station["id"]),
    ("lot", lambda r: r.lot),
    ("product", lambda r: r.dut.product),
    ("shift", _shift),
])
def test_yields_equal_a_direct_count(line_db: tuple, group: str | None, key: object) -> None:
    db, records = line_db
    with db.engine.connect() as con:
        got = {y.group: (y.units, y.tests, y.first_pass, y.final_pass)
               for y in yields_by(con, group)}
    assert got == direct_yields(records, key)
    if group is None:
        (units, tests, fp, final), = got.values()
        assert tests > units and fp < final <= units  # the data has retests that pass


def test_bissell_interval_is_the_published_formula() -> None:
    lo, hi = bissell_interval(1.33, 50, 0.95)
    half = 1.959964 * math.sqrt(1 / (9 * 50) + 1.33**2 / (2 * 49))
    assert lo == pytest.approx(1.33 - half, rel=1e-6) and hi == pytest.approx(1.33 + half)
    wider = bissell_interval(1.33, 10, 0.95)
    assert wider[0] < lo and wider[1] > hi
    with pytest.raises(ValueError, match="at least 2"):
        bissell_interval(1.0, 1)


def test_cpk_uses_the_nearer_limit() -> None:
    assert cpk(1.0, 0.5, -2.0, 2.0) == pytest.approx(1.0 / 1.5)
    assert cpk(0.0, 1.0, None, 6.0) == pytest.approx(2.0)
    assert cpk(0.0, 0.0, -1.0, 1.0) is None and cpk(0.0, 1.0, None, None) is None


def test_dashboard_cpk_equals_numpy_over_first_tests(line_db: tuple) -> None:
    db, records = line_db
    with db.engine.connect() as con:
        caps = queries.capabilities(con, Filters())
    firsts: dict[str, object] = {}
    for r in sorted(records, key=lambda r: (r.started_utc, r.run_id)):
        firsts.setdefault(r.dut.serial, r)
    checked = 0
    for c in caps:
        values = np.array([m.value for r in firsts.values() for m in r.measurements  # type: ignore[attr-defined]
                           if m.name == c["name"] and (m.condition or "") == c["condition"]
                           and m.value is not None])
        sd = float(values.std(ddof=1))
        expect = capability(len(values), float(values.mean()), sd, c["low"], c["high"])
        assert c["n"] == len(values)
        if expect.cpk is None:  # no spread (a constant in the synthetic records)
            assert c["cpk"] is None
            continue
        assert c["cpk"] == pytest.approx(expect.cpk, rel=1e-9)
        assert c["ci_low"] == pytest.approx(expect.ci_low, rel=1e-9)
        checked += 1
    assert checked >= 3


@pytest.mark.parametrize("values,rule,at", [
    ([0, 0.5, -0.5, 3.5, 0], 1, 3),
    ([0, 2.5, 0.2, 2.4, 0], 2, 3),
    ([1.5, 1.2, 0.3, 1.1, 1.4], 3, 4),
    ([0.2, 0.4, 0.1, 0.3, 0.5, 0.2, 0.6, 0.1], 4, 7),
    ([0, -0.5, 0.3, -3.2, 0], 1, 3),
])
def test_western_electric_rules_flag_the_point_completing_them(
        values: list[float], rule: int, at: int) -> None:
    flags = western_electric(values, 0.0, 1.0)
    assert rule in flags[at]
    assert all(rule not in f for i, f in enumerate(flags) if i < at)


def test_in_control_data_breaks_no_rule() -> None:
    assert all(not f for f in western_electric([0.3, -0.4, 0.5, -0.2, 0.1, -0.6], 0.0, 1.0))


def test_control_chart_of_a_coefficient(line_db: tuple) -> None:
    db, _ = line_db
    with db.engine.connect() as con:
        chart = queries.control_chart(con, Filters(station="EOL-B"), "bias_dps", limit=50)
        with pytest.raises(ValueError, match="choose one of"):
            queries.control_chart(con, Filters(), "nonsense")
    values = [p["value"] for p in chart["points"]]
    assert len(values) == 50
    assert chart["centre"] == pytest.approx(float(np.mean(values)))
    assert chart["sigma"] == pytest.approx(float(np.mean(np.abs(np.diff(values)))) / 1.128)
    times = [p["started_utc"] for p in chart["points"]]
    assert times == sorted(times)
