// Review screen: run history with filters, yield, and each run's certificate.
"use strict";
const $ = (id) => document.getElementById(id);

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
    body.appendChild(tr);
  }
}

$("filters").addEventListener("submit", (e) => { e.preventDefault(); load(); });
$("filters").addEventListener("reset", () => setTimeout(load, 0));
// A finished run appears without a reload.
new EventSource("/api/events").onmessage = (m) => { if (JSON.parse(m.data).type === "finished") load(); };
load();
