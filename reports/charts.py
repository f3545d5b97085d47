"""Vector charts for the station's PDFs, drawn with reportlab.graphics (no raster images).

General on purpose (certificates, lot reports and discrepancy reports share it):

    chart = Chart(480, 200, title="Rate", x_label="time (s)", y_label="rate (deg/s)")
    chart.shade_x(0.0, 3.0, STATIC_FILL, label="static")
    chart.line(t, y, label="gyro")
    chart.scatter(x, y); chart.hline(1.0); chart.band_y(-0.1, 0.1)
    drawing = chart.drawing()           # a reportlab Drawing, a platypus flowable

`log_x` / `log_y` give log axes (non-positive values are dropped). Long lines are thinned
by min/max decimation per horizontal point so a 100k-sample record stays small and fast
without hiding spikes. `bar_chart` draws categories; `message_box` stands in for a plot that
cannot be drawn and says why.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from reportlab.graphics.shapes import Drawing, Group, Line, PolyLine, Rect, String
from reportlab.lib import colors
from reportlab.lib.colors import Color
from reportlab.pdfbase.pdfmetrics import stringWidth

from reports.styles import FONT, FONT_BOLD

PALETTE = [
    colors.HexColor("#1f5fa8"),
    colors.HexColor("#d2691e"),
    colors.HexColor("#2e8b57"),
    colors.HexColor("#8b2fa0"),
    colors.HexColor("#b22222"),
    colors.HexColor("#4a6670"),
]
STATIC_FILL = colors.HexColor("#cfe3f7")
INTEGRATION_FILL = colors.HexColor("#fde0b8")
LIMIT_RED = colors.HexColor("#c0141c")
GRID = colors.HexColor("#e3e6ea")

_LEFT, _RIGHT, _BOTTOM, _TOP = 46.0, 8.0, 26.0, 16.0
_Map = Callable[[ArrayLike], np.ndarray]  # data -> page coordinates
_Range = tuple[float, float]


@dataclass
class _Series:
    kind: str  # line | scatter | shade_x | band_y | hline | vline | bars
    xs: np.ndarray
    ys: np.ndarray
    color: colors.Color
    label: str | None = None
    width: float = 0.8
    dash: tuple[float, ...] | None = None
    size: float = 2.0


def nice_ticks(lo: float, hi: float, target: int = 5) -> list[float]:
    """About `target` round tick values (1, 2, 5 x 10^k steps) covering [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo]
    raw = (hi - lo) / max(target, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9)
    last = math.floor(hi / step + 1e-9)
    # index times step (not a running sum), so ticks do not drift on long ranges
    return [0.0 if i == 0 else i * step for i in range(first, last + 1)]


def log_ticks(lo: float, hi: float) -> list[float]:
    """Decades inside [lo, hi]; adds 2 and 5 when fewer than two decades show."""
    d0, d1 = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    mults = (1,) if d1 - d0 >= 2 else (1, 2, 5)
    ticks = [m * 10.0**d for d in range(d0, d1 + 1) for m in mults]
    return [t for t in ticks if lo * (1 - 1e-9) <= t <= hi * (1 + 1e-9)]


def tick_label(v: float) -> str:
    if v == 0:
        return "0"
    a = abs(v)
    if a >= 1e5 or a < 1e-3:
        m, e = f"{v:.0e}".split("e")
        return f"{m}e{int(e)}"
    return f"{v:.6g}"


def decimate(xs: np.ndarray, ys: np.ndarray, buckets: int) -> tuple[np.ndarray, np.ndarray]:
    """Keep the min and max of each of `buckets` equal slices: a thin line, spikes kept."""
    n = xs.size
    if n <= 2 * buckets:
        return xs, ys
    edges = np.linspace(0, n, buckets + 1).astype(int)
    keep: list[int] = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b <= a:
            continue
        seg = ys[a:b]
        i_min, i_max = a + int(np.argmin(seg)), a + int(np.argmax(seg))
        keep.extend(sorted((i_min, i_max)))
    idx = np.asarray(keep, dtype=int)
    return xs[idx], ys[idx]


