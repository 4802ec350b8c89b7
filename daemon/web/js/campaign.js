// View 2, Campaign: create and pick a campaign, plan poses, capture (manual with a joint form
// for the manual robot, or auto), the samples with exclude/include, the joint coverage.
import { api, download, saveBlob } from "./api.js";
import { isManualRobot, readinessWords } from "./cell.js";
import { $, changed, clock, dismiss, el, every, fillTable, fix, hasRoute, onChange, requestSchema, setText, showMessage, state } from "./ui.js";

const CAMPAIGN_KEY = "cablecal-campaign";
const JOINTS = ["q1", "q2", "q3", "q4", "q5", "q6"];
let samples = [];
let robot = null; // GET /robots/{id} of the selected campaign
let plan = null; // GET /campaigns/{id}/plan, or null

/** Included samples needed before Identify is offered: the API's count for the campaign's robot
 * and anchors at the default options (``min_samples_to_identify``; tab 3 asks the API for
 * another test fraction). Null before a campaign. */
export function samplesNeeded() {
  return state.campaign ? state.campaign.min_samples_to_identify : null;
}

/** Reload the selected campaign's row (its counts, anchors and the samples identify needs). */
export async function refreshCampaign() {
  if (!state.campaign) return;
  const fresh = await api("GET", `/campaigns/${state.campaign.id}`);
  if (state.campaign?.id === fresh.id && JSON.stringify(fresh) !== JSON.stringify(state.campaign)) {
    state.campaign = fresh;
    changed("campaign-data");
  }
}

export const campaignSamples = () => samples;

async function loadCampaigns() {
  const list = await api("GET", "/campaigns");
  const items = Array.isArray(list) ? list : list.items || [];
  const selected = state.campaign?.id;
  // a hold check's own campaigns are listed only on request (item 22): they are compared
  // in tab 4, never identified, and crowd the list
  const checks = items.filter((c) => String(c.notes || "").startsWith("hold check"));
  const showChecks = $("campaign-show-checks").checked;
  $("campaign-show-checks-label").hidden = !checks.length;
  setText("campaign-show-checks-count", `Show the ${checks.length} hold-check campaign${checks.length === 1 ? "" : "s"}`);
  const listed = items.filter((c) => showChecks || c.id === selected || !checks.includes(c));
  fillTable($("campaign-list"), [
    { label: "#", num: true }, { label: "name" }, { label: "robot" }, { label: "model" }, { label: "samples", num: true },
    { label: "excluded", num: true }, { label: "auto" }, { label: "created" },
  ], listed.slice().reverse().map((c) => ({
    class: c.id === selected ? "selected" : "",
    onclick: () => select(c),
    cells: [String(c.id), c.name, c.robot_name, c.robot_model_name, String(c.n_samples), String(c.n_excluded),
      c.auto_capture ? "on" : "", clock(c.created_at)],
  })), JSON.stringify([selected, listed]));
  if (selected) {
    const fresh = items.find((c) => c.id === selected);
    if (fresh && JSON.stringify(fresh) !== JSON.stringify(state.campaign)) {
      state.campaign = fresh;
      changed("campaign-data");
    }
  }
  return items;
}

/** Make ``c`` the selected campaign (remembered for this browser tab). */
export async function select(c) {
  state.campaign = c;
  sessionStorage.setItem(CAMPAIGN_KEY, String(c.id));
  robot = await api("GET", `/robots/${c.robot_id}`);
  samples = [];
  plan = null;
  $("campaign-list").dataset.key = "";
  delete $("capture-anchor").dataset.typed; // the anchor field follows the new campaign
  $("capture-anchor").value = "A"; // not the anchor of the campaign selected before (item 8)
  delete $("plan-form").elements.n.dataset.typed;
  changed("campaign");
  await loadCampaigns(); // the list marks the new selection at once
  await refreshDetail();
}

