// View 3, Identify: options, progress with a live cost curve, and the result: residuals before
// and after, histogram, convergence, DH errors ±1σ (implausible ones in red), identifiability,
// TCP uncertainty, Accept, and downloads sent with the token.
import { api, download, saveBlob } from "./api.js";
import { campaignSamples, refreshCampaign, refreshDetail, samplesNeeded } from "./campaign.js";
import { costChart, histogramChart, residualChart } from "./charts.js";
import { $, clock, el, every, fillTable, fix, hasRoute, heldOut, onChange, setText, showMessage, sig, state } from "./ui.js";

const FINISHED = ["succeeded", "failed", "cancelled"];
const DH = [["alpha", "α", "deg"], ["a", "a", "mm"], ["d", "d", "mm"], ["theta", "θ", "deg"]];
let job = null; // the job followed (GET /identifications/{id})
let live = { x: [], y: [], plot: null };
let shownResult = null; // job id whose result is rendered
const plots = [];

async function loadJobs() {
  if (!state.campaign) return;
  const list = await api("GET", `/campaigns/${state.campaign.id}/identifications`);
  const items = Array.isArray(list) ? list : list.items || [];
  fillTable($("job-list"), [{ label: "#", num: true }, { label: "method" }, { label: "status" }, { label: "started" }, { label: "message" }],
    items.slice().reverse().map((j) => ({
      class: job?.id === j.id ? "selected" : "",
      onclick: () => follow(j.id),
      cells: [String(j.id), j.method, j.status, clock(j.created_at), j.error || j.message || ""],
    })), JSON.stringify([job?.id, items.map((j) => [j.id, j.status, j.message])]));
  if (!job && items.length) await follow(items[items.length - 1].id);
}

function updateNeed() {
  const n = campaignSamples().filter((s) => !s.excluded).length;
  const tf = Number($("identify-form").elements.test_fraction.value) || 0;
  const need = samplesNeeded(tf);
  if (need == null) {
    $("identify-start").disabled = true;
    setText("identify-need", "Pick or create a campaign in tab 2.");
    return;
  }
  const c = state.campaign;
  const anchors = Math.max(1, c.anchors.length);
  $("identify-start").disabled = n < need || (job && !FINISHED.includes(job.status));
  setText("identify-need", n < need
    ? `${n} of ${need} samples: Identify needs at least ${need} included samples with this test fraction (${c.min_training_samples} to train on, for this robot and ${anchors} anchor${anchors > 1 ? "s" : ""}). Capture more in tab 2.`
    : `${n} included samples: ${n - heldOut(tf, n)} for training, ${heldOut(tf, n)} held out to test.`);
}

async function start(ev) {
  ev.preventDefault();
  const f = ev.target.elements;
  const body = {
    method: f.method.value, test_fraction: Number(f.test_fraction.value), seed: Number(f.seed.value),
    holdout: f.holdout.value, robust: f.robust.value, prior: f.prior.checked,
  };
  try {
    const j = await api("POST", `/campaigns/${state.campaign.id}/identifications`, { json: body });
    live = { x: [], y: [], plot: live.plot };
    await follow(j.id);
  } catch { /* in the message area */ }
}

async function follow(id) {
  job = await api("GET", `/identifications/${id}`);
  if (shownResult !== id) { live.x = []; live.y = []; }
  renderJob();
  $("job-list").dataset.key = "";
}

async function poll() {
  if (job && !FINISHED.includes(job.status)) {
    job = await api("GET", `/identifications/${job.id}`);
    renderJob();
  }
}

function renderJob() {
  const bar = $("job-bar");
  bar.style.width = `${100 * (job.progress || 0)}%`;
  bar.className = job.status === "succeeded" ? "done" : "";
  const words = {
    queued: "Queued: waiting for a worker.",
    running: `Running: ${Math.round(100 * job.progress)} % — ${job.message || ""}`,
    succeeded: `Finished in ${fix(job.result?.elapsed_s, 1)} s: ${job.message || ""}.`,
    failed: `Failed: ${job.error || job.message}`,
    cancelled: `Cancelled: ${job.error || ""}`,
  };
  setText("job-state", `Identification #${job.id} (${job.method}). ${words[job.status] || job.status}`);
  const m = /rms ([0-9.eE+-]+) mm/.exec(job.message || "");
  if (m && job.status === "running") {
    live.x.push(live.x.length + 1);
    live.y.push(Number(m[1]));
  }
  if (job.result?.cost_history_rms_mm) {
    live.y = job.result.cost_history_rms_mm.slice();
    live.x = live.y.map((_, i) => i);
  }
  live.plot ||= costChart($("cost-live"), 150);
  live.plot.setData([live.x, live.y]);
  if (FINISHED.includes(job.status)) $("job-list").dataset.key = "";
  if (job.status === "failed") showMessage("error", `Identification #${job.id} failed: ${job.error}`, `job-${job.id}`);
  updateNeed();
  if (job.status === "succeeded" && shownResult !== job.id) renderResult().catch((e) => showMessage("error", `result: ${e.message}`));
  if (job.status !== "succeeded") $("result").hidden = true;
}

