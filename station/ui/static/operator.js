// Operator screen: state comes from the server as a snapshot, then as pushed events (SSE).
// Every word the operator reads comes from the message catalog (GET /api/messages); the
// server sends facts as phrases {key, params} (station/ui/plain_words.py) rendered here.
"use strict";
const $ = (id) => document.getElementById(id);
const S = { station: null, selection: null, run: null, last: null, instruments: [], chart: {}, role: "operator",
  csrf: "", operator: "", operatorsOpen: true, operatorRequired: false, engineerLogin: false };
const sockets = {};  // socket number -> {root, input, msg, ...}
let progressAt = 0;  // performance.now() when the last progress event arrived
let detailSocket = null;  // the socket whose detail view is open
let M = {};  // the message catalog of this page's language
// Timings for the benchmark: Start pressed -> run acknowledged / first progress / first engine step.
window.__ui = { startClickedAt: null, firstProgressMs: null, firstRunEventMs: null, firstStepMs: null, events: 0 };

// ---------------------------------------------------------------- words
function t(key, params) {
  const text = Object.prototype.hasOwnProperty.call(M, key) ? M[key] : key;
  return text.replace(/\{(\w+)\}/g, (all, name) => {
    const v = params ? params[name] : undefined;
    if (v === undefined || v === null) return "";
    if (typeof v === "object") return say(v);
    // a decimal number as the language writes it (5.25 -> 5,25 in German)
    return /^[-+]?\d+\.\d+$/.test(String(v)) ? String(v).replace(".", M["number.decimal"] || ".") : String(v);
  }).replace(/ +/g, " ").trim();
}
function say(phrase) { return phrase && phrase.key ? t(phrase.key, phrase.params) : ""; }
function sayAll(phrases) { return (phrases || []).map(say).filter((s) => s).join(", "); }

async function loadCatalog() {
  const langs = (navigator.languages && navigator.languages.length ? navigator.languages : [navigator.language || "en"]).join(",");
  const r = await call("/api/messages?lang=" + encodeURIComponent(langs));
  if (!r.ok) return;
  M = r.data.messages || {};
  document.documentElement.lang = r.data.language || "en";
  document.title = t("page.title");
  for (const el of document.querySelectorAll("[data-i18n]")) el.textContent = t(el.dataset.i18n);
  for (const el of document.querySelectorAll("[data-i18n-label]")) el.setAttribute("aria-label", t(el.dataset.i18nLabel));
}

// ---------------------------------------------------------------- server calls
async function call(path, body) {
  const opt = body === undefined ? {} : { method: "POST", headers: { "Content-Type": "application/json", "X-CSRF-Token": S.csrf }, body: JSON.stringify(body) };
  const r = await fetch(path, opt);
  let data = {};
  try { data = await r.json(); } catch (e) { data = { error: t("error.answer", { status: r.status }) }; }
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
  S.engineerLogin = !!d.engineer_login;
  renderRole(); renderOperator(); renderStart();
}

// ---------------------------------------------------------------- layout
// Columns x rows for n sockets on one screen: 8 is 4 x 2, 16 is 4 x 4, 32 is 8 x 4.
function gridFor(n) {
  const cols = n <= 1 ? 1 : n <= 4 ? 2 : n <= 8 ? 4 : n <= 16 ? 4 : n <= 24 ? 6 : 8;
  return { cols, rows: Math.max(1, Math.ceil(n / cols)) };
}

