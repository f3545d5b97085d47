"""How a ramp calibration measured the part (step ramp_calibration, `record.analysis.ramp`),
for the certificate's Test conditions and its page-one summary.

A ramp run has no stable conditions: the chamber heats the dies across the span and cools
them back while the table cycles and the supply alternates. What a reviewer needs instead is
the span the part's own sensor covered each way, the supplies, how many plateaus each half
gave, the element lag the fit estimated for this part (with its U), the hysteresis and
whether the coefficients' U were widened for the lag. The record's figures are k = 1; the
certificate states U (k = 2).
"""

from __future__ import annotations

from dataclasses import dataclass

from reportlab.lib.units import mm
from reportlab.platypus import Flowable, Paragraph, Spacer

from procedures.runtime.record import RunRecord
from procedures.runtime.results import RampResults
from reports.record_keys import die_heating
from reports.styles import BODY, CELL, HEADER_GREY, NOTE, escape, fmt, grid_style
from reports.table_fit import fitted_table

CONTENT_WIDTH = 182 * mm

# the coefficients' short names in the "U widened" line, with their units
_LAG_TERMS = {
    "bias_dps": ("bias", "deg/s"),
    "bias_temp_coeff_dps_per_c": ("bias TC", "deg/s/C"),
    "bias_supply_coeff_dps_per_v": ("bias VC", "deg/s/V"),
    "scale": ("scale", ""),
    "scale_temp_coeff_per_c": ("scale TC", "1/C"),
    "scale_supply_coeff_per_v": ("scale VC", "1/V"),
}


@dataclass(frozen=True)
class Half:
    """One half of the ramp as the part's own sensor saw it."""

    name: str  # heating | cooling
    plateaus: int
    bottom_c: float | None
    top_c: float | None
    rate_lo_c_per_min: float | None
    rate_hi_c_per_min: float | None
    supplies_v: list[float]


def _finite(values: list[float | None]) -> list[float]:
    return [float(v) for v in values if v is not None and v == v and abs(v) != float("inf")]


def _column(values: list[float | None], rows: list[int]) -> list[float]:
    return _finite([values[i] for i in rows if i < len(values)])


def half(ramp: RampResults, heating: bool) -> Half:
    """The plateaus at which the die was heating (or cooling), by its own rate."""
    rows = [i for i, h in enumerate(die_heating(ramp)) if h is heating]
    temps = _column(ramp.die_temp_c, rows)
    rates = _column(ramp.die_rate_c_per_min, rows)
    volts = sorted({round(v, 3) for v in _column(ramp.supply_v, rows)})
    return Half("heating" if heating else "cooling", len(rows),
                min(temps, default=None), max(temps, default=None),
                min(rates, default=None), max(rates, default=None), volts)


def supplies_text(ramp: RampResults) -> str:
    """The supply levels set (else those measured), as '4.75/5.25 V'."""
    levels = _finite(ramp.supplies_v) or sorted({round(v, 2) for v in _finite(ramp.supply_v)})
    return "/".join(fmt(v) for v in levels) + " V" if levels else "supplies not recorded"


def summary(rec: RunRecord) -> str | None:
    """The page-one phrase for a ramp run ('over a heating-and-cooling ramp ...'), or None
    when the record has no ramp section."""
    ramp = rec.analysis.ramp
    if ramp is None:
        return None
    return (f" over a heating-and-cooling ramp (die {fmt(ramp.die_min_c)} to "
            f"{fmt(ramp.die_max_c)} C on its own sensor, {supplies_text(ramp)}, "
            f"{len(ramp.time_s)} plateaus)")


def _range(lo: float | None, hi: float | None, digits: int = 3) -> str:
    if lo is None or hi is None:
        return "-"
    return f"{fmt(lo, digits)} to {fmt(hi, digits)}"


def halves_table(ramp: RampResults) -> Flowable:
    heads = ["Half", "Plateaus", "Die bottom (C)", "Die top (C)", "Die rate (C/min)",
             "Supply measured (V)"]
    rows: list[list[str | Paragraph]] = [[Paragraph(h, CELL) for h in heads]]
    for h in (half(ramp, True), half(ramp, False)):
        # numbers as plain strings: never broken (table_fit gives each column its widest)
        rows.append([h.name, str(h.plateaus), fmt(h.bottom_c), fmt(h.top_c),
                     _range(h.rate_lo_c_per_min, h.rate_hi_c_per_min),
                     ", ".join(fmt(v) for v in h.supplies_v) or "-"])
    return fitted_table(rows, CONTENT_WIDTH, grid_style(), repeatRows=1)


def _twice(u: float | None) -> float | None:
    return None if u is None else 2.0 * u


