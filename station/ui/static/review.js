// Review screen: run history with filters, yield, each run's certificate, whether its
// folder is intact (signed manifest), its approvals, and for the quality role an Approve button.
"use strict";
const $ = (id) => document.getElementById(id);
const session = { csrf: "", quality: false };
const MAX_CHECKED = 100;  // rows whose folder is verified on load (the newest first)

async function openSession() {
  const r = await fetch("/api/session");
  if (r.ok) { const d = await r.json(); session.csrf = d.csrf; session.quality = !!d.quality; }
}

function runKey(run) {
  const m = /^\/runs\/([^/]+)\/certificate\.pdf$/.exec(run.certificate_url || "");
  return m ? m[1] : "";
}

// A run that did not PASS (FAIL, ERROR, ABORTED) is approved only with a remark saying why
// (station/approvals.py); it is shown on the certificate beside the approver's name.
async function approveRun(key, cell, verdict) {
  let remark = "";
  if (verdict !== "PASS") {
    remark = (window.prompt("This run is " + verdict + ". Remark for approving it (shown on the certificate):") || "").trim();
    if (!remark) { $("review-msg").textContent = "Approving a " + verdict + " run needs a remark."; return; }
  }
  const r = await fetch("/api/runs/" + encodeURIComponent(key) + "/approve", {
    method: "POST", headers: { "Content-Type": "application/json", "X-CSRF-Token": session.csrf },
    body: JSON.stringify({ remark }) });
  const d = await r.json();
  if (!r.ok) { $("review-msg").textContent = d.error; return; }
  $("review-msg").textContent = "";
  await showIntegrity(key, cell, verdict);
}

async function showIntegrity(key, cell, verdict) {
  const r = await fetch("/api/runs/" + encodeURIComponent(key) + "/integrity");
  if (!r.ok) return;
  const d = await r.json();
  cell.textContent = "";
  const status = document.createElement("span");
  status.className = "integrity-" + d.status;
  status.textContent = d.status === "intact" ? "intact" : "ALTERED: " + d.altered_files.join(", ");
  status.title = d.problems.join("\n");
  cell.appendChild(status);
  for (const a of d.approvals) {
    const s = document.createElement("div");
    s.className = "approval";
    s.textContent = "approved by " + a.by + " " + a.time_utc.replace("T", " ").slice(0, 16);
    cell.appendChild(s);
  }
  if (session.quality && d.status === "intact") {
    const b = document.createElement("button");
    b.type = "button"; b.className = "approve"; b.textContent = "Approve";
    b.addEventListener("click", () => approveRun(key, cell, verdict));
    cell.appendChild(b);
  }
}

async function load() {
  const params = new URLSearchParams();
  for (const [k, v] of new FormData($("filters"))) if (v) params.set(k, v);
  const r = await fetch("/api/runs?" + params);
  const data = await r.json();
  if (!r.ok) { $("review-msg").textContent = data.error; return; }
  $("review-msg").textContent = "";
  const s = data.summary;
  const y = s.yield === null ? "-" : (s.yield * 100).toFixed(1) + " %";
  $("summary").innerHTML = "";
  for (const [label, value] of [["Yield", y], ["Runs", s.total], ["PASS", s.counts.PASS], ["FAIL", s.counts.FAIL], ["ABORTED", s.counts.ABORTED], ["ERROR", s.counts.ERROR]]) {
    const d = document.createElement("div");
    d.innerHTML = "<span></span><br><b></b>";
    d.querySelector("span").textContent = label;
    d.querySelector("b").textContent = value;
    d.id = "sum-" + label.toLowerCase();
    $("summary").appendChild(d);
  }
  const body = $("runs");
  body.textContent = "";
  for (const run of data.runs) {
    const tr = document.createElement("tr");
    const reason = run.reason || [...new Set(run.failed.map((f) => f.name))].join(", ");
    for (const [v, cls] of [[run.started_utc.replace("T", " ").slice(0, 19), ""], [run.serial, ""], [run.socket, ""], [run.product, ""], [run.procedure, ""], [run.operator, ""], [run.verdict, run.verdict], [reason, ""]]) {
      const td = document.createElement("td"); td.textContent = v; if (cls) td.className = cls; tr.appendChild(td);
    }
    const td = document.createElement("td");
    if (run.certificate_url) { const a = document.createElement("a"); a.href = run.certificate_url; a.target = "_blank"; a.textContent = "PDF"; td.appendChild(a); }
    tr.appendChild(td);
    const rec = document.createElement("td");
    rec.className = "record-cell";
    tr.appendChild(rec);
    const key = runKey(run);
    if (key && body.children.length < MAX_CHECKED) showIntegrity(key, rec, run.verdict);  // each hashes a folder
    body.appendChild(tr);
  }
}

$("filters").addEventListener("submit", (e) => { e.preventDefault(); load(); });
$("filters").addEventListener("reset", () => setTimeout(load, 0));
// A finished run appears without a reload.
new EventSource("/api/events").onmessage = (m) => { if (JSON.parse(m.data).type === "finished") load(); };
openSession().then(load);
