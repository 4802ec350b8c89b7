// View 3, Identify: options, progress with a live cost curve, and the result: residuals before
// and after, histogram, convergence, DH errors ±1σ (implausible ones in red), identifiability,
// TCP uncertainty, Accept, and downloads sent with the token.
import { api, download, saveBlob } from "./api.js";
import { refreshCampaign, refreshDetail } from "./campaign.js";
import { costChart, driftChart, histogramChart, residualChart } from "./charts.js";
import { $, clock, dismiss, duration, el, every, fillTable, fix, onChange, setText, showMessage, sig, state } from "./ui.js";

const DH = [["alpha", "α", "deg"], ["a", "a", "mm"], ["d", "d", "mm"], ["theta", "θ", "deg"]];
// Everything about an option (type, default, limits, choices, help, and whether it is shown
// first or under "More options": main_fields) comes from GET /options/identify.
let spec = null; // GET /options/identify
let job = null; // the job followed (GET /identifications/{id})
let live = { x: [], y: [], plot: null };
let shownResult = null; // job id whose result is rendered
let shownJob = null; // that job
let readiness = null; // GET /campaigns/{id}/identification-readiness
const plots = [];

const finished = (status) => !!spec && spec.finished_states.includes(status);
const label = (name) => name.replaceAll("_", " ").replace(/^./, (c) => c.toUpperCase());

// ------------------------------------------------------------------ the form, from the API
/** An option's field with its help in view (not in a hover tooltip, item 23): the label,
 * then the help as a hint the field is described by. */
function fieldNode(f) {
  if (f.type === "bool") {
    return el("label", { class: "check" }, el("input", { name: f.name, type: "checkbox", checked: !!f.default }), ` ${label(f.name)}: ${f.help}`);
  }
  const help = `help-${f.name}`;
  const hint = f.help ? el("p", { class: "hint option-help", id: help }, f.help) : null;
  const describedby = f.help ? help : null;
  if (f.type === "choice") {
    return el("div", { class: "option" }, el("label", {}, `${label(f.name)} `, el("select", { name: f.name, "aria-describedby": describedby },
      f.choices.map((c) => el("option", { value: c, selected: c === f.default }, c === f.default ? `${c} (default)` : c)))), hint);
  }
  const value = f.type === "names" ? (f.default || []).join(", ") : String(f.default ?? "");
  return el("div", { class: "option" }, el("label", {}, `${label(f.name)} `,
    el("input", { name: f.name, type: "text", inputmode: f.type === "names" ? "text" : "decimal", value, autocomplete: "off", "aria-describedby": describedby }),
    el("small", { class: "hint" }, ` ${rangeWords(f)}`)), hint);
}

/** A result note's numbers as the figure means them (item 23): a length to the µm
 * (0.004872320524477666 mm → 0.005 mm), an angle to 0.0001 deg, any other long decimal
 * to 4 significant digits. */
export function noteText(note) {
  return String(note).replace(/(-?\d+\.\d{5,})(\s*)(mm|deg|°)?/g, (_, x, sp, unit) => {
    const v = Number(x);
    const text = unit === "mm" ? (Math.abs(v) >= 0.001 ? v.toFixed(3) : sig(v, 2)) : unit ? v.toFixed(4) : sig(v, 4);
    return `${text}${sp}${unit || ""}`;
  });
}

/** The field's range in words, from the API's bounds. */
function rangeWords(f) {
  if (f.type === "names") return "(names, comma-separated)";
  const lo = f.ge != null ? `from ${f.ge}` : f.gt != null ? `above ${f.gt}` : "";
  const hi = f.le != null ? `to ${f.le}` : f.lt != null ? `to below ${f.lt}` : "";
  return lo || hi ? `(${[f.type === "int" ? "a whole number" : "a number", lo, hi].filter(Boolean).join(" ")})` : "";
}

async function buildForm() {
  spec = await api("GET", "/options/identify");
  const main = [], more = [];
  for (const f of spec.fields) (spec.main_fields.includes(f.name) ? main : more).push(fieldNode(f));
  $("identify-fields").replaceChildren(...main);
  $("identify-more-fields").replaceChildren(...more);
}

const NUMBER = /^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$/;

/** The request body from the form, checked against the API's spec; throws an Error in the
 * operator's words naming the field. */
