// Operator screen: state comes from the server as a snapshot, then as pushed events (SSE).
"use strict";
const $ = (id) => document.getElementById(id);
const S = { station: null, selection: null, run: null, last: null, instruments: [], chart: {}, role: "operator",
  csrf: "", operator: "", operatorsOpen: true, operatorRequired: false };
const sockets = {};  // socket number -> {root, input, msg, ...}
let progressAt = 0;  // performance.now() when the last progress event arrived
// Timings for the benchmark: Start pressed -> run acknowledged / first progress / first engine step.
window.__ui = { startClickedAt: null, firstProgressMs: null, firstRunEventMs: null, firstStepMs: null, events: 0 };

async function call(path, body) {
  const opt = body === undefined ? {} : { method: "POST", headers: { "Content-Type": "application/json", "X-CSRF-Token": S.csrf }, body: JSON.stringify(body) };
  const r = await fetch(path, opt);
  let data = {};
  try { data = await r.json(); } catch (e) { data = { error: "the station answered " + r.status }; }
  return { ok: r.ok, status: r.status, data };
}

// Every command needs the session's CSRF token; a station restarted since the page loaded
// has forgotten the session: open a new one and send the command once more.
async function api(path, body) {
  const r = await call(path, body);
  if (body !== undefined && (r.status === 401 || r.status === 403) && /no session|X-CSRF-Token/.test(r.data.error || "")) {
    if (await openSession()) return call(path, body);
  }
  return r;
}

async function openSession() {
  const r = await call("/api/session");
  if (r.ok) applySession(r.data);
  return r.ok;
}

function applySession(d) {
  S.csrf = d.csrf; S.role = d.role; S.operator = d.operator || "";
  S.operatorsOpen = !!d.operators_open; S.operatorRequired = !!d.operator_required;
  renderRole(); renderOperator();
}

// ---------------------------------------------------------------- rendering
function buildSockets() {
  const box = $("sockets"), tpl = $("socket-tpl");
  for (const n of S.station.sockets) {
    if (sockets[n]) continue;
    const root = tpl.content.firstElementChild.cloneNode(true);
    root.id = "socket-" + n;
    root.querySelector(".socket-no").textContent = n;
    const s = {
      root, input: root.querySelector(".serial"), msg: root.querySelector(".serial-msg"),
      box: root.querySelector(".verdict-box"), verdict: root.querySelector(".verdict"),
      vserial: root.querySelector(".verdict-serial"), reasons: root.querySelector(".reasons"),
      cert: root.querySelector(".certificate"), canvas: root.querySelector(".chart"),
    };
    s.input.id = "serial-" + n;
    s.input.addEventListener("keydown", (e) => { if (e.key === "Enter") { e.preventDefault(); validate(n); } });
    s.input.addEventListener("input", () => { s.input.classList.remove("ok", "bad"); s.msg.textContent = ""; });
    sockets[n] = s;
    box.appendChild(root);
  }
}

function renderInstruments() {
  const box = $("instruments");
  box.textContent = "";
  for (const i of S.instruments) {
    const d = document.createElement("div");
    d.className = "inst";
    d.dataset.name = i.name;
    d.title = i.detail || "";
    const cal = i.in_calibration === null ? "warn" : i.in_calibration ? "on" : "bad";
    d.innerHTML = "<b></b>" +
      `<span class="light ${i.connected ? "on" : "bad"}" data-light="connected"></span>connected` +
      `<span class="light ${cal}" data-light="calibration"></span>in cal` +
      `<span class="light ${i.faulted ? "bad" : ""}" data-light="fault"></span>fault`;
    d.querySelector("b").textContent = i.name + (i.calibration_due ? " (due " + i.calibration_due + ")" : "");
    box.appendChild(d);
  }
}

function renderSelection() {
  const sel = S.selection || {};
  $("procedure-name").textContent = sel.procedure_name || sel.procedure || "-";
  $("product-name").textContent = sel.product_name || sel.product || "-";
  $("serial-pattern").textContent = sel.serial_example ? "like " + sel.serial_example : sel.serial_pattern || "-";
  $("serial-pattern").title = sel.serial_pattern || "";
}

