"""The honest thermal bench through the station (issue 29, deliverable 1): run folders of
`station run --sim` with both shipped procedures (config/procedures/eol-ramp.yaml, which heats
and cools, and eol-rate-table.yaml, which heats and soaks), six parts each, analysed from the
ideal first-order model. The bench's truth is each part's draws (tests/model/thermal_station.py),
and what each folder can show of it, each effect's z on the folder against the workflow's own
test (tests/model/thermal_truth.py): expected to be named at z >= the 90 %-power threshold of
a library term at the first Holm step (5.47 on these folders). On every folder:

- every effect named depends on a thermal variable the part's hidden effects depend on
  (`temperature_rate` for the element's lag and the gradient bias, `temperature_direction`
  for the hysteresis), and otherwise only on the rate or the temperature (never misnamed);
- every expected effect is named: on the ramp the element's lag through the scale (w x dT/dt,
  or its element-lagged variant: `rate`, `temperature_rate`) on every part, alone (z 18-57;
  the default bench's gradient and hysteresis, z 0.2-2.3 over two runs, are below what one
  ramp shows against the parts' own bias wander); on the rate table nothing is expected
  (z <= 1.6);
- the gap after is within 1.5 x the floor of the same part run with the thermal physics off;
- those null folders (thermal physics off, both procedures) name nothing;
- on a bench with only the gradient bias (0.01 (deg/s)/(C/min) on every part), or only the
  hysteresis (0.05 deg/s), nothing but that one's variable is named, it is named wherever
  expected (two runs: the gradient expected on 3 and 2 of 6, z up to 11.7, named on 5 and
  2; the hysteresis expected on 5 and 4, named on 6 and 4), and on at least MIN_NAMED of the
  six parts. Below the threshold it may be named or not (over four runs the gradient was
  named on 5, 5, 2 and 2 of 6, the hysteresis on 6, 5, 4 and 4).

The bench runs in lockstep: a run of the grid draws the same noise as the last on the same
code (two runs from scratch gave the same table). Other code may draw other noise; an
expected effect at z just above the threshold is then missed one time in ten (the power),
but the effects here lie mostly far above it.

Six station runs of 15 to 85 s each on the 2-core machine, and a few seconds of workflow
per folder: a long grid (`-m station_grid`).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import thermal_station as ts
from threadpoolctl import threadpool_limits

pytestmark = [pytest.mark.slow, pytest.mark.station_grid]

SERIALS = [f"SIM-{2931 + i}" for i in range(6)]
MIN_NAMED = 1  # of the six parts, with one effect alone on the bench
_folders: dict[tuple[str, str], dict[str, Path]] = {}
_results: dict[tuple[str, str, str], ts.Analysis] = {}


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("thermal-station")


def _result(work: Path, procedure: str, bench: str, serial: str) -> ts.FolderResult:
    for b in ("ideal", bench):
        if (procedure, b) not in _folders:
            _folders[(procedure, b)] = ts.station_run(work / f"{procedure}-{b}", b, procedure,
                                                      SERIALS)
        folder = _folders[(procedure, b)].get(serial)
        assert folder is not None, f"{serial} did not finish the {procedure} on {b}"
        if (procedure, b, serial) not in _results:
            with threadpool_limits(limits=1, user_api="blas"):
                _results[(procedure, b, serial)] = ts.analyse(folder, serial,
                                                              ts.truth(serial, b))
    ideal_floor = _results[(procedure, "ideal", serial)].floor_dps
    return ts.FolderResult(serial, procedure, bench, _results[(procedure, bench, serial)],
                           ideal_floor)


@pytest.mark.parametrize("procedure", list(ts.PROCEDURES))
@pytest.mark.parametrize("serial", SERIALS)
def test_the_honest_bench_named_by_its_variables_and_the_gap_closed(
        work: Path, procedure: str, serial: str) -> None:
    """Every effect named is in the truth, every effect the folder shows is named (on the
    ramp the lag through the scale on every part, alone), the gap within 1.5 x the ideal
    floor."""
    row = _result(work, procedure, "honest", serial)
    truth = ts.truth(serial, "honest")
    assert ts.verdict(row, truth) == [], (ts.sizes_label(row.answer), row.named)
    if procedure == "ramp":  # the lag's scale signature, w x dT/dt: far above the threshold
        assert [s.expected for s in row.answer.sizes if s.name == "lag (scale)"] == [True]


@pytest.mark.parametrize("procedure", list(ts.PROCEDURES))
@pytest.mark.parametrize("serial", SERIALS)
def test_the_null_folders_name_nothing(work: Path, procedure: str, serial: str) -> None:
    """The same parts with the thermal physics off: nothing named, the gap within 1.5 x
    its floor."""
    row = _result(work, procedure, "ideal", serial)
    assert row.named == () and ts.verdict(row, ts.truth(serial, "ideal")) == [], row.named


@pytest.mark.parametrize("bench,word", [("gradient-only", "temperature_rate"),
                                        ("hysteresis-only", "temperature_direction")])
def test_one_effect_alone_is_named_by_its_variable(work: Path, bench: str, word: str) -> None:
    """Nothing but the effect's own variable is ever named; it is named wherever the folder
    shows it (z at least the expected threshold: thermal_truth), at least MIN_NAMED of the
    six parts, and where it is named or expected the gap closes to 1.5 x the ideal floor.
    A folder below the threshold keeps its gap: on one run SIM-2931 and -2935 with the
    gradient alone measured floors 1.6 and 2.0 x their ideal folders' (the wander estimated
    higher on that noise: 1.4 x with the bench's own gradient subtracted), z 3.9 and 3.6,
    not named, gap after 2.20 and 2.35 x the ideal floor."""
    rows = [_result(work, "ramp", bench, s) for s in SERIALS]
    wrong = {r.serial: ts.verdict(r, ts.truth(r.serial, bench), every_gap=False)
             for r in rows}
    assert not any(wrong.values()), wrong
    named = [r for r in rows if word in {w for _, regs in r.named for w in regs}]
    assert len(named) >= MIN_NAMED, [(r.serial, r.named) for r in rows]