function readForm() {
  const els = $("identify-form").elements;
  const body = {};
  for (const f of spec.fields) {
    const input = els[f.name];
    if (!input) continue;
    if (f.type === "bool") { body[f.name] = input.checked; continue; }
    const text = input.value.trim();
    if (f.type === "choice") { body[f.name] = text; continue; }
    if (f.type === "names") { body[f.name] = text ? text.split(/[\s,]+/).filter(Boolean) : []; continue; }
    if (text === "" && f.name === "noise_mm") continue; // empty: the daemon's default
    const what = `${label(f.name)}: “${text}”`;
    if (!NUMBER.test(text)) throw new Error(`${what} is not a number; type ${rangeWords(f).slice(1, -1)}.`);
    const x = Number(text);
    if (f.type === "int" && !Number.isInteger(x)) throw new Error(`${what} must be a whole number.`);
    const out = (f.ge != null && x < f.ge) || (f.gt != null && x <= f.gt) || (f.le != null && x > f.le) || (f.lt != null && x >= f.lt);
    if (out) throw new Error(`${what} is out of range; type ${rangeWords(f).slice(1, -1)}.`);
    body[f.name] = x;
  }
  return body;
}

function formError(message) {
  const node = $("identify-form-error");
  node.hidden = !message;
  setText(node, message || "");
}

// ------------------------------------------------------------------ jobs
async function loadJobs() {
  if (!state.campaign) return;
  const list = await api("GET", `/campaigns/${state.campaign.id}/identifications`);
  const items = Array.isArray(list) ? list : list.items || [];
  fillTable($("job-list"), [{ label: "#", num: true }, { label: "method" }, { label: "status" }, { label: "started" }, { label: "message" }],
    items.slice().reverse().map((j) => ({
      class: job?.id === j.id ? "selected" : "",
      onclick: () => follow(j.id),
      cells: [String(j.id), j.method, j.current ? el("b", { class: "ok", title: "the robot's current calibration" }, `${j.status} · current`) : j.status,
        clock(j.created_at), j.error || j.message || ""],
    })), JSON.stringify([job?.id, items.map((j) => [j.id, j.status, j.message, j.current])]));
  if (!job && items.length) {
    const current = items.filter((j) => j.current).pop();
    await follow((current || items[items.length - 1]).id);
  }
}

/** The test fraction typed, or null when it is not a valid one (the form says why). */
function testFraction() {
  try {
    const body = readForm();
    formError("");
    return body.test_fraction;
  } catch (exc) {
    formError(exc.message);
    return null;
  }
}

async function updateReadiness() {
  if (!state.campaign || !spec) return;
  const tf = testFraction();
  if (tf == null) { readiness = null; updateNeed(); return; }
  readiness = await api("GET", `/campaigns/${state.campaign.id}/identification-readiness?test_fraction=${tf}`);
  updateNeed();
}

function updateNeed() {
  const c = state.campaign;
  const busy = !!job && !finished(job.status);
  if (!c || !spec) {
    $("identify-start").disabled = true;
    setText("identify-need", "Pick or create a campaign in tab 2.");
    return;
  }
  if (!readiness) { $("identify-start").disabled = true; setText("identify-need", ""); return; }
  const r = readiness;
  const anchors = Math.max(1, c.anchors.length);
  $("identify-start").disabled = !r.ready || busy;
  setText("identify-need", !r.ready && r.min_samples == null
    ? `A test fraction of ${r.test_fraction} leaves too few samples to train on; lower it.`
    : !r.ready
    ? `${r.n_included} of ${r.min_samples} samples: Identify needs at least ${r.min_samples} included samples with this test fraction (${r.min_training_samples} to train on, for this robot and ${anchors} anchor${anchors > 1 ? "s" : ""}). Capture more in tab 2.`
    : `${r.n_included} included samples: ${r.n_train} for training, ${r.n_test} held out to test.` + (busy ? " Wait for the running identification (or cancel it)." : ""));
}

async function start(ev) {
  ev.preventDefault();
  let body;
  try { body = readForm(); } catch (exc) { formError(exc.message); return; }
  formError("");
  try {
    // one already running for this campaign (another tab may have started it): ask first
    const list = await api("GET", `/campaigns/${state.campaign.id}/identifications`);
    const running = (Array.isArray(list) ? list : list.items || []).filter((x) => !finished(x.status));
    if (running.length && !confirm(`Identification #${running[0].id} (${running[0].method}, started ${clock(running[0].created_at)}) is still ${running[0].status} for this campaign, perhaps from another tab.\n\nStart another identification anyway?`)) {
      setText("identify-need", `Not started: identification #${running[0].id} is still ${running[0].status}; its result comes first.`);
      return;
    }
    const j = await api("POST", `/campaigns/${state.campaign.id}/identifications`, { json: body });
    live = { x: [], y: [], plot: live.plot };
    await follow(j.id);
  } catch { /* in the message area */ }
}