/** Reload the selected campaign's samples and plan, and redraw its view. */
export async function refreshDetail() {
  const c = state.campaign;
  $("campaign-detail").hidden = !c;
  if (!c) return;
  const list = await api("GET", `/campaigns/${c.id}/samples`);
  samples = Array.isArray(list) ? list : list.items || [];
  renderCounts();
  renderPlanCount();
  renderSamples();
  renderCoverage();
  await refreshPlan();
  renderCaptureState();
}

function renderCounts() {
  const c = state.campaign;
  const included = samples.filter((s) => !s.excluded).length;
  const need = samplesNeeded();
  setText("campaign-title", `Campaign #${c.id}: ${c.name}`);
  setText("campaign-counts", `robot ${c.robot_name} (model ${c.robot_model_name}) · ${samples.length} samples, ${included} included, ${samples.length - included} excluded`);
  const bar = $("campaign-need-bar");
  bar.style.width = `${Math.min(100, (100 * included) / need)}%`;
  bar.className = included >= need ? "done" : "";
  if (String(c.notes || "").startsWith("hold check")) {
    // a hold check's own campaign: compared with the calibration, never identified (item 15)
    setText("campaign-need", `A hold check's own campaign (${c.notes}): its ${included} samples are compared with the robot's calibration in tab 4, not identified.`);
    return;
  }
  const anchors = c.anchors.length > 1 ? `, ${c.anchors.length} anchors` : "";
  const counts = `${need} minimum, ${c.recommended_samples} recommended for this robot and ${c.anchors.length > 1 ? `${c.anchors.length} anchors` : "anchor"}: from ${c.recommended_samples} the fit can also screen outliers`;
  setText("campaign-need", included >= need
    ? `${included} samples: enough to identify (with a 20 % test set${anchors}; ${counts}). More poses, spread over the workspace, give a more accurate result.`
    : `${included} of ${need} samples needed before Identify (${c.min_training_samples} to train on with a 20 % test set${anchors}; ${counts}).`);
}

function renderSamples() {
  const rows = samples.slice().reverse().map((s) => {
    const action = s.excluded
      ? el("button", { class: "secondary small", "aria-label": `Include sample #${s.id}`, onclick: () => setExcluded(s, false) }, "Include")
      : el("button", { class: "secondary small", "aria-label": `Exclude sample #${s.id}`, onclick: () => setExcluded(s, true) }, "Exclude");
    return {
      class: s.excluded ? "excluded" : "",
      cells: [String(s.id), clock(s.t_end ?? s.created_at), ...JOINTS.map((q) => fix(s[q], 3)),
        s.anchor ?? "–", fix(s.length_mm, 3), fix(s.length_std_mm, 4), s.count == null ? "–" : String(s.count),
        s.mode || s.source, el("span", { class: "keep" }, s.excluded ? `excluded: ${s.excluded_reason || "no reason"}` : "included"), action],
    };
  });
  fillTable($("samples"), [
    { label: "#", num: true }, { label: "time" }, ...JOINTS.map((q) => ({ label: `${q.replace("q", "J")} [deg]`, num: true })),
    { label: "anchor" }, { label: "length [mm]", num: true }, { label: "std [mm]", num: true }, { label: "readings", num: true },
    { label: "how" }, { label: "status", class: "keep" }, { label: "action" },
  ], rows, JSON.stringify(samples.map((s) => [s.id, s.excluded, s.excluded_reason, s.anchor])));
}

async function setExcluded(s, excluded) {
  let reason = null;
  if (excluded) {
    reason = prompt(`Why exclude sample #${s.id}? (kept with the sample)`, "outlier");
    if (reason === null) return;
  }
  await api("PATCH", `/samples/${s.id}`, { json: { excluded, reason } });
  await refreshDetail();
  await loadCampaigns();
}

function limitsDeg() {
  const joints = robot?.model?.joints || [];
  return JOINTS.map((_, j) => joints[j]?.limits_deg || [-180, 180]);
}