// ------------------------------------------------------------------ result
function tile(label, value, unit, cls = "") {
  return el("div", { class: `tile ${cls}` }, el("div", { class: "label" }, label),
    el("div", { class: "value" }, value, unit ? el("small", {}, ` ${unit}`) : null));
}

async function renderResult() {
  const r = job.result;
  shownResult = job.id;
  $("result").hidden = false;
  const plaus = r.plausibility || {};
  setText("result-title", `Result of identification #${job.id} — ${r.method} on ${r.robot}`);
  const verdict = $("result-verdict");
  verdict.className = `pill ${job.accepted ? "ok" : plaus.plausible ? "warn" : "bad"}`;
  setText(verdict, job.accepted ? "accepted: this is the robot's calibration" : plaus.plausible ? "plausible, not accepted yet" : "implausible parameters — review before accepting");
  $("accept").hidden = !!job.accepted;
  const mb = r.metrics?.before || {};
  const ma = r.metrics?.after || {};
  const tcp = r.tcp_uncertainty_mm;
  $("result-tiles").replaceChildren(
    tile("test RMSE before", fix(mb.test?.rmse_mm, 3), "mm"),
    tile("test RMSE after", fix(ma.test?.rmse_mm, 3), "mm", "ok"),
    tile("train RMSE before → after", `${fix(mb.train?.rmse_mm, 3)} → ${fix(ma.train?.rmse_mm, 3)}`, "mm"),
    tile("max error after (test)", fix(ma.test?.max_mm, 3), "mm"),
    tile("TCP uncertainty (1σ RMS)", tcp ? fix(tcp.rms, 3) : "–", tcp ? "mm" : ""),
    tile("samples train / test", `${r.split?.n_train ?? "–"} / ${r.split?.n_test ?? "–"}`, ""),
  );
  renderDh(r);
  renderIdent(r);
  $("result-notes").replaceChildren(...(r.notes || []).map((n) => el("li", {}, n)));
  $("result-notes-card").hidden = !(r.notes || []).length;
  for (const p of plots.splice(0)) p.cleanup();
  const cost = r.cost_history_rms_mm || [];
  const cp = costChart($("chart-cost"));
  cp.setData([cost.map((_, i) => i), cost]);
  plots.push(cp);
  try {
    const res = await api("GET", `/identifications/${job.id}/residuals`, { quiet: true });
    const idx = res.after_mm.map((_, i) => i + 1);
    plots.push(residualChart($("chart-residuals"), idx, res.before_mm, res.after_mm));
    plots.push(histogramChart($("chart-histogram"), res.before_mm, res.after_mm));
    const differs = res.n_job_samples != null && res.n_job_samples !== res.after_mm.length;
    setText("residuals-note", `${res.before_note}.` + (differs ? ` Note: the campaign now has ${res.after_mm.length} included samples; the identification used ${res.n_job_samples}.` : ""));
  } catch (exc) {
    setText("residuals-note", `Residuals per sample not available: ${exc.message}`);
  }
}

function renderDh(r) {
  const sigma = r.uncertainty || {};
  const bad = new Set((r.plausibility?.parameters || []).filter((p) => p.ok === false).map((p) => p.name));
  const rows = (r.dh_error || []).map((e, i) => {
    const j = e.joint ?? i + 1;
    return [`J${j}`, ...DH.map(([k, , unit]) => {
      const name = `${k}${j}`;
      const s = sigma[name];
      const text = `${sig(e[`${k}_${unit}`], 3)}${s != null ? ` ± ${sig(s, 2)}` : ""}`;
      return el("span", { class: bad.has(name) ? "bad" : "", title: bad.has(name) ? "outside the plausible bounds" : "" }, text);
    })];
  });
  const tool = r.tool_mm || [];
  rows.push(["tool", ...["x", "y", "z"].map((a, i) => { const s = sigma[`tool_${a}`]; return `${a} ${fix(tool[i], 2)}${s != null ? ` ± ${sig(s, 2)}` : ""}`; }), "(mm, absolute)"]);
  fillTable($("dh-table"), [{ label: "joint" }, ...DH.map(([, sym, unit]) => ({ label: `Δ${sym} [${unit}]`, num: true }))], rows);
}