function buildSockets() {
  const box = $("sockets"), tpl = $("socket-tpl");
  for (const n of S.station.sockets) {
    if (sockets[n]) continue;
    const root = tpl.content.firstElementChild.cloneNode(true);
    root.id = "socket-" + n;
    root.dataset.socket = n;
    root.querySelector(".socket-label").textContent = t("socket.label", { n });
    for (const el of root.querySelectorAll("[data-i18n]")) el.textContent = t(el.dataset.i18n);
    const s = {
      root, input: root.querySelector(".serial"), msg: root.querySelector(".serial-msg"),
      step: root.querySelector(".socket-step"), state: root.querySelector(".socket-state"),
      fixture: root.querySelector(".fixture-light"),
      box: root.querySelector(".verdict-box"), verdict: root.querySelector(".verdict"),
      vserial: root.querySelector(".verdict-serial"), disposition: root.querySelector(".disposition"),
      reasons: root.querySelector(".reasons"), cert: root.querySelector(".certificate"),
      canvas: root.querySelector(".mini-chart"),
    };
    s.input.id = "serial-" + n;
    s.input.placeholder = t("socket.scan");
    s.input.addEventListener("keydown", (e) => { if (e.key === "Enter") { e.preventDefault(); validate(n); } });
    s.input.addEventListener("input", () => { s.input.classList.remove("ok", "bad", "dup"); s.msg.textContent = ""; renderStart(); });
    root.addEventListener("click", (e) => {
      if (e.target.closest("input, a")) return;  // scanning and the certificate link stay theirs
      openDetail(n);
    });
    sockets[n] = s;
    box.appendChild(root);
  }
  const count = S.station.sockets.length, g = gridFor(count);
  box.style.gridTemplateColumns = `repeat(${g.cols}, minmax(0, 1fr))`;
  box.style.gridTemplateRows = `repeat(${g.rows}, minmax(0, 1fr))`;
  box.classList.toggle("roomy", count <= 4);  // room for each socket's live chart
  box.classList.toggle("dense", count > 8);
  box.classList.toggle("denser", count > 16);
}

// ---------------------------------------------------------------- rendering
function renderInstruments() {
  const box = $("instruments");
  box.textContent = "";
  for (const n in sockets) sockets[n].fixture.hidden = true;
  for (const i of S.instruments) {
    const own = i.socket !== null && i.socket !== undefined ? sockets[i.socket] : null;
    if (own) {  // a socket's fixture board: its light sits on that socket
      own.fixture.hidden = false;
      own.fixture.className = "light fixture-light " + (!i.connected || i.faulted ? "bad" : "on");
      own.fixture.title = i.name + (i.detail ? ": " + i.detail : "");
      continue;
    }
    const d = document.createElement("div");
    d.className = "inst" + (!i.connected || i.faulted ? " down" : "");
    d.dataset.name = i.name;
    d.title = i.detail || "";
    const cal = i.in_calibration === null ? "warn" : i.in_calibration ? "on" : "bad";
    d.innerHTML = "<b></b>" +
      `<span class="light ${i.connected ? "on" : "bad"}" data-light="connected"></span>` +
      `<span class="light ${cal}" data-light="calibration"></span>` +
      `<span class="light ${i.faulted ? "bad" : ""}" data-light="fault"></span>`;
    d.querySelector("b").textContent = instrumentName(i.name);
    if (i.calibration_due) d.title = t("inst.due", { date: i.calibration_due }) + (i.detail ? "; " + i.detail : "");
    for (const light of d.querySelectorAll(".light")) light.setAttribute("aria-label", t(LIGHT_WORDS[light.dataset.light]));
    if (!box.firstChild) box.appendChild(lightLegend());
    box.appendChild(d);
  }
}

// The three lights' names once, above their columns (each row's lights line up under them).
const LIGHT_WORDS = { connected: "inst.connected", calibration: "inst.calibration", fault: "inst.fault" };
function lightLegend() {
  const head = document.createElement("div");
  head.className = "inst-legend";
  head.innerHTML = "<span></span><span></span><span></span><span></span>";
  const cells = head.querySelectorAll("span");
  cells[0].textContent = t("inst.lights");
  Object.values(LIGHT_WORDS).forEach((key, k) => { cells[k + 1].textContent = t(key); });
  return head;
}

// The station's instrument names in the page's language ("rate table" -> "Drehtisch").
function instrumentName(name) {
  const key = "inst.name." + name;
  return Object.prototype.hasOwnProperty.call(M, key) ? M[key] : name;
}

function renderSelection() {
  const sel = S.selection || {};
  $("procedure-name").textContent = sel.procedure_name || sel.procedure || "-";
  $("product-name").textContent = sel.product_name || sel.product || "-";
  $("serial-pattern").textContent = sel.serial_example ? t("sel.serial_like", { example: sel.serial_example }) : sel.serial_pattern || "-";
  $("serial-pattern").title = sel.serial_pattern || "";
}

function renderRole() {
  const eng = S.role === "engineer";
  $("role-badge").textContent = t(eng ? "role.engineer" : "role.operator");
  $("role-badge").classList.toggle("engineer", eng);
  $("engineer-btn").textContent = t(eng ? "header.log_out" : "header.engineer");
  $("engineer-btn").hidden = !eng && !S.engineerLogin;  // no password set: no engineer role
  $("engineer-panel").hidden = !eng;
  if (eng) loadChoices(); else { $("procedure-select").textContent = ""; $("product-select").textContent = ""; }
}