async function follow(id) {
  job = await api("GET", `/identifications/${id}`);
  if (job.id !== shownResult) { live.x = []; live.y = []; }
  renderJob();
  $("job-list").dataset.key = "";
}

async function poll() {
  if (job && !finished(job.status)) {
    job = await api("GET", `/identifications/${job.id}`);
    renderJob();
  }
}

async function cancelJob() {
  if (!job || finished(job.status)) return;
  job = await api("DELETE", `/identifications/${job.id}`);
  renderJob();
}

/** The live cost curve: one point per whole iteration the job reports (numbers, not text). */
function renderLive() {
  const p = job.progress || {};
  if (typeof p.iteration === "number" && typeof p.cost_rms_mm === "number" && live.x[live.x.length - 1] !== p.iteration) {
    live.x.push(p.iteration);
    live.y.push(p.cost_rms_mm);
  }
  live.plot ||= costChart($("cost-live"), 150);
  live.plot.setData([live.x, live.y]);
  const rises = live.y.some((y, i) => i > 0 && y > live.y[i - 1] * 1.001);
  setText("cost-live-note", live.x.length
    ? `Iteration ${live.x[live.x.length - 1]}: ${fix(live.y[live.y.length - 1], 4)} mm RMS.` +
      " Counted over every fit of the run (the noise estimate's fits first, then the final fit the result's convergence chart shows)." +
      (rises ? " The curve rises where a new fit starts." : "") +
      (live.x.length === 1 && finished(job.status)
        ? " The run ended before the page's next poll, so only its last iteration is drawn; the convergence chart below shows every iteration of the final fit."
        : "")
    : "");
}

function renderJob() {
  const bar = $("job-bar");
  const fraction = job.progress?.fraction ?? 0;
  bar.style.width = `${100 * fraction}%`;
  bar.className = job.status === "succeeded" ? "done" : "";
  const words = {
    queued: "Queued: waiting for a worker.",
    running: `Running: ${Math.round(100 * fraction)} % — ${job.message || ""}`,
    succeeded: `Finished in ${duration(job.result?.elapsed_s)}: ${job.message || ""}.`,
    failed: `Failed: ${job.error || job.message}`,
    cancelled: `Cancelled: ${job.error || ""}`,
  };
  setText("job-state", `Identification #${job.id} (${job.method}). ${words[job.status] || job.status}`);
  $("job-cancel").hidden = finished(job.status);
  renderLive();
  if (finished(job.status)) $("job-list").dataset.key = "";
  if (job.status === "failed") showMessage("error", `Identification #${job.id} failed: ${job.error}`, "identify-job");
  else dismiss("identify-job");
  updateNeed();
  if (job.status === "succeeded" && (shownResult !== job.id || shownJob?.current !== job.current)) {
    renderResult(job).then(() => dismiss("identify-result"))
      .catch((e) => showMessage("error", `The result of identification #${job.id} could not be shown: ${e.message}`, "identify-result", e.detail));
  }
  // While another job runs, the result shown (the previous one) stays, and says so.
  const note = $("result-shown-note");
  note.hidden = !(shownJob && shownJob.id !== job.id);
  if (!note.hidden) setText(note, `Showing identification #${shownJob.id}${shownJob.current ? " (the current calibration)" : ""} while #${job.id} is ${job.status}.`);
}

// ------------------------------------------------------------------ result
function tile(label, value, unit, cls = "") {
  return el("div", { class: `tile ${cls}` }, el("div", { class: "label" }, label),
    el("div", { class: "value" }, value, unit ? el("small", {}, ` ${unit}`) : null));
}