function renderIdent(r) {
  const id = r.identifiability || {};
  const tcp = r.tcp_uncertainty_mm;
  const un = id.unidentifiable || [];
  const parts = [
    el("p", { class: "sentence" }, tcp
      ? `Predicted tool-point uncertainty after calibration: ${fix(tcp.rms, 3)} mm RMS, ${fix(tcp.max, 3)} mm at worst over the workspace (1σ).`
      : "No TCP uncertainty in this result."),
    el("p", { class: "sentence" }, `Identifiability: rank ${id.rank ?? "–"}, condition number ${sig(id.condition_number, 3)} (${sig(id.condition_number_base, 3)} on the identifiable base set). ` +
      (un.length ? `${un.length} parameters cannot be told apart with these poses and stay at their nominal values:` : "Every parameter is identifiable with these poses.")),
  ];
  if (un.length) parts.push(el("ul", {}, un.map((n) => el("li", {}, el("code", {}, n), id.reasons?.[n] ? ` — ${id.reasons[n]}` : ""))));
  const out = r.plausibility?.outside_bounds || [];
  parts.push(el("p", { class: `sentence ${out.length ? "bad" : "ok"}` }, out.length
    ? `Outside the plausible bounds: ${out.join(", ")}.` : "All parameters within the plausible bounds."));
  $("result-ident").replaceChildren(...parts);
}

async function accept() {
  const plaus = job.result?.plausibility || {};
  if (!plaus.plausible && !confirm(`These parameters are outside the plausible bounds (${(plaus.outside_bounds || []).join(", ")}).\nAccept them as the robot's calibration anyway?`)) return;
  job = await api("POST", `/identifications/${job.id}/accept`);
  shownResult = null;
  renderJob();
  showMessage("info", `Identification #${job.id} accepted: it is now the calibrated model of robot ${state.campaign.robot_name}.`, "accepted");
}

async function downloadKind(kind) {
  const id = job.id;
  const robotId = job.robot_id;
  if (kind === "result") {
    saveBlob(new Blob([JSON.stringify(job.result, null, 2)], { type: "application/json" }), `identification-${id}-result.json`);
  } else if (kind === "report") {
    await download(`/identifications/${id}/report.html`, `identification-${id}-report.html`);
  } else if (kind === "samples") {
    await download(`/campaigns/${job.campaign_id}/samples?format=csv`, `campaign-${job.campaign_id}-samples.csv`);
  } else if (!job.accepted) {
    showMessage("warn", "The calibrated model is the robot's ACCEPTED result: accept this one first (or download another accepted one).", "model-dl");
  } else {
    const response = await api("GET", `/robots/${robotId}/calibrated-model?format=${kind}`, { raw: true });
    const type = response.headers.get("Content-Type") || "";
    // A daemon without the export formats answers JSON whatever the format: say so, save .json.
    const ext = type.includes("json") ? "json" : kind;
    if (ext !== kind) showMessage("warn", `This daemon serves the calibrated model as JSON only; saved as .json instead of .${kind}.`, "model-format");
    saveBlob(await response.blob(), `robot-${robotId}-calibrated.${ext}`);
  }
}

export function initIdentify() {
  $("identify-form").addEventListener("submit", start);
  $("identify-form").addEventListener("input", updateNeed);
  $("accept").addEventListener("click", () => accept().catch(() => {}));
  for (const b of document.querySelectorAll("[data-download]")) {
    b.addEventListener("click", () => downloadKind(b.dataset.download).catch(() => {}));
  }
  onChange((kind) => {
    if (kind === "campaign") { job = null; shownResult = null; $("result").hidden = true; }
    const has = !!state.campaign;
    $("identify-empty").hidden = has;
    $("identify-body").hidden = !has;
  });
  every(700, poll, () => state.view === "identify");
  every(3000, async () => { await refreshCampaign(); await refreshDetail(); await loadJobs(); updateNeed(); }, () => state.view === "identify");
}

export const currentJob = () => job;
