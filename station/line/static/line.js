// The line's dashboard: reads /api/stations, /api/yields, /api/capability, /api/chart and
// /api/runs (simulated runs left out unless the switch asks for them); renders with the DOM
// (textContent only: nothing from the database is parsed as HTML). Nothing loads before a
// sign-in (/api/session, /api/signin); panels above the user's role are hidden (the server
// refuses them anyway): viewer < quality (capability, certificates) < engineer (simulated).
"use strict";

const ROLES = ["viewer", "quality", "engineer"];
const state = { summary: null, group: "station", asked: 0, role: "", csrf: "", timer: null };

function may(needs) { return ROLES.indexOf(state.role) >= ROLES.indexOf(needs); }

function el(tag, attrs = {}, text = "") {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== "") e.textContent = text;
  return e;
}

function pct(x) { return x === null || x === undefined ? "–" : (100 * x).toFixed(1) + " %"; }
function num(x, d = 4) {
  if (x === null || x === undefined) return "–";
  const a = Math.abs(x);
  return a !== 0 && (a < 1e-3 || a >= 1e5) ? x.toExponential(d - 1) : x.toPrecision(d);
}

function query() {
  const data = new FormData(document.getElementById("filters"));
  const q = new URLSearchParams();
  for (const [k, v] of data.entries()) if (v) q.set(k, v);
  return q;
}

async function getJson(path) {
  const r = await fetch(path);
  const body = await r.json();
  if (r.status === 401) showSignIn("");
  if (!r.ok) throw new Error(body.error || r.statusText);
  return body;
}

async function post(path, data) {
  const r = await fetch(path, {
    method: "POST", body: JSON.stringify(data),
    headers: { "Content-Type": "application/json", "X-CSRF-Token": state.csrf },
  });
  const body = await r.json();
  if (!r.ok) throw new Error(body.error || r.statusText);
  return body;
}

function signedIn(session) {
  state.role = session.role;
  state.csrf = session.csrf;
  document.body.dataset.role = session.role;
}

function showSignIn(message) {
  state.role = "";
  document.body.dataset.role = "";
  document.getElementById("top").hidden = true;
  document.getElementById("dashboard").hidden = true;
  document.getElementById("signin").hidden = false;
  document.getElementById("signin-error").textContent = message;
  if (state.timer !== null) { clearInterval(state.timer); state.timer = null; }
}

function showDashboard(user) {
  document.getElementById("signin").hidden = true;
  document.getElementById("top").hidden = false;
  document.getElementById("dashboard").hidden = false;
  document.getElementById("who-name").textContent = `${user} (${state.role})`;
  for (const e of document.querySelectorAll("[data-needs]")) e.hidden = !may(e.dataset.needs);
  if (!may("engineer")) document.querySelector('#filters input[name="simulated"]').checked = false;
  refresh();
  if (state.timer === null) state.timer = setInterval(refresh, 30000);
}

function fillChoices(choices) {
  const form = document.getElementById("filters");
  for (const name of ["product", "station", "lot"]) {
    const sel = form.elements[name];
    const keep = sel.value;
    sel.replaceChildren(el("option", { value: "" }, "all"));
    for (const v of choices[name]) sel.append(el("option", { value: v }, v));
    sel.value = keep;
  }
}

function renderStations(list) {
  const box = document.getElementById("stations");
  box.replaceChildren();
  for (const s of list) {
    const card = el("div", { class: "card", "data-station": s.station_id });
    card.append(el("div", { class: "id" }, s.station_id || "(no id)"));
    card.append(el("div", { class: "state " + s.state.replace(/\s/g, "-") }, s.state));
    if (s.last_seen_utc) card.append(el("div", { class: "note" }, "last sync " + s.last_seen_utc));
    if (s.pending_runs) card.append(el("div", { class: "note" }, s.pending_runs + " runs queued"));
    const dots = el("div", { class: "recent" });
    for (const r of s.recent) {
      dots.append(el("span", { class: "dot " + r.verdict, title: `${r.serial} ${r.verdict} ${r.started_utc}` }));
    }
    card.append(dots);
    if (s.recent.length) {
      const r = s.recent[0];
      card.append(el("div", { class: "note" }, `last: ${r.serial} ${r.verdict} (${r.started_utc})`));
    }
    box.append(card);
  }
}

