"""The certificate of a ramp calibration (config/procedures/eol-ramp.yaml) says how the part
was measured: the span its own sensor covered heating and cooling, the supplies, the plateaus
per direction, its element lag with U, its hysteresis and that U was widened for the lag;
a ramp chart (die temperature over the ramp, the fit's residual per plateau); and no empty
placeholder for a plot of a step the procedure never planned, while a planned step that left
nothing keeps its "Not drawn" (reports/cert_ramp.py, cert_ramp_chart.py, cert_figures.py)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from procedures.runtime.record import RunRecord, read_record, write_record
from procedures.runtime.results import PlanResults
from reports.cert_ramp import half
from reports.certificate import render_certificate
from reports.record_keys import die_heating
from reports.styles import fmt
from station.sim_run import run_simulated
from tests.reports.conftest import pdf_text
from tests.reports.synth_run import Part, make_run

ROOT = Path(__file__).resolve().parents[2]
RAMP = ROOT / "config" / "procedures" / "eol-ramp.yaml"
CLASSIC = ("Stop method: rate record", "Rate table: output versus input",
           "Noise: Allan deviation", "Thermal stabilisation (part's own sensor)")


@pytest.fixture(scope="module")
def ramp_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, RunRecord]:
    """One part's eol-ramp run on the simulated bench in lockstep, its certificate drawn."""
    out = tmp_path_factory.mktemp("ramp")
    result, _truth = run_simulated([{"socket": 1, "serial": "SIM-0001"}],
                                   procedure_path=RAMP, out=out)
    folder = result.folders[1]  # by socket
    render_certificate(folder)
    return folder, read_record(folder)


@pytest.fixture(scope="module")
def ramp_text(ramp_run: tuple[Path, RunRecord]) -> str:
    return pdf_text(ramp_run[0] / "certificate.pdf")


def _spaced(text: str) -> str:
    return re.sub(r"\s+", " ", text)


@pytest.mark.slow
def test_the_engine_records_the_planned_step_types(ramp_run: tuple[Path, RunRecord]) -> None:
    _folder, rec = ramp_run
    assert rec.analysis.plan is not None
    assert rec.analysis.plan.steps == ["power_identify", "ramp_calibration", "program",
                                       "verify"]
    ramp = rec.analysis.ramp
    assert ramp is not None and ramp.supplies_v == [4.75, 5.25]


@pytest.mark.slow
def test_a_ramp_certificate_states_the_span_supplies_plateaus_and_lag(
        ramp_run: tuple[Path, RunRecord], ramp_text: str) -> None:
    _folder, rec = ramp_run
    ramp = rec.analysis.ramp
    assert ramp is not None and ramp.element_tau_s is not None
    assert ramp.u_element_tau_s is not None and ramp.hysteresis_dps is not None
    text = _spaced(ramp_text)
    assert "No conditions recorded" not in text
    assert "Span asked 25 to 45 C die temperature" in text
    assert "Supplies 4.75/5.25 V, alternated each sweep" in text
    heat, cool = half(ramp, True), half(ramp, False)
    assert heat.plateaus > 0 and cool.plateaus > 0
    assert heat.plateaus + cool.plateaus == len(ramp.time_s)
    # each direction's row: its plateaus, the bottom and top its own sensor reached
    for h in (heat, cool):
        assert f"{h.name} {h.plateaus} {fmt(h.bottom_c)} {fmt(h.top_c)} " in text
    lag = (f"Element lag {fmt(ramp.element_tau_s, 4)} s behind the part's own sensor, "
           f"U (k = 2) {fmt(2 * ramp.u_element_tau_s, 2)} s")
    assert lag in text
    assert f"Hysteresis {fmt(ramp.hysteresis_dps, 3)} deg/s" in text
    # the value wraps around its label in -layout: both there, the value whole
    assert "U widened" in text
    assert "yes, for the lag: each coefficient's U (k = 2) includes the error" in text
    assert f"over a heating-and-cooling ramp (die {fmt(ramp.die_min_c)} to" in text