function renderCoverage() {
  const box = $("coverage");
  const lim = limitsDeg();
  const used = samples.filter((s) => !s.excluded);
  const key = JSON.stringify([lim, used.map((s) => s.id)]);
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  const ns = "http://www.w3.org/2000/svg";
  box.replaceChildren(...JOINTS.map((q, j) => {
    const [lo, hi] = lim[j];
    const xs = used.map((s) => s[q]);
    const min = xs.length ? Math.min(...xs) : null;
    const max = xs.length ? Math.max(...xs) : null;
    const pos = (v) => `${(100 * (v - lo)) / (hi - lo)}%`;
    const svg = document.createElementNS(ns, "svg");
    const rect = (x, w, fill, h = 14, y = 4) => {
      const r = document.createElementNS(ns, "rect");
      Object.entries({ x, width: w, y, height: h, fill, rx: 2 }).forEach(([k, v]) => r.setAttribute(k, v));
      svg.append(r);
    };
    rect("0%", "100%", "#e3e8ef");
    if (min != null) {
      rect(pos(min), `${(100 * (max - min)) / (hi - lo)}%`, "#9cc0ef");
      for (const v of xs) rect(pos(v), "1.5", "#1f5fae", 14, 4);
    }
    const share = min == null ? 0 : (100 * (max - min)) / (hi - lo);
    return el("div", { class: "joint", title: `J${j + 1} limits ${lo}…${hi} deg` }, el("b", {}, `J${j + 1}`), svg,
      el("span", { class: "range" }, min == null ? `limits ${lo}…${hi}` : `${fix(min, 0)}…${fix(max, 0)} (${share.toFixed(0)} %)`));
  }));
}

// ------------------------------------------------------------------ capture
/** The campaign's unresolved sensor move (the ``watch`` block of /status), or null. */
export function campaignMove() {
  return (state.status?.watch?.moves || []).find((m) => m.campaign_id === state.campaign?.id) || null;
}

/** The anchor session captures of this campaign go to now: auto capture's, else the new
 * session of a sensor move the watch found, else the newest sample's; null with no sample. */
function anchorInUse(on) {
  if (on) return state.status.sampler.auto_anchor;
  const move = campaignMove();
  if (move) return move.new_anchor;
  return samples.length ? samples[samples.length - 1].anchor : null;
}

function renderCaptureState() {
  const manual = isManualRobot();
  $("manual-joints").hidden = !manual;
  const s = state.status?.sampler;
  const auto = $("auto-capture");
  const on = !!state.campaign && s?.mode === "auto" && s.auto_campaign_id === state.campaign.id;
  const wanted = autoWanted && Date.now() < autoWanted.until && autoWanted.enabled !== on;
  if (!wanted) { autoWanted = null; auto.checked = on; }
  $("capture-now").disabled = on;
  // The anchor field follows the session in use until the operator types one of their own
  // (a new sensor position); auto capture's anchor is the daemon's, not the field's.
  const field = $("capture-anchor");
  const inUse = anchorInUse(on);
  if (inUse && (on || !field.dataset.typed) && document.activeElement !== field) field.value = inUse;
  field.disabled = on;
  const session = `Anchor session in use: ${field.value || "A"}.`;
  // A frozen controller is said here at once, where the operator presses Capture.
  const frozen = s?.settle_state === "frozen";
  $("capture-state").classList.toggle("bad", frozen);
  setText("capture-state", frozen ? `${readinessWords(s)} ${session}` : (on
    ? `Auto capture is on: ${samples.length} samples so far. Move the robot through the poses; each new still pose is captured once.`
    : manual ? "Manual robot: enter the six joint angles, then Capture now." : "Press Capture now when the robot stands still at a pose.") + ` ${session}`);
}