function renderYields() {
  const y = state.summary.yields;
  const all = y.all[0];
  document.getElementById("yield-all").textContent = all
    ? `${all.units} units, ${all.tests} tests: first-pass yield ${pct(all.first_pass_yield)}, final yield ${pct(all.final_yield)}`
    : "no units";
  if (all) {
    document.getElementById("yield-all").dataset.fpy = pct(all.first_pass_yield);
    document.getElementById("yield-all").dataset.final = pct(all.final_yield);
  }
  const body = document.querySelector("#yields tbody");
  body.replaceChildren();
  for (const r of y[state.group]) {
    const tr = el("tr", { "data-group": r.group });
    tr.append(el("td", {}, r.group || "(none)"), el("td", {}, String(r.units)),
      el("td", {}, String(r.tests)), el("td", { class: "fpy" }, pct(r.first_pass_yield)),
      el("td", { class: "final" }, pct(r.final_yield)));
    body.append(tr);
  }
  for (const b of document.querySelectorAll("#yield-tabs button")) {
    b.classList.toggle("on", b.dataset.group === state.group);
  }
}

function renderCapability() {
  document.getElementById("cpk-note").textContent =
    `Cpk = min(USL − mean, mean − LSL) / 3 sd over the ${state.summary.window}; interval: ${state.summary.cpk_interval}.`;
  const body = document.querySelector("#capability tbody");
  body.replaceChildren();
  for (const c of state.summary.capability) {
    const tr = el("tr", { "data-name": c.name, "data-condition": c.condition });
    const limits = `${c.low === null ? "" : num(c.low)} … ${c.high === null ? "" : num(c.high)} ${c.units}`;
    const ci = c.cpk === null ? "–" : `${c.ci_low.toFixed(2)} – ${c.ci_high.toFixed(2)}`;
    tr.append(el("td", {}, c.name), el("td", {}, c.condition || ""), el("td", {}, String(c.n)),
      el("td", {}, num(c.mean)), el("td", {}, num(c.sd)), el("td", {}, limits),
      el("td", { class: "cpk" }, c.cpk === null ? c.reason || "–" : c.cpk.toFixed(2)),
      el("td", { class: "ci" }, ci));
    body.append(tr);
  }
}

// About `target` round values (1, 2, 2.5, 5 x 10^k) covering [lo, hi], for the chart's axis.
function niceTicks(lo, hi, target = 5) {
  if (!(isFinite(lo) && isFinite(hi)) || hi <= lo) return [lo];
  const raw = (hi - lo) / target;
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => s >= raw);
  const out = [];
  for (let i = Math.ceil(lo / step - 1e-9); i <= Math.floor(hi / step + 1e-9); i++) out.push(i === 0 ? 0 : i * step);
  return out;
}
// An axis value: as many digits as the tick step needs, never "-0".
function tickLabel(v, step) {
  if (v === 0) return "0";
  const a = Math.abs(v);
  if (a >= 1e5 || a < 1e-3) {
    const e = v.toExponential(Math.max(0, Math.min(6, Math.ceil(-Math.log10(step / a)))));
    return e.replace(/(\.\d*?)0+e/, "$1e").replace(/\.e/, "e");
  }
  const s = v.toFixed(Math.max(0, Math.min(10, Math.ceil(-Math.log10(step)) + 1)));
  return s.replace(/(\.\d*?)0+$/, "$1").replace(/\.$/, "");
}

// The chart's frame: pixel scales over the values, the limits and the product's limits.
function chartFrame(data) {
  const W = 900, H = 280, top = 16, bottom = 48, left = 78, right = 104;
  const pts = data.points;
  const edges = [data.centre - 3.5 * data.sigma, data.centre + 3.5 * data.sigma,
    data.product_low, data.product_high, ...pts.map((p) => p.value)].filter((v) => v !== null && isFinite(v));
  const lo = Math.min(...edges), hi = Math.max(...edges);
  const span = hi - lo || 1;
  return {
    W, H, top, bottom, left, right, lo, hi,
    x: (i) => left + (i * (W - left - right)) / Math.max(1, pts.length - 1),
    y: (v) => H - bottom - ((v - lo) * (H - top - bottom)) / span,
  };
}

function svgAdd(svg, tag, attrs, text = "") {
  const e = document.createElementNS("http://www.w3.org/2000/svg", tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== "") e.textContent = text;
  svg.append(e);
  return e;
}

function chartText(svg, x, y, s, attrs = {}) {
  return svgAdd(svg, "text", { x, y, "font-size": 11, fill: "#333", ...attrs }, s);
}

