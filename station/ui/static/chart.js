// Tiny two-axis line chart on a canvas: rate (left axis) and part temperature (right axis);
// time (x) is counted from the run's start (the station sends it so) and shown as min:s.
"use strict";
function drawChart(canvas, data) {
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth || canvas.width, h = canvas.clientHeight || canvas.height;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) { canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr); }
  const g = canvas.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, w, h);
  const t = (data && data.t_s) || [];
  const pad = { l: 64, r: 56, t: 10, b: 26 };
  g.font = "16px system-ui,sans-serif";
  g.strokeStyle = "#d1d5db";
  g.strokeRect(pad.l, pad.t, w - pad.l - pad.r, h - pad.t - pad.b);
  if (t.length < 2) {
    g.fillStyle = "#6b7280";
    g.fillText(typeof window.t === "function" ? window.t("chart.waiting") : "waiting for samples", pad.l + 8, pad.t + 22);
    return;
  }
  const t0 = t[0], t1 = t[t.length - 1] > t0 ? t[t.length - 1] : t0 + 1;
  const x = (v) => pad.l + ((v - t0) / (t1 - t0)) * (w - pad.l - pad.r);
  const series = [
    { v: data.rate_dps, color: "#2563eb", side: "l" },
    { v: data.temp_c, color: "#ea580c", side: "r" },
  ];
  for (const s of series) {
    let lo = Infinity, hi = -Infinity;
    for (const v of s.v) if (v !== null && isFinite(v)) { if (v < lo) lo = v; if (v > hi) hi = v; }
    if (!isFinite(lo)) continue;
    if (hi - lo < 1e-6) { lo -= 0.5; hi += 0.5; }
    const m = (hi - lo) * 0.05; lo -= m; hi += m;
    const y = (v) => pad.t + (1 - (v - lo) / (hi - lo)) * (h - pad.t - pad.b);
    g.strokeStyle = s.color; g.lineWidth = 1.5; g.beginPath();
    let pen = false;
    for (let i = 0; i < t.length; i++) {
      const v = s.v[i];
      if (v === null || !isFinite(v)) { pen = false; continue; }
      if (pen) g.lineTo(x(t[i]), y(v)); else { g.moveTo(x(t[i]), y(v)); pen = true; }
    }
    g.stroke();
    g.fillStyle = s.color;
    const tx = s.side === "l" ? 2 : w - pad.r + 4;
    g.fillText(fmt(hi - m), tx, pad.t + 14);
    g.fillText(fmt(lo + m), tx, h - pad.b);
  }
  g.fillStyle = "#6b7280";
  g.fillText(clock(t0), pad.l, h - 6);
  g.fillText(clock(t1), w - pad.r - 48, h - 6);
}
// An axis value: two significant digits below 0.01 (toFixed(2) made -0.001 read "-0.00"),
// and never a minus on a zero.
function fmt(v) {
  const a = Math.abs(v);
  const s = a >= 1000 ? v.toFixed(0) : a >= 10 ? v.toFixed(1) : a >= 0.01 ? v.toFixed(2) : a >= 1e-12 ? v.toPrecision(2) : "0";
  return /^-0(\.0*)?$/.test(s) ? s.slice(1) : s;
}
function clock(s) { const v = Math.max(0, Math.round(s)); return Math.floor(v / 60) + ":" + String(v % 60).padStart(2, "0"); }
