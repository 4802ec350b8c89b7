// View 4, Apply: compensate pasted or uploaded targets with the robot's calibrated model, and
// the drift-check state and history (the ``drift`` block of /status).
import { api, saveBlob } from "./api.js";
import { $, clock, every, fillTable, fix, hasRoute, onChange, setText, showMessage, sig, state } from "./ui.js";

let lastCsv = null;

function cell(v) {
  if (typeof v === "number") return Number.isInteger(v) ? String(v) : sig(v, 6);
  if (typeof v === "boolean") return v ? "yes" : "no";
  if (v == null) return "–";
  if (Array.isArray(v)) return v.map((x) => (typeof x === "number" ? fix(x, 3) : String(x))).join(", ");
  return typeof v === "object" ? JSON.stringify(v) : String(v);
}

/** Rows of objects (or arrays) as a table with the union of their keys as columns. */
function objectTable(table, rows) {
  if (!rows.length) { fillTable(table, [], []); return; }
  if (Array.isArray(rows[0])) {
    fillTable(table, rows[0].map((_, i) => ({ label: `J${i + 1} [deg]`, num: true })), rows.map((r) => r.map((v) => fix(v, 3))));
    return;
  }
  const keys = [...new Set(rows.flatMap((r) => Object.keys(r)))];
  fillTable(table, keys.map((k) => ({ label: k, num: typeof rows[0][k] === "number" })), rows.map((r) => keys.map((k) => cell(r[k]))));
}

function csvRows(text) {
  const lines = text.trim().split(/\r?\n/).filter((l) => l && !l.startsWith("#"));
  const head = lines[0].split(",").map((h) => h.trim());
  return lines.slice(1).map((l) => Object.fromEntries(l.split(",").map((v, i) => [head[i], Number.isNaN(Number(v)) ? v : Number(v)])));
}

async function compensate(ev) {
  ev.preventDefault();
  const c = state.campaign;
  if (!hasRoute("POST", "/robots/{}/compensate")) {
    showMessage("error", "Compensate: this daemon has no compensation route (POST /robots/{id}/compensate).");
    return;
  }
  if (!c) { showMessage("error", "Compensate: select the campaign of the robot first (tab 2)."); return; }
  const f = ev.target.elements;
  const file = f.file.files[0];
  const text = file ? await file.text() : f.csv.value;
  if (!text.trim()) { showMessage("error", "Compensate: paste targets (CSV with q1..q6 in deg) or choose a file."); return; }
  setText("compensate-state", "Compensating …");
  let out;
  try {
    out = await api("POST", `/robots/${c.robot_id}/compensate`, { body: text, type: "text/csv" });
  } catch (exc) {
    setText("compensate-state", exc.status === 404 ? `No accepted calibration for robot ${c.robot_name} yet (accept one in tab 3), or compensation is not available on this daemon.` : `Compensation failed: ${exc.message}`);
    return;
  }
  let rows;
  if (typeof out === "string") {
    lastCsv = out;
    rows = csvRows(out);
  } else {
    rows = Array.isArray(out) ? out : out.rows || out.poses || out.targets || out.compensated || [];
    lastCsv = null;
  }
  objectTable($("compensate-result"), rows);
  $("compensate-download").hidden = false;
  const summary = !Array.isArray(out) && typeof out === "object"
    ? Object.entries(out).filter(([, v]) => !Array.isArray(v) && typeof v !== "object").map(([k, v]) => `${k} ${cell(v)}`).join(", ")
    : "";
  setText("compensate-state", `${rows.length} targets compensated with the calibrated model of ${c.robot_name}.${summary ? ` ${summary}.` : ""}`);
  $("compensate-download").onclick = () => {
    const body = lastCsv ?? JSON.stringify(out, null, 2);
    saveBlob(new Blob([body], { type: lastCsv ? "text/csv" : "application/json" }), `robot-${c.robot_id}-compensated.${lastCsv ? "csv" : "json"}`);
  };
}

function renderDrift() {
  const drift = state.status?.drift;
  if (!drift) {
    setText("drift-state", "No drift check data: the daemon reports no drift block (drift checks not configured, or not available on this daemon).");
    return;
  }
  const flat = Object.entries(drift).filter(([, v]) => v == null || typeof v !== "object");
  const words = flat.map(([k, v]) => `${k.replaceAll("_", " ")}: ${k.endsWith("_at") || k.startsWith("t_") ? clock(v) : cell(v)}`).join(" · ");
  const bad = drift.ok === false || drift.drifted === true || drift.state === "drift";
  const node = $("drift-state");
  node.className = `sentence ${bad ? "bad" : ""}`;
  setText(node, words || "Drift checks configured.");
  const history = drift.history || drift.checks || [];
  objectTable($("drift-history"), Array.isArray(history) ? history.slice(-50).reverse() : []);
}

export function initApply() {
  $("compensate-form").addEventListener("submit", (ev) => compensate(ev).catch((e) => showMessage("error", `compensate: ${e.message}`)));
  onChange((kind) => { if (kind === "status" && state.view === "apply") renderDrift(); });
  every(5000, async () => renderDrift(), () => state.view === "apply");
}