// A horizontal line across the plot at value v, labelled at its right end.
function chartLevel(svg, f, v, cls, stroke, dash, label) {
  svgAdd(svg, "line", { x1: f.left, x2: f.W - f.right, y1: f.y(v), y2: f.y(v), stroke,
    "stroke-dasharray": dash, class: cls, "data-value": v });
  if (label) chartText(svg, f.W - f.right + 4, f.y(v) + 4, label, { fill: stroke, class: "chart-line-label " + cls });
}

// The value axis: its line, round ticks with their values, the coefficient and its units.
function chartValueAxis(svg, f, data) {
  const ticks = niceTicks(f.lo, f.hi, 5);
  const step = ticks.length > 1 ? ticks[1] - ticks[0] : f.hi - f.lo || 1;
  for (const t of ticks) {
    chartLevel(svg, f, t, "chart-grid", "#eee", "");
    chartText(svg, f.left - 6, f.y(t) + 4, tickLabel(t, step), { "text-anchor": "end", class: "chart-tick", "data-value": t });
  }
  svgAdd(svg, "line", { x1: f.left, x2: f.left, y1: f.top, y2: f.H - f.bottom, stroke: "#333", class: "chart-axis-line" });
  const units = data.units && data.units !== "1" ? data.units : "dimensionless";
  chartText(svg, 14, (f.H - f.bottom + f.top) / 2, `${data.coefficient} (${units})`,
    { transform: `rotate(-90 14 ${(f.H - f.bottom + f.top) / 2})`, "text-anchor": "middle", class: "chart-axis chart-units" });
  return step;
}

// The time axis: each test's start (UTC) at about six evenly spaced points.
function chartTimeAxis(svg, f, pts) {
  const base = f.H - f.bottom;
  svgAdd(svg, "line", { x1: f.left, x2: f.W - f.right, y1: base, y2: base, stroke: "#333", class: "chart-axis-line" });
  const every = Math.max(1, Math.ceil((pts.length - 1) / 5));
  for (let i = 0; i < pts.length; i += every) {
    svgAdd(svg, "line", { x1: f.x(i), x2: f.x(i), y1: base, y2: base + 4, stroke: "#333" });
    const when = pts[i].started_utc.slice(5, 16).replace("T", " ");
    chartText(svg, f.x(i), base + 16, when, { "text-anchor": "middle", class: "chart-xtick", "data-index": i });
  }
  chartText(svg, (f.left + f.W - f.right) / 2, f.H - 8,
    `first test started (UTC, MM-DD hh:mm), oldest to newest (${pts.length} tests)`, { "text-anchor": "middle", class: "chart-axis" });
}

// Centre, the control limits (centre +/- 3 sigma, and 1, 2 sigma faint) and the product's limits.
function chartLimits(svg, f, data, step) {
  const v = (x) => tickLabel(x, step / 10);
  for (const k of [1, 2]) {
    chartLevel(svg, f, data.centre + k * data.sigma, "chart-sigma", "#bbb", "2 4");
    chartLevel(svg, f, data.centre - k * data.sigma, "chart-sigma", "#bbb", "2 4");
  }
  chartLevel(svg, f, data.centre, "chart-centre", "#555", "4 3", "centre " + v(data.centre));
  chartLevel(svg, f, data.ucl, "chart-ucl", "#c62828", "6 3", "UCL " + v(data.ucl));
  chartLevel(svg, f, data.lcl, "chart-lcl", "#c62828", "6 3", "LCL " + v(data.lcl));
  if (data.product_high !== null) chartLevel(svg, f, data.product_high, "chart-usl", "#6a1b9a", "", "USL " + v(data.product_high));
  if (data.product_low !== null) chartLevel(svg, f, data.product_low, "chart-lsl", "#6a1b9a", "", "LSL " + v(data.product_low));
}

function chartPoints(svg, f, pts) {
  const list = document.getElementById("violations");
  svgAdd(svg, "polyline", { points: pts.map((p, i) => `${f.x(i)},${f.y(p.value)}`).join(" "), fill: "none", stroke: "#0b6bcb" });
  pts.forEach((p, i) => {
    const c = svgAdd(svg, "circle", { cx: f.x(i), cy: f.y(p.value), r: p.rules.length ? 4 : 2.5,
      fill: p.rules.length ? "#c62828" : "#0b6bcb", "data-value": p.value });
    const t = document.createElementNS("http://www.w3.org/2000/svg", "title");
    t.textContent = `${p.serial} ${p.started_utc} ${num(p.value)}${p.rules.length ? " rules " + p.rules.join(",") : ""}`;
    c.append(t);
    if (p.rules.length) list.append(el("li", {}, `${p.started_utc} ${p.serial}: rule ${p.rules.join(", ")}`));
  });
}