function renderOperator() {
  $("operator-name").textContent = S.operator || (S.operatorRequired ? t("header.not_signed_in") : "-");
  $("signin-btn").textContent = t(S.operator ? "header.sign_out" : "header.sign_in");
  $("badge-row").hidden = S.operatorsOpen;
  $("pin-row").hidden = S.operatorsOpen;
  $("signin-title").textContent = t(S.operatorsOpen ? "signin.title_open" : "signin.title");
}

// Why START may not be pressed now, in words; [] when it may.
function startBlockers() {
  const why = [];
  for (const i of S.instruments) {
    // a socket's fixture matters only when a part is scanned into that socket
    if (i.socket !== null && i.socket !== undefined && !(sockets[i.socket] && sockets[i.socket].input.value.trim())) continue;
    if (!i.connected) why.push(t("block.instrument_down", { name: instrumentName(i.name) }));
    else if (i.faulted) why.push(t("block.instrument_fault", { name: instrumentName(i.name) }));
  }
  if (S.operatorRequired && !S.operator) why.push(t("block.no_operator"));
  for (const [serial, where] of Object.entries(duplicates())) {
    why.push(t("block.duplicate", { serial, sockets: where.join(", ") }));
  }
  return why;
}

function duplicates() {
  const seen = {};
  for (const n in sockets) {
    const v = sockets[n].input.value.trim();
    if (v) (seen[v] = seen[v] || []).push(n);
  }
  return Object.fromEntries(Object.entries(seen).filter(([, where]) => where.length > 1));
}

function renderStart() {
  if (!S.station) return;
  const running = !!S.run;
  const why = running ? [] : startBlockers();
  $("start-btn").disabled = running || why.length > 0;
  $("start-reason").textContent = why.length ? t("block.start_disabled", { reasons: why.join("; ") }) : "";
}

function renderRun() {
  const run = S.run;
  const running = !!run;
  $("abort-btn").disabled = !running || run.aborting;
  $("apply-selection").disabled = running;
  $("work-order").disabled = running; $("lot").disabled = running;
  const p = running ? run.progress : null;
  const stepWords = running ? (run.aborting ? t("progress.aborting") : p ? sayAll(p.words) || p.step : t("progress.starting")) : "";
  for (const n in sockets) {
    const s = sockets[n];
    s.input.disabled = running;
    // A part dropped mid-run (e.g. it stopped streaming) shows here while the others go on.
    const st = running && p && p.sockets ? p.sockets[n] || "" : "";
    s.state.textContent = st ? t("state." + st) : "";
    s.state.className = "socket-state " + st;
    const inRun = running && run.serials[n] !== undefined;
    s.root.classList.toggle("running", inRun);
    s.step.textContent = inRun && st !== "ERROR" && st !== "FAIL" ? stepWords : "";
  }
  renderStart();
  renderPrompt();
  $("progress").hidden = !running;
  if (!running) { if (detailSocket !== null) renderDetail(); return; }
  for (const [n, serial] of Object.entries(run.serials)) if (sockets[n]) sockets[n].input.value = serial;
  if (run.work_order !== undefined) $("work-order").value = run.work_order;
  if (run.lot !== undefined) $("lot").value = run.lot;
  $("step-name").textContent = stepWords;
  $("step-name").title = p ? p.step + (p.condition ? " " + p.condition : "") : "";
  $("condition-name").textContent = p && p.step_count ? t("progress.step_of", { index: p.step_index + 1, count: p.step_count }) : "";
  $("bar-fill").style.width = (p ? Math.max(0, Math.min(1, p.fraction)) * 100 : 0) + "%";
  const list = $("step-list");
  list.textContent = "";
  const current = p ? p.step_index : -1;
  run.steps.forEach((name, i) => {
    const li = document.createElement("li");
    const words = run.step_words && run.step_words[i];
    li.textContent = words ? sayAll(words) : name;
    li.title = name;  // the engineering name
    li.className = i < current ? "done" : i === current ? "current" : "";
    list.appendChild(li);
  });
  const cur = list.querySelector("li.current");
  if (cur) list.scrollTop = cur.offsetTop - list.offsetTop - 8;
  renderRemaining();
  if (detailSocket !== null) renderDetail();
}