async function renderResult(j) {
  const r = j.result;
  shownResult = j.id;
  shownJob = j;
  $("result").hidden = false;
  const plaus = r.plausibility || {};
  // the robot is the physical one (its own name), the result's robot its model
  const robotName = state.campaign && state.campaign.robot_id === j.robot_id ? `robot ${state.campaign.robot_name} (${r.robot})` : r.robot;
  setText("result-title", `Result of identification #${j.id} — ${r.method} on ${robotName}`);
  const verdict = $("result-verdict");
  verdict.className = `pill ${j.current ? "ok" : plaus.plausible ? "warn" : "bad"}`;
  // the first plausible result is made current by the daemon (jobs.auto_accept): said, and
  // the operator asked to review it (item 23)
  const auto = j.current && /first calibration/.test(j.message || "");
  $("result-auto-note").hidden = !auto;
  if (auto) {
    setText("result-auto-note", `Accepted automatically as the robot's first calibration (its parameters are plausible): review the figures below before filtering programs with it. Identify again, and accept the better result, if they do not convince you.`);
  }
  setText(verdict, j.current ? (auto ? "current (accepted automatically): review it" : "current: this is the robot's calibration")
    : j.accepted ? "accepted earlier, replaced by a newer calibration"
      : plaus.plausible ? "plausible, waiting for Accept" : "implausible parameters — review before accepting");
  $("accept").hidden = !!j.current;
  renderModelDownloads(j);
  await renderCompare(j);
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
  $("result-notes").replaceChildren(...(r.notes || []).map((n) => el("li", {}, noteText(n))));
  $("result-notes-card").hidden = !(r.notes || []).length;
  for (const p of plots.splice(0)) p.cleanup();
  renderCost(r);
  renderDrift(r);
  try {
    const res = await api("GET", `/identifications/${j.id}/residuals`, { quiet: true, what: "Not available" });
    const idx = res.after_mm.map((_, i) => i + 1);
    plots.push(residualChart($("chart-residuals"), idx, res.before_mm, res.after_mm));
    plots.push(histogramChart($("chart-histogram"), res.before_mm, res.after_mm));
    const differs = res.n_job_samples != null && res.n_job_samples !== res.after_mm.length;
    setText("residuals-note", `${res.before_note}.` + (differs ? ` Note: the campaign now has ${res.after_mm.length} included samples; the identification used ${res.n_job_samples}.` : ""));
  } catch (exc) {
    setText("residuals-note", `Residuals per sample: ${exc.message}`);
  }
}

/** The convergence chart: whole iterations on x; each fit (robust rounds restart from the
 * start) its own segment, broken where the next one begins. */
/** What calib.drift found, in its own words (result.drift.summary), with the drift per sample. */
function renderDrift(r) {
  const d = r.drift;
  $("result-drift-card").hidden = !d;
  if (!d) return;
  setText("result-drift", d.summary || "");
  // A method that does not model drift (the result's note): the line says so; the card's
  // explanation of what is modelled does not apply.
  $("result-drift-hint").hidden = !!d.note;
  const per = d.per_sample_mm || [];
  const found = d.model !== "none" && per.length;
  $("chart-drift").hidden = !found;
  if (found) plots.push(driftChart($("chart-drift"), per.map((_, i) => i + 1), per));
}

function renderCost(r) {
  const cost = r.cost_history_rms_mm || [];
  const starts = (r.cost_history_fit_starts || [0]).filter((i) => i > 0 && i < cost.length);
  const xs = [], ys = [];
  let x = 0;
  cost.forEach((y, i) => {
    if (starts.includes(i)) { xs.push(x); ys.push(null); } // a gap: the next fit starts over
    xs.push(x);
    ys.push(y);
    if (!starts.includes(i + 1)) x += 1;
  });
  const cp = costChart($("chart-cost"));
  cp.setData([xs, ys]);
  plots.push(cp);
  const fits = starts.length + 1;
  const rises = cost.some((y, i) => i > 0 && !starts.includes(i) && y > cost[i - 1] * 1.001);
  setText("cost-note", `${r.iterations ?? "–"} iterations` + (fits > 1
    ? ` in ${fits} fits: after the first fit the robust step ${r.robust === "huber" || r.robust === "soft_l1" ? "reweighted" : "set aside"} the flagged rows and fitted again from the start, so each segment starts high again.`
    : ".") + (rises && r.prior?.used
    ? " Where the curve rises within a fit, the solver traded fit to the samples for the prior toward the nominal model: the plotted data RMS is one part of the cost it lowers."
    : ""));
}

/** The calibrated model (TOML, URDF) is the robot's accepted calibration: its buttons work
 * only on the result that is the current one, and say why otherwise. */