@pytest.mark.slow
def test_a_ramp_certificate_says_what_its_figures_are(ramp_run: tuple[Path, RunRecord]) -> None:
    """The wording a new user's trial asked for: the span the dies covered beside the span
    asked, what the lag in "U widened" is, raw_* as the fitted laws, and a measurement
    without limits recorded rather than passed."""
    folder, rec = ramp_run
    ramp = rec.analysis.ramp
    assert ramp is not None and ramp.die_min_c is not None and ramp.die_max_c is not None
    flowing = _spaced(pdf_text(folder / "certificate.pdf", layout=False))  # lines undone
    assert (f"Span covered {fmt(ramp.die_min_c, 4)} to {fmt(ramp.die_max_c, 4)} C, the lowest "
            "and highest plateau's die temperature") in flowing
    assert (f"at a lag of {fmt(ramp.tau_bound_s, 3)} s (the part's lag plus its U (k = 2), "
            "the most it may be)") in flowing
    assert "raw_bias_dps and raw_scale_error at each condition are the fitted laws" in flowing
    hysteresis = next(m for m in rec.measurements if m.name == "hysteresis_dps")
    assert hysteresis.low is None and hysteresis.high is None
    row = re.search(r"hysteresis_dps .*?(recorded \(no limit\)|PASS)", flowing)
    assert row is not None and row.group(1) == "recorded (no limit)", row


@pytest.mark.slow
def test_a_ramp_certificate_draws_the_ramp_and_no_placeholder_for_unplanned_steps(
        ramp_text: str) -> None:
    text = _spaced(ramp_text)
    assert "Ramp calibration: die temperature and fit residuals" in text
    assert "Die temperature over the ramp" in text and "Fit residual per plateau" in text
    assert "Not drawn" not in text
    # the static dwell's noise is drawn as the bias step's is (analysis.allan)
    assert "Noise: Allan deviation" in text
    for heading in (CLASSIC[1], CLASSIC[3]):
        assert heading not in text
    assert ("Procedure eol-ramp has no step of its own for: rate table, "
            "thermal stabilisation") in text


@pytest.mark.slow
def test_a_ramp_with_stop_moves_draws_them_as_the_articles_figure_4(
        ramp_run: tuple[Path, RunRecord], ramp_text: str) -> None:
    """eol-ramp carries the stop method at both ends of its span: the stop-method section
    shows (though its plan holds no stop_method step), a chart per end, each end's stop
    scale against the ramp fit's law there."""
    rec = ramp_run[1]
    assert rec.analysis.ramp_stop is not None
    text = _spaced(ramp_text)
    assert "Stop method: rate record (as the article's Figure 4)" in text
    for end in rec.analysis.ramp_stop.ends:
        assert f"Stop method, condition {end.label}" in text
        assert f"{end.label}: die {fmt(end.die_temp_c, 4)} C" in text
        assert f"E_n {fmt(end.normalised_difference, 3)}" in text
    assert [e.label for e in rec.analysis.ramp_stop.ends] == ["ramp_top", "ramp_bottom"]


def test_a_ramp_without_stop_moves_leaves_the_stop_plot_out(tmp_path: Path) -> None:
    folder, rec = make_run(tmp_path, Part(serial="SIM-PLAN-3"))
    rec.analysis.plan = PlanResults(steps=["power_identify", "ramp_calibration", "verify"])
    rec.analysis.stop_method = {}
    write_record(folder, rec)
    render_certificate(folder)
    text = _spaced(pdf_text(folder / "certificate.pdf"))
    assert "Stop method: rate record" not in text
    assert "has no step of its own for: stop method, rate table" in text