function renderRole() {
  const eng = S.role === "engineer";
  $("role-badge").textContent = eng ? "ENGINEER" : "OPERATOR";
  $("role-badge").classList.toggle("engineer", eng);
  $("engineer-btn").textContent = eng ? "Log out" : "Engineer";
  $("engineer-panel").hidden = !eng;
  if (eng) loadChoices(); else { $("procedure-select").textContent = ""; $("product-select").textContent = ""; }
}

function renderOperator() {
  $("operator-name").textContent = S.operator || (S.operatorRequired ? "not signed in" : "-");
  $("signin-btn").textContent = S.operator ? "Sign out" : "Sign in";
  $("badge-row").hidden = S.operatorsOpen;
  $("pin-row").hidden = S.operatorsOpen;
  $("signin-title").textContent = S.operatorsOpen ? "Operator sign-in: your name" : "Operator sign-in: scan your badge, or enter your name and PIN";
}

async function signinButton() {
  if (S.operator) { const r = await api("/api/signout", {}); if (r.ok) applySession(r.data); return; }
  for (const id of ["badge", "operator-input", "pin"]) $(id).value = "";
  $("signin-msg").textContent = "";
  $("signin-dialog").showModal();
  (S.operatorsOpen ? $("operator-input") : $("badge")).focus();
}

async function signin(e) {
  e.preventDefault();
  const badge = $("badge").value.trim(), name = $("operator-input").value.trim(), pin = $("pin").value;
  const body = !S.operatorsOpen && badge ? { badge } : S.operatorsOpen ? { name } : { name, pin };
  const r = await api("/api/signin", body);
  $("pin").value = ""; $("badge").value = "";
  if (!r.ok) { $("signin-msg").textContent = r.data.error; return; }
  $("signin-dialog").close();
  applySession(r.data);
}

function renderRun() {
  const run = S.run;
  const running = !!run;
  $("start-btn").disabled = running;
  $("abort-btn").disabled = !running || run.aborting;
  $("apply-selection").disabled = running;
  for (const n in sockets) {
    sockets[n].input.disabled = running;
    // A part dropped mid-run (e.g. it stopped streaming) shows here while the others go on.
    const st = running && run.progress && run.progress.sockets ? run.progress.sockets[n] || "" : "";
    const badge = sockets[n].root.querySelector(".socket-state");
    badge.textContent = st; badge.className = "socket-state " + st;
  }
  $("progress").hidden = !running;
  if (!running) return;
  for (const [n, serial] of Object.entries(run.serials)) if (sockets[n]) sockets[n].input.value = serial;
  const p = run.progress;
  $("step-name").textContent = run.aborting ? "Aborting: cleaning up..." : p ? p.step : "Starting...";
  $("condition-name").textContent = p && p.condition ? p.condition : "";
  $("bar-fill").style.width = (p ? Math.max(0, Math.min(1, p.fraction)) * 100 : 0) + "%";
  const list = $("step-list");
  list.textContent = "";
  const current = p ? p.step_index : -1;
  run.steps.forEach((name, i) => {
    const li = document.createElement("li");
    li.textContent = name;
    li.className = i < current ? "done" : i === current ? "current" : "";
    list.appendChild(li);
  });
  renderRemaining();
}

function renderRemaining() {
  const p = S.run && S.run.progress;
  if (!p || p.remaining_s === null || p.remaining_s === undefined) { $("remaining").textContent = ""; return; }
  const left = Math.max(0, p.remaining_s - (performance.now() - progressAt) / 1000);
  const m = Math.floor(left / 60), s = Math.floor(left % 60);
  $("remaining").textContent = (m ? m + " min " : "") + s + " s left";
}

function renderLast() {
  for (const n in sockets) sockets[n].box.hidden = true;
  const last = S.last;
  const safe = $("safe-state");
  safe.hidden = !(last && last.safe_state);
  if (last && last.safe_state) {
    const st = last.safe_state;
    safe.className = "safe-state " + (st.all ? "ok" : "bad");
    safe.textContent = st.all ? "Bench safe: table stopped, supply off, chamber safe"
      : "Bench NOT safe: " + Object.keys(st).filter((k) => k !== "all" && !st[k]).join(", ").replace(/_/g, " ");
  }
  if (last && last.message) $("message").textContent = last.message;
  if (!last) return;
  for (const r of last.results) {
    const s = sockets[r.socket];
    if (!s) continue;
    s.box.hidden = false;
    s.box.className = "verdict-box " + r.verdict;
    s.verdict.textContent = r.verdict;
    s.vserial.textContent = r.serial;
    s.reasons.textContent = "";
    const lines = r.failed.map((f) => `${f.name}${f.condition ? " @ " + f.condition : ""}: ${num(f.value)} ${f.units} (limits ${num(f.low)} .. ${num(f.high)})`);
    if (r.reason && !lines.length) lines.push(r.reason);  // the failing measurements say it all
    for (const line of lines) { const li = document.createElement("li"); li.textContent = line; s.reasons.appendChild(li); }
    s.cert.hidden = !r.certificate_url;
    if (r.certificate_url) s.cert.href = r.certificate_url;
  }
}