async function captureNow() {
  const body = { anchor: $("capture-anchor").value || "A" };
  if (isManualRobot()) {
    const form = $("manual-joints");
    if (!form.reportValidity()) return;
    body.joints_deg = JOINTS.map((q) => Number(form.elements[q].value));
  }
  const button = $("capture-now");
  button.disabled = true;
  setText(button, "Capturing … (waiting for the robot to settle)");
  const url = `/campaigns/${state.campaign.id}/captures`;
  try {
    let s;
    try {
      s = await api("POST", url, { json: body, quiet: true });
    } catch (exc) {
      // A pose the campaign has already (auto capture's rule): ask before storing it again.
      if (exc.status !== 409 || exc.body?.detail?.reason !== "not_new_pose") throw exc;
      dismiss("capture-repeat");
      if (!confirm(`This pose was captured already: ${exc.body.detail.detail.replace(/; move it.*$/, "")}.\n\nStore another sample at the same pose?`)) {
        showMessage("info", "Not captured: the robot stands at a pose the campaign has already. Move it to a new pose (or confirm the repeat).", "capture-repeat");
        return;
      }
      s = await api("POST", url, { json: { ...body, repeat: true } });
    }
    dismiss("POST /campaigns/{id}/captures");
    showMessage("info", `Sample #${s.id} captured: length ${fix(s.length_mm, 3)} mm (std ${fix(s.length_std_mm, 4)} mm over ${s.count} readings).`, "capture");
    if (isManualRobot()) $("manual-joints").reset();
  } catch (exc) {
    if (exc.status !== 401) showMessage("error", exc.message, "POST /campaigns/{id}/captures", exc.detail);
  } finally {
    button.disabled = false;
    setText(button, "Capture now");
  }
  await refreshDetail();
  await loadCampaigns();
}

// The operator's last switch of auto capture, kept on the box until the daemon's status says
// so (or 3 s pass); otherwise the box shows the daemon's state, focused or not: another tab
// may have switched it (item 20).
let autoWanted = null;

async function setAuto(enabled) {
  autoWanted = { enabled, until: Date.now() + 3000 };
  try {
    await api("PUT", `/campaigns/${state.campaign.id}/auto-capture`, { json: { enabled, anchor: $("capture-anchor").value || "A" } });
  } catch {
    autoWanted = null;
    $("auto-capture").checked = !enabled;
  }
  await loadCampaigns();
}

// ------------------------------------------------------------------ plan
/** Download buttons of the plan, one per format of the REST enum (CSV and the robot programs
 * the pendant runs); the file name is the one the daemon gives (a KRL or Fanuc program must
 * keep it). */
function renderPlanDownloads() {
  const box = $("plan-downloads");
  box.hidden = !plan || !state.downloadFormats.length;
  const key = box.hidden ? "" : `${state.campaign.id}:${plan.id}`;
  if (box.dataset.key === key) return; // drawn already: keep the buttons (and focus)
  box.dataset.key = key;
  if (box.hidden) return;
  const fetchOne = async (fmt, anchor) => {
    const q = anchor == null ? "" : `&anchor=${encodeURIComponent(anchor)}`;
    const r = await api("GET", `/campaigns/${state.campaign.id}/plan?format=${fmt}${q}`, { raw: true });
    const m = /filename="([^"]+)"/.exec(r.headers.get("Content-Disposition") || "");
    saveBlob(await r.blob(), m ? m[1] : `campaign-${state.campaign.id}-plan.${fmt}`);
  };
  // The sensor is moved by hand between anchors: one program per anchor (the CSV has all).
  const anchors = [...new Set(plan.poses.map((p) => p.anchor))];
  const choices = state.downloadFormats.flatMap((fmt) => (fmt === "csv" || anchors.length < 2
    ? [[fmt, null]] : anchors.map((a) => [fmt, a])));
  box.replaceChildren("Download the plan for the robot: ", ...choices.map(([fmt, anchor]) => {
    const label = anchor == null ? fmt : `${fmt} (sensor at ${anchor})`;
    const b = el("button", { type: "button", "data-format": fmt, "data-anchor": anchor, "aria-label": `Download the plan as ${label}` }, label);
    b.addEventListener("click", () => fetchOne(fmt, anchor).catch(() => {}));
    return b;
  }));
}