@dataclass
class Chart:
    width: float
    height: float
    title: str = ""
    x_label: str = ""
    y_label: str = ""
    log_x: bool = False
    log_y: bool = False
    x_range: tuple[float, float] | None = None
    y_range: tuple[float, float] | None = None
    _series: list[_Series] = field(default_factory=list)

    # ---- adding data ---------------------------------------------------------------
    def _next_colour(self) -> colors.Color:
        used = sum(1 for s in self._series if s.kind in ("line", "scatter"))
        return PALETTE[used % len(PALETTE)]

    def _clean(self, xs: ArrayLike, ys: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        x = np.asarray(xs, dtype=float).ravel()
        y = np.asarray(ys, dtype=float).ravel()
        if x.size != y.size:
            raise ValueError(f"chart {self.title!r}: x has {x.size} values, y has {y.size}")
        ok = np.isfinite(x) & np.isfinite(y)
        if self.log_x:
            ok &= x > 0
        if self.log_y:
            ok &= y > 0
        return x[ok], y[ok]

    def line(self, xs: ArrayLike, ys: ArrayLike, color: Color | None = None,
             label: str | None = None, width: float = 0.8,
             dash: tuple[float, ...] | None = None) -> Chart:
        x, y = self._clean(xs, ys)
        self._series.append(_Series("line", x, y, color or self._next_colour(), label, width, dash))
        return self

    def scatter(self, xs: ArrayLike, ys: ArrayLike, color: Color | None = None,
                label: str | None = None, size: float = 2.0) -> Chart:
        x, y = self._clean(xs, ys)
        self._series.append(
            _Series("scatter", x, y, color or self._next_colour(), label, size=size)
        )
        return self

    def shade_x(self, x0: float, x1: float, color: Color = STATIC_FILL,
                label: str | None = None) -> Chart:
        self._series.append(_Series("shade_x", np.array([x0, x1]), np.array([]), color, label))
        return self

    def band_y(self, y0: float, y1: float, color: Color = STATIC_FILL,
               label: str | None = None) -> Chart:
        self._series.append(_Series("band_y", np.array([]), np.array([y0, y1]), color, label))
        return self

    def hline(self, y: float, color: Color = LIMIT_RED, label: str | None = None,
              dash: tuple[float, ...] | None = (3, 2), width: float = 0.8) -> Chart:
        self._series.append(
            _Series("hline", np.array([]), np.array([y]), color, label, width, dash))
        return self

    def vline(self, x: float, color: Color = LIMIT_RED, label: str | None = None,
              dash: tuple[float, ...] | None = (3, 2), width: float = 0.8) -> Chart:
        self._series.append(
            _Series("vline", np.array([x]), np.array([]), color, label, width, dash))
        return self

    def bars(self, edges: ArrayLike, counts: ArrayLike, color: Color | None = None,
             label: str | None = None) -> Chart:
        """Histogram bars: len(edges) == len(counts) + 1."""
        e = np.asarray(edges, dtype=float)
        c = np.asarray(counts, dtype=float)
        if e.size != c.size + 1:
            raise ValueError(f"chart {self.title!r}: {e.size} edges for {c.size} counts")
        self._series.append(_Series("bars", e, c, color or PALETTE[0], label))
        return self

    # ---- layout -------------------------------------------------------------------
    def _data_range(self, axis: str) -> tuple[float, float]:
        vals: list[np.ndarray] = []
        for s in self._series:
            if axis == "x" and s.kind in ("line", "scatter", "vline", "shade_x", "bars"):
                vals.append(s.xs)
            if axis == "y" and s.kind in ("line", "scatter", "hline", "band_y"):
                vals.append(s.ys)
            if axis == "y" and s.kind == "bars":
                vals.append(np.append(s.ys, 0.0))
        log = self.log_x if axis == "x" else self.log_y
        allv = np.concatenate(vals) if vals else np.array([])
        allv = allv[np.isfinite(allv)]
        if log:
            allv = allv[allv > 0]
        if allv.size == 0:
            return (1.0, 10.0) if log else (0.0, 1.0)
        lo, hi = float(allv.min()), float(allv.max())
        if log:
            if hi <= lo:
                lo, hi = lo / 2, hi * 2
            return 10 ** math.floor(math.log10(lo) + 1e-9), 10 ** math.ceil(math.log10(hi) - 1e-9)
        if hi <= lo:
            pad = abs(lo) * 0.05 or 1.0
            return lo - pad, hi + pad
        pad = 0.04 * (hi - lo) if axis == "y" else 0.0
        return lo - pad, hi + pad

    def drawing(self) -> Drawing:
        d = Drawing(self.width, self.height)
        x0, y0 = _LEFT, _BOTTOM
        pw = self.width - _LEFT - _RIGHT
        legend_rows = self._legend_rows(pw)
        ph = self.height - _BOTTOM - _TOP - 9.0 * len(legend_rows)
        xr = self.x_range or self._data_range("x")
        yr = self.y_range or self._data_range("y")

        def tx(v: ArrayLike) -> np.ndarray:
            if self.log_x:
                a, b = math.log10(xr[0]), math.log10(xr[1])
                return np.asarray(x0 + (np.log10(v) - a) / (b - a) * pw)
            return np.asarray(x0 + (np.asarray(v) - xr[0]) / (xr[1] - xr[0]) * pw)

        def ty(v: ArrayLike) -> np.ndarray:
            if self.log_y:
                a, b = math.log10(yr[0]), math.log10(yr[1])
                return np.asarray(y0 + (np.log10(v) - a) / (b - a) * ph)
            return np.asarray(y0 + (np.asarray(v) - yr[0]) / (yr[1] - yr[0]) * ph)

        self._draw_axes(d, tx, ty, xr, yr, x0, y0, pw, ph)
        # Fills first so lines and points stay visible over them.
        fills_first = sorted(self._series, key=lambda s: s.kind not in ("shade_x", "band_y"))
        for s in fills_first:
            self._draw_series(d, s, tx, ty, xr, yr, x0, y0, pw, ph)
        d.add(Rect(x0, y0, pw, ph, fillColor=None, strokeColor=colors.black, strokeWidth=0.6))
        self._draw_legend(d, legend_rows, x0, y0 + ph)
        d.add(String(x0, self.height - 11, self.title, fontName=FONT_BOLD, fontSize=8))
        return d

    def _draw_axes(self, d: Drawing, tx: _Map, ty: _Map, xr: _Range, yr: _Range, x0: float,
                   y0: float, pw: float, ph: float) -> None:
        xt = log_ticks(*xr) if self.log_x else nice_ticks(*xr)
        yt = log_ticks(*yr) if self.log_y else nice_ticks(yr[0], yr[1], target=4)
        for v in xt:
            px = float(tx(v))
            if x0 - 0.5 <= px <= x0 + pw + 0.5:
                d.add(Line(px, y0, px, y0 + ph, strokeColor=GRID, strokeWidth=0.4))
                d.add(Line(px, y0, px, y0 - 2.5, strokeColor=colors.black, strokeWidth=0.5))
                d.add(String(px, y0 - 10, tick_label(v), fontName=FONT, fontSize=6.5,
                             textAnchor="middle"))
        for v in yt:
            py = float(ty(v))
            if y0 - 0.5 <= py <= y0 + ph + 0.5:
                d.add(Line(x0, py, x0 + pw, py, strokeColor=GRID, strokeWidth=0.4))
                d.add(Line(x0 - 2.5, py, x0, py, strokeColor=colors.black, strokeWidth=0.5))
                d.add(String(x0 - 4, py - 2.2, tick_label(v), fontName=FONT, fontSize=6.5,
                             textAnchor="end"))
        d.add(String(x0 + pw / 2, 4, self.x_label, fontName=FONT, fontSize=7,
                     textAnchor="middle"))
        ylab = String(0, 0, self.y_label, fontName=FONT, fontSize=7, textAnchor="middle")
        g = Group(ylab)
        g.translate(8, y0 + ph / 2)
        g.rotate(90)
        d.add(g)

    def _draw_series(self, d: Drawing, s: _Series, tx: _Map, ty: _Map, xr: _Range, yr: _Range,
                     x0: float, y0: float, pw: float, ph: float) -> None:
        top, right = y0 + ph, x0 + pw
        if s.kind == "shade_x":
            a = float(np.clip(tx(max(min(s.xs), xr[0]) if not self.log_x else s.xs[0]), x0, right))
            b = float(np.clip(tx(min(max(s.xs), xr[1]) if not self.log_x else s.xs[1]), x0, right))
            if b > a:
                d.add(Rect(a, y0, b - a, ph, fillColor=s.color, strokeColor=None, strokeWidth=0))
        elif s.kind == "band_y":
            a = float(np.clip(ty(min(s.ys)), y0, top))
            b = float(np.clip(ty(max(s.ys)), y0, top))
            if b > a:
                d.add(Rect(x0, a, pw, b - a, fillColor=s.color, strokeColor=None, strokeWidth=0))
        elif s.kind == "hline":
            if self.log_y and not s.ys[0] > 0:
                return
            py = float(ty(s.ys[0]))
            if y0 <= py <= top:
                d.add(Line(x0, py, right, py, strokeColor=s.color, strokeWidth=s.width,
                           strokeDashArray=list(s.dash) if s.dash else None))
        elif s.kind == "vline":
            if self.log_x and not s.xs[0] > 0:
                return
            px = float(tx(s.xs[0]))
            if x0 <= px <= right:
                d.add(Line(px, y0, px, top, strokeColor=s.color, strokeWidth=s.width,
                           strokeDashArray=list(s.dash) if s.dash else None))
        elif s.kind == "bars":
            base = float(ty(max(yr[0], 0.0)))
            for a, b, c in zip(s.xs[:-1], s.xs[1:], s.ys, strict=True):
                if c <= 0:
                    continue
                pa, pb = float(np.clip(tx(a), x0, right)), float(np.clip(tx(b), x0, right))
                pc = float(np.clip(ty(c), y0, top))
                d.add(Rect(pa, base, max(pb - pa - 0.4, 0.3), pc - base, fillColor=s.color,
                           strokeColor=None, strokeWidth=0))
        elif s.kind == "line" and s.xs.size:
            xs, ys = decimate(s.xs, s.ys, int(pw))
            lx, ly = np.asarray(tx(xs), dtype=float), np.asarray(ty(ys), dtype=float)
            tol = 0.01
            inside = (lx >= x0 - tol) & (lx <= right + tol) & (ly >= y0 - tol) & (ly <= top + tol)
            # Points outside the axes break the line rather than being pinned to the frame.
            breaks = np.flatnonzero(np.diff(inside.astype(int)) != 0) + 1
            for run in np.split(np.arange(lx.size), breaks):
                if run.size < 2 or not inside[run[0]]:
                    continue
                pts = [round(float(v), 2) for i in run for v in (lx[i], ly[i])]
                d.add(PolyLine(pts, strokeColor=s.color, strokeWidth=s.width,
                               strokeDashArray=list(s.dash) if s.dash else None))
        elif s.kind == "scatter" and s.xs.size:
            lx, ly = tx(s.xs), ty(s.ys)
            h = s.size
            for a, b in zip(np.atleast_1d(lx), np.atleast_1d(ly), strict=True):
                if x0 <= a <= right and y0 <= b <= top:
                    d.add(Rect(float(a) - h / 2, float(b) - h / 2, h, h, fillColor=s.color,
                               strokeColor=None, strokeWidth=0))

    def _legend_rows(self, width: float) -> list[list[_Series]]:
        rows: list[list[_Series]] = []
        used = width + 1
        for s in self._series:
            if not s.label:
                continue
            w = stringWidth(s.label, FONT, 6.5) + 18
            if used + w > width:
                rows.append([])
                used = 0.0
            rows[-1].append(s)
            used += w
        return rows

    def _draw_legend(self, d: Drawing, rows: list[list[_Series]], x: float, top: float) -> None:
        for r, row in enumerate(rows):
            sy = top + 3 + 9.0 * (len(rows) - 1 - r)
            cx = x
            for s in row:
                if s.kind in ("shade_x", "band_y", "bars", "scatter"):
                    d.add(Rect(cx, sy, 8, 5, fillColor=s.color, strokeColor=None, strokeWidth=0))
                else:
                    d.add(Line(cx, sy + 2.5, cx + 9, sy + 2.5, strokeColor=s.color,
                               strokeWidth=1.2,
                               strokeDashArray=list(s.dash) if s.dash else None))
                d.add(String(cx + 11, sy, s.label or "", fontName=FONT, fontSize=6.5))
                cx += stringWidth(s.label or "", FONT, 6.5) + 18


def bar_chart(
    width: float,
    height: float,
    categories: Sequence[str],
    values: Sequence[float],
    title: str = "",
    y_label: str = "",
    color: colors.Color = PALETTE[4],
    value_labels: Sequence[str] | None = None,
) -> Drawing:
    """Vertical bars with category labels (e.g. a failure pareto, largest first).

    `value_labels` replaces the number printed above each bar (e.g. "7 (41 %)").
    """
    d = Drawing(width, height)
    x0, y0 = _LEFT, _BOTTOM + 22
    pw, ph = width - _LEFT - _RIGHT, height - y0 - _TOP
    vmax = max([float(v) for v in values] + [1.0])
    ticks = nice_ticks(0.0, max(vmax, 4.0), target=4)
    if all(float(v).is_integer() for v in values):
        ticks = [t for t in ticks if float(t).is_integer()]  # counts: no 2.5 ticks
    ymax = max(ticks[-1], vmax * 1.12)  # room for the label above the tallest bar
    for t in ticks:
        py = y0 + t / ymax * ph
        d.add(Line(x0, py, x0 + pw, py, strokeColor=GRID, strokeWidth=0.4))
        d.add(String(x0 - 4, py - 2.2, tick_label(t), fontName=FONT, fontSize=6.5,
                     textAnchor="end"))
    n = max(len(categories), 1)
    slot = min(pw / n, 70.0)  # a few categories stay narrow bars, not slabs
    for i, (cat, v) in enumerate(zip(categories, values, strict=True)):
        bx = x0 + i * slot + slot * 0.15
        bh = float(v) / ymax * ph
        d.add(Rect(bx, y0, slot * 0.7, bh, fillColor=color, strokeColor=None, strokeWidth=0))
        text = value_labels[i] if value_labels is not None else tick_label(float(v))
        d.add(String(bx + slot * 0.35, y0 + bh + 2, text, fontName=FONT,
                     fontSize=6.5, textAnchor="middle"))
        label = cat if len(cat) <= 22 else cat[:21] + "."
        g = Group(String(0, 0, label, fontName=FONT, fontSize=6.2, textAnchor="end"))
        g.translate(bx + slot * 0.35 + 2, y0 - 4)
        g.rotate(30)
        d.add(g)
    d.add(Rect(x0, y0, pw, ph, fillColor=None, strokeColor=colors.black, strokeWidth=0.6))
    d.add(String(x0, height - 11, title, fontName=FONT_BOLD, fontSize=8))
    g = Group(String(0, 0, y_label, fontName=FONT, fontSize=7, textAnchor="middle"))
    g.translate(8, y0 + ph / 2)
    g.rotate(90)
    d.add(g)
    return d


def message_box(width: float, height: float, title: str, reason: str) -> Drawing:
    """A framed placeholder saying why a plot is not drawn; never a crash."""
    d = Drawing(width, height)
    d.add(Rect(1, 1, width - 2, height - 14, fillColor=colors.HexColor("#f6f6f6"),
               strokeColor=colors.HexColor("#b0b0b0"), strokeWidth=0.6,
               strokeDashArray=[3, 2]))
    d.add(String(2, height - 10, title, fontName=FONT_BOLD, fontSize=8))
    words, lines, cur = reason.split(), [], ""
    for w in words:
        trial = f"{cur} {w}".strip()
        if stringWidth(trial, FONT, 7.5) > width - 20 and cur:
            lines.append(cur)
            cur = w
        else:
            cur = trial
    if cur:
        lines.append(cur)
    y = (height - 14) / 2 + 6 * len(lines) / 2
    for line in lines[:6]:
        d.add(String(width / 2, y, line, fontName=FONT, fontSize=7.5, textAnchor="middle",
                     fillColor=colors.HexColor("#444444")))
        y -= 10
    return d