@pytest.mark.slow
def test_the_ramp_conditions_never_run_numbers_together(ramp_run: tuple[Path, RunRecord],
                                                        ramp_text: str) -> None:
    """Each halves-table row is its own cells, two or more spaces apart in -layout."""
    ramp = ramp_run[1].analysis.ramp
    assert ramp is not None
    rows = [line.split("  ") for line in ramp_text.splitlines()
            if line.startswith(("heating ", "cooling "))]
    assert len(rows) == 2
    for row in rows:
        cells = [c.strip() for c in row if c.strip()]
        h = half(ramp, cells[0] == "heating")
        assert cells[:4] == [h.name, str(h.plateaus), fmt(h.bottom_c), fmt(h.top_c)]
        assert cells[5] == "4.75, 5.25"


@pytest.mark.slow
def test_a_refused_ramp_keeps_its_not_drawn_residuals(ramp_run: tuple[Path, RunRecord],
                                                      tmp_path: Path) -> None:
    """A planned step that left no fit: the residual chart says why, the refusal is stated."""
    folder = Path(shutil.copytree(ramp_run[0], tmp_path / ramp_run[0].name))
    rec = read_record(folder)
    assert rec.analysis.ramp is not None
    rec.analysis.ramp = rec.analysis.ramp.model_copy(update={
        "residual_dps": [], "element_tau_s": None, "u_element_tau_s": None,
        "chi2_per_dof": None, "lag_error_k2": {},
        "refused": "the element lags the temperature sensor by 95 s (beyond 40 s)"})
    write_record(folder, rec)
    render_certificate(folder)
    text = _spaced(pdf_text(folder / "certificate.pdf"))
    assert "Not drawn: the fit gave no residuals" in text
    assert "Refused the element lags the temperature sensor by 95 s" in text
    assert "Element lag not resolved by the fit" in text
    assert "Die temperature over the ramp" in text


def test_a_planned_step_that_left_nothing_keeps_not_drawn(tmp_path: Path) -> None:
    """A plan naming ramp_calibration whose record holds no ramp section (the step never
    got to write it): the gap stays on the page, with why."""
    folder, rec = make_run(tmp_path, Part(serial="SIM-PLAN-1"))
    assert rec.analysis.ramp is None
    rec.analysis.plan = PlanResults(estimated_station_s=100.0, steps=[
        "power_identify", "thermal", "bias", "rate_table", "stop_method", "ramp_calibration",
        "fit", "program", "verify"])
    write_record(folder, rec)
    written = json.loads((folder / "record.json").read_text())
    assert written["analysis"]["plan"]["steps"][5] == "ramp_calibration"
    render_certificate(folder)
    text = _spaced(pdf_text(folder / "certificate.pdf"))
    assert ("Ramp calibration: die temperature and fit residuals Ramp calibration Not drawn: "
            "record.analysis has no 'ramp'") in text
    for heading in CLASSIC:
        assert heading in text
    assert "has no step of its own" not in text


def test_a_plan_without_the_stop_method_leaves_its_plot_out(tmp_path: Path) -> None:
    folder, rec = make_run(tmp_path, Part(serial="SIM-PLAN-2"))
    rec.analysis.plan = PlanResults(steps=["thermal", "bias", "rate_table", "fit"])
    write_record(folder, rec)
    render_certificate(folder)
    text = _spaced(pdf_text(folder / "certificate.pdf"))
    assert "Stop method: rate record" not in text
    assert "has no step of its own for: stop method (no plot for them)" in text
    assert "Rate table: output versus input" in text


def test_a_die_heating_after_the_chamber_turned_counts_as_heating() -> None:
    """The die goes on heating a while after the chamber turns: its own rate decides."""
    from procedures.runtime.results import RampResults
    ramp = RampResults(low_c=25.0, high_c=45.0, time_s=[0.0, 10.0, 20.0, 30.0],
                       die_temp_c=[40.0, 44.0, 44.5, 43.0],
                       die_rate_c_per_min=[3.0, 1.0, -0.5, -3.0],
                       heating=[True, False, False, False])
    assert die_heating(ramp) == [True, True, False, False]
    heat = half(ramp, True)
    assert (heat.plateaus, heat.bottom_c, heat.top_c) == (2, 40.0, 44.0)
    legacy = ramp.model_copy(update={"die_rate_c_per_min": []})
    assert die_heating(legacy) == [True, False, False, False]