function num(v) { return v === null || v === undefined ? "-" : Math.abs(v) >= 1e4 || (Math.abs(v) < 1e-3 && v !== 0) ? v.toExponential(3) : +v.toPrecision(5); }

function renderCharts() { for (const n in sockets) drawChart(sockets[n].canvas, S.chart[n]); }

function renderAll() {
  $("station-name").textContent = S.station.name;
  $("sim-badge").hidden = !S.station.simulated;
  buildSockets(); renderInstruments(); renderSelection(); renderRun(); renderLast(); renderCharts();
}

// ---------------------------------------------------------------- live events
function apply(ev) {
  window.__ui.events++;
  switch (ev.type) {
    case "snapshot":
      Object.assign(S, { station: ev.station, selection: ev.selection, run: ev.run, last: ev.last, instruments: ev.instruments, chart: ev.chart || {} });
      progressAt = performance.now();
      renderAll();
      break;
    case "run":
      if (ev.run && window.__ui.startClickedAt !== null && window.__ui.firstRunEventMs === null) window.__ui.firstRunEventMs = performance.now() - window.__ui.startClickedAt;
      if (ev.run && (!S.run || S.run.started_utc !== ev.run.started_utc)) { S.chart = {}; S.last = null; renderLast(); renderCharts(); }
      S.run = ev.run; renderRun(); break;
    case "steps": if (S.run) { S.run.steps = ev.steps; renderRun(); } break;
    case "progress":
      if (window.__ui.startClickedAt !== null) {
        const dt = performance.now() - window.__ui.startClickedAt;
        if (window.__ui.firstProgressMs === null) window.__ui.firstProgressMs = dt;
        if (window.__ui.firstStepMs === null && ev.step_index >= 1) window.__ui.firstStepMs = dt;
      }
      if (S.run) { S.run.progress = ev; progressAt = performance.now(); renderRun(); }
      break;
    case "samples": {
      const c = S.chart[ev.socket] || (S.chart[ev.socket] = { t_s: [], rate_dps: [], temp_c: [] });
      for (const k of ["t_s", "rate_dps", "temp_c"]) c[k].push(...ev[k]);
      if (c.t_s.length > 1500) for (const k in c) c[k] = c[k].filter((_, i) => i % 2 === 0);
      scheduleCharts();
      break;
    }
    case "instruments": S.instruments = ev.instruments; renderInstruments(); break;
    case "last": S.last = ev.last; renderLast(); break;
    case "selection": S.selection = ev.selection; renderSelection(); if (S.role === "engineer") loadChoices(); break;
    case "finished":
      S.run = null; S.last = ev.last; renderRun(); renderLast(); readyForNext(); break;
  }
}

let chartQueued = false;
function scheduleCharts() { if (!chartQueued) { chartQueued = true; requestAnimationFrame(() => { chartQueued = false; renderCharts(); }); } }

function readyForNext() {
  for (const n in sockets) { const s = sockets[n]; s.input.value = ""; s.input.classList.remove("ok", "bad"); s.msg.textContent = ""; }
  const first = Object.keys(sockets)[0];
  if (first) sockets[first].input.focus();
}

function connect() {
  const es = new EventSource("/api/events");
  es.onopen = () => { $("conn").hidden = true; };
  es.onmessage = (m) => apply(JSON.parse(m.data));
  es.onerror = () => { $("conn").hidden = false; };
}

// ---------------------------------------------------------------- commands
async function validate(n) {
  const s = sockets[n];
  const r = await api("/api/validate", { socket: +n, serial: s.input.value });
  s.input.classList.toggle("ok", r.ok);
  s.input.classList.toggle("bad", !r.ok);
  s.msg.textContent = r.ok ? "" : r.data.error;
  if (!r.ok) { s.input.select(); return false; }
  s.input.value = r.data.serial;
  const keys = Object.keys(sockets);
  const next = keys.find((k) => +k > +n && !sockets[k].input.value);
  (next ? sockets[next].input : $("start-btn")).focus();
  return true;
}