/** The plan form's pose count: at least the samples Identify needs, the recommended count by
 * default, both said next to it. The counts are the campaign's (the API's), for the anchors
 * its samples have; "add to the samples already taken" counts the included ones already there.
 * The largest count is the plan request's own bound (/openapi.json). */
function planCounts() {
  const c = state.campaign;
  const included = samples.filter((s) => !s.excluded).length;
  const onTop = $("plan-form").elements.start_from_samples.checked ? included : 0;
  const max = requestSchema("PlanRequest")?.properties?.n?.maximum ?? null;
  const min = Math.max(1, c.min_samples_to_identify - onTop);
  const recommended = Math.max(min, c.recommended_samples - onTop);
  return { min, recommended, max: max == null ? null : Math.max(min, max), onTop };
}

function renderPlanCount() {
  const input = $("plan-form").elements.n;
  const k = planCounts();
  input.min = String(k.min);
  if (k.max != null) input.max = String(k.max);
  if (!input.dataset.typed && document.activeElement !== input) input.value = String(k.recommended);
  const c = state.campaign;
  setText("plan-count-note", (k.onTop
    ? `On top of the ${k.onTop} included samples: at least ${k.min} more poses (Identify needs ${c.min_samples_to_identify} in all), ${k.recommended} recommended`
    : `At least ${k.min} poses (the fewest Identify accepts for this robot), ${k.recommended} recommended (from ${c.recommended_samples} samples the fit can also screen outliers)`) +
    (k.max != null ? `; at most ${k.max} per plan.` : "."));
}

/** Why the plan form cannot be sent, in words (null when it can). */
function planFormProblem(f) {
  const k = planCounts();
  const n = Number(f.n.value);
  if (f.n.value === "" || !Number.isInteger(n)) return `Poses: type a whole number from ${k.min}${k.max != null ? ` to ${k.max}` : ""}.`;
  if (n < k.min) return `Poses: ${n} is too few. Identify needs at least ${k.min}${k.onTop ? " more" : ""} poses; ${k.recommended} are recommended.`;
  if (k.max != null && n > k.max) return `Poses: at most ${k.max} per plan.`;
  const given = ["ax", "ay", "az"].filter((a) => f[a].value !== "");
  if (given.length && given.length < 3) return "Sensor position: give all three of x, y and z [mm], or none.";
  if (!given.length && !f.start_from_samples.checked) return "Give the sensor position x, y, z [mm] (roughly, within a few cm), or tick “add to the samples already taken”.";
  const coord = requestSchema("PlanRequest")?.properties?.min_z_mm;
  for (const a of given) {
    const v = Number(f[a].value);
    if (!Number.isFinite(v) || (coord?.minimum != null && v < coord.minimum) || (coord?.maximum != null && v > coord.maximum)) {
      return `Sensor position ${a.slice(1)}: ${f[a].value} mm is not a position in the cell (from ${coord?.minimum} to ${coord?.maximum} mm).`;
    }
  }
  return null;
}

function planFormError(message) {
  const node = $("plan-form-error");
  node.hidden = !message;
  setText(node, message || "");
}

async function refreshPlan() {
  if (!hasRoute("GET", "/campaigns/{}/plan")) {
    $("plan-form").querySelector("button").disabled = true;
    setText("plan-summary", "Pose planning is not available on this daemon (no plan route); capture poses of your own choosing.");
    return;
  }
  // The campaign says whether it has a plan (plan_id): no request, so no 404 in the console,
  // while it has none. A plan made elsewhere (cablecal plan) shows up with the 2 s refresh.
  const { id, plan_id: planId } = state.campaign;
  if (planId == null) { plan = null; renderPlan(); return; }
  try {
    plan = await api("GET", `/campaigns/${id}/plan`, { quiet: true, what: "The plan could not be read" });
    dismiss("plan");
  } catch (exc) {
    if (exc.status !== 404) showMessage("error", exc.message, "plan", exc.detail);
    plan = null;
  }
  renderPlan();
}