function renderPrompt() {
  const pr = S.run && S.run.prompt;
  $("prompt").hidden = !pr;
  for (const n in sockets) sockets[n].root.classList.toggle("prompted", !!pr && (pr.sockets || []).map(String).includes(String(n)));
  if (!pr) return;
  $("prompt-message").textContent = pr.message;
  $("prompt-sockets").textContent = pr.sockets && pr.sockets.length ? t("prompt.sockets", { list: pr.sockets.join(", ") }) : t("prompt.title");
}

function renderRemaining() {
  const p = S.run && S.run.progress;
  if (!p || p.remaining_s === null || p.remaining_s === undefined) { $("remaining").textContent = ""; return; }
  const left = Math.max(0, p.remaining_s - (performance.now() - progressAt) / 1000);
  $("remaining").textContent = left >= 120 ? t("time.min_left", { min: Math.round(left / 60) }) : t("time.s_left", { s: Math.floor(left) });
}

function renderLast() {
  for (const n in sockets) sockets[n].box.hidden = true;
  const last = S.last;
  const safe = $("safe-state");
  safe.hidden = !(last && last.safe_state);
  if (last && last.safe_state) {
    const st = last.safe_state;
    safe.className = "safe-state " + (st.all ? "ok" : "bad");
    // the station's own readback of each instrument (station/ui/runner_adapter.py)
    safe.textContent = st.all ? t("safe.ok") : t("safe.bad", { what: st.unsafe && st.unsafe.length ? st.unsafe.join("; ")
      : Object.keys(st).filter((k) => k !== "all" && k !== "unsafe" && !st[k]).join(", ").replace(/_/g, " ") });
  }
  $("message").textContent = last && last.message ? last.message : "";
  if (!last) return;
  for (const r of last.results) {
    const s = sockets[r.socket];
    if (!s) continue;
    s.box.hidden = false;
    s.box.className = "verdict-box " + r.verdict;
    s.verdict.textContent = t("verdict." + r.verdict);
    s.vserial.textContent = r.serial;
    s.disposition.textContent = r.disposition || "";
    s.reasons.textContent = "";
    // plain words only: the failing measurements, how many passed near a limit, or that an
    // error or an abort ended the run; the engine's own reason (engineering names) is in
    // the socket's detail view
    const lines = failureLines(r.failed || []);
    if (!lines.length) lines.push(...plainReason(r));
    for (const line of lines) { const li = document.createElement("li"); li.textContent = line; s.reasons.appendChild(li); }
    s.cert.hidden = !r.certificate_url;
    if (r.certificate_url) s.cert.href = r.certificate_url;
  }
  if (detailSocket !== null) renderDetail();
}

function plainReason(r) {
  if (r.verdict === "ERROR") return [t("reason.error_detail")];
  if (r.verdict === "ABORTED") return [t("reason.aborted")];
  return r.marginal ? [t("reason.marginal", { n: r.marginal })] : [];
}

// One line per failed measurement (its worst condition), with how many conditions failed.
function failureLines(failed) {
  const worst = {}, count = {};
  for (const f of failed) {
    count[f.name] = (count[f.name] || 0) + 1;
    const w = worst[f.name];
    if (!w || Math.abs(f.value || 0) > Math.abs(w.value || 0)) worst[f.name] = f;
  }
  return Object.values(worst).map((f) => {
    const text = f.words ? say(f.words) : f.name;
    return count[f.name] > 1 ? t("fail.conditions", { text, n: count[f.name] }) : text;
  });
}

function num(v) { return v === null || v === undefined ? "-" : Math.abs(v) >= 1e4 || (Math.abs(v) < 1e-3 && v !== 0) ? v.toExponential(3) : +v.toPrecision(5); }

// ---------------------------------------------------------------- the detail view (engineering names)
function openDetail(n) {
  detailSocket = String(n);
  renderDetail();
  if (!$("detail-dialog").open) $("detail-dialog").showModal();
  drawChart($("detail-chart"), S.chart[detailSocket]);
}

