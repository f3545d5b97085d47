"""Certificate section: the temperature fit (order 1 to 3) of bias and scale.

Drawn from `record.analysis["temperature_fit"]` only, which the fit step writes when the fit
is beyond first order or spans three or more temperatures (today's two-temperature,
first-order runs have no such key, so their certificates are unchanged). The section holds
a table of every fitted coefficient with its expanded (k = 2) uncertainty and two plots, bias
and scale against the part's die temperature: the measured conditions (one colour per supply
level, with their k = 2 error bars) and the fitted curve at each supply level.

Keys read (`temperature_fit`): `order`, `reference_temperature_c`, `reference_supply_v`,
`coefficients` (each `name`, `value`, `uncertainty_k2`, `units`), `bias_params` (b0, b1 ..
bN, bV), `scale_params` (s0, s1 .. sN, sV), `bias_chi2`, `scale_chi2`, `dof`, `points` (each
`condition`, `bias_temp_c`, `scale_temp_c`, `supply_v`, `bias_dps`, `u_bias_dps`, `scale`,
`u_scale`). Nothing here raises on a malformed record: a missing part is said in a box.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np
from reportlab.lib.units import mm
from reportlab.platypus import Flowable, KeepTogether, Paragraph, Table, TableStyle

from procedures.runtime.results import TemperatureFitResults, TemperaturePoint
from reports.cert_inputs import CertificateInputs
from reports.charts import PALETTE, Chart, message_box
from reports.styles import CELL, CELL_MONO, H2, NOTE, escape, fmt, grid_style, unit_label
from reports.table_fit import fitted_table

log = logging.getLogger(__name__)

KEY = "temperature_fit"
FULL_W = 182 * mm
HALF_W = 90 * mm
_ORDER_WORDS = {1: "first", 2: "second", 3: "third"}


class MalformedFit(ValueError):
    """record.analysis.temperature_fit holds a null (non-finite) number or no points."""


def _num(value: float | None, key: str) -> float:
    if value is None or not math.isfinite(value):
        raise MalformedFit(f"{KEY}.{key} is not a finite number")
    return float(value)


def _nums(values: list[float | None], key: str) -> list[float]:
    if not values:
        raise MalformedFit(f"{KEY}.{key} is not a list of numbers")
    return [_num(x, key) for x in values]


def polynomial_at(
    params: Sequence[float], order: int, temp_c: np.ndarray, supply_v: float, t0: float, v0: float,
    relative: bool,
) -> np.ndarray:
    """b0 + sum b_k dT^k + bV dV, or for the scale s0 (1 + sum s_k dT^k + sV dV)."""
    dt = temp_c - t0
    terms = sum(params[k] * dt**k for k in range(1, order + 1)) + params[-1] * (supply_v - v0)
    return np.asarray(params[0] * (1.0 + terms) if relative else params[0] + terms)


def _table(fit: TemperatureFitResults) -> Table:
    rows: list[list[str | Paragraph]] = [
        [Paragraph(h, CELL) for h in ("Coefficient", "Value", "U (k=2)", "Units")]]
    if not fit.coefficients:
        raise MalformedFit(f"{KEY}.coefficients is not a list")
    for c in fit.coefficients:
        rows.append([Paragraph(escape(c.name), CELL_MONO),
                     fmt(_num(c.value, "value"), 7),  # numbers: never broken (table_fit)
                     fmt(_num(c.uncertainty_k2, "uncertainty_k2"), 3),
                     Paragraph(escape(unit_label(c.units)), CELL)])
    return fitted_table(rows, FULL_W, grid_style(), repeatRows=1)


def _point(p: TemperaturePoint, kind: str) -> tuple[float, float, float, float]:
    """(die temperature, supply, value, its k=1 u) of one fitted condition, for `kind`."""
    temp, value, u = ((p.bias_temp_c, p.bias_dps, p.u_bias_dps) if kind == "bias"
                      else (p.scale_temp_c, p.scale, p.u_scale))
    return (_num(temp, f"{kind}_temp_c"), _num(p.supply_v, "supply_v"),
            _num(value, f"points.{kind}"), _num(u, f"points.u_{kind}"))


def _chart(fit: TemperatureFitResults, kind: str) -> Chart:
    order = fit.order
    t0, v0 = _num(fit.reference_temperature_c, "reference_temperature_c"), _num(
        fit.reference_supply_v, "reference_supply_v")
    params = _nums(fit.bias_params if kind == "bias" else fit.scale_params, f"{kind}_params")
    if len(params) != order + 2:
        raise MalformedFit(f"{KEY}.{kind}_params holds {len(params)} values, not {order + 2}")
    if not fit.points:
        raise MalformedFit(f"{KEY}.points is not a list")
    rows = [_point(p, kind) for p in fit.points]
    title = "Bias against die temperature" if kind == "bias" else "Scale against die temperature"
    chart = Chart(HALF_W, 62 * mm, title=title, x_label="die temperature (C)",
                  y_label="bias (deg/s)" if kind == "bias" else "scale (1)")
    temps = np.array([r[0] for r in rows])
    grid = np.linspace(temps.min() - 2.0, temps.max() + 2.0, 80)
    for i, supply in enumerate(sorted({round(r[1], 2) for r in rows})):
        colour = PALETTE[i % len(PALETTE)]
        mine = [r for r in rows if round(r[1], 2) == supply]
        curve = polynomial_at(params, order, grid, supply, t0, v0, relative=kind == "scale")
        chart.line(grid, curve, colour, f"fit at {fmt(supply)} V", width=0.7)
        chart.scatter([r[0] for r in mine], [r[2] for r in mine], colour, size=2.2)
        for temp, _, value, u in mine:  # k = 2 error bars
            chart.line([temp, temp], [value - 2 * u, value + 2 * u], colour, width=0.6)
    return chart


def _note(fit: TemperatureFitResults) -> Paragraph:
    order = fit.order
    if fit.dof is None:
        raise MalformedFit(f"{KEY}.dof is not a finite number")
    dof = fit.dof
    text = (f"{_ORDER_WORDS.get(order, str(order)).capitalize()}-order fit in temperature "
            f"(first order in supply) about {fmt(fit.reference_temperature_c)} C and "
            f"{fmt(fit.reference_supply_v)} V, weighted by each condition's own "
            f"uncertainty: bias = b0 + sum b_k dT^k + bV dV, scale = s0 (1 + sum s_k dT^k + "
            f"sV dV). Points: the measured conditions with k = 2 error bars; lines: the fit at "
            f"each supply level.")
    if dof > 0:
        text += (f" Chi-square of the fit: bias {fmt(_num(fit.bias_chi2, 'bias_chi2'), 3)}, "
                 f"scale {fmt(_num(fit.scale_chi2, 'scale_chi2'), 3)}, on {dof} degree(s) "
                 "of freedom.")
    else:
        text += " No spare degree of freedom: the fit passes through every condition."
    return Paragraph(escape(text), NOTE)


def temperature_fit(inputs: CertificateInputs) -> list[Flowable]:
    """The section's flowables; empty when the record has no temperature fit to show."""
    rec = inputs.record
    fit = rec.analysis.temperature_fit if rec is not None else None
    if fit is None:
        return []
    story: list[Flowable] = [Paragraph("Temperature fit of bias and scale", H2)]
    try:
        table, note = _table(fit), _note(fit)
        charts = Table([[_chart(fit, "bias").drawing(), _chart(fit, "scale").drawing()]],
                       colWidths=[HALF_W + 1 * mm, HALF_W])
        charts.setStyle(TableStyle([("LEFTPADDING", (0, 0), (-1, -1), 0),
                                    ("RIGHTPADDING", (0, 0), (-1, -1), 0)]))
    except MalformedFit as exc:
        return story + [message_box(FULL_W, 30 * mm, "Temperature fit", f"Not drawn: {exc}.")]
    except Exception as exc:  # a section must never stop a certificate being issued
        log.exception("temperature fit section failed")
        return story + [message_box(FULL_W, 30 * mm, "Temperature fit",
                                    f"Not drawn: {type(exc).__name__}: {exc}. Report this to "
                                    "the station software team with the run folder.")]
    return [KeepTogether([story[0], table]), charts, note]
