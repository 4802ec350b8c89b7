// View 4, Apply: compensate pasted or uploaded targets with the robot's calibrated model, and
// the hold-check state and history (the ``hold_check`` block of /status).
import { api, download, saveBlob } from "./api.js";
import { initFilter, renderFilterTarget } from "./filter.js";
import { $, clock, dismiss, el, every, fillTable, fix, hasRoute, onChange, setText, showMessage, sig, state } from "./ui.js";

let lastCsv = null;

function cell(v) {
  if (typeof v === "number") return Number.isInteger(v) ? String(v) : sig(v, 6);
  if (typeof v === "boolean") return v ? "yes" : "no";
  if (v == null) return "–";
  if (Array.isArray(v)) return v.map((x) => (typeof x === "number" ? fix(x, 3) : String(x))).join(", ");
  return typeof v === "object" ? JSON.stringify(v) : String(v);
}

/** The example and the IK seed from the robot's joint limits (GET /robots/{id}): the middle
 * of each joint's range, so the example is inside the limits whatever the robot. */
let exampleFor = null;
async function loadExample() {
  const c = state.campaign;
  if (!c || exampleFor === c.robot_id) return;
  const robot = await api("GET", `/robots/${c.robot_id}`);
  const mids = (robot.model?.joints || []).map((j) => (j.limits_deg ? (j.limits_deg[0] + j.limits_deg[1]) / 2 : 0));
  if (mids.length !== 6) return;
  const text = mids.map((v) => fix(v, 1)).join(",");
  const f = $("compensate-form").elements;
  f.csv.placeholder = `q1,q2,q3,q4,q5,q6\n${text}\n\nor x,y,z [mm] (+ rx,ry,rz [deg]) with the IK seed below`;
  if (!f.seed.value) f.seed.value = text;
  exampleFor = c.robot_id;
}

async function compensate(ev) {
  ev.preventDefault();
  const c = state.campaign;
  if (!hasRoute("POST", "/robots/{}/compensate")) {
    showMessage("error", "The program was not compensated: this daemon cannot compensate (it has no compensation route).", "compensate", "no route POST /robots/{id}/compensate in /openapi.json");
    return;
  }
  if (!c) { showMessage("error", "The program was not compensated: select the campaign of the robot first (tab 2).", "compensate"); return; }
  const f = ev.target.elements;
  const file = f.file.files[0];
  const text = file ? await file.text() : f.csv.value;
  if (!text.trim()) { showMessage("error", "The program was not compensated: paste targets (CSV with q1..q6 in deg) or choose a file.", "compensate"); return; }
  const seed = f.seed.value.trim().split(/[\s,]+/).filter(Boolean);
  if (seed.length && (seed.length !== 6 || seed.some((v) => !Number.isFinite(Number(v))))) {
    setText("compensate-state", `The program was not compensated: the IK seed needs six joint angles q1..q6 in deg, comma-separated (got “${f.seed.value}”).`);
    return;
  }
  const query = seed.length ? `?seed_deg=${encodeURIComponent(seed.join(","))}` : "";
  setText("compensate-state", "Compensating …");
  let out;
  try {
    out = await api("POST", `/robots/${c.robot_id}/compensate${query}`, { body: text, type: "text/csv", quiet: true });
  } catch (exc) {
    const text = exc.status === 404 ? `The program was not compensated: robot ${c.robot_name} has no accepted calibration yet (accept one in tab 3).` : exc.message;
    setText("compensate-state", text);
    showMessage("error", text, "compensate", exc.detail);
    return;
  }
  dismiss("compensate");
  const rows = out.rows || [];
  const show = [["q1", "J1 [deg]", 4], ["q2", "J2 [deg]", 4], ["q3", "J3 [deg]", 4], ["q4", "J4 [deg]", 4],
    ["q5", "J5 [deg]", 4], ["q6", "J6 [deg]", 4], ["max_correction_deg", "largest correction [deg]", 3],
    ["uncompensated_error_mm", "error removed [mm]", 3], ["residual_mm", "IK residual [mm]", null], ["flags", "flags", null]];
  fillTable($("compensate-result"), [{ label: "#", num: true }, ...show.map(([, label, d]) => ({ label, num: d !== null || label.includes("[") }))],
    rows.map((r, i) => [String(i + 1), ...show.map(([k, , d]) => (k === "flags" ? el("span", { class: r[k] ? "bad" : "" }, flagWords(r[k]))
      : d == null ? sig(r[k], 2) : fix(r[k], d)))]));
  // The server's own CSV (every column, nominal joints too), for the controller program.
  lastCsv = await api("POST", `/robots/${c.robot_id}/compensate${query}`, { body: text, type: "text/csv", accept: "text/csv" });
  $("compensate-download").hidden = false;
  const m = out.summary || {};
  setText("compensate-state", `${m.n ?? rows.length} ${out.kind === "joints" ? "joint-space" : out.kind || ""} targets compensated (${out.mode || "position"} mode) with the accepted calibration of ${c.robot_name}: ` +
    `largest joint correction ${fix(m.max_correction_deg, 3)} deg, tool-point error removed ${fix(m.rms_uncompensated_error_mm, 3)} mm RMS, ` +
    `largest IK residual ${sig(m.max_residual_mm, 2)} mm, ${m.n_flagged ?? 0} flagged.`);
  setText("compensate-note", out.note || "");
  $("compensate-download").onclick = () => saveBlob(new Blob([lastCsv], { type: "text/csv" }), `robot-${c.robot_id}-compensated.csv`);
}

