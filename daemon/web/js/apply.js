// View 4, Apply: compensate pasted or uploaded targets with the robot's calibrated model, and
// the drift-check state and history (the ``drift`` block of /status).
import { api, saveBlob } from "./api.js";
import { $, clock, el, every, fillTable, fix, hasRoute, setText, showMessage, sig, state } from "./ui.js";

let lastCsv = null;

function cell(v) {
  if (typeof v === "number") return Number.isInteger(v) ? String(v) : sig(v, 6);
  if (typeof v === "boolean") return v ? "yes" : "no";
  if (v == null) return "–";
  if (Array.isArray(v)) return v.map((x) => (typeof x === "number" ? fix(x, 3) : String(x))).join(", ");
  return typeof v === "object" ? JSON.stringify(v) : String(v);
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
    out = await api("POST", `/robots/${c.robot_id}/compensate`, { body: text, type: "text/csv", quiet: true });
  } catch (exc) {
    const why = exc.status === 404 ? `robot ${c.robot_name} has no accepted calibration yet (accept one in tab 3)` : exc.message;
    setText("compensate-state", `Compensation failed: ${why}`);
    showMessage("error", `Compensate: ${why}`, "compensate");
    return;
  }
  const rows = out.rows || [];
  const keys = rows.length ? Object.keys(rows[0]) : [];
  const unit = (k) => (/^q\d$/.test(k) ? `${k.replace("q", "J")} [deg]` : k.replace(/_mm$/, " [mm]").replace(/_deg$/, " [deg]").replaceAll("_", " "));
  const cellOf = (k, v) => (/^q\d$/.test(k) ? fix(v, 4) : k.startsWith("residual") ? sig(v, 2) : cell(v));
  fillTable($("compensate-result"), [{ label: "#", num: true }, ...keys.map((k) => ({ label: unit(k), num: typeof rows[0][k] === "number" }))],
    rows.map((r, i) => [String(i + 1), ...keys.map((k) => cellOf(k, r[k]))]));
  lastCsv = [keys.join(","), ...rows.map((r) => keys.map((k) => (r[k] == null ? "" : Array.isArray(r[k]) ? r[k].join(" ") : r[k])).join(","))].join("\n") + "\n";
  $("compensate-download").hidden = false;
  const summary = out.summary && typeof out.summary === "object"
    ? Object.entries(out.summary).filter(([, v]) => typeof v !== "object").map(([k, v]) => `${k.replaceAll("_", " ")} ${cell(v)}`).join(", ")
    : "";
  setText("compensate-state", `${rows.length} ${out.kind || ""} targets compensated (${out.mode || "position"} mode) with the calibrated model of ${c.robot_name}. ${summary}${out.note ? ` — ${out.note}` : ""}`);
  $("compensate-download").onclick = () => saveBlob(new Blob([lastCsv], { type: "text/csv" }), `robot-${c.robot_id}-compensated.csv`);
}

const DRIFT_WORDS = {
  ok: "Last drift check OK: the robot still matches its calibration.",
  drift: "DRIFT: the last check is above the threshold. Calibrate the robot again.",
  failed: "The last drift check failed (see its error below).",
  none: "No drift check yet.",
};

async function renderDrift() {
  const drift = state.status?.drift;
  const node = $("drift-state");
  if (!drift) {
    setText(node, "Drift checks are not available on this daemon.");
    $("drift-start").disabled = true;
    return;
  }
  node.className = `sentence ${drift.state === "drift" || drift.state === "failed" ? "bad" : drift.state === "ok" ? "ok" : ""}`;
  const last = drift.last_check_at ? ` Check #${drift.check_id} at ${clock(drift.last_check_at)}: ${fix(drift.rms_mm, 3)} mm RMS against a threshold of ${fix(drift.threshold_mm, 3)} mm.` : "";
  const running = drift.running ? ` Check #${drift.running} is running: move the robot through the check poses.` : "";
  const every = drift.check_interval_h ? ` Scheduled every ${drift.check_interval_h} h.` : " No scheduled checks.";
  setText(node, `${DRIFT_WORDS[drift.state] || drift.state}${last}${running}${every}`);
  const c = state.campaign;
  if (!c || !hasRoute("GET", "/robots/{}/checks")) return;
  const list = await api("GET", `/robots/${c.robot_id}/checks`);
  const items = (Array.isArray(list) ? list : list.items || []).slice().reverse();
  fillTable($("drift-history"), [{ label: "#", num: true }, { label: "started" }, { label: "trigger" }, { label: "status" },
    { label: "RMS [mm]", num: true }, { label: "max [mm]", num: true }, { label: "threshold [mm]", num: true }, { label: "poses", num: true }],
  items.map((k) => [String(k.id), clock(k.started_at), k.trigger,
    el("span", { class: k.status === "ok" ? "ok" : k.status === "running" ? "" : "bad", title: k.error || "" }, k.status),
    fix(k.rms_mm, 3), fix(k.max_mm, 3), fix(k.threshold_mm, 3), k.n == null ? "–" : String(k.n)]),
  JSON.stringify(items.map((k) => [k.id, k.status])));
}

async function startDrift() {
  const c = state.campaign;
  if (!c) { showMessage("error", "Drift check: select the campaign of the robot first (tab 2)."); return; }
  const k = await api("POST", `/robots/${c.robot_id}/checks`);
  showMessage("info", `Drift check #${k.id} started: auto capture now records the check poses.`, "drift");
}

export function initApply() {
  $("compensate-form").addEventListener("submit", (ev) => compensate(ev).catch((e) => showMessage("error", `compensate: ${e.message}`)));
  $("drift-start").addEventListener("click", () => startDrift().catch(() => {}));
  every(3000, renderDrift, () => state.view === "apply");
}