function renderPlan() {
  renderPlanDownloads();
  if (!plan) {
    setText("plan-summary", "No plan yet. A plan picks the poses that make the calibration most accurate; give the sensor position roughly (or plan on top of samples already taken).");
    fillTable($("plan-poses"), [], [], "none");
    return;
  }
  const tcp = plan.summary?.tcp_sigma_mm;
  const pr = plan.progress || {};
  setText("plan-summary", `${pr.n_planned} planned poses: ${pr.n_done} captured, ${pr.n_pending} to go` +
    (pr.next_pose != null ? ` (next: pose ${pr.next_pose})` : "") +
    (pr.n_not_capturable ? `, ${pr.n_not_capturable} not capturable (the sampler refused them; plan again to replace them)` : "") + "." +
    (tcp ? ` Predicted tool-point accuracy after calibration: ${fix(tcp.plan?.rms, 3)} mm RMS (1σ; max ${fix(tcp.plan?.max, 3)} mm), against ${fix(tcp.random?.rms, 3)} mm with as many random poses.` : "") +
    (plan.summary?.noise_mm ? ` It assumes ${fix(plan.summary.noise_mm, 4)} mm length noise per capture` +
      (plan.summary.noise_detail ? ` (${plan.summary.noise_detail}).` : ".") : ""));
  fillTable($("plan-poses"), [{ label: "pose", num: true }, ...JOINTS.map((q) => ({ label: `${q.replace("q", "J")} [deg]`, num: true })),
    { label: "anchor" }, { label: "status" }],
  plan.poses.map((p) => [String(p.pose), ...JOINTS.map((q) => fix(p[q], 2)), p.anchor,
    p.status === "not_capturable" ? el("span", { class: "pill warn", title: p.why || "" }, `not capturable: ${String(p.why || "").replace(/^over_range: /, "over range: ")}`)
      : el("span", { class: p.status === "done" ? "ok" : "muted" }, p.status === "done" ? `done (#${p.sample_id})` : "pending")]),
  JSON.stringify([plan.id, plan.poses.map((p) => p.status)]));
}

async function startPlan(ev) {
  ev.preventDefault();
  const f = ev.target.elements;
  const problem = planFormProblem(f);
  planFormError(problem);
  if (problem) return;
  const body = { n: Number(f.n.value), min_z_mm: Number(f.min_z_mm.value), seed: Number(f.seed.value),
    start_from_samples: f.start_from_samples.checked };
  if (f.ax.value !== "" || f.ay.value !== "" || f.az.value !== "") {
    body.anchors_mm = [[Number(f.ax.value), Number(f.ay.value), Number(f.az.value)]];
  }
  // New poses go to the anchor in use (after a sensor move: the new one, where captures go),
  // not to the campaign's first anchor (item 7).
  const current = $("capture-anchor").value || "A";
  if (body.anchors_mm || state.campaign.anchors.includes(current)) body.anchor_ids = [current];
  const button = ev.target.querySelector("button");
  button.disabled = true;
  $("plan-progress").hidden = false;
  $("plan-progress").firstElementChild.style.width = "100%";
  setText("plan-summary", `Planning ${body.n} poses … (the cell PC computes for up to a minute)`);
  try {
    plan = await api("POST", `/campaigns/${state.campaign.id}/plan`, { json: body });
    state.campaign.plan_id = plan.id;
  } finally {
    button.disabled = false;
    $("plan-progress").hidden = true;
  }
  renderPlan();
}