// The filter card is filter.js's (initFilter, renderFilterTarget).

/** ``outside_limits:J3=-80.000<-75.000`` → "J3 -80.000 deg below its limit -75.000 deg". */
function flagWords(flags) {
  if (!flags) return "ok";
  return flags.split(";").map((f) => {
    const m = /^outside_limits:J(\d)=([-0-9.]+)([<>])([-0-9.]+)$/.exec(f);
    return m ? `J${m[1]} ${m[2]} deg ${m[3] === "<" ? "below" : "above"} its limit ${m[4]} deg` : f.replaceAll("_", " ");
  }).join("; ");
}

const HOLD_WORDS = {
  ok: "Last hold check OK: the robot still holds its calibration.",
  not_held: "NOT HELD: the last check is above the threshold.",
  failed: "The last hold check failed.",
  none: "No hold check yet.",
};

/** The hold-check block's headline: what moved (the API's own explanation, ``cause.text``,
 * with its figure) when not held, the reason at a failure. */
function holdHeadline(hold) {
  const words = HOLD_WORDS[hold.state] || hold.state;
  if (hold.state === "not_held" && hold.cause) {
    const who = { sensor: "SENSOR MOVED", robot: "ROBOT CHANGED", unclear: "NOT HELD" }[hold.cause.kind] || "NOT HELD";
    return `${who}: ${hold.cause.text.replace(/^./, (c) => c.toUpperCase())}.`;
  }
  if (hold.state === "not_held") return `${words} Calibrate the robot again.`;
  if (hold.state === "failed" && hold.error) return `${words} Why: ${hold.error}.`;
  return words;
}

async function renderHoldCheck() {
  const hold = state.status?.hold_check;
  const node = $("hold-check-state");
  if (!hold) {
    setText(node, "Hold checks are not available on this daemon.");
    $("hold-check-start").disabled = true;
    return;
  }
  node.className = `sentence ${hold.state === "not_held" || hold.state === "failed" ? "bad" : hold.state === "ok" ? "ok" : ""}`;
  const last = hold.last_check_at ? ` Check #${hold.check_id} at ${clock(hold.last_check_at)}: ${fix(hold.rms_mm, 3)} mm RMS against a threshold of ${fix(hold.threshold_mm, 3)} mm.` : "";
  const running = hold.running ? ` Check #${hold.running} is running: move the robot through the check poses.` : "";
  const every = hold.check_interval_h ? ` Scheduled every ${hold.check_interval_h} h.` : " No scheduled checks.";
  setText(node, `${holdHeadline(hold)}${last}${running}${every}`);
  const c = state.campaign;
  if (!c || !hasRoute("GET", "/robots/{}/checks")) return;
  const list = await api("GET", `/robots/${c.robot_id}/checks`);
  const items = (Array.isArray(list) ? list : list.items || []).slice().reverse();
  fillTable($("hold-check-history"), [{ label: "#", num: true }, { label: "started" }, { label: "trigger" }, { label: "status" },
    { label: "RMS [mm]", num: true }, { label: "max [mm]", num: true }, { label: "threshold [mm]", num: true },
    { label: "poses", num: true }, { label: "samples used", num: true }, { label: "why", class: "keep" }],
  items.map((k) => [String(k.id), clock(k.started_at), k.trigger,
    el("span", { class: k.status === "ok" ? "ok" : k.status === "running" ? "" : "bad" }, k.status),
    fix(k.rms_mm, 3), fix(k.max_mm, 3), fix(k.threshold_mm, 3), String((k.poses_deg || []).length), k.n == null ? "–" : String(k.n),
    k.error || ""]),
  JSON.stringify(items.map((k) => [k.id, k.status, k.error])));
  await renderCheckPoses(c, items.find((k) => k.status === "running"));
}

/** The check poses (of the running check, else the robot's), and while a check runs how many
 * of them are captured so far (samples in the check's own campaign). */