function renderModelDownloads(j) {
  for (const b of document.querySelectorAll("[data-download=toml], [data-download=urdf]")) {
    b.disabled = !j.current;
    b.title = j.current ? "" : "The calibrated model is the robot's accepted calibration: accept this result first.";
  }
  setText("model-download-note", j.current ? "" : "The calibrated model (TOML, URDF) is offered for the accepted calibration only: accept this result first.");
}

/** Old and new side by side: test RMSE on the same held-out rows, TCP σ, the parameters
 * that changed (GET /identifications/{id}/compare). */
async function renderCompare(j) {
  const box = $("compare");
  if (j.current) { box.hidden = true; return; }
  const c = await api("GET", `/identifications/${j.id}/compare`, { quiet: true });
  if (!c.current) { box.hidden = true; return; }
  box.hidden = false;
  setText("compare-title", `#${j.id} next to the current calibration #${c.current.job_id}`);
  // The new result's figures are the tiles' (its result.json): one source. The current
  // calibration is scored by the daemon on the new one's held-out rows as the campaign has
  // them now; when the samples changed since the new result (an exclusion, an Undo of a
  // sensor move), the new model scores differently on them today, and the page says so.
  const own = j.result.metrics?.after?.test?.rmse_mm;
  const tcpOwn = j.result.tcp_uncertainty_mm?.rms;
  fillTable($("compare-table"), [{ label: "figure" }, { label: `current #${c.current.job_id} (${c.current.method})`, num: true }, { label: `new #${j.id} (${c.new.method})`, num: true }], [
    [`test RMSE on the same ${c.n_rows} held-out rows [mm]`, c.current.test_rmse_mm == null ? "– (see below)" : fix(c.current.test_rmse_mm, 3), fix(own, 3)],
    ["TCP uncertainty 1σ RMS [mm]", fix(c.current.tcp_sigma_mm, 3), fix(tcpOwn, 3)],
  ]);
  await renderCompareWhy(j, c);
  const today = c.new.test_rmse_mm;
  const stale = typeof own === "number" && typeof today === "number" && fix(own, 3) !== fix(today, 3);
  $("compare-stale").hidden = !stale;
  if (stale) {
    setText("compare-stale", `The campaign's samples changed since #${j.id} was identified (samples excluded, or moved between anchor sessions): `
      + `on its held-out rows as they are now, #${j.id} scores ${fix(today, 3)} mm, not the ${fix(own, 3)} mm of its result. Identify again before accepting.`);
  }
  fillTable($("compare-changed"), [{ label: "parameter" }, { label: "current", num: true }, { label: "new", num: true }, { label: "change", num: true }],
    c.changed.length ? c.changed.map((p) => [p.name, `${fix(p.current, 3)} ${p.unit}`, `${fix(p.new, 3)} ${p.unit}`, `${p.change > 0 ? "+" : ""}${fix(p.change, 3)} ${p.unit}`])
      : [["no parameter changed by more than 0.001", "", "", ""]]);
  $("accept").textContent = `Accept: replace calibration #${c.current.job_id} by #${j.id}`;
}

/** Why the current calibration has no test RMSE (item 18): no held-out rows, or rows at an
 * anchor session (a sensor position) the current calibration never saw. */
async function renderCompareWhy(j, c) {
  const node = $("compare-why");
  node.hidden = c.current.test_rmse_mm != null;
  if (node.hidden) return;
  if (!c.n_rows) {
    setText(node, `– : #${j.id} held out no rows (test fraction 0), so neither model is scored on held-out rows; compare the TCP uncertainty.`);
    return;
  }
  const anchorsOf = (r) => [r?.anchor_id, ...Object.keys(r?.anchors || {})].filter(Boolean);
  const current = await api("GET", `/identifications/${c.current.job_id}`, { quiet: true });
  const known = anchorsOf(current.result);
  const missing = anchorsOf(j.result).filter((a) => !known.includes(a));
  setText(node, `– : the current calibration #${c.current.job_id} knows the sensor position of anchor session ${known.join(", ") || "–"} only; `
    + `#${j.id}'s held-out rows include anchor session ${missing.join(", ") || "(another)"} (the sensor stand was moved after #${c.current.job_id}), `
    + "where its sensor position is unknown, so it cannot be scored on them. Compare the TCP uncertainty, or run a hold check (tab 4) to score the current calibration now.");
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
  const j = shownJob;
  const plaus = j.result?.plausibility || {};
  if (!plaus.plausible && !confirm(`These parameters are outside the plausible bounds (${(plaus.outside_bounds || []).join(", ")}).\nAccept them as the robot's calibration anyway?`)) return;
  // The calibration it replaces, for the Undo (item 13): none before the first acceptance.
  let replaced = null;
  try {
    replaced = (await api("GET", `/robots/${j.robot_id}/calibrated-model`, { quiet: true })).job_id;
  } catch (exc) {
    if (exc.status !== 404) throw exc;
  }
  job = await api("POST", `/identifications/${j.id}/accept`);
  shownResult = null;
  $("accept").textContent = "Accept as the robot's calibration";
  renderJob();
  $("job-list").dataset.key = "";
  await loadJobs();
  showMessage("info", `Identification #${job.id} accepted: it is now the current calibration of robot ${state.campaign.robot_name}.`, "accepted");
  showUndo(job, replaced);
}