function renderDetail() {
  const n = detailSocket;
  const s = sockets[n];
  if (!s) return;
  $("detail-title").textContent = t("socket.label", { n });
  const result = S.last && !S.run ? S.last.results.find((r) => String(r.socket) === n) : null;
  $("detail-serial").textContent = S.run ? S.run.serials[n] || "" : result ? result.serial : s.input.value;
  $("detail-verdict").textContent = result ? result.verdict : "";
  const p = S.run && S.run.progress;
  $("detail-step").textContent = p ? [p.step, p.condition].filter((x) => x).join(" @ ") : result ? result.verdict : "-";
  const list = $("detail-failed");
  list.textContent = "";
  for (const f of (result && result.failed) || []) {
    const li = document.createElement("li");
    li.textContent = `${f.name}${f.condition ? " @ " + f.condition : ""}: ${num(f.value)} ${f.units} (limits ${num(f.low)} .. ${num(f.high)})`;
    list.appendChild(li);
  }
  $("detail-reason").textContent = result && result.reason ? result.reason : "";
}

function renderCharts() {
  if ($("sockets").classList.contains("roomy")) for (const n in sockets) drawChart(sockets[n].canvas, S.chart[n]);
  if (detailSocket !== null && $("detail-dialog").open) drawChart($("detail-chart"), S.chart[detailSocket]);
}

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
    case "steps": if (S.run) { S.run.steps = ev.steps; S.run.step_words = ev.step_words; renderRun(); } break;
    case "progress":
      if (window.__ui.startClickedAt !== null) {
        const dt = performance.now() - window.__ui.startClickedAt;
        if (window.__ui.firstProgressMs === null) window.__ui.firstProgressMs = dt;
        if (window.__ui.firstStepMs === null && ev.step_index >= 1) window.__ui.firstStepMs = dt;
      }
      if (S.run) { S.run.progress = ev; progressAt = performance.now(); renderRun(); }
      break;
    case "prompt": if (S.run) { S.run.prompt = { message: ev.message, sockets: ev.sockets || [] }; renderPrompt(); } break;
    case "prompt_done": if (S.run) { S.run.prompt = null; renderPrompt(); } break;
    case "samples": {
      const c = S.chart[ev.socket] || (S.chart[ev.socket] = { t_s: [], rate_dps: [], temp_c: [] });
      for (const k of ["t_s", "rate_dps", "temp_c"]) c[k].push(...ev[k]);
      if (c.t_s.length > 1500) for (const k in c) c[k] = c[k].filter((_, i) => i % 2 === 0);
      scheduleCharts();
      break;
    }
    case "instruments": S.instruments = ev.instruments; renderInstruments(); renderStart(); break;
    case "last": S.last = ev.last; renderLast(); break;
    case "selection": S.selection = ev.selection; renderSelection(); if (S.role === "engineer") loadChoices(); break;
    case "finished":
      S.run = null; S.last = ev.last; renderRun(); renderLast(); readyForNext(); break;
  }
}

let chartQueued = false;
function scheduleCharts() { if (!chartQueued) { chartQueued = true; requestAnimationFrame(() => { chartQueued = false; renderCharts(); }); } }

function readyForNext() {
  for (const n in sockets) { const s = sockets[n]; s.input.value = ""; s.input.classList.remove("ok", "bad", "dup"); s.msg.textContent = ""; }
  renderStart();
  const first = Object.keys(sockets)[0];
  if (first && !document.querySelector("dialog[open]")) sockets[first].input.focus();
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
  if (!r.ok) { if (document.activeElement === s.input) s.input.select(); renderStart(); return false; }
  s.input.value = r.data.serial;
  // The same serial in two sockets is flagged at once, not at START.
  const other = Object.keys(sockets).find((k) => k !== String(n) && sockets[k].input.value.trim() === r.data.serial);
  if (other) {
    s.input.classList.remove("ok"); s.input.classList.add("bad", "dup");
    sockets[other].input.classList.add("dup");
    s.msg.textContent = t("socket.duplicate", { other });
    if (document.activeElement === s.input) s.input.select();
    renderStart(); return false;
  }
  renderStart();
  // The reply may come after the operator has moved on (tapped or scanned into another
  // field): the focus moves on only from the field this reply is for, so no scan lands
  // in a socket other than the one the operator chose.
  if (document.activeElement !== s.input) return true;
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
  const r = await api("/api/start", { serials, work_order: $("work-order").value.trim(), lot: $("lot").value.trim() });
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
  $("selection-msg").textContent = r.ok ? t("sel.applied") : r.data.error;
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
$("detail-close").addEventListener("click", () => $("detail-dialog").close());
$("detail-dialog").addEventListener("close", () => { detailSocket = null; });
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
// The words first, then the session (its token signs every command), then the live state.
loadCatalog().then(openSession).then(() => {
  connect();
  if (S.operatorRequired && !S.operator) signinButton();  // a badge scan signs in at once
});