function renderChart(data) {
  const svg = document.getElementById("chart");
  svg.replaceChildren();
  document.getElementById("violations").replaceChildren();
  if (!data.points.length) return;
  const f = chartFrame(data);
  const step = chartValueAxis(svg, f, data);
  chartTimeAxis(svg, f, data.points);
  chartLimits(svg, f, data, step);
  chartPoints(svg, f, data.points);
}

function renderSimulated(included, leftOut) {
  const note = document.getElementById("simulated-note");
  note.textContent = included ? "simulated runs included: these numbers are not production"
    : leftOut ? `${leftOut} simulated runs left out` : "";
  note.classList.toggle("warn", included);
}

function renderRuns(runs) {
  const body = document.querySelector("#runs tbody");
  body.replaceChildren();
  for (const r of runs) {
    const tr = el("tr", { "data-run": r.run_id });
    const cell = el("td");
    if (may("quality")) {
      cell.append(el("a", { href: "/certificate/" + encodeURIComponent(r.run_id), target: "_blank" }, "PDF"));
    }
    tr.append(el("td", {}, r.started_utc), el("td", {}, r.station_id), el("td", {}, r.serial),
      el("td", {}, r.product), el("td", {}, r.lot), el("td", {}, r.attempt === 1 ? "first" : "retest " + (r.attempt - 1)),
      el("td", { class: "verdict-" + r.verdict }, r.verdict), cell);
    body.append(tr);
  }
}

async function refresh() {
  const status = document.getElementById("status");
  const q = query();
  const coef = document.getElementById("coefficient");
  const asked = ++state.asked;
  try {
    const t0 = performance.now();
    const chartQuery = new URLSearchParams(q);
    chartQuery.set("coefficient", coef.value || "bias_dps");
    const [stations, yields, capability, runs, chart] = await Promise.all([
      getJson("/api/stations?" + q), getJson("/api/yields?" + q),
      may("quality") ? getJson("/api/capability?" + q) : {}, getJson("/api/runs?" + q),
      getJson("/api/chart?" + chartQuery)]);
    if (asked !== state.asked) return; // a newer refresh (other filters) is under way
    state.summary = { yields, ...capability };
    fillChoices(stations.choices);
    renderSimulated(q.get("simulated") === "include", stations.simulated_left_out);
    renderStations(stations.stations);
    renderYields();
    if (may("quality")) renderCapability();
    renderRuns(runs.runs);
    if (!coef.options.length) for (const c of stations.coefficients) coef.append(el("option", { value: c }, c));
    renderChart(chart);
    status.textContent = `updated ${new Date().toISOString().slice(11, 19)} UTC in ${((performance.now() - t0) / 1000).toFixed(2)} s`;
    document.body.dataset.query = q.toString();
    document.body.dataset.loaded = "1";
  } catch (err) {
    status.textContent = "could not load: " + err.message;
  }
}

document.getElementById("filters").addEventListener("submit", (e) => { e.preventDefault(); refresh(); });
document.getElementById("yield-tabs").addEventListener("click", (e) => {
  if (e.target.dataset.group && state.summary) { state.group = e.target.dataset.group; renderYields(); }
});
document.getElementById("coefficient").addEventListener("change", refresh);
document.querySelector('#filters input[name="simulated"]').addEventListener("change", refresh);
document.getElementById("signin").addEventListener("submit", async (e) => {
  e.preventDefault();
  const form = e.target;
  try {
    const session = await post("/api/signin", { name: form.elements.name.value, password: form.elements.password.value });
    form.elements.password.value = "";
    signedIn(session);
    showDashboard(session.user);
  } catch (err) {
    document.getElementById("signin-error").textContent = err.message;
  }
});
document.getElementById("signout").addEventListener("click", async () => {
  try { await post("/api/signout", {}); } finally { location.reload(); }
});

async function start() {
  try {
    const r = await fetch("/api/session");
    const session = await r.json();
    if (!r.ok) throw new Error(session.error || r.statusText);
    signedIn(session);
    if (session.role) showDashboard(session.user); else showSignIn("");
  } catch (err) {
    showSignIn("cannot reach the dashboard: " + err.message);
  }
}
start();