/** One button back: the calibration an acceptance replaced becomes current again (it is
 * accepted again; the replaced one stays listed, accepted earlier). */
function showUndo(accepted, replaced) {
  const box = $("accept-undo");
  if (replaced == null || replaced === accepted.id) { box.hidden = true; return; }
  box.hidden = false;
  box.dataset.accepted = String(accepted.id);
  box.dataset.replaced = String(replaced);
  setText("accept-undo-text", `Identification #${accepted.id} replaced calibration #${replaced} of robot ${state.campaign.robot_name}.`);
  $("accept-undo-button").textContent = `Undo: make #${replaced} current again`;
}

async function undoAccept() {
  const box = $("accept-undo");
  const back = Number(box.dataset.replaced);
  const undone = Number(box.dataset.accepted);
  await api("POST", `/identifications/${back}/accept`, { what: "The acceptance was not undone" });
  box.hidden = true;
  $("job-list").dataset.key = "";
  await loadJobs();
  if (job?.id === undone) {
    job = await api("GET", `/identifications/${undone}`);
    shownResult = null;
    renderJob();
  }
  showMessage("info", `Undone: calibration #${back} is the current calibration of robot ${state.campaign.robot_name} again; #${undone} stays listed.`, "accepted");
}

async function downloadKind(kind) {
  const shown = shownJob || job;
  const id = shown.id;
  const robotId = shown.robot_id;
  if (kind === "result") {
    saveBlob(new Blob([JSON.stringify(shown.result, null, 2)], { type: "application/json" }), `identification-${id}-result.json`);
  } else if (kind === "report") {
    await download(`/identifications/${id}/report.html`, `identification-${id}-report.html`);
  } else if (kind === "samples") {
    await download(`/campaigns/${shown.campaign_id}/samples?format=csv`, `campaign-${shown.campaign_id}-samples.csv`);
  } else if (shown.current) {
    const response = await api("GET", `/robots/${robotId}/calibrated-model?format=${kind}`, { raw: true });
    const type = response.headers.get("Content-Type") || "";
    // A daemon without the export formats answers JSON whatever the format: say so, save .json.
    const ext = type.includes("json") ? "json" : kind;
    if (ext !== kind) showMessage("warn", `This daemon serves the calibrated model as JSON only; saved as .json instead of .${kind}.`, "model-format");
    else dismiss("model-format");
    saveBlob(await response.blob(), `robot-${robotId}-calibrated.${ext}`);
  }
}

export function initIdentify() {
  $("identify-form").addEventListener("submit", start);
  $("identify-form").addEventListener("input", () => updateReadiness().catch(() => {}));
  $("accept").addEventListener("click", () => accept().catch(() => {}));
  $("accept-undo-button").addEventListener("click", () => undoAccept().catch(() => {}));
  $("job-cancel").addEventListener("click", () => cancelJob().catch(() => {}));
  buildForm().then(() => updateReadiness()).catch(() => {});
  for (const b of document.querySelectorAll("[data-download]")) {
    b.addEventListener("click", () => downloadKind(b.dataset.download).catch(() => {}));
  }
  onChange((kind) => {
    if (kind === "campaign") { job = null; shownResult = null; shownJob = null; readiness = null; $("result").hidden = true; updateReadiness().catch(() => {}); }
    const has = !!state.campaign;
    $("identify-empty").hidden = has;
    $("identify-body").hidden = !has;
  });
  every(700, poll, () => state.view === "identify");
  every(3000, async () => { await refreshCampaign(); await refreshDetail(); await loadJobs(); await updateReadiness(); }, () => state.view === "identify");
}

export const currentJob = () => job;