async function renderCheckPoses(c, running) {
  let poses;
  try {
    poses = running ? running.poses_deg : (await api("GET", `/robots/${c.robot_id}/check-poses`, { quiet: true })).poses_deg;
  } catch (exc) {
    if (exc.status !== 404) throw exc;
    // No accepted calibration yet: there is nothing to check against, so no check poses.
    fillTable($("hold-check-poses"), [], [], "none");
    $("hold-check-downloads").hidden = true;
    setText("hold-check-poses-note", `Robot ${c.robot_name} has no accepted calibration yet: a hold check compares against one (accept a result in tab 3).`);
    return;
  }
  let done = null;
  if (running) done = (await api("GET", `/campaigns/${running.campaign_id}`)).n_included;
  renderCheckDownloads(c);
  fillTable($("hold-check-poses"), [{ label: "pose", num: true }, ...[1, 2, 3, 4, 5, 6].map((j) => ({ label: `J${j} [deg]`, num: true })), { label: "state" }],
    poses.map((q, i) => [String(i + 1), ...q.map((v) => fix(v, 1)), done == null ? "" : i < done ? "captured" : i === done ? "next" : ""]),
    JSON.stringify([poses, done]));
  setText("hold-check-poses-note", running
    ? `Check #${running.id}: ${Math.min(done, poses.length)} of ${poses.length} poses captured. Move the robot through the poses below; auto capture records each one.`
    : `${poses.length} check poses: a hold check moves through these.`);
}

/** Download buttons of the check poses, one per format of the REST enum (the plan's: CSV
 * and the robot programs), from the check poses' own route; the file name is the daemon's. */
function renderCheckDownloads(c) {
  const box = $("hold-check-downloads");
  box.hidden = !state.downloadFormats.length;
  const key = box.hidden ? "" : String(c.robot_id);
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  if (box.hidden) return;
  const fetchOne = async (fmt) => {
    const r = await api("GET", `/robots/${c.robot_id}/check-poses?format=${fmt}`, { raw: true, what: "The check poses could not be downloaded" });
    const m = /filename="([^"]+)"/.exec(r.headers.get("Content-Disposition") || "");
    saveBlob(await r.blob(), m ? m[1] : `robot-${c.robot_id}-check-poses.${fmt}`);
  };
  box.replaceChildren("Download the check poses for the robot: ", ...state.downloadFormats.map((fmt) => {
    const b = el("button", { type: "button", class: "secondary small", "data-format": fmt, "aria-label": `Download the check poses as ${fmt}` }, fmt);
    b.addEventListener("click", () => fetchOne(fmt).catch(() => {}));
    return b;
  }));
}

/** Start a hold check. A check records its poses with auto capture, so while auto capture
 * runs for a campaign the operator is asked first: switch it off and start, or keep it and
 * be told in words why no check started. */
async function startHoldCheck() {
  const c = state.campaign;
  if (!c) { showMessage("error", "The hold check did not start: select the campaign of the robot first (tab 2).", "hold-check"); return; }
  const s = state.status?.sampler;
  if (s?.mode === "auto" && s.auto_campaign_id != null) {
    const busy = s.auto_campaign_id;
    const ok = confirm(`Auto capture is on for campaign #${busy}. A hold check needs auto capture for its own poses.\n\n`
      + `Switch auto capture off for campaign #${busy} and start the check? (Switch it on again in tab 2 afterwards.)`);
    if (!ok) {
      showMessage("warn", `No hold check started: auto capture is still on for campaign #${busy}. A check needs it for its own poses; switch it off in tab 2 (or answer OK here) to start one.`, "hold-check-auto");
      return;
    }
    await api("PUT", `/campaigns/${busy}/auto-capture`, { json: { enabled: false } });
  }
  const k = await api("POST", `/robots/${c.robot_id}/checks`);
  dismiss("hold-check-auto");
  showMessage("info", `Hold check #${k.id} started: auto capture now records the check poses. Run the check poses on the robot (download them below).`, "hold-check");
}

export function initApply() {
  initFilter();
  $("compensate-form").addEventListener("submit", (ev) => compensate(ev).catch(() => {}));
  $("hold-check-start").addEventListener("click", () => startHoldCheck().catch(() => {}));
  every(3000, renderHoldCheck, () => state.view === "apply");
  onChange((kind) => {
    // the "auto capture is still on" warning goes once auto capture is off (its cause)
    if (kind === "status" && state.status?.sampler?.mode !== "auto") dismiss("hold-check-auto");
    if (kind === "campaign" && state.view === "apply") renderFilterTarget().catch(() => {});
    if (kind === "view" && state.view === "apply") {
      renderHoldCheck().catch(() => {});
      loadExample().catch(() => {});
      renderFilterTarget().catch(() => {});
    }
  });
}