def lag_text(ramp: RampResults) -> str:
    if ramp.element_tau_s is None:
        tail = (f"; U computed for a lag of {fmt(ramp.tau_bound_s, 3)} s"
                if ramp.tau_bound_s is not None else "")
        return "not resolved by the fit (the part's scale hardly depends on temperature)" + tail
    text = (f"{fmt(ramp.element_tau_s, 4)} s behind the part's own sensor, U (k = 2) "
            f"{fmt(_twice(ramp.u_element_tau_s), 2)} s")
    if ramp.max_element_tau_s is not None:
        text += f"; a part beyond {fmt(ramp.max_element_tau_s, 3)} s is refused"
    return text


def hysteresis_text(ramp: RampResults) -> str:
    if ramp.hysteresis_dps is None:
        return "not given by the fit"
    return (f"{fmt(ramp.hysteresis_dps, 3)} deg/s between heating and cooling, U (k = 2) "
            f"{fmt(_twice(ramp.u_hysteresis_dps), 2)} deg/s")


def widened_text(ramp: RampResults) -> str:
    terms = {k: v for k, v in ramp.lag_error_k2.items() if v}
    if not terms:
        return "no (the fit gave no lag-correction error)" if ramp.element_tau_s is not None \
            else "not recorded"
    parts = []
    for key, value in terms.items():
        label, units = _LAG_TERMS.get(key, (key, ""))
        parts.append(f"{label} +{fmt(value, 2)}{' ' + units if units else ''}")
    bound = ("the part's lag plus its U (k = 2), the most it may be"
             if ramp.element_tau_s is not None
             else "the lag assumed where the fit cannot tell the part's own")
    at = (f" at a lag of {fmt(ramp.tau_bound_s, 3)} s ({bound})"
          if ramp.tau_bound_s is not None else "")
    return ("yes, for the lag: each coefficient's U (k = 2) includes the error the lag "
            f"correction may leave{at} ({'; '.join(parts)})")


def covered_text(ramp: RampResults) -> str:
    if ramp.die_min_c is None or ramp.die_max_c is None:
        return "not recorded"
    return (f"{fmt(ramp.die_min_c, 4)} to {fmt(ramp.die_max_c, 4)} C, the lowest and highest "
            "plateau's die temperature")


def fit_rows(ramp: RampResults) -> list[tuple[str, str]]:
    rows = [
        ("Span asked", f"{fmt(ramp.low_c)} to {fmt(ramp.high_c)} C die temperature (the "
         "part's own sensor), heated up and cooled back"),
        ("Span covered", covered_text(ramp)),
        ("Supplies", f"{supplies_text(ramp)}, alternated each sweep of the rate set"),
        ("Element lag", lag_text(ramp)),
        ("Hysteresis", hysteresis_text(ramp)),
        ("U widened", widened_text(ramp)),
        ("Gradient bias", f"{fmt(ramp.gradient_dps_per_c_per_min, 3)} deg/s per C/min"
         if ramp.gradient_dps_per_c_per_min is not None else "not given by the fit"),
        ("Fit", f"chi2/dof {fmt(ramp.chi2_per_dof, 3)} over {len(ramp.time_s)} plateaus in "
         f"{fmt(ramp.duration_s, 4)} s" if ramp.chi2_per_dof is not None
         else f"no fit ({len(ramp.time_s)} plateaus measured)"),
    ]
    if ramp.refused:
        rows.append(("Refused", ramp.refused))
    return rows


def ramp_conditions(rec: RunRecord) -> list[Flowable]:
    """The ramp's conditions (a heading, the halves and the fit), or nothing when the record
    has no ramp section."""
    ramp = rec.analysis.ramp
    if ramp is None:
        return []
    style = grid_style(header_rows=0)
    style.add("BACKGROUND", (0, 0), (0, -1), HEADER_GREY)
    style.add("RIGHTPADDING", (0, 0), (0, -1), 12)  # a label never touches its value
    fit = fitted_table([[k, Paragraph(escape(v), CELL)] for k, v in fit_rows(ramp)],
                       CONTENT_WIDTH, style)
    return [Paragraph("<b>Ramp calibration</b> (step ramp_calibration): the chamber heated "
                      "the part across the span and cooled it back while the rate table "
                      "cycled through its rate set and the supply alternated; bias and scale "
                      "were fitted over every plateau, with the part's own element lag.", BODY),
            Spacer(1, 1.5 * mm), halves_table(ramp), Spacer(1, 1.5 * mm), fit,
            Paragraph("Die temperatures and rates are the part's own sensor's means over each "
                      "plateau; a plateau counts as heating when the die's own temperature was "
                      "rising (it goes on rising a while after the chamber turns). "
                      "U (k = 2) is twice the fit's standard uncertainty. In the results, "
                      "raw_bias_dps and raw_scale_error at each condition are the fitted laws "
                      "evaluated at that temperature and supply (the ramp holds no condition "
                      "still).", NOTE)]