// ------------------------------------------------------------------ create
const MODEL_FILE = "__file__";
const UPLOADED = "robot:"; // value prefix of a model uploaded before: the robot that has it
let uploaded = new Map(); // option value -> the uploaded model mapping

/** The robot picker: every robot (GET /robots: its own name and model) and "a new robot";
 * the model picker: the built-in models (GET /robots/models), the models uploaded before
 * (each once, from the robots that have them) and a file. Kept as the operator left them
 * while the lists are the same. */
async function loadRobots() {
  const [robots, models] = await Promise.all([api("GET", "/robots"), api("GET", "/robots/models")]);
  builtins = models;
  const pick = $("robot-pick");
  const key = JSON.stringify(robots.map((r) => [r.id, r.name, r.model_name]));
  if (pick.dataset.key !== key) {
    const kept = pick.value;
    pick.replaceChildren(el("option", { value: "" }, "A new robot …"),
      ...robots.map((r) => el("option", { value: String(r.id) }, r.name === r.model_name ? r.name : `${r.name} (${r.model_name})`)));
    pick.value = [...pick.options].some((o) => o.value === kept) ? kept : "";
    pick.dataset.key = key;
  }
  const model = $("robot-model");
  const seen = new Set();
  uploaded = new Map();
  for (const r of robots.filter((x) => x.source === "uploaded")) {
    const same = JSON.stringify(r.model);
    if (seen.has(same)) continue;
    seen.add(same);
    uploaded.set(`${UPLOADED}${r.id}`, { model: r.model, label: `${r.model_name} (uploaded with robot ${r.name})` });
  }
  const modelKey = JSON.stringify([models.map((m) => m.name), [...uploaded.keys()]]);
  if (model.dataset.key !== modelKey) {
    const kept = model.value;
    const sorted = models.slice().sort((a, b) => Number(b.default) - Number(a.default));
    model.replaceChildren(
      el("optgroup", { label: "Built-in models" }, ...sorted.map((m) => el("option", { value: m.name },
        `${m.name} (${[m.maker?.toUpperCase(), m.title].filter(Boolean).join(" ") || "built-in"})`))),
      ...(uploaded.size ? [el("optgroup", { label: "Models uploaded before" },
        ...[...uploaded].map(([value, u]) => el("option", { value }, u.label)))] : []),
      el("option", { value: MODEL_FILE }, "From a model file (.toml or .json) …"));
    if ([...model.options].some((o) => o.value === kept)) model.value = kept;
    model.dataset.key = modelKey;
  }
  preselectModel();
  showRobotFields();
}

let builtins = []; // GET /robots/models: name, default, maker, title

/** Until the operator picks a model, the picker shows the model of the connected controller's
 * maker (the robot driver's, GET /status devices.robot.maker): the default model when it is
 * that maker's, else that maker's first; the note says which controller it is. */
function preselectModel() {
  const model = $("robot-model");
  const robotDevice = Object.values(state.status?.devices || {}).find((d) => d.role === "robot");
  const maker = robotDevice?.maker || null;
  const note = $("robot-model-note");
  const mine = builtins.filter((m) => maker && m.maker === maker);
  const pickFor = mine.find((m) => m.default) || mine[0] || builtins.find((m) => m.default);
  if (!model.dataset.chosen && pickFor && model.value !== pickFor.name) model.value = pickFor.name;
  setText(note, (maker
    ? `The connected controller is ${maker.toUpperCase()}'s (driver ${robotDevice.driver})${mine.length ? `: its ${mine.length === 1 ? "model is" : `${mine.length} models are`} ${mine.map((m) => m.name).join(", ")}` : ": no built-in model of that maker; give a model file"}. `
    : robotDevice ? `The connected controller (driver ${robotDevice.driver}) does not say its maker. ` : "")
    + "Pick the arm's model, or give a model file: TOML or JSON (name, convention, tool_mm, one [[joints]] table per joint; see examples/hsr-jr680.toml).");
}

