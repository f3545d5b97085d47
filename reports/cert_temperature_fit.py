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
from typing import Any

import numpy as np
from reportlab.lib.units import mm
from reportlab.platypus import Flowable, KeepTogether, Paragraph, Table, TableStyle

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
    """record.analysis["temperature_fit"] lacks a key or holds a non-number there."""


def _num(d: dict[str, Any], key: str) -> float:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise MalformedFit(f"{KEY}.{key} is not a finite number")
    return float(v)


def _nums(d: dict[str, Any], key: str) -> list[float]:
    v = d.get(key)
    if not isinstance(v, list) or not v:
        raise MalformedFit(f"{KEY}.{key} is not a list of numbers")
    return [_num({"x": x}, "x") for x in v]


def polynomial_at(
    params: Sequence[float], order: int, temp_c: np.ndarray, supply_v: float, t0: float, v0: float,
    relative: bool,
) -> np.ndarray:
    """b0 + sum b_k dT^k + bV dV, or for the scale s0 (1 + sum s_k dT^k + sV dV)."""
    dt = temp_c - t0
    terms = sum(params[k] * dt**k for k in range(1, order + 1)) + params[-1] * (supply_v - v0)
    return np.asarray(params[0] * (1.0 + terms) if relative else params[0] + terms)


def _table(fit: dict[str, Any]) -> Table:
    rows: list[list[str | Paragraph]] = [
        [Paragraph(h, CELL) for h in ("Coefficient", "Value", "U (k=2)", "Units")]]
    coefficients = fit.get("coefficients")
    if not isinstance(coefficients, list) or not coefficients:
        raise MalformedFit(f"{KEY}.coefficients is not a list")
    for c in coefficients:
        if not isinstance(c, dict):
            raise MalformedFit(f"{KEY}.coefficients holds a non-mapping")
        rows.append([Paragraph(escape(c.get("name", "-")), CELL_MONO),
                     fmt(_num(c, "value"), 7),  # numbers: never broken (table_fit)
                     fmt(_num(c, "uncertainty_k2"), 3),
                     Paragraph(escape(unit_label(str(c.get("units", "")))), CELL)])
    return fitted_table(rows, FULL_W, grid_style(), repeatRows=1)


def _chart(fit: dict[str, Any], kind: str) -> Chart:
    order = int(_num(fit, "order"))
    t0, v0 = _num(fit, "reference_temperature_c"), _num(fit, "reference_supply_v")
    params = _nums(fit, f"{kind}_params")
    if len(params) != order + 2:
        raise MalformedFit(f"{KEY}.{kind}_params holds {len(params)} values, not {order + 2}")
    points = fit.get("points")
    if not isinstance(points, list) or not points:
        raise MalformedFit(f"{KEY}.points is not a list")
    value_key, u_key = ("bias_dps", "u_bias_dps") if kind == "bias" else ("scale", "u_scale")
    rows = [(_num(p, f"{kind}_temp_c"), _num(p, "supply_v"), _num(p, value_key), _num(p, u_key))
            for p in points if isinstance(p, dict)]
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


def _note(fit: dict[str, Any]) -> Paragraph:
    order = int(_num(fit, "order"))
    dof = int(_num(fit, "dof"))
    text = (f"{_ORDER_WORDS.get(order, str(order)).capitalize()}-order fit in temperature "
            f"(first order in supply) about {fmt(_num(fit, 'reference_temperature_c'))} C and "
            f"{fmt(_num(fit, 'reference_supply_v'))} V, weighted by each condition's own "
            f"uncertainty: bias = b0 + sum b_k dT^k + bV dV, scale = s0 (1 + sum s_k dT^k + "
            f"sV dV). Points: the measured conditions with k = 2 error bars; lines: the fit at "
            f"each supply level.")
    if dof > 0:
        text += (f" Chi-square of the fit: bias {fmt(_num(fit, 'bias_chi2'), 3)}, scale "
                 f"{fmt(_num(fit, 'scale_chi2'), 3)}, on {dof} degree(s) of freedom.")
    else:
        text += " No spare degree of freedom: the fit passes through every condition."
    return Paragraph(escape(text), NOTE)


def temperature_fit(inputs: CertificateInputs) -> list[Flowable]:
    """The section's flowables; empty when the record has no temperature fit to show."""
    rec = inputs.record
    fit = rec.analysis.get(KEY) if rec is not None else None
    if fit is None:
        return []
    story: list[Flowable] = [Paragraph("Temperature fit of bias and scale", H2)]
    try:
        if not isinstance(fit, dict):
            raise MalformedFit(f"{KEY} is not a mapping")
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