async function start() {
  $("message").textContent = "";
  const serials = {};
  for (const n in sockets) serials[n] = sockets[n].input.value;
  window.__ui.startClickedAt = performance.now();
  window.__ui.firstProgressMs = null; window.__ui.firstRunEventMs = null; window.__ui.firstStepMs = null;
  const r = await api("/api/start", { serials });
  if (!r.ok) {
    window.__ui.startClickedAt = null;
    $("message").textContent = r.data.error;
    if (r.data.socket && sockets[r.data.socket]) {
      const s = sockets[r.data.socket];
      s.input.classList.add("bad"); s.msg.textContent = r.data.error;
    }
  }
}

async function abortRun() {
  $("abort-dialog").close();
  const r = await api("/api/abort", {});
  if (!r.ok) $("message").textContent = r.data.error;
}

async function loadChoices() {
  const r = await api("/api/choices");
  if (!r.ok) { $("selection-msg").textContent = r.data.error; return; }
  fill($("procedure-select"), r.data.procedures, r.data.selection.procedure);
  fill($("product-select"), r.data.products, r.data.selection.product);
}

function fill(select, items, current) {
  // a choice the engineer made but has not applied yet survives a refresh of the list
  const pending = select.dataset.dirty === "1" ? select.value : null;
  const keep = pending !== null && items.some((it) => it.path === pending) ? pending : current;
  select.textContent = "";
  for (const it of items) { const o = new Option(it.name, it.path); o.selected = it.path === keep; select.appendChild(o); }
}

async function applySelection() {
  const body = { procedure: $("procedure-select").value, product: $("product-select").value };
  $("procedure-select").dataset.dirty = ""; $("product-select").dataset.dirty = "";
  const r = await api("/api/select", body);
  $("selection-msg").textContent = r.ok ? "Applied" : r.data.error;
}

async function engineerButton() {
  if (S.role === "engineer") { const r = await api("/api/logout", {}); if (r.ok) applySession(r.data); return; }
  $("login-msg").textContent = ""; $("password").value = "";
  $("login-dialog").showModal();
}

async function login(e) {
  e.preventDefault();
  const r = await api("/api/login", { password: $("password").value });
  if (!r.ok) { $("login-msg").textContent = r.data.error; return; }
  $("login-dialog").close();
  applySession(r.data);
}

// ---------------------------------------------------------------- wiring
$("start-btn").addEventListener("click", start);
$("abort-btn").addEventListener("click", () => $("abort-dialog").showModal());
$("abort-confirm").addEventListener("click", abortRun);
$("abort-cancel").addEventListener("click", () => $("abort-dialog").close());
$("engineer-btn").addEventListener("click", engineerButton);
$("login-form").addEventListener("submit", login);
$("login-cancel").addEventListener("click", () => $("login-dialog").close());
$("apply-selection").addEventListener("click", applySelection);
for (const id of ["procedure-select", "product-select"]) {
  $(id).addEventListener("change", () => { $(id).dataset.dirty = "1"; });
}
$("signin-btn").addEventListener("click", signinButton);
$("signin-form").addEventListener("submit", signin);
$("signin-cancel").addEventListener("click", () => $("signin-dialog").close());
// A scan while no field has the focus (after a touch elsewhere) goes to the first empty socket.
document.addEventListener("keydown", (e) => {
  const t = e.target;
  if (e.key.length !== 1 || e.ctrlKey || e.altKey || e.metaKey) return;
  if (t instanceof HTMLInputElement || t instanceof HTMLSelectElement || t instanceof HTMLTextAreaElement) return;
  if (document.querySelector("dialog[open]")) return;
  const empty = Object.values(sockets).find((s) => !s.input.disabled && !s.input.value);
  if (empty) empty.input.focus();
});
setInterval(renderRemaining, 1000);
window.addEventListener("resize", scheduleCharts);
// The session first (its token signs every command), then the live state.
openSession().then(() => {
  connect();
  if (S.operatorRequired && !S.operator) signinButton();  // a badge scan signs in at once
});