function showRobotFields() {
  const f = $("campaign-form").elements;
  $("new-robot").hidden = f.robot_id.value !== "";
  const file = f.robot_model.value === MODEL_FILE;
  $("robot-file-label").hidden = !file;
  $("robot-file-note").hidden = !file;
}

async function createCampaign(ev) {
  ev.preventDefault();
  const f = ev.target.elements;
  const body = { name: f.name.value.trim(), notes: f.notes.value };
  if (f.robot_id.value !== "") {
    body.robot_id = Number(f.robot_id.value);
  } else {
    if (f.robot.value.trim()) body.robot = f.robot.value.trim();
    if (f.robot_model.value === MODEL_FILE) {
      const file = f.robot_file.files[0];
      if (!file) { showMessage("error", "The campaign was not created: choose the robot's model file (.toml or .json).", "campaign-form"); return; }
      body.robot_model_file = { filename: file.name, text: await file.text() };
    } else if (uploaded.has(f.robot_model.value)) {
      body.robot_model = uploaded.get(f.robot_model.value).model; // a model uploaded before
    } else if (f.robot_model.value) {
      body.robot_model = f.robot_model.value; // else (list not loaded yet) the API's default
    }
  }
  const c = await api("POST", "/campaigns", { json: body });
  dismiss("campaign-form");
  ev.target.reset();
  await loadRobots();
  await loadCampaigns();
  await select(c);
  showMessage("info", `Campaign #${c.id} "${c.name}" created on robot ${c.robot_name}. Plan poses or start capturing.`, "created");
}

export async function restoreCampaign() {
  await loadRobots();
  const id = Number(sessionStorage.getItem(CAMPAIGN_KEY));
  const items = await loadCampaigns();
  // A fresh tab opens the newest operator campaign, not a hold check's own campaign
  // (daemon.monitors.holdcheck notes those "hold check (…)").
  const own = items.filter((x) => !String(x.notes || "").startsWith("hold check"));
  const c = items.find((x) => x.id === id) || own[own.length - 1] || items[items.length - 1] || null;
  if (c) await select(c);
}

export function initCampaign() {
  $("campaign-form").addEventListener("submit", (ev) => createCampaign(ev).catch(() => {}));
  $("robot-pick").addEventListener("change", showRobotFields);
  $("campaign-show-checks").addEventListener("change", () => loadCampaigns().catch(() => {}));
  $("robot-model").addEventListener("change", (ev) => { ev.target.dataset.chosen = "1"; showRobotFields(); });
  $("campaign-form").addEventListener("reset", () => setTimeout(() => { delete $("robot-model").dataset.chosen; loadRobots().catch(() => {}); }));
  $("plan-form").addEventListener("submit", (ev) => startPlan(ev).catch(() => {}));
  $("plan-form").addEventListener("input", (ev) => {
    if (ev.target.name === "n") ev.target.dataset.typed = "1";
    if (ev.target.name === "start_from_samples" && state.campaign) renderPlanCount();
    // the form's error is the form's: it goes as soon as the form is right again
    if (!$("plan-form-error").hidden) planFormError(planFormProblem(ev.currentTarget.elements));
  });
  $("capture-anchor").addEventListener("input", (ev) => { ev.target.dataset.typed = "1"; });
  $("capture-now").addEventListener("click", () => captureNow());
  $("auto-capture").addEventListener("change", (ev) => setAuto(ev.target.checked));
  $("download-samples").addEventListener("click", () => download(`/campaigns/${state.campaign.id}/samples?format=csv`, `campaign-${state.campaign.id}-samples.csv`).catch(() => {}));
  onChange((kind) => {
    if (kind === "status" && state.view === "campaign" && state.campaign) renderCaptureState();
    if (kind === "status" && state.view === "campaign") preselectModel();
  });
  every(2000, async () => { await loadCampaigns(); await refreshDetail(); }, () => state.view === "campaign");
}
